"""Accuracy metrics of a trajectory estimate against the reference trajectory (``truth.csv``).

:func:`compute_metrics` interpolates the truth to the solution epochs and summarizes the errors
(estimate minus truth) in a JSON-serializable dict; :func:`write_metrics_json` writes the
``metrics.json`` of ``fusion run`` (one entry per solution file).

Conventions
-----------
* Truth is interpolated linearly in time for position and velocity; attitude angles are
  unwrapped along time before the linear interpolation, and every attitude error is wrapped to
  ``[-180, 180)`` degrees.  Solution epochs outside the truth's time span are excluded (counted in
  ``epochs_excluded``).
* ``std`` is the population standard deviation (``ddof=0``), so ``rms² = mean² + std²``.
* The cutting cycle of an epoch is the ``cycle`` of the last truth sample at or before it.
  ``sep_per_cycle[c]`` is the spherical error probable of cycle ``c >= 1``, taken here as the
  empirical median of the 3-D position error norm (the radius of the sphere holding 50 % of the
  epochs of that cycle); ``None`` when no solution epoch falls in that cycle.  ``sep`` is the same
  over all epochs.
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
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from fusion.recording import FloatArray, TruthData
from fusion.solution import Solution

__all__ = ["compute_metrics", "interpolate_truth", "write_metrics_json"]

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


def _nees(err: FloatArray, solution: Solution, inside: np.ndarray) -> dict[str, Any]:
    cov = solution.position_covariance
    if cov is None:
        return {
            "source": "sigma_position",
            "normalized_rms": _normalized_rms(err, solution.sigma_position[inside]),
        }
    p = cov[inside]
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
        ``epochs``, ``epochs_excluded`` (outside the truth span), ``t_start``, ``t_end``;
        ``position`` {axis e/n/u: {max_abs, mean_abs, mean, std, rms}} (m);
        ``horizontal_rms``, ``horizontal_max``, ``rms_3d``, ``max_3d`` (m);
        ``velocity`` {axis: {rms, max_abs}} (m/s);
        ``attitude_deg`` {roll/pitch/yaw: {rms, max_abs, mean}} (degrees);
        ``sep`` and ``sep_per_cycle`` {cycle (int): SEP or None} (m); ``nees`` (see the module
        docstring).

    Raises
    ------
    ValueError
        When no solution epoch lies inside the truth's time span.
    """
    inside, pos, vel, att, cycle = interpolate_truth(truth, solution.t)
    used = int(np.count_nonzero(inside))
    if used == 0:
        raise ValueError("no solution epoch lies inside the time span of the truth trajectory")
    err = solution.position[inside] - pos
    verr = solution.velocity[inside] - vel
    aerr = np.rad2deg(_wrap_pi(solution.attitude[inside] - att))
    horiz = np.hypot(err[:, 0], err[:, 1])
    norm3 = np.linalg.norm(err, axis=1)

    sep_per_cycle: dict[int, float | None] = {}
    for c in np.unique(truth.cycle):
        if c >= 1:
            sel = cycle == c
            sep_per_cycle[int(c)] = _f(np.median(norm3[sel])) if sel.any() else None

    t_used = solution.t[inside]
    return {
        "epochs": used,
        "epochs_excluded": int(solution.t.size - used),
        "t_start": _f(t_used[0]),
        "t_end": _f(t_used[-1]),
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
        "nees": _nees(err, solution, inside),
    }


def write_metrics_json(metrics_by_file: dict[str, dict[str, Any]], path: str | Path) -> None:
    """Write ``metrics.json``: ``{"solution.csv": {...}, "smoothed.csv": {...}}`` (``fusion run``
    adds ``"screening"``: the samples rejected per stream, fusion.screening).

    Parameters
    ----------
    metrics_by_file : dict
        Metrics (from :func:`compute_metrics`) keyed by the solution file name.
    path : str or Path
        Output file; written with sorted keys, an indent of 2 and strict JSON (no NaN).
    """
    text = json.dumps(metrics_by_file, sort_keys=True, indent=2, allow_nan=False)
    Path(path).write_text(text + "\n", encoding="utf-8")
