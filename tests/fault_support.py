"""Fault-injection helpers shared by the tests: a clean/faulty pair of recordings, the
maximum horizontal error of a run (``horizontal_max`` of :func:`fusion.metrics.compute_metrics`),
its RMS(ε/σ) east and north, and a configuration with the UWB plugin's NLOS test off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.config import FusionConfig, parse_config
from fusion.engine import RunResult
from fusion.metrics import compute_metrics, interpolate_truth
from fusion.recording import Recording, read_recording
from fusion.sim.simulate import simulate

# longwall-200m seed 4: 30 s static, then along the first 35 m of the face (UWB in reach) for
# the rest of the recording (370 s in 400).
MID_FACE = ["static_start_s=30"]


def clean_and_faulty(
    tmp_path: Path, fault: str, duration_s: float = 400.0, uwb_rate_hz: float = 10.0
) -> tuple[Recording, Recording]:
    """``longwall-200m`` seed 4 over :data:`MID_FACE` (cut to ``duration_s``), without and with
    ``fault`` (a ``faults=[…]`` override). Each anchor is ranged at ``uwb_rate_hz``: 10 Hz as
    in the random worlds' rounds (5–20 Hz), where the preset's 40 Hz makes every federated run
    four times the work."""
    overrides = [*MID_FACE, f"duration_s={duration_s}", f"uwb.rate_hz={uwb_rate_hz}"]
    simulate("longwall-200m", tmp_path / "clean", seed=4, overrides=overrides)
    simulate("longwall-200m", tmp_path / "faulty", seed=4, overrides=[*overrides, fault])
    return read_recording(tmp_path / "clean"), read_recording(tmp_path / "faulty")


def max_horizontal(result: RunResult, rec: Recording) -> float:
    """Largest horizontal position error of ``result`` against ``rec``'s truth (m)."""
    assert rec.truth is not None
    return float(compute_metrics(result.solution, rec.truth)["horizontal_max"])


def normalized_rms(result: RunResult, rec: Recording) -> NDArray[np.float64]:
    """RMS(ε/σ) of ``result``'s east and north positions against ``rec``'s truth."""
    assert rec.truth is not None
    inside, position, *_ = interpolate_truth(rec.truth, result.solution.t)
    error = result.solution.position[inside, :2] - position[:, :2]
    ratio = error / result.solution.sigma_position[inside, :2]
    return np.asarray(np.sqrt(np.mean(ratio**2, axis=0)))


def without_nlos_test(config: FusionConfig) -> FusionConfig:
    """``config`` with every ``uwb`` block's ``nlos_test`` off: NLOS left to the gate and to
    the federated master's isolation."""
    data = config.model_dump()
    for block in data["plugins"]:
        if block["type"] == "uwb":
            block["nlos_test"] = False
    return parse_config(data)
