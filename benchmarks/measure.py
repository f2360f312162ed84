"""Child process of the speed suite: ``python -m benchmarks.measure CONFIG.yaml RECORDING``.

Reads the recording, runs the engine once and prints JSON ``{wall_s, duration_s,
realtime_factor, read_s, smoother_peak_steps}`` on stdout. ``wall_s`` is the engine's run time
(reading the recording is reported apart as ``read_s``); the parent reads this process's peak
resident memory from the operating system when it exits (imports, recording and run together).
"""

from __future__ import annotations

import json
import sys
import time

from fusion.config import load_config
from fusion.engine import Engine
from fusion.recording import read_recording


def main(argv: list[str]) -> int:
    """Run one configuration on one recording and print the timing as JSON."""
    if len(argv) != 2:
        print("usage: python -m benchmarks.measure CONFIG.yaml RECORDING_DIR", file=sys.stderr)
        return 2
    config = load_config(argv[0])
    start = time.perf_counter()
    recording = read_recording(argv[1], bridge_imu_gaps=config.bridge_imu_gaps)
    read_s = time.perf_counter() - start
    result = Engine(config, recording).run()
    figures = {
        "wall_s": result.wall_time_s,
        "duration_s": result.duration_s,
        "realtime_factor": result.realtime_factor,
        "read_s": read_s,
        "smoother_peak_steps": float(result.smoother_peak_steps),
    }
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
