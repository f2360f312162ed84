"""What the engine asks of a filter architecture, and the centralized filter (CKF) that provides it.

The engine owns the SINS and the event loop; a *filter bank* owns the error-state estimates. At a
covariance step it receives Φ and Q_d over the full state layout (the 15 common SINS error states
followed by every plugin's states, one centralized specification). For a plugin's epoch it names
the filter that serves the plugin (its layout and :class:`~fusion.kalman.KalmanFilter`). After an
update round it returns the correction of the 15 common states to feed back into the SINS and
re-references its estimates to the corrected SINS (closed loop). The centralized filter is one
Kalman filter over the whole layout; :mod:`fusion.federated` cuts local filters out of the same
layout by index sets.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fusion.error_model import POSITION, StateLayout
from fusion.fault_detection import FaultEvent
from fusion.kalman import KalmanFilter, UpdateResult

COMMON = slice(0, 15)


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

    def record(self, plugin: int, t: float, result: UpdateResult, suspect: bool) -> None:
        """Note the outcome of one update of plugin ``plugin`` (fault monitoring)."""

    def fusion_due(self, t: float, updated: bool) -> bool:
        """Whether to compute and feed back a correction now."""

    def feedback(self, t: float) -> NDArray[np.float64]:
        """The 15 common-state correction to apply to the SINS; estimates re-referenced."""

    def position_covariance(self) -> NDArray[np.float64]:
        """Current 3×3 covariance of the position error (local metres)."""

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

    def __init__(self, layout: StateLayout) -> None:
        self.layout = layout
        self.kf = KalmanFilter(np.zeros(layout.dim), layout.initial_covariance())
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

    def record(self, plugin: int, t: float, result: UpdateResult, suspect: bool) -> None:
        """Nothing to monitor: gating is the CKF's only defence."""

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
