"""What the data observed: per state, the share of its prior variance the measurements removed.

The *prior* is the covariance the filter would hold had no measurement arrived: the initial
covariance propagated with the run's own transitions and process noise,

    P⁻₀ = P₀,   P⁻ₖ₊₁ = Φₖ P⁻ₖ Φₖᵀ + Q_d,k.

A Kalman update lowers the covariance in the positive-semidefinite order and the propagation
keeps that order, so the filter's covariance P stays below P⁻, and for each state i

    removed_i = 1 − P_ii / P⁻_ii ∈ [0, 1]

is the share of its prior variance that the data removed: 0 for a state nothing measured (its
estimate is the prior's), 1 for one the data pinned down. It is the diagonal of the ratio of
posterior to prior covariance that Ham & Brown (IEEE TAES 19(2), 1983) use as the degree of
observability. A jump taken in or a restart adds variance (:mod:`fusion.jumps`,
:mod:`fusion.lock`); where that leaves P above P⁻ the share is 0.

It is the filter's own account: a filter that invents information (the heading of a SINS at a
standstill, where ``fⁿ × φ`` is evaluated at a fluctuating nominal force) reports it as observed.
The report says what the covariance claims; RMS(err/σ) against truth says whether to believe it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.error_model import StateLayout
from fusion.kalman import propagate_covariance
from fusion.rows import RowBuffer

HISTORY_STEP_S = 1.0
"""Least time between two rows of the history (s): an 8-hour run keeps ≤ 28 800 rows."""


def removed_share(
    variance: NDArray[np.float64], prior_variance: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``1 − P_ii / P⁻_ii`` clipped to [0, 1]; 0 where the prior variance is 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        share = 1.0 - variance / prior_variance
    return np.clip(np.where(prior_variance > 0.0, share, 0.0), 0.0, 1.0)


@dataclass(frozen=True)
class Observability:
    """Per state of a run's layout: its prior variance and the share of it the data removed.

    ``removed`` is at the end of the run; ``t`` and ``removed_history`` (len(t) × states) sample
    it at most every :data:`HISTORY_STEP_S` seconds at output epochs.
    """

    labels: tuple[str, ...]
    """``block.label`` of every state (:attr:`fusion.error_model.StateLayout.labels`)."""
    prior_variance: NDArray[np.float64]
    variance: NDArray[np.float64]
    t: NDArray[np.float64]
    removed_history: NDArray[np.float64]

    @property
    def removed(self) -> NDArray[np.float64]:
        """Share of each state's prior variance removed by the end of the run."""
        return removed_share(self.variance, self.prior_variance)

    def share(self, label: str) -> float:
        """Share removed by the end of the run for one state, e.g. ``"gyro_bias.z"``."""
        try:
            return float(self.removed[self.labels.index(label)])
        except ValueError:
            raise KeyError(f"no state {label!r}; the layout has {list(self.labels)}") from None

    def by_block(self) -> dict[str, dict[str, float]]:
        """``{block: {label: share removed}}`` in layout order (metrics.json's form)."""
        out: dict[str, dict[str, float]] = {}
        for label, share in zip(self.labels, self.removed, strict=True):
            block, _, name = label.rpartition(".")
            out.setdefault(block, {})[name] = round(float(share), 4)
        return out

    def to_dict(self) -> dict[str, Any]:
        """metrics.json's ``observability`` entry."""
        return {
            "definition": "share of each state's prior variance removed by the data, "
            "1 - P/P_prior, at the end of the run (P_prior: P0 propagated without updates)",
            "removed": self.by_block(),
        }

    def describe(self) -> list[str]:
        """Summary lines, one per block: ``gyro_bias: x 2 %, y 3 %, z 0 %``."""
        return [
            f"{block}: " + ", ".join(f"{name} {100.0 * share:.0f} %" for name, share in s.items())
            for block, s in self.by_block().items()
        ]


class ObservabilityTracker:
    """Propagates the prior alongside the filter and samples the shares removed."""

    def __init__(self, layout: StateLayout) -> None:
        self.labels = tuple(layout.labels)
        self._prior = layout.initial_covariance()
        self._t = RowBuffer()
        self._history = RowBuffer((layout.dim,))
        self._last = -np.inf

    def predict(self, phi: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """``P⁻ ← Φ P⁻ Φᵀ + Q_d`` with the filter's own Φ and Q_d."""
        self._prior = propagate_covariance(self._prior, phi, qd)

    def due(self, t: float) -> bool:
        """Whether the history takes a row at output epoch ``t``."""
        return t - self._last >= HISTORY_STEP_S

    def sample(self, t: float, covariance: NDArray[np.float64]) -> None:
        """Note the shares removed at ``t`` from the filter's covariance over the layout."""
        self._last = t
        self._t.append(t)
        self._history.append(removed_share(np.diag(covariance), np.diag(self._prior)))

    def report(self, covariance: NDArray[np.float64]) -> Observability:
        """The report at the end of the run (``covariance``: the filter's final one)."""
        return Observability(
            labels=self.labels,
            prior_variance=np.diag(self._prior).copy(),
            variance=np.diag(covariance).copy(),
            t=self._t.take(),
            removed_history=self._history.take(),
        )
