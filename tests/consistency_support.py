"""RMS(ε/σ) of the horizontal position pooled over runs, for the statistical tests."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from fusion.engine import RunResult
from fusion.metrics import interpolate_truth
from fusion.recording import Recording


def pooled_horizontal_z(runs: Iterable[tuple[RunResult, Recording]]) -> float:
    """RMS of east and north error ÷ σ over every epoch of every run (within its truth)."""
    sumsq, count = 0.0, 0
    for result, recording in runs:
        assert recording.truth is not None
        inside, truth, *_ = interpolate_truth(recording.truth, result.solution.t)
        error = result.solution.position[inside, :2] - truth[:, :2]
        z = error / result.solution.sigma_position[inside, :2]
        sumsq += float(np.sum(z**2))
        count += z.size
    return math.sqrt(sumsq / count)
