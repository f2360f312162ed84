"""Accuracy metrics of a trajectory estimate against the reference trajectory (``truth.csv``).

:func:`compute_metrics` scores the estimate at the truth's epochs and summarizes the errors
(estimate minus truth) in a JSON-serializable dict; :func:`write_metrics_json` writes the
``metrics.json`` of ``fusion run`` (one entry per solution file).

Conventions
-----------
* Errors are taken at the truth epochs inside the solution's time span, the solution (and its
  sigma or covariance) interpolated linearly onto them (:func:`interpolate_solution`): a truth
  sampled at 1 Hz through a turn is then never replaced by its chord.  Attitude angles are
  unwrapped along time before the linear interpolation, and every attitude error is wrapped to
  ``[-180, 180)`` degrees.  Solution epochs outside the truth's time span are not scored
  (counted in ``epochs_excluded``), nor truth epochs outside the solution's
  (``truth_epochs_excluded``).
* ``std`` is the population standard deviation (``ddof=0``), so ``rms² = mean² + std²``.
* The cutting cycle of an epoch is the truth's ``cycle`` there.  ``sep_per_cycle[c]`` is the
  spherical error probable of cycle ``c >= 1``, taken here as the empirical median of the 3-D
  position error norm (the radius of the sphere holding 50 % of the epochs of that cycle);
  ``None`` when no epoch is scored in that cycle.  ``sep`` is the same over all epochs.
* ``nees`` checks the filter's consistency: ``normalized_rms`` is ``RMS(error / sigma)`` per
  axis (1 for a consistent filter), with sigma from the diagonal of ``position_covariance`` when
  the solution has one (``source: "covariance"``), else from ``sigma_position``.  With a covariance
  it also holds ``mean_3d``, the mean 3-D position NEES ``eᵀ P⁻¹ e`` (3 for a consistent filter),
  and ``fraction_within_95``, the fraction of epochs whose NEES lies below the 95 % point of the
  χ²(3) distribution.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from fusion.recording import FloatArray, TruthData
from fusion.solution import Solution

__all__ = [
    "SolutionAt",
    "compute_metrics",
    "interpolate_solution",
    "interpolate_truth",
    "write_metrics_json",
]

_AXES = ("e", "n", "u")
_ANGLES = ("roll", "pitch", "yaw")


def _wrap_pi(angle: FloatArray) -> FloatArray:
    """Wrap angles (rad) to ``[-pi, pi)``."""
    return np.asarray((angle + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def interpolate_truth(
    truth: TruthData, t: FloatArray
) -> tuple[np.ndarray, FloatArray, FloatArray, FloatArray, np.ndarray]:
    """Truth at the epochs ``t`` that lie inside its time span.

    Parameters
    ----------
    truth : TruthData
        Reference trajectory.
    t : ndarray, shape (N,)
        Epochs (s).

    Returns
    -------
    inside : ndarray of bool, shape (N,)
        Epochs within ``[truth.t[0], truth.t[-1]]``; the other outputs have one row per such
        epoch.
    position, velocity : ndarray, shape (M, 3)
        Linearly interpolated ENU position (m) and velocity (m/s).
    attitude : ndarray, shape (M, 3)
        Roll, pitch, yaw (rad), interpolated after unwrapping (so possibly outside ±pi).
    cycle : ndarray of int64, shape (M,)
        Cycle of the last truth sample at or before each epoch.
    """
    t = np.asarray(t, dtype=np.float64)
    if truth.t.size == 0:
        empty = np.empty((0, 3))
        return np.zeros(t.shape, dtype=bool), empty, empty, empty, np.empty(0, dtype=np.int64)
    inside = (t >= truth.t[0]) & (t <= truth.t[-1])
    ti = t[inside]
    att = np.unwrap(truth.attitude, axis=0)

    def interp(values: FloatArray) -> FloatArray:
        return np.column_stack([np.interp(ti, truth.t, values[:, k]) for k in range(3)])

    idx = np.clip(np.searchsorted(truth.t, ti, side="right") - 1, 0, truth.t.size - 1)
    return (
        inside,
        interp(truth.position),
        interp(truth.velocity),
        interp(att),
        truth.cycle[idx].astype(np.int64),
    )


@dataclass(frozen=True)
class SolutionAt:
    """A solution interpolated linearly onto given epochs (:func:`interpolate_solution`)."""

    inside: NDArray[np.bool_]
    """Epochs within the solution's time span; the arrays below have one row per such epoch."""
    t: FloatArray
    position: FloatArray
    velocity: FloatArray
    attitude: FloatArray
    """Roll, pitch, yaw (rad), interpolated after unwrapping (so possibly outside ±pi)."""
    sigma_position: FloatArray
    position_covariance: FloatArray | None
    """Element-wise interpolation of the covariance (a convex combination: still PSD)."""


