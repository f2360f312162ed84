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

The χ² sum is blind to a bias that the local absorbs: a slipping wheel mid-face, where the
odometer is the only velocity aid, pulls the velocity along within a second or two and the
sum of squares hardly rises (on ``longwall-200m`` a 30 % slip lifts the 5-s odometer sum from
52 to 127 over 150 degrees of freedom). The *mean test* looks for that bias directly: per
plugin, with its whitened innovations w_k (m components, unit covariance when consistent) over
the window,

    M(t) = ‖Σ w_k‖² / n ~ χ²_m,    fault ⇔ M(t) > χ²_m(p)   (n ≥ 10, m constant in the window)

(the same slip gives M = 31 against a threshold of 21 and a nominal maximum of 14). A single
outlier among n ≥ 10 cannot trip it; a plugin whose measurement size changes (UWB ranges to a
varying set of anchors) restarts its window at each change.

A healthy local that fails the test is *isolated* (excluded from fusion and from resets; it keeps
filtering on its own). A local that owns a state that may jump (:mod:`fusion.jumps`: a slip) is
isolated only once it has failed on ``confirm_updates`` consecutive updates: a jump the detector
takes in within that time explains the failure (the windows are then forgotten) and the local
stays in the fusion, aiding with the jump estimated, rather than leaving the SINS to coast.
An isolated local is *re-admitted* once it has passed the test without
interruption for ``hold_s`` seconds. Every transition is a :class:`FaultEvent` (written to
``faults.csv``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.config import FaultDetectionOptions
from fusion.kalman import chi2_threshold

MEAN_TEST_MIN_SAMPLES = 10

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


@dataclass
class _MeanWindow:
    """Whitened innovations of one plugin over the window, and their running sum."""

    dof: int
    samples: deque[tuple[float, NDArray[np.float64]]] = field(default_factory=deque)
    total: NDArray[np.float64] = field(init=False)

    def __post_init__(self) -> None:
        self.total = np.zeros(self.dof)

    def add(self, t: float, whitened: NDArray[np.float64], window_s: float) -> float:
        """Add one update; return M = ‖Σ w‖² / n (0 below the minimum sample count)."""
        self.samples.append((t, whitened))
        self.total += whitened
        while self.samples[0][0] <= t - window_s:
            self.total -= self.samples.popleft()[1]
        n = len(self.samples)
        return float(self.total @ self.total) / n if n >= MEAN_TEST_MIN_SAMPLES else 0.0


class FaultMonitor:
    """Sliding-window χ² test plus plugin indicators for one local filter.

    Parameters
    ----------
    local
        Name of the local filter (for the events).
    options
        Window, probability, hold time, use of indicators.
    confirm_updates
        Consecutive failing updates before an isolation (0: at the first; a local whose
        failure a jump may explain waits for the jump detector's decision).
    """

    def __init__(
        self, local: str, options: FaultDetectionOptions, confirm_updates: int = 0
    ) -> None:
        self.local = local
        self.options = options
        self.confirm_updates = confirm_updates
        self.isolated = False
        self._failing = 0
        self._window: deque[tuple[float, float, int]] = deque()
        self._nis_sum = 0.0
        self._dof_sum = 0
        self._clean_since: float | None = None
        self._means: dict[str, _MeanWindow] = {}

    def observe(
        self,
        t: float,
        nis: float,
        dof: int,
        suspect: bool,
        source: str = "",
        whitened: NDArray[np.float64] | None = None,
    ) -> FaultEvent | None:
        """Add one update of plugin ``source`` (its NIS and, for the mean test, its whitened
        innovation); return the event if the local changes state."""
        opts = self.options
        if not opts.enabled:
            return None
        mean_statistic, mean_threshold = self._mean_test(t, source, whitened)
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
        biased = mean_statistic > mean_threshold
        if statistic > threshold or flagged or biased:
            self._clean_since = None
            self._failing += 1
            if not self.isolated and self._failing > self.confirm_updates:
                self.isolated = True
                if flagged:
                    reason = "plugin indicator"
                elif statistic > threshold:
                    reason = "window chi-square"
                else:
                    statistic, threshold = mean_statistic, mean_threshold
                    reason = f"window mean of {source}"
                return FaultEvent(t, self.local, statistic, threshold, ISOLATE, reason)
            return None
        self._failing = 0
        if self._clean_since is None:
            self._clean_since = t
        if self.isolated and t - self._clean_since >= opts.hold_s:
            self.isolated = False
            return FaultEvent(t, self.local, statistic, threshold, READMIT, "consistent for hold")
        return None

    def forget(self) -> None:
        """Empty the windows (a jump taken in, :mod:`fusion.jumps`, explains what they hold);
        isolation and the clean time are kept."""
        self._window.clear()
        self._nis_sum = 0.0
        self._dof_sum = 0
        self._means.clear()
        self._failing = 0

    def _mean_test(
        self, t: float, source: str, whitened: NDArray[np.float64] | None
    ) -> tuple[float, float]:
        """M(t) of plugin ``source`` and its threshold (0, inf when the test is off)."""
        if not self.options.mean_test or whitened is None or whitened.size == 0:
            return 0.0, np.inf
        window = self._means.get(source)
        if window is None or window.dof != whitened.size:
            window = self._means[source] = _MeanWindow(whitened.size)
        statistic = window.add(t, whitened, self.options.window_s)
        return statistic, chi2_threshold(whitened.size, self.options.probability)
