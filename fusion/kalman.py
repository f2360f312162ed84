"""Kalman filter core: prediction, Cholesky-gain Joseph-form update, gating, whitened innovations.

For a measurement ``z = H x + v``, ``v ~ N(0, R)`` the update computes ::

    S = H P Hᵀ + R = L Lᵀ            (Cholesky)
    K = P Hᵀ S⁻¹                      (two triangular solves, no explicit inverse)
    ν = z − H x,  ν_w = L⁻¹ ν,  NIS = ν_wᵀ ν_w ~ χ²(m) when the filter is consistent
    x ← x + K ν
    P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ   (Joseph form, symmetric and PSD by construction)

A measurement whose NIS exceeds the χ² quantile of the configured probability is rejected
(gating is off unless a probability is given). Prediction is ``x ← Φ x``, ``P ← Φ P Φᵀ + Q_d``.

*Signature columns* (``signatures``, n × c, none by default) follow the estimate's linear
dynamics without a measurement input, ``E ← Φ E`` and ``E ← (I − K H) E``: a column started at
a unit jump of one state is the part of that jump the filter has not yet absorbed (the
generalized-likelihood-ratio signature of :mod:`fusion.jumps`). Closed-loop feedback moves the
estimate into the SINS but leaves the columns alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np
import scipy.linalg
import scipy.stats
from numpy.typing import NDArray


@lru_cache(maxsize=256)
def chi2_threshold(dof: int, probability: float) -> float:
    """χ² quantile: the NIS below which a consistent measurement falls with ``probability``."""
    return float(scipy.stats.chi2.ppf(probability, dof))


@dataclass(frozen=True)
class UpdateResult:
    """Outcome of one measurement update.

    Attributes
    ----------
    accepted
        False when the gate rejected the measurement (the state is then unchanged).
    innovation
        ``z − H x`` before the update.
    whitened
        ``L⁻¹ ν`` with ``S = L Lᵀ``: unit-covariance components when the filter is consistent.
    nis
        Normalized innovation squared ``νᵀ S⁻¹ ν``.
    threshold
        Gate threshold used, or ``None`` when gating is off.
    whitening
        The lower Cholesky factor L of the S that whitened the innovation.
    """

    accepted: bool
    innovation: NDArray[np.float64]
    whitened: NDArray[np.float64]
    nis: float
    threshold: float | None
    whitening: NDArray[np.float64]

    @property
    def dof(self) -> int:
        """Degrees of freedom (measurement dimension)."""
        return int(self.innovation.shape[0])


class KalmanFilter:
    """Linear Kalman filter on an error state.

    Parameters
    ----------
    x
        Initial state (n,).
    p
        Initial covariance (n, n).
    """

    def __init__(self, x: NDArray[np.float64], p: NDArray[np.float64]) -> None:
        self.x = np.array(x, dtype=float)
        self.P = np.array(p, dtype=float)
        self.signatures = np.zeros((self.dim, 0))
        self._identity = np.eye(self.dim)

    @property
    def dim(self) -> int:
        """State dimension."""
        return int(self.x.shape[0])

    def predict(self, phi: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """Time update with transition ``phi`` and discrete process noise ``qd``."""
        self.x = phi @ self.x
        if self.signatures.shape[1]:
            self.signatures = phi @ self.signatures
        p = phi @ self.P @ phi.T + qd
        self.P = 0.5 * (p + p.T)

    def update(
        self,
        z: NDArray[np.float64],
        h: NDArray[np.float64],
        r: NDArray[np.float64],
        gate_probability: float | None = None,
        statistic_covariance: NDArray[np.float64] | None = None,
    ) -> UpdateResult:
        """Measurement update (see module docstring); ``z`` (m,), ``h`` (m, n), ``r`` (m, m).

        ``statistic_covariance`` (default: ``P``) is the state covariance against which the
        innovation is whitened and gated, S = H P' Hᵀ + R; the gain always uses ``P``. A
        federated local passes its covariance at unit share (:mod:`fusion.federated`): its own
        ``P`` is inflated by 1/β_i and would make every test 1/β_i too lenient.
        """
        z = np.atleast_1d(np.asarray(z, dtype=float))
        h = np.ascontiguousarray(np.atleast_2d(h), dtype=float)
        r = np.ascontiguousarray(np.atleast_2d(r), dtype=float)
        nu, chol, ph_t = _innovation(self.x, self.P, z, h, r)
        whitening = chol
        if statistic_covariance is not None:
            whitening = _s_cholesky(statistic_covariance, h, r)[0]
        whitened = _forward_substitution(whitening, nu)
        nis = float(whitened @ whitened)
        threshold = None
        if gate_probability is not None:
            threshold = chi2_threshold(len(z), gate_probability)
            if nis > threshold:
                return UpdateResult(False, nu, whitened, nis, threshold, whitening)
        self.x, self.P, gain = _joseph(self.x, self.P, nu, chol, ph_t, h, r, self._identity)
        if self.signatures.shape[1]:
            self.signatures = self.signatures - gain @ (h @ self.signatures)
        return UpdateResult(True, nu, whitened, nis, threshold, whitening)

    def take_in(self, column: int, jump: float, variance: float) -> None:
        """A jump along signature column E (:mod:`fusion.jumps`): x ← x + E·jump and
        P ← P + E·variance·Eᵀ."""
        e = self.signatures[:, column]
        self.x += e * jump
        self.P += variance * np.outer(e, e)

    def restart(self, index: int, value: float, variance: float) -> None:
        """Restart state ``index`` at ``value`` with ``variance``, uncorrelated with the rest:
        the state itself changed (it is not a measurement of what it had been), so nothing
        else moves; its part of the signature columns goes with it."""
        self.x[index] = value
        self.P[index, :] = 0.0
        self.P[:, index] = 0.0
        self.P[index, index] = variance
        if self.signatures.shape[1]:
            self.signatures[index, :] = 0.0

    def condition(self, index: int, value: float) -> None:
        """Condition on state ``index`` being exactly ``value``: an update with H = e_indexᵀ and
        R = 10⁻¹² P_jj, so the correlated states follow."""
        h = np.zeros((1, self.dim))
        h[0, index] = 1.0
        self.update(np.array([value]), h, np.array([[1e-12 * self.P[index, index]]]))


def cholesky_solve(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """``a⁻¹ b`` through LAPACK's Cholesky factor and solve (potrf, potrs); None when ``a`` is
    not positive definite.

    The LAPACK routines are called directly: for the 15×15 covariances of the federated fusion
    and the smoother, ``scipy.linalg.cho_factor``/``solve``'s argument checks cost 3/4 of the
    call. Only finiteness is checked (LAPACK would carry a NaN through silently).

    Raises
    ------
    ValueError
        When ``a`` has a NaN or infinite entry.
    """
    if not np.isfinite(a).all():
        raise ValueError("covariance with a NaN or infinite entry")
    factor, info = scipy.linalg.lapack.dpotrf(a, lower=True, clean=False)
    if info != 0:
        return None
    solution, info = scipy.linalg.lapack.dpotrs(factor, b, lower=True)
    return np.asarray(solution) if info == 0 else None


def whiten(lower: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``L⁻¹ b`` for the lower Cholesky factor of an :class:`UpdateResult` (``b`` (m,) or
    (m, k)): the whitened form of anything the innovation carries."""
    return _forward_substitution(lower, np.ascontiguousarray(b, dtype=np.float64))