def interpolate_solution(solution: Solution, t: FloatArray) -> SolutionAt:
    """``solution`` at the epochs ``t`` (s) that lie inside its time span."""
    t = np.asarray(t, dtype=np.float64)
    st = solution.t
    inside = (t >= st[0]) & (t <= st[-1]) if st.size else np.zeros(t.shape, dtype=bool)
    ti = t[inside]

    def interp(values: FloatArray) -> FloatArray:
        flat = values.reshape(values.shape[0], -1)
        cols = [np.interp(ti, st, flat[:, k]) for k in range(flat.shape[1])]
        return np.stack(cols, axis=-1).reshape((ti.size, *values.shape[1:]))

    cov = solution.position_covariance
    return SolutionAt(
        inside=inside,
        t=ti,
        position=interp(solution.position),
        velocity=interp(solution.velocity),
        attitude=interp(np.unwrap(solution.attitude, axis=0)),
        sigma_position=interp(solution.sigma_position),
        position_covariance=None if cov is None else interp(cov),
    )


def _f(x: Any) -> float | None:
    """A JSON-safe float (None for NaN/inf)."""
    value = float(x)
    return value if math.isfinite(value) else None


def _axis_stats(err: FloatArray) -> dict[str, float | None]:
    return {
        "max_abs": _f(np.max(np.abs(err))),
        "mean_abs": _f(np.mean(np.abs(err))),
        "mean": _f(np.mean(err)),
        "std": _f(np.std(err)),
        "rms": _f(np.sqrt(np.mean(err**2))),
    }


def _normalized_rms(err: FloatArray, sigma: FloatArray) -> dict[str, float | None]:
    out: dict[str, float | None] = {}
    for k, axis in enumerate(_AXES):
        ok = np.isfinite(sigma[:, k]) & (sigma[:, k] > 0)
        ratio = err[ok, k] / sigma[ok, k]
        out[axis] = _f(np.sqrt(np.mean(ratio**2))) if ratio.size else None
    return out


