"""Fault-injection helpers shared by the tests: a clean/faulty pair of recordings and the
maximum horizontal error of a run (``horizontal_max`` of :func:`fusion.metrics.compute_metrics`).
"""

from __future__ import annotations

from pathlib import Path

from fusion.engine import RunResult
from fusion.metrics import compute_metrics
from fusion.recording import Recording, read_recording
from fusion.sim.simulate import simulate

# longwall-200m seed 4: 30 s static, then 370 s along the first 35 m of the face (UWB in reach).
MID_FACE = ["static_start_s=30", "duration_s=400"]


def clean_and_faulty(tmp_path: Path, fault: str) -> tuple[Recording, Recording]:
    """``longwall-200m`` seed 4 over :data:`MID_FACE`, without and with ``fault`` (a
    ``faults=[…]`` override)."""
    simulate("longwall-200m", tmp_path / "clean", seed=4, overrides=MID_FACE)
    simulate("longwall-200m", tmp_path / "faulty", seed=4, overrides=[*MID_FACE, fault])
    return read_recording(tmp_path / "clean"), read_recording(tmp_path / "faulty")


def max_horizontal(result: RunResult, rec: Recording) -> float:
    """Largest horizontal position error of ``result`` against ``rec``'s truth (m)."""
    assert rec.truth is not None
    return float(compute_metrics(result.solution, rec.truth)["horizontal_max"])