@numba.njit(cache=True)
def _forward_substitution(
    lower: NDArray[np.float64], b: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Solve ``L y = b`` for lower-triangular L; ``b`` (m,) or (m, k)."""
    y = b.copy()
    for i in range(lower.shape[0]):
        for j in range(i):
            y[i] -= lower[i, j] * y[j]
        y[i] /= lower[i, i]
    return y


@numba.njit(cache=True)
def _back_substitution(lower: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Solve ``Lᵀ y = b`` for lower-triangular L; ``b`` (m, k)."""
    y = b.copy()
    m = lower.shape[0]
    for i in range(m - 1, -1, -1):
        for j in range(i + 1, m):
            y[i] -= lower[j, i] * y[j]
        y[i] /= lower[i, i]
    return y


@numba.njit(cache=True)
def _s_cholesky(
    p: NDArray[np.float64], h: NDArray[np.float64], r: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Lower Cholesky factor L of S = H P Hᵀ + R, and P Hᵀ."""
    ph_t = p @ h.T
    s = h @ ph_t + r
    return np.linalg.cholesky(0.5 * (s + s.T)).astype(np.float64), ph_t


@numba.njit(cache=True)
def _innovation(
    x: NDArray[np.float64],
    p: NDArray[np.float64],
    z: NDArray[np.float64],
    h: NDArray[np.float64],
    r: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Innovation ν, Cholesky factor L of S, and P Hᵀ."""
    chol, ph_t = _s_cholesky(p, h, r)
    return z - h @ x, chol, ph_t


@numba.njit(cache=True)
def _joseph(
    x: NDArray[np.float64],
    p: NDArray[np.float64],
    nu: NDArray[np.float64],
    chol: NDArray[np.float64],
    ph_t: NDArray[np.float64],
    h: NDArray[np.float64],
    r: NDArray[np.float64],
    identity: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Gain K = P Hᵀ S⁻¹ by two triangular solves; the new state, Joseph-form covariance, K."""
    gain = _back_substitution(chol, _forward_substitution(chol, np.ascontiguousarray(ph_t.T))).T
    x_new = x + gain @ nu
    i_kh = identity - gain @ h
    p_new = i_kh @ p @ i_kh.T + gain @ r @ gain.T
    return x_new, 0.5 * (p_new + p_new.T), gain