def _nees(err: FloatArray, at: SolutionAt) -> dict[str, Any]:
    p = at.position_covariance
    if p is None:
        return {
            "source": "sigma_position",
            "normalized_rms": _normalized_rms(err, at.sigma_position),
        }
    sigma = np.sqrt(np.clip(np.diagonal(p, axis1=1, axis2=2), 0.0, None))
    try:
        sol = np.linalg.solve(p, err[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        sol = np.einsum("nij,nj->ni", np.linalg.pinv(p), err)
    nees = np.einsum("ni,ni->n", err, sol)
    bound = float(chi2.ppf(0.95, df=3))
    return {
        "source": "covariance",
        "normalized_rms": _normalized_rms(err, sigma),
        "mean_3d": _f(np.mean(nees)),
        "fraction_within_95": _f(np.mean(nees <= bound)),
        "chi2_95_bound": bound,
    }


def compute_metrics(solution: Solution, truth: TruthData) -> dict[str, Any]:
    """Errors of ``solution`` against ``truth``, as a JSON-serializable dict.

    Parameters
    ----------
    solution : Solution
        The estimate (``solution.csv`` or ``smoothed.csv`` contents).
    truth : TruthData
        The reference trajectory.

    Returns
    -------
    dict
        ``epochs`` (truth epochs scored), ``epochs_excluded`` (solution epochs outside the
        truth's span), ``truth_epochs_excluded`` (truth epochs outside the solution's span),
        ``t_start``, ``t_end`` (first and last epoch scored);
        ``position`` {axis e/n/u: {max_abs, mean_abs, mean, std, rms}} (m);
        ``horizontal_rms``, ``horizontal_max``, ``rms_3d``, ``max_3d`` (m);
        ``velocity`` {axis: {rms, max_abs}} (m/s);
        ``attitude_deg`` {roll/pitch/yaw: {rms, max_abs, mean}} (degrees);
        ``sep`` and ``sep_per_cycle`` {cycle (int): SEP or None} (m); ``nees`` (see the module
        docstring).

    Raises
    ------
    ValueError
        When no truth epoch lies inside the solution's time span.
    """
    at = interpolate_solution(solution, truth.t)
    used = at.t.size
    if used == 0:
        raise ValueError("no truth epoch lies inside the time span of the solution")
    err = at.position - truth.position[at.inside]
    verr = at.velocity - truth.velocity[at.inside]
    aerr = np.rad2deg(_wrap_pi(at.attitude - truth.attitude[at.inside]))
    cycle = truth.cycle[at.inside]
    outside = (solution.t < truth.t[0]) | (solution.t > truth.t[-1])
    horiz = np.hypot(err[:, 0], err[:, 1])
    norm3 = np.linalg.norm(err, axis=1)

    sep_per_cycle: dict[int, float | None] = {}
    for c in np.unique(truth.cycle):
        if c >= 1:
            sel = cycle == c
            sep_per_cycle[int(c)] = _f(np.median(norm3[sel])) if sel.any() else None

    return {
        "epochs": used,
        "epochs_excluded": int(np.count_nonzero(outside)),
        "truth_epochs_excluded": int(truth.t.size - used),
        "t_start": _f(at.t[0]),
        "t_end": _f(at.t[-1]),
        "position": {axis: _axis_stats(err[:, k]) for k, axis in enumerate(_AXES)},
        "horizontal_rms": _f(np.sqrt(np.mean(horiz**2))),
        "horizontal_max": _f(np.max(horiz)),
        "rms_3d": _f(np.sqrt(np.mean(norm3**2))),
        "max_3d": _f(np.max(norm3)),
        "velocity": {
            axis: {
                "rms": _f(np.sqrt(np.mean(verr[:, k] ** 2))),
                "max_abs": _f(np.max(np.abs(verr[:, k]))),
            }
            for k, axis in enumerate(_AXES)
        },
        "attitude_deg": {
            name: {
                "rms": _f(np.sqrt(np.mean(aerr[:, k] ** 2))),
                "max_abs": _f(np.max(np.abs(aerr[:, k]))),
                "mean": _f(np.mean(aerr[:, k])),
            }
            for k, name in enumerate(_ANGLES)
        },
        "sep": _f(np.median(norm3)),
        "sep_per_cycle": sep_per_cycle,
        "nees": _nees(err, at),
    }


def write_metrics_json(metrics_by_file: dict[str, dict[str, Any]], path: str | Path) -> None:
    """Write ``metrics.json``: ``{"solution.csv": {...}, "smoothed.csv": {...}}`` (``fusion run``
    adds ``"screening"``: the samples rejected per stream, fusion.screening, and ``"left_out"``:
    the configured plugins whose stream the recording lacks).

    Parameters
    ----------
    metrics_by_file : dict
        Metrics (from :func:`compute_metrics`) keyed by the solution file name.
    path : str or Path
        Output file; written with sorted keys, an indent of 2 and strict JSON (no NaN).
    """
    text = json.dumps(metrics_by_file, sort_keys=True, indent=2, allow_nan=False)
    Path(path).write_text(text + "\n", encoding="utf-8")
