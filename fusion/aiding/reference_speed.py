"""The vehicle speed at which the odometer's scale and attitude columns are evaluated.

The odometer's measurement (:mod:`fusion.aiding.odometer`) has the columns ``−v`` for the scale
error δk_D (and the slip s) and ``−C (v^n×)`` for the attitude, a derivative taken at the vehicle's
speed v. Which estimate of v goes there decides whether the filter stays consistent:

* Not this epoch's reading and not the SINS velocity: both carry errors that are also in this
  epoch's residual z, and a column correlated with its own residual makes every update push
  the scale the same way (at a standstill δk_D walked to −0.05 against a true +0.01).
* Not the readings just before either, although that is what the plain 1-s window gives. The
  filter's velocity estimate holds those readings' noise through the corrections they made, so
  the column is still correlated with z; and at a constant speed δk_D and the velocity along the
  track are one unobservable direction ``[v, 1]`` whose Jacobian the column's noise keeps
  turning. With R at the encoder's own noise the two effects walk the pair along it
  (``longwall-200m``, 8 seeds of 300 s, sins_od_ckf with σ 2 mm/s: δk_D 3.0–4.3σ off, position
  RMS(ε/σ) 1.41, horizontal RMS 1.14 m). With the noise-free encoder speed as the column the
  same runs give 0.1–1.6σ, 1.15 and 0.35 m: the walk is the column's, not the data's.

The column therefore takes, while the speed is steady, the mean of a long *steady window*
(``steady_window_s``, 10 s) ending ``steady_lag_s`` (2 s) before the reading: its noise is a
third of the 1-s mean's, it changes little from one epoch to the next, and it holds no reading
the velocity estimate still remembers. The speed is steady when the 1-s mean before the reading
(the *short window*, ``reference_window_s``) agrees with the steady window's mean within 3σ of
their difference,

    |s̄_short − s̄_steady| ≤ 3 σ̂ √(1/n_short + 1/n_steady),

with the readings' noise σ̂ from their successive differences in the steady window,
``σ̂² = Σ (s_j − s_{j−1})² / (2 (n − 1))`` (insensitive to a slow change of speed; it includes
what vibration puts into the readings). When they disagree, the SINS decides: if its own speed
along the track over the same two windows (from ``MeasurementContext.travel``) changed by less
than the same bound, the readings moved without the machine — a wheel that started to slip —
and the steady window, which the slip has not reached, stays; otherwise the machine changed
speed and the short window follows it within a second.

While the speed stays steady the column takes the mean of the whole *steady segment*: every
reading from the segment's start to the steady window's end. A sliding window's mean moves from
one reading to the next by about σ̂ √2 / n, for as long as the machine runs, and each move turns
the direction ``[v, 1]`` the filter takes for unobservable: the filter learns δk_D from the
column's noise. A growing segment's mean moves by σ̂ / n, and the sum of its moves converges.
With a 1-Hz encoder (σ̂ 16 mm/s, the machine cutting at 65 mm/s: the 10-s window's mean moved
3.5 % per reading) δk_D walked from 0 to −9.9 % at a σ of 2.8 % over a 4100-s pass, against a
true +0.8 %, and the run ended 17 m off (sins_od_ckf, full-length random world 2); with the
segment −0.2 % and 2.5 m horizontal RMS, with the true speed as the column 2.3 m. A segment
starts with the steady window at a run's start, at the first reading of a change of speed or of
a slip taken in, and again at the steady window's start when the window's mean leaves the
segment's by more than 4σ of their difference (a slow change of speed;
:meth:`ReferenceSpeed._segment_mean`).
A column steadier than the machine's speed costs information the speed changes carry; one
noisier than it invents information.

Measured with R at the encoder's 2 mm/s (``longwall-200m``, 8 seeds of 300 s): δk_D 0.4–1.2σ
off, position RMS(ε/σ) 0.78, horizontal RMS 0.38 m (20 seeds: see the odometer's Monte Carlo
test). At the shipped 1 cm/s: 0.27 m (0.28 m with the short window alone); ``seed000-carrier``
(reversals every pass) and full_ckf over 1200 s of ``longwall-200m`` (0.066 m) unchanged. A
reference *held* while the readings stayed within 10 % of it had cost full_ckf 40 %: the steady
window is never more than its 3σ bound away from the last second's readings.

Each reading is divided by the scale in effect when it was read, ``1 + δk̂_D + s(t_j)``: a slip
taken in (:mod:`fusion.jumps`) splits a window at its onset, the readings before it divided by
the slip estimate of before (:meth:`ReferenceSpeed.jumped`). Without the split, the second after
a 30 % slip was taken in had columns 20 % short, a residual of 5 cm/s (NIS 22), and the filter
moved the position 1.2 m along the track to explain it (``seed003-brokenline`` seed 2,
sins_od_mag_afkf: worst horizontal 5.6 m against 3.3 m without the slip; 3.2 m with the split).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

STEADY_SIGMAS = 3.0
"""The speed is steady while the short and steady means agree within this many σ."""

SEGMENT_SIGMAS = 4.0
"""A steady segment starts again when the steady window's mean leaves the segment's by this many
σ of their difference. The test repeats at every reading of a segment that may last an hour,
and a false restart moves the column by the window's noise: at 3σ a steady 1-Hz machine
restarted twice in 900 readings (``test_reference_speed_steady_segment``), at 4σ (a chance of
6·10⁻⁵ per reading) not once."""


def reading_noise(
    speed: NDArray[np.float64], first: NDArray[np.intp], last: NDArray[np.intp]
) -> NDArray[np.float64]:
    """The readings' noise σ̂ in each window ``speed[first:last]`` from their successive
    differences, ``σ̂² = Σ (s_j − s_{j−1})² / (2 (n − 1))`` over the pairs inside the window
    (insensitive to a slow change of speed; it includes what vibration puts into the readings;
    0 for a window of fewer than two readings)."""
    return window_noise(summed_steps(speed), first, last)


def window_noise(
    total_step2: NDArray[np.float64], first: NDArray[np.intp] | int, last: NDArray[np.intp] | int
) -> NDArray[np.float64]:
    """:func:`reading_noise` from the readings' :func:`summed_steps`."""
    pairs = np.maximum(np.subtract(last, first) - 1, 1)
    steps = total_step2[last] - total_step2[np.minimum(np.add(first, 1), last)]
    noise: NDArray[np.float64] = np.sqrt(steps / (2.0 * pairs))
    return noise


