"""Fault detection and isolation of a local filter (seed 003 §4 motivates the AFKF's tolerance).

Each local filter of the federated master has a monitor. Every measurement update of the local
adds its normalized innovation squared NIS_k (χ² with m_k degrees of freedom when the local is
consistent) and the plugin's own indicator (``Measurement.suspect``, e.g. a magnetic field off
the expected earth field). At time t the window statistic over the last ``window_s`` seconds is

    T(t) = Σ min(NIS_k, χ²_{m_k}(p)),   d(t) = Σ m_k,
    fault ⇔ T(t) > s·χ²_{d(t)}(p)  or  (indicators on and the updates suspect for ≥ t_confirm)

Each update's NIS is capped at its own χ² quantile: one outlier (a gated range, a single wild
sample) adds at most that, so it takes a run of them to isolate a local. Uncapped, the two
first samples of a magnetic disturbance (NIS 107 and 147) isolated the magnetometer before its
indicator spoke, and the last CPOEM update of a recording that ended mid-pass (NIS 5 400)
isolated CPOEM.

A plugin's indicator isolates only when it persists (``indicator_confirm_s``, default 2 s):
the plugin down-weights a suspect epoch itself (the magnetometer by the heading error the
disturbance it sees can make), so a flag that comes and goes costs at most that epoch's
information, while isolating at the first flag threw away a healthy sensor whenever its
indicator was benignly off (a site field a few per cent from meta.yaml's) and never
re-admitted it.

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

    M(t) = ‖Σ w_k‖² / n ~ χ²_m,    fault ⇔ M(t) > χ²_m(p_M)   (n ≥ 10, m constant in the window)

(the same slip gives M = 31 against a threshold of 26 and a nominal maximum of 14). The test
runs at every update, so its false-alarm rate is its tail probability times the update rate:
UWB ranges at 35 per second and p_M = 0.9999 isolated the UWB local of an independent world
once every 8 minutes at statistics just over the bound (15.4–17.4 against 15.1); p_M is
``mean_probability``, default 0.99999. A single
outlier among n ≥ 10 cannot trip it; a plugin whose measurement size changes (UWB ranges to a
varying set of anchors) restarts its window at each change.

χ²_m is M's law only for white innovations. Real sensors against a real IMU leave residuals
correlated over seconds — BROAD's 10-Hz optical fixes have a lag-1 correlation of 0.96, its
magnetometer a heading residual that drifts with the board's attitude — and then ‖Σ w_k‖² / n
has the mean f·m with f > 1 (for an AR(1) sequence f = (1 + ρ)/(1 − ρ) − 2ρ(1 − ρⁿ)/(n(1 − ρ)²),
28 for n = 50, ρ = 0.96; uncorrected, the test fired in 60 % of BROAD's 5-s windows). Each
plugin therefore learns, from its updates that *passed* every test, the factor
f̂ = mean of ‖Σ w‖² / (n m) over their windows (a batch-means estimate of the long-run variance,
whatever the correlation's shape) and its lag-1 correlation ρ̂; the mean test divides M by the
larger of f̂, the AR(1) factor of ρ̂ and 1 (the batch estimate lags a change of regime — rest to
motion — that ρ̂, from adjacent pairs, follows sooner).
The χ² sum keeps its mean d but its variance grows to 2 d g, g = (1 + ρ̂²)/(1 − ρ̂²) per
plugin (w_k² has lag-j correlation ρ^{2j}); it is tested against Satterthwaite's g·χ²_{d/g}(p),
g the dof-weighted mean over the window. Both are exponentially forgotten over
``REFERENCE_WINDOWS`` windows; a failing update teaches nothing (and breaks the lag chain), so a
fault does not raise its own tolerance — a slowly growing one can, which is the price of
learning the null from the data. ρ̂ is used once ``REFERENCE_PAIRS`` pairs are learned (0
before). Both window tests are armed once the plugin has been learned over
``REFERENCE_SPAN_WINDOWS`` windows; until then its updates fail neither (each still passes its
own gate) and the indicators act alone: at the start the filter's own initial errors and a
sensor's uncalibrated residuals (a hard iron a little beyond its prior) make every innovation
alike, and the χ² sum taken as white isolated a healthy magnetometer within its first seconds
on 8 of 20 random worlds. An update given without its whitened innovation (nothing is learned
from it) is tested by the χ² sum from the start. On the simulator's white
innovations f̂ ≈ 1 and ρ̂ ≈ 0.

A healthy local that fails the test is *isolated* (excluded from fusion and from resets; it keeps
filtering on its own). A local that owns a state that may jump (:mod:`fusion.jumps`: a slip) is
isolated only once it has failed on ``confirm_updates`` consecutive updates: a jump the detector
takes in within that time explains the failure (the windows are then forgotten) and the local
stays in the fusion, aiding with the jump estimated, rather than leaving the SINS to coast.
A local whose failure a jump of another local's state explains is
not isolated at all (:class:`fusion.federated.FederatedFilter` refuses the isolation:
:meth:`FaultMonitor.excuse`). An isolated local is *re-admitted* once it has passed the test
without interruption for ``hold_s`` seconds. Every transition is a :class:`FaultEvent` (written to
``faults.csv``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.config import FaultDetectionOptions
from fusion.kalman import chi2_threshold

MEAN_TEST_MIN_SAMPLES = 10
REFERENCE_SPAN_WINDOWS = 3.0
REFERENCE_PAIRS = 20
REFERENCE_WINDOWS = 10.0
MAX_CORRELATION = 0.99

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


def ar1_sum_variance_factor(n: int, rho: float) -> float:
    """Var(Σ_{k=1..n} w_k) / n for a unit-variance AR(1) sequence with lag-1 correlation ρ."""
    if rho <= 0.0:
        return 1.0
    return (1 + rho) / (1 - rho) - 2 * rho * (1 - rho**n) / (n * (1 - rho) ** 2)


def nis_variance_factor(rho: float) -> float:
    """Var(Σ w_k²) / (2n) for a long unit-variance AR(1) sequence: w_k² has lag-j correlation
    ρ^{2j}, so (1 + ρ²)/(1 − ρ²)."""
    return (1 + rho**2) / (1 - rho**2)


@dataclass
class _Reference:
    """How one plugin's whitened innovations behave while it passes every test, exponentially
    forgotten with time constant ``horizon_s``: the lag-1 correlation ρ̂ and the window-sum
    variance factor f̂ = mean of ‖Σ w‖² / (n m) over the learned windows."""

    horizon_s: float
    lagged: float = 0.0
    power: float = 0.0
    ratio_sum: float = 0.0
    ratio_weight: float = 0.0
    pairs: int = 0
    first_t: float | None = None
    last_t: float | None = None
    previous: NDArray[np.float64] | None = None

    def learn(self, t: float, whitened: NDArray[np.float64], window_ratio: float | None) -> None:
        """Add an update that passed (``window_ratio``: its window's ‖Σ w‖² / (n m), None
        while the window is short); it pairs with the previous one if that passed too."""
        forget = 1.0 if self.last_t is None else math.exp(-(t - self.last_t) / self.horizon_s)
        self.lagged *= forget
        self.power *= forget
        self.ratio_sum *= forget
        self.ratio_weight *= forget
        if self.previous is not None and self.previous.size == whitened.size:
            self.lagged += float(whitened @ self.previous)
            self.power += float(whitened @ whitened)
            self.pairs += 1
        if window_ratio is not None:
            self.ratio_sum += window_ratio
            self.ratio_weight += 1.0
            self.first_t = t if self.first_t is None else self.first_t
        self.previous, self.last_t = whitened, t

    def break_chain(self) -> None:
        """A failing update: it is not a sample of the consistent sequence."""
        self.previous = None

    def armed(self, window_s: float) -> bool:
        """Learned over at least ``REFERENCE_SPAN_WINDOWS`` windows."""
        return (
            self.first_t is not None
            and self.last_t is not None
            and self.last_t - self.first_t >= REFERENCE_SPAN_WINDOWS * window_s
        )

    def rho(self) -> float:
        """ρ̂ in [0, MAX_CORRELATION] (0 until ``REFERENCE_PAIRS`` pairs are learned)."""
        if self.pairs < REFERENCE_PAIRS or self.power <= 0.0:
            return 0.0
        return min(max(self.lagged / self.power, 0.0), MAX_CORRELATION)

    def sum_factor(self, n: int) -> float:
        """f̂ for a window of n updates: the larger of the batch-means estimate and the AR(1)
        factor of ρ̂, never below 1 (never stricter than the plugin's own noise model)."""
        batch = self.ratio_sum / self.ratio_weight if self.ratio_weight else 1.0
        return max(1.0, batch, ar1_sum_variance_factor(n, self.rho()))


@dataclass
class _MeanWindow:
    """Whitened innovations of one plugin over the window, and their running sum."""

    dof: int
    samples: deque[tuple[float, NDArray[np.float64]]] = field(default_factory=deque)
    total: NDArray[np.float64] = field(init=False)

    def __post_init__(self) -> None:
        self.total = np.zeros(self.dof)

    def add(
        self, t: float, whitened: NDArray[np.float64], window_s: float
    ) -> tuple[float, int] | None:
        """Add one update; return ‖Σ w‖² / n and n (None below the minimum count)."""
        self.samples.append((t, whitened))
        self.total += whitened
        while self.samples[0][0] <= t - window_s:
            self.total -= self.samples.popleft()[1]
        n = len(self.samples)
        return (float(self.total @ self.total) / n, n) if n >= MEAN_TEST_MIN_SAMPLES else None


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
        self._window: deque[tuple[float, float, int, float]] = deque()
        self._nis_sum = 0.0
        self._dof_sum = 0
        self._spread_sum = 0.0
        self._clean_since: float | None = None
        self._flag_since: dict[str, float] = {}
        self._means: dict[str, _MeanWindow] = {}
        self._references: dict[str, _Reference] = {}

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
        reference = self._references.get(source)
        if reference is None:
            reference = self._references[source] = _Reference(REFERENCE_WINDOWS * opts.window_s)
        raw_mean = self._window_mean(t, source, whitened)
        mean_statistic, mean_threshold = 0.0, np.inf
        if reference.armed(opts.window_s) and raw_mean is not None and whitened is not None:
            mean_statistic = raw_mean[0] / reference.sum_factor(raw_mean[1])
            mean_threshold = chi2_threshold(whitened.size, opts.mean_probability)
        statistic, threshold = self._window_chi_square(t, nis, dof, reference.rho())
        summed = statistic > threshold and (whitened is None or reference.armed(opts.window_s))
        flagged = (
            opts.use_indicators
            and self._flagged_for(t, source, suspect) >= opts.indicator_confirm_s
        )
        biased = mean_statistic > mean_threshold
        failing = summed or flagged or biased
        if whitened is not None and whitened.size:
            if failing:
                reference.break_chain()
            else:
                reference.learn(t, whitened, None if raw_mean is None else raw_mean[0] / dof)
        if failing:
            self._clean_since = None
            self._failing += 1
            if not self.isolated and self._failing > self.confirm_updates:
                self.isolated = True
                if flagged:
                    reason = "plugin indicator"
                elif summed:
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

    def keep_isolated(self, t: float) -> None:
        """Refuse a re-admission just reported: the local stays isolated and its hold restarts."""
        self.isolated = True
        self._clean_since = t

    def excuse(self) -> None:
        """Refuse an isolation just reported: something else explains the failure, which still
        counts as one, and the local stays in."""
        self.isolated = False

    def isolate(self, t: float, statistic: float, threshold: float, reason: str) -> FaultEvent:
        """Isolate the local for a fault found elsewhere (a jump against its state's direction)."""
        self.isolated = True
        self._clean_since = None
        return FaultEvent(t, self.local, statistic, threshold, ISOLATE, reason)

    def _flagged_for(self, t: float, source: str, suspect: bool) -> float:
        """How long plugin ``source``'s indicator has flagged without a break (s; −inf: it does
        not flag this update)."""
        if not suspect:
            self._flag_since.pop(source, None)
            return -math.inf
        return t - self._flag_since.setdefault(source, t)

    def forget(self) -> None:
        """Empty the windows (a jump taken in, :mod:`fusion.jumps`, explains what they hold);
        isolation and the clean time are kept."""
        self._window.clear()
        self._nis_sum = 0.0
        self._dof_sum = 0
        self._spread_sum = 0.0
        self._means.clear()
        self._failing = 0

    def _window_chi_square(self, t: float, nis: float, dof: int, rho: float) -> tuple[float, float]:
        """Add one update to the local's window (its NIS capped at the χ²_m quantile); return
        T(t) and its threshold."""
        nis = min(nis, chi2_threshold(dof, self.options.probability))
        spread = dof * nis_variance_factor(rho)
        self._window.append((t, nis, dof, spread))
        self._nis_sum += nis
        self._dof_sum += dof
        self._spread_sum += spread
        while self._window[0][0] <= t - self.options.window_s:
            _, old_nis, old_dof, old_spread = self._window.popleft()
            self._nis_sum -= old_nis
            self._dof_sum -= old_dof
            self._spread_sum -= old_spread
        return max(self._nis_sum, 0.0), self.options.threshold_scale * self._sum_quantile()

    def _sum_quantile(self) -> float:
        """Quantile of the window's NIS sum: χ²_d(p), or with serially correlated plugins
        Satterthwaite's g·χ²_{d/g}(p), g = Σ m_k g_k / d (same mean d, variance 2 d g)."""
        g = max(self._spread_sum / self._dof_sum, 1.0)
        if g < 1.0 + 1e-3:
            return chi2_threshold(self._dof_sum, self.options.probability)
        return g * chi2_threshold(max(1, round(self._dof_sum / g)), self.options.probability)

    def _window_mean(
        self, t: float, source: str, whitened: NDArray[np.float64] | None
    ) -> tuple[float, int] | None:
        """‖Σ w‖² / n and n over plugin ``source``'s window (None when the test is off or the
        window is short)."""
        if not self.options.mean_test or whitened is None or whitened.size == 0:
            return None
        window = self._means.get(source)
        if window is None or window.dof != whitened.size:
            window = self._means[source] = _MeanWindow(whitened.size)
        return window.add(t, whitened, self.options.window_s)
