"""Lost lock: a plugin whose every update the filter rejects, and its re-acquisition.

A filter that has drifted far from the truth — a SINS coasting through a face traversal with no
aiding in reach, then meeting the UWB anchors of the other face end — rejects every reading of
a healthy sensor at its χ² gate: the innovations are far outside S because the σ is far below
the error. Nothing then brings it back (``sins_uwb`` on random worlds: 10⁶ m horizontal RMS, the
fix never re-acquired at the next face end), and nothing says so.

:class:`LockMonitor` watches one gated plugin's updates: when over the last ``window_s`` it has had
at least ``min_updates`` and the filter rejected every one, while no other plugin had an update
accepted (another sensor still holding the filter makes this one the suspect: NLOS on every anchor
looks the same from the UWB alone), the lock is lost. The engine then asks the plugin for what it
can say alone (:meth:`fusion.plugin.Plugin.reacquire`, e.g. a UWB least-squares fix from the ranges
of the last seconds), restarts the filter's position and velocity at that fix, uncorrelated with the
rest, and writes a ``reacquire`` line to ``faults.csv`` (a fix within the filter's own σ, from a
filter uncertain rather than lost, is taken in as a position update instead:
``Engine._take_in_fix``). A plugin whose every update is rejected while another still holds the
filter is not re-acquired from, but gets one ``disputed`` line until one of its updates is accepted
again: either it or the filter is wrong, and the user is told. The jump detector is then asked
whether a jump of a holder's state since the plugin last agreed (a wheel that began to slip
while no range came) explains the rejected update, and takes it in if so
(:meth:`fusion.jumps.JumpDetector.unseen_jump`). A plugin that cannot say where the
machine is (an odometer, a motion constraint) gets a ``lost lock`` line, and the variances of the
SINS states are multiplied by the fading factor λ of the last rejected innovation
(:func:`fading_factor`): the smallest λ with ``νᵀ (λ H P Hᵀ + R)⁻¹ ν = m``, the factor that makes
that innovation a 1-σ one (the fading-memory step; Fagin 1964; Xia, Rao, Ying & Shen, *Adaptive
fading Kalman filter with an application*, Automatica 1994), at most :data:`MAX_FADING`, the
attitude's only up to a σ of :data:`MAX_INFLATED_ATTITUDE_SIGMA` (:func:`inflation_variances`). The
increase is added as uncorrelated noise (:meth:`fusion.kalman.KalmanFilter.add_variances`), not as
``λ P``: the velocity–attitude correlations of a converged SINS, kept at full strength, let the
first zero velocity after the inflation swing the attitude. A SINS whose gyro bias is several times
its prior (a harsh world's 2700 °/h against 720 °/h) otherwise tilts faster than its covariance
allows, has every odometer update rejected from its first seconds, and coasts for the rest of the
recording. Not when the plugin doubts that the lost lock is the SINS's
(:meth:`fusion.plugin.Plugin.lost_lock_doubt`: a ZUPT whose standstill only the IMU's detector
claims, which a car at a steady speed fools): the line is written, nothing inflated. Only the
SINS states are inflated: the rejected plugin's own states (mounting, scale)
would otherwise take up the next update instead of the SINS. Once per loss: a lost lock again before
a window with most updates accepted is only reported (:meth:`LockMonitor.first_inflation`). An
encoder cannot say where the machine is, but it can say what the machine does: once an
inflation has not brought its readings back, it re-acquires the velocity (zero at a standstill,
its speed along the travel axis while the machine hauls) and the tilt from the accelerometers
(:class:`RestLevel`, less the haulage's acceleration;
:meth:`fusion.aiding.odometer.Odometer.reacquire`). Either way the monitor starts over.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from fusion.earth import normal_gravity
from fusion.error_model import ATTITUDE, COMMON_BLOCKS, ImuNoise
from fusion.recording import Recording

if TYPE_CHECKING:
    from fusion.plugin import Measurement

LOST_LOCK, REACQUIRE, DISPUTED = "lost lock", "reacquire", "disputed"


@dataclass(frozen=True)
class Level:
    """The tilt of a SINS at rest, from the gravity its accelerometers read: the attitude error
    ``φ`` (rad, local ENU; vertical component zero) whose removal (``C ← R(φ) C̃``) turns the
    measured specific force vertical, and the variance of each of its two horizontal
    components (rad²)."""

    attitude_error: NDArray[np.float64]
    variance: float


@dataclass(frozen=True)
class Reacquisition:
    """Where a plugin says the IMU is and how it moves, from its own readings alone: origin-ENU
    position (m) and velocity (m/s) with their covariances (origin ENU axes); ``level``: the
    tilt, from a plugin that knows the machine stands (a ZUPT), restarted with the velocity
    whether or not the position fix agrees with the filter."""

    position_enu: NDArray[np.float64]
    covariance: NDArray[np.float64]
    velocity_enu: NDArray[np.float64]
    velocity_covariance: NDArray[np.float64]
    level: Level | None = None


def level(force_n: NDArray[np.float64]) -> NDArray[np.float64]:
    """The attitude error ``φ`` (rad, local ENU) of a SINS at rest whose nominal attitude puts
    the measured specific force at ``force_n``: the rotation, about a horizontal axis, that
    turns it up (``C ← R(φ) C̃``; exact for any tilt, ``φ ≈ (f_n, −f_e)/g`` for a small one)."""
    unit = force_n / np.linalg.norm(force_n)
    axis = np.cross(unit, np.array([0.0, 0.0, 1.0]))
    sine = float(np.linalg.norm(axis))
    if sine == 0.0:
        return np.zeros(3) if unit[2] > 0 else np.array([math.pi, 0.0, 0.0])
    return axis / sine * math.atan2(sine, float(unit[2]))


class RestLevel:
    """The tilt of a machine known to stand, or to move at a known acceleration, from its
    accelerometers (:class:`Level`): the re-acquisition of a plugin that knows the standstill
    (a ZUPT, an encoder at rest) or the haulage (an encoder in motion).

    The mean specific force of the last seconds, less the fed-back accelerometer bias and the
    known acceleration, is the vertical (:func:`level`) to within the datasheet accelerometer
    bias over gravity (an unknown bias tilts the measured vertical by ``b/g``), the mean's white
    noise (the samples' scatter over their number) and, for a known acceleration ``a``, ``|a|/g``
    (how far it may have changed over the window)."""

    def __init__(self, recording: Recording) -> None:
        self._imu = recording.imu
        spec = recording.meta.imu.spec
        self._accel_bias_sigma = (
            ImuNoise.from_datasheet(**spec.model_dump()).accel_bias
            if spec is not None and None not in spec.model_dump().values()
            else None
        )
        origin = recording.meta.origin
        self._gravity = float(normal_gravity(math.radians(origin.lat_deg), origin.height_m))

    def over(
        self,
        start: float,
        end: float,
        c_b_n: NDArray[np.float64],
        accel_bias: NDArray[np.float64],
        acceleration: NDArray[np.float64] | None = None,
    ) -> Level | None:
        """The level from the IMU samples in ``(start, end]`` at the nominal attitude
        ``c_b_n`` with the fed-back bias ``accel_bias`` and the machine's ``acceleration``
        (m/s², body; None: it stands); None without a sample."""
        samples = (self._imu.t > start) & (self._imu.t <= end)
        accel = self._imu.accel[samples]
        if not accel.shape[0]:
            return None
        known = np.zeros(3) if acceleration is None else acceleration
        tilt = level(c_b_n @ (accel.mean(axis=0) - accel_bias - known))
        n = accel.shape[0]
        scatter = float(np.mean(np.var(accel, axis=0, ddof=1))) / n if n > 1 else 0.0
        variance = scatter / self._gravity**2
        variance += float(known @ known) / self._gravity**2
        if self._accel_bias_sigma is not None:
            variance += (self._accel_bias_sigma / self._gravity) ** 2
        return Level(tilt, variance)


FIX_GATE_PROBABILITY = 0.999
"""χ² probability within which a re-acquisition fix of a plugin without a gate of its own agrees
with the filter (and is taken in as an update rather than restarting the position)."""


@cache
def _agreement_threshold(rows: int) -> float:
    return float(chi2.ppf(FIX_GATE_PROBABILITY, rows))


def agrees(measurement: Measurement, covariance: NDArray[np.float64]) -> bool:
    """Whether the filter's ``covariance`` explains a measurement's innovation: ``zᵀ S⁻¹ z``
    with ``S = H P Hᵀ + R`` within χ²_m(:data:`FIX_GATE_PROBABILITY`) for its m rows. A plugin
    that re-acquires at rest (a ZUPT, an encoder) keeps the position of the last epoch that
    agreed as the place to go back to."""
    h = measurement.H
    s = h @ covariance @ h.T + measurement.R
    try:
        statistic = float(measurement.z @ np.linalg.solve(s, measurement.z))
    except np.linalg.LinAlgError:
        return False
    return statistic <= _agreement_threshold(measurement.z.size)


MAX_FADING = 1e4
"""Largest fading factor (a σ 100 times the filter's): an innovation that no inflation of
``H P Hᵀ`` within it explains lies mostly in R's directions — the sensor's own inconsistency,
which no SINS covariance can absorb."""


MAX_INFLATED_ATTITUDE_SIGMA = math.radians(30.0)
"""Largest attitude σ an inflation gives: the error state is a small angle, and beyond some
tens of degrees its first-order model describes nothing (a ×1000 inflation gave a yaw σ of
3000° and sent a UWB-aided filter 2.8·10⁷ m off)."""


def inflation_variances(variances: NDArray[np.float64], factor: float) -> NDArray[np.float64]:
    """The variances to add to the 15 common (SINS) states, in layout order, to multiply
    ``variances`` by ``factor``: ``(factor − 1) P_ii``, the attitude's only up to a σ of
    :data:`MAX_INFLATED_ATTITUDE_SIGMA` (an attitude σ already beyond it stays)."""
    added = (factor - 1.0) * np.asarray(variances, dtype=float)
    attitude = slice(3 * COMMON_BLOCKS.index(ATTITUDE), 3 * COMMON_BLOCKS.index(ATTITUDE) + 3)
    room = np.maximum(MAX_INFLATED_ATTITUDE_SIGMA**2 - variances[attitude], 0.0)
    added[attitude] = np.minimum(added[attitude], room)
    return added


def fading_factor(
    innovation: NDArray[np.float64], predicted: NDArray[np.float64], noise: NDArray[np.float64]
) -> float:
    """The fading factor λ ≥ 1 with ``νᵀ (λ A + R)⁻¹ ν = m`` (module docstring) for innovation
    ``ν`` (m,), its state part ``A = H P Hᵀ`` and noise part ``R`` (m, m); 1 when ``ν`` is
    already within that, :data:`MAX_FADING` when no λ up to it suffices.

    The statistic falls monotonically in λ; it is solved by bisection on log λ.
    """
    m = innovation.size

    def excess(lam: float) -> float:
        return float(innovation @ np.linalg.solve(lam * predicted + noise, innovation)) - m

    if excess(1.0) <= 0.0:
        return 1.0
    if excess(MAX_FADING) > 0.0:
        return MAX_FADING
    lo, hi = 0.0, math.log(MAX_FADING)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(math.exp(mid)) > 0.0 else (lo, mid)
    return math.exp(hi)


class LockMonitor:
    """Rejections of one plugin's updates over a sliding window (module docstring).

    Parameters
    ----------
    window_s
        Shortest length of the window (s).
    min_updates
        Updates the window must hold before a lost lock is declared: it reaches back as far as
        its latest ``min_updates`` updates, beyond ``window_s`` for a slow sensor. A window of
        ``window_s`` alone never held 10 readings of an encoder at 1 or 2 Hz, and a SINS that
        tilted away from its first zero speed coasted 900 km with every one rejected and no
        line in ``faults.csv`` (docs/design/2026-12-02-initial-attitude-covariance.md).
    """

    def __init__(self, window_s: float, min_updates: int) -> None:
        self.window_s = window_s
        self.min_updates = min_updates
        self._updates: deque[tuple[float, bool]] = deque()
        self._accepted = 0
        self._since: float | None = None
        self.last_accepted: float | None = None
        """Time of the last update the filter accepted (None: none yet)."""
        self._inflated = False
        self._disputed = False

    def first_dispute(self) -> bool:
        """Whether a lost lock the engine will not re-acquire from (another plugin holds the
        filter) is to be reported: only the first since one of the plugin's updates was
        accepted."""
        if self._disputed:
            return False
        self._disputed = True
        return True

    def first_inflation(self) -> bool:
        """Whether the filter may inflate for this lost lock: not when it already did for an
        earlier one and no full window since has had most of its updates accepted. An
        inflation that did not bring the plugin's updates back shows a sensor the gate is right
        to reject (a false standstill, a slipping wheel): repeated ones compounded (×16, ×15,
        ×29 … every 3 s, each followed by one accepted update, on a random world's SINS + ZUPT:
        σ 10⁵ times its size and the SINS 15 km off)."""
        if self._inflated:
            return False
        self._inflated = True
        return True

    def observe(self, t: float, accepted: bool) -> bool:
        """Add one update; whether the lock is lost (every update of a full window rejected)."""
        if accepted:
            self.last_accepted = t
            self._disputed = False
        if self._since is None:
            self._since = t
        self._updates.append((t, accepted))
        self._accepted += accepted
        while len(self._updates) > self.min_updates and self._updates[0][0] <= t - self.window_s:
            self._accepted -= self._updates.popleft()[1]
        full = t - self._since >= self.window_s and len(self._updates) >= self.min_updates
        if full and 2 * self._accepted >= len(self._updates):
            self._inflated = False  # the lock is back: a window with most updates accepted
        return full and self._accepted == 0

    def span_s(self, t: float) -> float:
        """How far back from ``t`` the window reaches (s): its first update's age."""
        return t - self._updates[0][0] if self._updates else 0.0

    def reset(self) -> None:
        """Start over (after a re-acquisition, or a lost lock reported): the next lost lock
        needs a whole window of rejections again."""
        self._updates.clear()
        self._accepted = 0
        self._since = None