def summed_steps(speed: NDArray[np.float64]) -> NDArray[np.float64]:
    """``Σ (s_j − s_{j−1})²`` over the readings before each index (0 and 1: none)."""
    step = np.diff(speed, prepend=speed[:1])
    return np.concatenate([[0.0], np.cumsum(step**2)])


class ReferenceSpeed:
    """Per reading, the window of earlier readings whose mean is the column's speed.

    Parameters
    ----------
    t, speed
        Odometer times (s) and readings (m/s).
    short_s
        The window before a reading used while the speed changes.
    steady_s, lag_s
        The steady window's length and its gap before the reading (``steady_s`` 0: always the
        short window). ``lag_s`` is at least ``short_s``, so that the windows do not overlap.
    """

    def __init__(
        self,
        t: NDArray[np.float64],
        speed: NDArray[np.float64],
        short_s: float,
        steady_s: float,
        lag_s: float,
    ) -> None:
        self.t, self.speed = t, speed
        index = np.arange(t.size)
        previous = np.maximum(index - 1, 0)
        self.short = (np.minimum(np.searchsorted(t, t - short_s, side="left"), previous), index)
        self.steady = (
            np.searchsorted(t, t - lag_s - steady_s, side="left"),
            np.minimum(np.searchsorted(t, t - lag_s, side="left"), previous),
        )
        self._total = np.concatenate([[0.0], np.cumsum(speed)])
        self._steps = summed_steps(speed)
        self.bound = self._bound() if steady_s > 0 else np.full(t.size, -1.0)
        self._segment: int | None = None  # first reading of the steady segment
        self._floor = 0  # no segment starts before the last slip onset
        self.travel = np.full((t.size, 3), np.nan)  # the SINS's ∫ v^n dt at each reading
        self._onsets: list[tuple[float, float]] = []  # (onset, slip estimate before it)

    def _bound(self) -> NDArray[np.float64]:
        """3σ of the difference of the two windows' means (−1 where a window is too short)."""
        (short_first, short_last), (steady_first, steady_last) = self.short, self.steady
        n_short = short_last - short_first
        n_steady = steady_last - steady_first
        usable = (n_short >= 1) & (n_steady >= 2)
        n_short, n_steady = np.maximum(n_short, 1), np.maximum(n_steady, 2)
        noise = window_noise(self._steps, steady_first, steady_last)
        bound = STEADY_SIGMAS * noise * np.sqrt(1.0 / n_short + 1.0 / n_steady)
        return np.where(usable, bound, -1.0)

    def start_run(self) -> None:
        """Forget a run's SINS travel and slip onsets."""
        self.travel.fill(np.nan)
        self._onsets.clear()
        self._segment = None
        self._floor = 0

    def jumped(self, onset: float, before: float) -> None:
        """A slip jump taken in at ``onset``; the slip estimate was ``before`` until then."""
        self._onsets.append((onset, before))
        self._floor = int(np.searchsorted(self.t, onset))
        self._segment = self._floor

    def at(self, index: int, scale_error: float, slip: float, along: NDArray[np.float64]) -> float:
        """The speed of reading ``index``'s columns (``slip``: the current slip estimate, 0
        without one; ``along``: the travel axis in n).

        The steady segment's mean (:meth:`_segment_mean`) while the short and steady windows'
        means agree (each reading divided by the scale in effect when read), or while they
        differ but the SINS speed along the track over the same windows changed by less than
        the same bound — a wheel that slipped, not a machine that changed speed; otherwise the
        short window's.
        """
        short = self._corrected_mean(*_window(self.short, index), scale_error, slip)
        bound = self.bound[index] / (1.0 + scale_error + slip)  # the readings' 3σ, in speed
        if bound < 0:
            self._segment = None
            return short
        steady = self._corrected_mean(*_window(self.steady, index), scale_error, slip)
        if abs(short - steady) > bound:
            sins_change = self._sins_speed(self.short, index, along) - self._sins_speed(
                self.steady, index, along
            )
            if not abs(sins_change) <= bound:  # NaN (no record): the machine changed speed
                self._segment = max(int(self.short[0][index]), self._floor)
                return short
        return self._segment_mean(index, steady, scale_error, slip)

    def _segment_mean(self, index: int, steady: float, scale_error: float, slip: float) -> float:
        """Mean of the steady segment: the readings from the segment's start to the steady
        window's end, once the segment is longer than the window (the window's mean until
        then). A segment starts with the steady window at a run's start, at the first reading
        of a change of speed or of a slip taken in (never before the last slip's onset, whose
        readings before and after differ by the slip), and again at the steady window's start
        when the two means differ by more than :data:`SEGMENT_SIGMAS` times the σ of their
        difference, ``σ̂ √(1/n_steady − 1/n_segment)`` (the window is part of the segment; σ̂
        from the segment's successive differences, as :func:`reading_noise`)."""
        first, last = _window(self.steady, index)
        if self._segment is None:
            self._segment = max(first, self._floor)
        if self._segment >= first:
            return steady
        spread = 1.0 / (last - first) - 1.0 / (last - self._segment)
        segment = self._corrected_mean(self._segment, last, scale_error, slip)
        noise = float(window_noise(self._steps, self._segment, last)) / (1.0 + scale_error + slip)
        if abs(segment - steady) > SEGMENT_SIGMAS * noise * math.sqrt(spread):
            self._segment = max(first, self._floor)
            return steady
        return segment

    def _corrected_mean(self, first: int, last: int, scale_error: float, slip: float) -> float:
        """Mean of the readings ``first:last``, each divided by the scale in effect when read."""
        if last <= first:
            return 0.0
        if not self._onsets or self._onsets[-1][0] <= self.t[first]:  # onsets in time order
            return float(self._total[last] - self._total[first]) / (
                (last - first) * (1.0 + scale_error + slip)
            )
        times = self.t[first:last]
        slips = np.full(times.size, slip)
        pending = np.ones(times.size, bool)
        for onset, before in self._onsets:  # in time order: the first later onset decides
            earlier = pending & (times < onset - 1e-9)
            slips[earlier] = before
            pending &= ~earlier
        return float(np.mean(self.speed[first:last] / (1.0 + scale_error + slips)))

    def _sins_speed(
        self,
        window: tuple[NDArray[np.intp], NDArray[np.intp]],
        index: int,
        along: NDArray[np.float64],
    ) -> float:
        """SINS mean speed along the travel axis over the intervals of a window's readings."""
        first, last = int(window[0][index]) - 1, int(window[1][index]) - 1
        if first < 0 or last <= first:
            return float("nan")
        travel = float(along @ (self.travel[last] - self.travel[first]))
        return travel / float(self.t[last] - self.t[first])


def _window(window: tuple[NDArray[np.intp], NDArray[np.intp]], index: int) -> tuple[int, int]:
    """The first and past-the-last reading of reading ``index``'s window."""
    return int(window[0][index]), int(window[1][index])
