"""Overlapping Allan deviation and the analytic Allan variances of the simulated noise terms.

For a rate signal y sampled at ``rate_hz`` (interval ``τ0 = 1/rate_hz``) let
``θ_k = τ0 Σ_{i≤k} y_i`` be its integral. The overlapping Allan variance at cluster time
``τ = m τ0`` is (IEEE Std 952, El-Sheimy et al. 2008)

    σ²(τ) = 1 / (2 τ² (N − 2m)) · Σ_{k=0}^{N−2m−1} (θ_{k+2m} − 2 θ_{k+m} + θ_k)²,

computed here for all requested m with numpy array slices (no Python loop over samples). The
mean of y is removed before integrating (the Allan variance is blind to it) to keep θ small.

Analytic curves used to check the simulator (:mod:`fusion.sim.sensors`):

* white noise of density N (rate units/√Hz; ARW or VRW):  ``σ²(τ) = N² / τ``;
* first-order Gauss–Markov process with stationary σ and correlation time T_c
  (autocorrelation ``σ² e^{−|Δt|/T_c}``):

      σ²(τ) = σ² (T_c/τ)² [2τ/T_c − 3 + 4 e^{−τ/T_c} − e^{−2τ/T_c}],

  which rises as ``σ² (2/3) τ/T_c`` for τ ≪ T_c, peaks at ``τ ≈ 1.8926 T_c`` with
  ``σ(τ) = 0.61736 σ`` (:data:`GM_ALLAN_PEAK_RATIO`), and falls as ``σ² 2T_c/τ`` for τ ≫ T_c;
* independent terms add in variance.

The bias-instability figure B of a datasheet is the level of the flat part ("floor") of the Allan
deviation curve. The simulator realizes it with a Gauss–Markov process whose Allan peak equals B,
i.e. ``σ_GM = B / 0.61736`` (:func:`gm_sigma_from_bias_instability`). (For comparison, pure flicker
noise of coefficient B has the floor ``0.664 B``; datasheets quote the floor value itself.)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

GM_ALLAN_PEAK_TAU_RATIO = 1.892617779
"""τ/T_c at which the Allan deviation of a first-order Gauss–Markov process peaks."""

GM_ALLAN_PEAK_RATIO = 0.6173642831
"""Peak Allan deviation of a first-order Gauss–Markov process divided by its stationary σ."""


def default_cluster_sizes(n: int, per_decade: int = 10) -> NDArray[np.int64]:
    """Log-spaced unique cluster sizes m from 1 to ``(n − 1) // 2``.

    Parameters
    ----------
    n
        Number of samples.
    per_decade
        Approximate number of cluster sizes per decade of τ.

    Returns
    -------
    numpy.ndarray of int
        Increasing cluster sizes (empty when n < 3).
    """
    m_max = (n - 1) // 2
    if m_max < 1:
        return np.zeros(0, dtype=np.int64)
    k = max(int(np.ceil(np.log10(m_max) * per_decade)) + 1, 1)
    return np.unique(np.logspace(0.0, np.log10(m_max), k).astype(np.int64))


def allan_deviation(
    y: ArrayLike,
    rate_hz: float,
    taus: ArrayLike | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Overlapping Allan deviation of a rate signal.

    Parameters
    ----------
    y
        (N,) or (N, K) samples (each column an independent signal, e.g. the three axes).
    rate_hz
        Sample rate (Hz).
    taus
        Cluster times (s); each is rounded to the nearest multiple m ≥ 1 of the sample interval
        and duplicates are removed. Default: about 10 log-spaced values per decade up to
        half the record length.

    Returns
    -------
    tau, adev
        (M,) cluster times actually used (s) and the Allan deviation, (M,) or (M, K) in the
        units of ``y``.
    """
    yy = np.asarray(y, dtype=float)
    n = yy.shape[0]
    tau0 = 1.0 / rate_hz
    if taus is None:
        m = default_cluster_sizes(n)
    else:
        m = np.unique(np.maximum(np.rint(np.asarray(taus, dtype=float) / tau0), 1).astype(np.int64))
        m = m[2 * m < n]
    if m.size == 0:
        raise ValueError(f"record of {n} samples too short for the requested cluster times")
    theta = np.zeros((n + 1, *yy.shape[1:]))
    np.cumsum((yy - yy.mean(axis=0)) * tau0, axis=0, out=theta[1:])
    avar = np.empty((m.size, *yy.shape[1:]))
    for i, mi in enumerate(m):
        d = theta[2 * mi :] - 2.0 * theta[mi:-mi] + theta[: -2 * mi]
        tau = mi * tau0
        avar[i] = np.mean(d * d, axis=0) / (2.0 * tau * tau)
    return (m * tau0).astype(float), np.sqrt(avar)


def allan_variance_white(density: float, tau: ArrayLike) -> NDArray[np.float64]:
    """Allan variance ``N²/τ`` of white rate noise of density N (units/√Hz)."""
    return density**2 / np.asarray(tau, dtype=float)


def allan_variance_gauss_markov(
    sigma: float, corr_time: float, tau: ArrayLike
) -> NDArray[np.float64]:
    """Allan variance of a first-order Gauss–Markov process (stationary σ, correlation time T_c).

    ``σ²(τ) = σ² (T_c/τ)² [2x − 3 + 4e^{−x} − e^{−2x}]`` with ``x = τ/T_c``; a series is used for
    x < 1e-3 where the bracket cancels (``≈ 2x³/3 − x⁴/2``).
    """
    x = np.asarray(tau, dtype=float) / corr_time
    small = x < 1e-3
    xs = np.where(small, 1.0, x)
    bracket = 2.0 * xs - 3.0 + 4.0 * np.exp(-xs) - np.exp(-2.0 * xs)
    val = bracket / (xs * xs)
    val = np.where(small, 2.0 * x / 3.0 - x * x / 2.0, val)
    return sigma**2 * val


def gm_sigma_from_bias_instability(bias_instability: float) -> float:
    """Stationary σ of the Gauss–Markov process whose Allan peak is ``bias_instability``."""
    return bias_instability / GM_ALLAN_PEAK_RATIO
