"""Fault detection and isolation of a local filter (seed 003 §4 motivates the AFKF's tolerance).

Each local filter of the federated master has a monitor. Every measurement update of the local
adds its normalized innovation squared NIS_k (χ² with m_k degrees of freedom when the local is
consistent) and the plugin's own indicator (``Measurement.suspect``, e.g. a magnetic field off
the expected earth field). At time t the window statistic over the last ``window_s`` seconds is

    T(t) = Σ NIS_k,   d(t) = Σ m_k,   fault ⇔ T(t) > s·χ²_{d(t)}(p)  or  (indicators on and
                                                                  the latest update is suspect)

The scale s ≥ 1 (``threshold_scale``, default 1.5) keeps the test for gross faults: over a window
of hundreds of degrees of freedom the plain χ² quantile is exceeded by a 20 % excess of
innovation variance, which a real model (reversals at the face ends, a sensor entering range)
shows without anything being faulty; an interference, an NLOS burst or a slip exceeds it many
times over.

A healthy local that fails the test is *isolated* (excluded from fusion and from resets; it keeps
filtering on its own). An isolated local is *re-admitted* once it has passed the test without
interruption for ``hold_s`` seconds. Every transition is a :class:`FaultEvent` (written to
``faults.csv``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from fusion.config import FaultDetectionOptions
from fusion.kalman import chi2_threshold

ISOLATE, READMIT = "isolate", "readmit"


@dataclass(frozen=True)
class FaultEvent:
    """One detection or recovery: ``faults.csv`` row."""

    t: float
    local: str
    statistic: float
    threshold: float
    action: str
    reason: str


class FaultMonitor:
    """Sliding-window χ² test plus plugin indicators for one local filter.

    Parameters
    ----------
    local
        Name of the local filter (for the events).
    options
        Window, probability, hold time, use of indicators.
    """

    def __init__(self, local: str, options: FaultDetectionOptions) -> None:
        self.local = local
        self.options = options
        self.isolated = False
        self._window: deque[tuple[float, float, int]] = deque()
        self._nis_sum = 0.0
        self._dof_sum = 0
        self._clean_since: float | None = None

    def observe(self, t: float, nis: float, dof: int, suspect: bool) -> FaultEvent | None:
        """Add one update's NIS; return the event if the local changes state."""
        opts = self.options
        if not opts.enabled:
            return None
        self._window.append((t, nis, dof))
        self._nis_sum += nis
        self._dof_sum += dof
        while self._window[0][0] <= t - opts.window_s:
            _, old_nis, old_dof = self._window.popleft()
            self._nis_sum -= old_nis
            self._dof_sum -= old_dof
        statistic = max(self._nis_sum, 0.0)
        threshold = opts.threshold_scale * chi2_threshold(self._dof_sum, opts.probability)
        flagged = opts.use_indicators and suspect
        faulty = statistic > threshold or flagged
        if faulty:
            self._clean_since = None
            if not self.isolated:
                self.isolated = True
                reason = "plugin indicator" if flagged else "window chi-square"
                return FaultEvent(t, self.local, statistic, threshold, ISOLATE, reason)
            return None
        if self._clean_since is None:
            self._clean_since = t
        if self.isolated and t - self._clean_since >= opts.hold_s:
            self.isolated = False
            return FaultEvent(t, self.local, statistic, threshold, READMIT, "consistent for hold")
        return None
