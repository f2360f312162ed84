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

*Stored errors* (stochastic cloning without refinement, Schmidt style). A plugin that stores an
estimate of the filter (CPOEM's optimal points) and later measures against it makes that
estimate's error ``e`` part of a later measurement's noise, ``w = v + B e_c`` (``e_c`` the stored
errors in ``columns``, :class:`CorrelatedNoise`). The filter tracks ``C = Cov(ε, e)`` of its
estimation error ε = x − x̂ (the true error state minus its estimate) with every stored error
(``cross``, n × m) and ``D = Cov(e, e)`` (``stored_covariance``, m × m). Storing ``e_c = H_s ε``
(:meth:`KalmanFilter.store_error`) sets ``C_c = P H_sᵀ``, ``D_cc = H_s P H_sᵀ`` and
``D_c· = H_s C``. With ``M = Cov(ε, w) = C_c Bᵀ`` an update is ::

    S = H P Hᵀ + R + H M + Mᵀ Hᵀ,   K = (P Hᵀ + M) S⁻¹
    P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ − (I − K H) M Kᵀ − K Mᵀ (I − K H)ᵀ
    C ← (I − K H) C − K B D_c·

(``R`` includes ``B D_cc Bᵀ``); every other update is the special case ``M = 0``,
``C ← (I − K H) C``, and a time step ``C ← Φ C``. Feedback leaves ε, hence C, unchanged.

A federated local's ``P`` counts its information 1/β_i times; what its updates add must be the
measurement's own information for the fusion to be exact, and a noise correlated with the state
error is not that. Given its error's covariance P_u (``statistic_covariance``, the unit share),
the local applies instead the equivalent measurement with independent noise: the regression of
w on ε taken out, ``G = P_u⁻¹ M``, ``z' = z + Gᵀ x̂``, ``H' = H + Gᵀ``, ``R' = R − Mᵀ G`` (the same
innovation and S), with ``Cov(w', e) = B D_c· − Gᵀ C`` in the update of C.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.linalg
import scipy.stats
from numpy.typing import NDArray

from fusion import kernels


@lru_cache(maxsize=256)
def chi2_threshold(dof: int, probability: float) -> float:
    """χ² quantile: the NIS below which a consistent measurement falls with ``probability``."""
    return float(scipy.stats.chi2.ppf(probability, dof))


@dataclass(frozen=True)
class CorrelatedNoise:
    """A measurement's noise carries stored errors: ``w = v + B e[columns]`` (module docstring).

    Attributes
    ----------
    columns
        Indices of the stored errors (``KalmanFilter.cross`` columns).
    mixing
        B, (measurement dimension × len(columns)).
    """

    columns: NDArray[np.intp]
    mixing: NDArray[np.float64]


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
    gain
        The gain K the update used (None when rejected).
    """

    accepted: bool
    innovation: NDArray[np.float64]
    whitened: NDArray[np.float64]
    nis: float
    threshold: float | None
    whitening: NDArray[np.float64]
    gain: NDArray[np.float64] | None = None

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
    stored_errors
        Number m of stored-error variables tracked (module docstring), uncorrelated and zero
        until stored.
    """

    def __init__(
        self, x: NDArray[np.float64], p: NDArray[np.float64], stored_errors: int = 0
    ) -> None:
        self.x = np.array(x, dtype=float)
        self.P = np.array(p, dtype=float)
        # One store for every column that follows the estimate's linear dynamics: the stored
        # errors' cross-covariances (fixed count), then the jump signatures (added and dropped).
        self.columns = np.zeros((self.dim, stored_errors))
        self.stored_covariance = np.zeros((stored_errors, stored_errors))
        self._identity = np.eye(self.dim)

    @property
    def dim(self) -> int:
        """State dimension."""
        return int(self.x.shape[0])

    @property
    def cross(self) -> NDArray[np.float64]:
        """C = Cov(ε, e), n × m (a view of :attr:`columns`)."""
        return self.columns[:, : self.stored_covariance.shape[0]]

    @cross.setter
    def cross(self, value: NDArray[np.float64]) -> None:
        self.columns[:, : self.stored_covariance.shape[0]] = value

    @property
    def signatures(self) -> NDArray[np.float64]:
        """The jump signature columns, n × c (a view of :attr:`columns`; assigning replaces
        them, as the jump detector adds and drops hypotheses)."""
        return self.columns[:, self.stored_covariance.shape[0] :]

    @signatures.setter
    def signatures(self, value: NDArray[np.float64]) -> None:
        self.columns = np.hstack([self.cross, value])

    def predict(self, phi: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """Time update with transition ``phi`` and discrete process noise ``qd``."""
        self.x = phi @ self.x
        if self.columns.shape[1]:
            self.columns = phi @ self.columns
        self.P = propagate_covariance(self.P, phi, qd)

    def update(
        self,
        z: NDArray[np.float64],
        h: NDArray[np.float64],
        r: NDArray[np.float64],
        gate_probability: float | None = None,
        statistic_covariance: NDArray[np.float64] | None = None,
        correlated: CorrelatedNoise | None = None,
        consider: tuple[int, ...] = (),
        withheld: bool = False,
    ) -> UpdateResult:
        """Measurement update (see module docstring); ``z`` (m,), ``h`` (m, n), ``r`` (m, m).

        ``statistic_covariance`` (default: ``P``) is the state covariance against which the
        innovation is whitened and gated, S = H P' Hᵀ + R; the gain always uses ``P``. A
        federated local passes its covariance at unit share (:mod:`fusion.federated`): its own
        ``P`` is inflated by 1/β_i and would make every test 1/β_i too lenient. ``correlated``:
        the noise carries stored errors (``R`` their part included). ``consider``: states
        whose gain is zero (Schmidt-Kalman): the Joseph form keeps P right for that gain and
        leaves their variances unchanged. ``withheld``: the innovation is computed and the update
        rejected, as the gate would (a reading the plugin's own test withholds).
        """
        z = np.atleast_1d(np.asarray(z, dtype=float))
        h = np.ascontiguousarray(np.atleast_2d(h), dtype=float)
        r = np.ascontiguousarray(np.atleast_2d(r), dtype=float)
        cov_state_noise = noise_with_stored = None
        r_innovation = r
        if correlated is not None:
            z, h, r, r_innovation, cov_state_noise, noise_with_stored = self._correlated_terms(
                z, h, r, correlated, statistic_covariance
            )
        nu, chol, ph_t = _innovation(self.x, self.P, z, h, r_innovation)
        whitening = chol
        if statistic_covariance is not None:
            whitening = _s_cholesky(statistic_covariance, h, r_innovation)[0]
        whitened = _forward_substitution(whitening, nu)
        nis = float(whitened @ whitened)
        threshold = None
        if gate_probability is not None:
            threshold = chi2_threshold(len(z), gate_probability)
        if withheld or (threshold is not None and nis > threshold):
            return UpdateResult(False, nu, whitened, nis, threshold, whitening)
        if cov_state_noise is not None:
            ph_t = ph_t + cov_state_noise
        if consider:
            ph_t = ph_t.copy()
            ph_t[list(consider)] = 0.0
        self.x, self.P, gain = _joseph(self.x, self.P, nu, chol, ph_t, h, r, self._identity)
        if self.columns.shape[1]:
            self.columns = self.columns - gain @ (h @ self.columns)
        if cov_state_noise is not None:
            term = (self._identity - gain @ h) @ cov_state_noise @ gain.T
            self.P -= term + term.T
        if noise_with_stored is not None:
            self.cross -= gain @ noise_with_stored
        return UpdateResult(True, nu, whitened, nis, threshold, whitening, gain)

    def _correlated_terms(
        self,
        z: NDArray[np.float64],
        h: NDArray[np.float64],
        r: NDArray[np.float64],
        correlated: CorrelatedNoise,
        statistic_covariance: NDArray[np.float64] | None,
    ) -> tuple[
        NDArray[np.float64],
        NDArray[np.float64],
        NDArray[np.float64],
        NDArray[np.float64],
        NDArray[np.float64] | None,
        NDArray[np.float64],
    ]:
        """z, H, R, the R that enters S, M = Cov(ε, w) (None when decorrelated) and
        Cov(w, e) for a noise carrying stored errors (module docstring)."""
        cov_state_noise = self.cross[:, correlated.columns] @ correlated.mixing.T
        noise_with_stored = correlated.mixing @ self.stored_covariance[correlated.columns]
        if statistic_covariance is not None:  # a federated local
            z, h, r, noise_with_stored = self._decorrelated(
                z, h, r, cov_state_noise, noise_with_stored, statistic_covariance
            )
            return z, h, r, r, None, noise_with_stored
        hm = h @ cov_state_noise
        return z, h, r, r + hm + hm.T, cov_state_noise, noise_with_stored

    def _decorrelated(
        self,
        z: NDArray[np.float64],
        h: NDArray[np.float64],
        r: NDArray[np.float64],
        cov_state_noise: NDArray[np.float64],
        noise_with_stored: NDArray[np.float64],
        covariance: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], ...]:
        """The equivalent measurement whose noise is independent of the state error, for a
        federated local whose own P is not its error's covariance (module docstring):
        G = P_u⁻¹ M, z' = z + Gᵀ x̂, H' = H + Gᵀ, R' = R − Mᵀ G, Cov(w', e) = B D − Gᵀ C."""
        g = cholesky_solve(0.5 * (covariance + covariance.T), cov_state_noise)
        if g is None:
            raise ValueError("a correlated update needs a positive definite state covariance")
        r_new = r - cov_state_noise.T @ g
        return (
            z + g.T @ self.x,
            np.ascontiguousarray(h + g.T),
            np.ascontiguousarray(0.5 * (r_new + r_new.T)),
            noise_with_stored - g.T @ self.cross,
        )

    def store_error(
        self,
        columns: NDArray[np.intp],
        h: NDArray[np.float64],
        covariance: NDArray[np.float64] | None = None,
    ) -> None:
        """The stored errors ``columns`` become ``h ε`` now (an estimate stored from this
        filter): C_c = P hᵀ, D_cc = h P hᵀ, D_c· = h C (module docstring). ``covariance``
        (default: ``P``) is the state covariance to take them from (a federated local's at unit
        share)."""
        p = self.P if covariance is None else covariance
        with_others = h @ self.cross
        self.stored_covariance[columns, :] = with_others
        self.stored_covariance[:, columns] = with_others.T
        self.stored_covariance[np.ix_(columns, columns)] = h @ p @ h.T
        self.cross[:, columns] = p @ h.T

    def take_in(self, column: int, jump: float, variance: float) -> None:
        """A jump along signature column E (:mod:`fusion.jumps`): x ← x + E·jump and
        P ← P + E·variance·Eᵀ."""
        e = self.signatures[:, column]
        self.x += e * jump
        self.P += variance * np.outer(e, e)

    def restart(self, index: int, value: float, variance: float) -> None:
        """Restart state ``index`` at ``value`` with ``variance``, uncorrelated with the rest:
        the state itself changed (it is not a measurement of what it had been), so nothing
        else moves; its rows of the signature columns and of the stored errors' cross-covariance
        go with it."""
        self.x[index] = value
        self.P[index, :] = 0.0
        self.P[:, index] = 0.0
        self.P[index, index] = variance
        self.columns[index, :] = 0.0

    def restart_block(self, indices: NDArray[np.intp], covariance: NDArray[np.float64]) -> None:
        """Restart states ``indices`` at zero with ``covariance``, uncorrelated with the rest
        (:meth:`restart` for a block)."""
        self.x[indices] = 0.0
        self.P[indices, :] = 0.0
        self.P[:, indices] = 0.0
        self.P[np.ix_(indices, indices)] = covariance
        self.columns[indices, :] = 0.0

    def change_coordinates(self, a: NDArray[np.float64]) -> None:
        """Express the state in new coordinates ``x' = A x``: ``P ← A P Aᵀ``, and the signature
        and cross-covariance columns (covariances of the state with fixed quantities) ``← A E``
        (:mod:`fusion.invariant_error`)."""
        self.x = a @ self.x
        self.P = a @ self.P @ a.T
        self.columns = a @ self.columns

    def add_variances(self, indices: slice | NDArray[np.intp], added: NDArray[np.float64]) -> None:
        """Add ``added`` to the variances of states ``indices`` as uncorrelated noise: the
        covariances stay, so the correlations shrink (an inflation, :mod:`fusion.lock`).
        Scaling the whole block instead (``D P D``) kept the tight velocity–attitude
        correlations of a converged SINS at full strength: the first zero velocity accepted
        after the inflation swung the attitude and the next ones were rejected at ten times
        their σ."""
        diagonal = np.zeros(self.dim)
        diagonal[indices] = added
        self.P = self.P + np.diag(diagonal)

    def hold_bounds(self, bounds: tuple[tuple[int, float], ...]) -> list[tuple[int, float]]:
        """Project the estimate back inside physical bounds ``(index, bound)``, ``|x_i| ≤ b``:
        a state beyond moves to the bound and the others with it along their covariance,
        ``x ← x − P eᵢ (x_i − b_i) / P_ii`` (the estimate projection of Simon, *Kalman filtering
        with state constraints: a survey of linear and nonlinear algorithms*, IET Control
        Theory & Applications 4(8), 2010, §2.3, with weight P⁻¹). ``P`` is kept: the bound says
        where the state cannot be, not where it is, and a covariance shrunk at every epoch
        the estimate pushes against it would claim the bound as new information each time.
        Returns ``(index, value before)`` of every state projected."""
        held = []
        for index, bound in bounds:
            value = float(self.x[index])
            if abs(value) > bound and self.P[index, index] > 0.0:
                excess = value - math.copysign(bound, value)
                self.x = self.x - self.P[:, index] * (excess / self.P[index, index])
                held.append((index, value))
        return held

    def condition(self, index: int, value: float) -> None:
        """Condition on state ``index`` being exactly ``value``: an update with H = e_indexᵀ and
        R = 10⁻¹² P_jj, so the correlated states follow."""
        h = np.zeros((1, self.dim))
        h[0, index] = 1.0
        self.update(np.array([value]), h, np.array([[1e-12 * self.P[index, index]]]))


def propagate_covariance(
    p: NDArray[np.float64], phi: NDArray[np.float64], qd: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``Φ P Φᵀ + Q_d``, symmetrized."""
    propagated = phi @ p @ phi.T + qd
    return 0.5 * (propagated + propagated.T)


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


@kernels.jit
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


@kernels.jit
def _back_substitution(lower: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Solve ``Lᵀ y = b`` for lower-triangular L; ``b`` (m, k)."""
    y = b.copy()
    m = lower.shape[0]
    for i in range(m - 1, -1, -1):
        for j in range(i + 1, m):
            y[i] -= lower[j, i] * y[j]
        y[i] /= lower[i, i]
    return y


@kernels.jit
def _s_cholesky(
    p: NDArray[np.float64], h: NDArray[np.float64], r: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Lower Cholesky factor L of S = H P Hᵀ + R, and P Hᵀ."""
    ph_t = p @ h.T
    s = h @ ph_t + r
    return np.linalg.cholesky(0.5 * (s + s.T)).astype(np.float64), ph_t


@kernels.jit
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


@kernels.jit
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
