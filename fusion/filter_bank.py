"""What the engine asks of a filter architecture, and the centralized filter (CKF) that provides it.

The engine owns the SINS and the event loop; a *filter bank* owns the error-state estimates. At a
covariance step it receives Φ and Q_d over the full state layout (the 15 common SINS error states
followed by every plugin's states, one centralized specification). For a plugin's epoch it names
the filter that serves the plugin (its layout and :class:`~fusion.kalman.KalmanFilter`). After an
update round it returns the correction of the 15 common states to feed back into the SINS and
re-references its estimates to the corrected SINS (closed loop). It carries the signature
columns of the jump hypotheses (:mod:`fusion.jumps`) and the cross-covariances of stored errors
(:mod:`fusion.kalman`) through the same linear steps as its estimates, and takes in a jump the
detector declares. The centralized filter is one
Kalman filter over the whole layout; :mod:`fusion.federated` cuts local filters out of the same
layout by index sets.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fusion.error_model import N_COMMON, POSITION, StateLayout
from fusion.fault_detection import FaultEvent
from fusion.kalman import KalmanFilter, UpdateResult
from fusion.lock import inflation_variances

COMMON = slice(0, N_COMMON)


class FilterBank(Protocol):
    """The engine's view of a filter architecture."""

    layout: StateLayout
    faults: list[FaultEvent]

    def predict(self, phi: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """Time update with Φ and Q_d over the full layout."""

    def filter_of(self, plugin: int) -> tuple[StateLayout, KalmanFilter]:
        """Layout and Kalman filter that serve plugin number ``plugin``."""

    def shared_covariance(self, plugin: int) -> NDArray[np.float64] | None:
        """The covariance a plugin's measurement is judged against (its context, gate and test
        statistic) when it is not its filter's own ``P``; ``None`` otherwise."""

    def record(
        self, plugin: int, t: float, result: UpdateResult, suspect: bool, holds: bool = False
    ) -> None:
        """Note the outcome of one update of plugin ``plugin`` (fault monitoring); ``holds``:
        it was accepted and determines the velocity or the position."""

    def in_fusion(self, plugin: int) -> bool:
        """Whether plugin ``plugin``'s updates reach the fused estimate now."""

    def signatures_of(self, plugin: int) -> NDArray[np.float64]:
        """The signature columns of the filter that serves ``plugin`` (its layout's rows)."""

    def add_signatures(self, columns: NDArray[np.float64]) -> None:
        """Append signature columns given over the full layout (n × k)."""

    def keep_signatures(self, keep: NDArray[np.bool_]) -> None:
        """Keep only the signature columns marked in ``keep``."""

    def accommodate(self, column: int, jump: float, variance: float) -> None:
        """Take in a jump along signature column E: x ← x + E·jump, P ← P + E·variance·Eᵀ."""

    def store_error(self, plugin: int, columns: NDArray[np.intp], h: NDArray[np.float64]) -> None:
        """Plugin ``plugin`` stored an estimate whose error is ``h ε`` of its filter (``h`` over
        that filter's layout) as stored errors ``columns``
        (:meth:`fusion.kalman.KalmanFilter.store_error`)."""

    def condition(self, index: int, value: float) -> None:
        """Set state ``index`` of the full layout to ``value`` by conditioning on it (the
        correlated states follow)."""

    def restart(self, index: int, value: float, variance: float) -> None:
        """Restart plugin state ``index`` of the full layout at ``value`` with ``variance``,
        uncorrelated with the rest (the state itself changed; nothing else moves)."""

    def fusion_due(self, t: float, updated: bool) -> bool:
        """Whether to compute and feed back a correction now."""

    def feedback(self, t: float) -> NDArray[np.float64]:
        """The 15 common-state correction to apply to the SINS; estimates re-referenced."""

    def position_covariance(self) -> NDArray[np.float64]:
        """Current 3×3 covariance of the position error (local metres)."""

    def common_covariance(self) -> NDArray[np.float64]:
        """Current 15×15 covariance of the common SINS error states (read-only)."""

    def restart_common(self, indices: NDArray[np.intp], covariance: NDArray[np.float64]) -> None:
        """Restart common states ``indices`` (the SINS has just been moved to a new estimate of
        them) at zero with ``covariance``, uncorrelated with everything else."""

    def inflate_common(self, factor: float) -> None:
        """Multiply the variances of the common (SINS) states by ``factor`` ≥ 1, the attitude's
        up to a bound, the increase added as uncorrelated noise
        (:func:`fusion.lock.inflation_variances`)."""

    def change_coordinates(self, a: NDArray[np.float64]) -> None:
        """Express every estimate in new coordinates ``x' = A x`` (A over the full layout, the
        identity outside the common states) (:meth:`fusion.kalman.KalmanFilter.
        change_coordinates`)."""

    @property
    def smoothing_dim(self) -> int:
        """Dimension of the state the smoother works on."""

    def smoothing_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Current estimate and covariance of the smoothed state (before any feedback)."""

    def smoothing_transition(self, phi: NDArray[np.float64]) -> NDArray[np.float64]:
        """Φ of the smoothed state cut from the full-layout Φ."""

    def estimate(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Current estimate and covariance over the full layout."""


class CentralizedFilter:
    """One Kalman filter over every state (the CKF baseline)."""

    def __init__(self, layout: StateLayout, stored_errors: int = 0) -> None:
        self.layout = layout
        self.kf = KalmanFilter(np.zeros(layout.dim), layout.initial_covariance(), stored_errors)
        self.faults: list[FaultEvent] = []
        self._position = layout.slice(POSITION)

    def predict(self, phi: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """Time update."""
        self.kf.predict(phi, qd)

    def filter_of(self, plugin: int) -> tuple[StateLayout, KalmanFilter]:
        """Every plugin is served by the one filter."""
        return self.layout, self.kf

    def shared_covariance(self, plugin: int) -> None:
        """The filter's own ``P`` serves every plugin."""
        return None

    def record(
        self, plugin: int, t: float, result: UpdateResult, suspect: bool, holds: bool = False
    ) -> None:
        """Nothing to monitor: gating (and jump detection) are the CKF's defences."""

    def in_fusion(self, plugin: int) -> bool:
        """Every update reaches the one filter."""
        return True

    def signatures_of(self, plugin: int) -> NDArray[np.float64]:
        """The filter's signature columns."""
        return self.kf.signatures

    def add_signatures(self, columns: NDArray[np.float64]) -> None:
        """Append columns."""
        self.kf.signatures = np.hstack([self.kf.signatures, columns])

    def keep_signatures(self, keep: NDArray[np.bool_]) -> None:
        """Drop the unmarked columns."""
        self.kf.signatures = self.kf.signatures[:, keep]

    def accommodate(self, column: int, jump: float, variance: float) -> None:
        """x ← x + E·jump, P ← P + E·variance·Eᵀ."""
        self.kf.take_in(column, jump, variance)

    def store_error(self, plugin: int, columns: NDArray[np.intp], h: NDArray[np.float64]) -> None:
        """The one filter stores it."""
        self.kf.store_error(columns, h)

    def condition(self, index: int, value: float) -> None:
        """A Kalman update on ``x[index] = value`` with a negligible R."""
        self.kf.condition(index, value)

    def restart(self, index: int, value: float, variance: float) -> None:
        """Restart a plugin state (:meth:`fusion.kalman.KalmanFilter.restart`)."""
        self.kf.restart(index, value, variance)

    def fusion_due(self, t: float, updated: bool) -> bool:
        """Feed back after every update round."""
        return updated

    def feedback(self, t: float) -> NDArray[np.float64]:
        """The common-state estimate; reset to zero (plugin states stay open loop)."""
        correction = self.kf.x[COMMON].copy()
        self.kf.x[COMMON] = 0.0
        return correction

    def position_covariance(self) -> NDArray[np.float64]:
        """Position block of P."""
        return self.kf.P[self._position, self._position].copy()

    def common_covariance(self) -> NDArray[np.float64]:
        """The common block of P (a view)."""
        return self.kf.P[COMMON, COMMON]

    def restart_common(self, indices: NDArray[np.intp], covariance: NDArray[np.float64]) -> None:
        """See :class:`FilterBank`."""
        self.kf.restart_block(indices, covariance)

    def inflate_common(self, factor: float) -> None:
        """See :class:`FilterBank`."""
        self.kf.add_variances(COMMON, inflation_variances(np.diagonal(self.kf.P)[COMMON], factor))

    def change_coordinates(self, a: NDArray[np.float64]) -> None:
        """See :class:`FilterBank`."""
        self.kf.change_coordinates(a)

    @property
    def smoothing_dim(self) -> int:
        """Every state is smoothed."""
        return self.layout.dim

    def smoothing_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The filter's state and covariance."""
        return self.kf.x.copy(), self.kf.P.copy()

    def smoothing_transition(self, phi: NDArray[np.float64]) -> NDArray[np.float64]:
        """The full Φ."""
        return phi

    def estimate(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The filter's state and covariance."""
        return self.kf.x.copy(), self.kf.P.copy()
