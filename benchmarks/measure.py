"""Child process of the speed suite: ``python -m benchmarks.measure CONFIG.yaml RECORDING``.

Reads the recording, runs the engine once and prints JSON ``{wall_s, duration_s,
realtime_factor, read_s, smoother_peak_steps, peak_rss_mb}`` on stdout. ``wall_s`` is the
engine's run time (reading the recording is reported apart as ``read_s``); ``peak_rss_mb`` is
this process's peak resident memory (interpreter, imports, recording and run together): the
high-water mark ``VmHWM`` of its own address space on Linux. ``getrusage``'s ``ru_maxrss`` is
not used on Linux because it survives ``exec``: a child forked from a parent holding 300 MB
would report the parent's 300 MB. Elsewhere it is the fallback.
"""

from __future__ import annotations

import json
import resource
import sys
import time
from pathlib import Path

from fusion.config import load_config
from fusion.engine import Engine
from fusion.recording import read_recording


def peak_rss_mb() -> float:
    """Peak resident memory of this process (MiB: VmHWM kB / 1024)."""
    try:
        for line in Path("/proc/self/status").read_text(encoding="utf-8").splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024.0 if sys.platform != "darwin" else rss / 1024.0**2


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
        "peak_rss_mb": peak_rss_mb(),
    }
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
