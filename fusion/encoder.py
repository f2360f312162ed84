"""Combining haulage-encoder readings into longer intervals by their exact travel.

An odometer reading is the travel counted over its sample interval divided by the interval's
length (RECORDING_FORMAT.md). An encoder counts whole steps, so a reading is quantized: with a
14 mm count at 20 Hz one count is 0.28 m/s, and a shearer hauling at 0.1 m/s reads 0 or
0.28 m/s, never its speed. The sub-count remainder is carried from one reading to the next, so
the *sum* of the readings' travels is right to one count whatever its length: combining ``n``
readings into one of their whole span divides the quantization error by ``n`` (white noise only
by ``√n``). Left as they were, such readings made every consumer wrong at once — a filter
weighing 0.28 m/s jumps at the encoder's 1 cm/s, a standstill seen in every run of zero counts
(zero-velocity and zero-angular-rate updates while the shearer hauled): 25 m of horizontal RMS
error on a world whose encoder counted 72 steps per metre.

:func:`combine_readings` merges consecutive readings until their span reaches ``1 / rate``:
a combined reading at the time of its last raw reading, whose speed is the span's travel over
the span (the data end closes the last window, however short). It is causal (a combined
reading uses raw readings up to its own time only) and a reading slower than the rate is kept
as it is. The engine hands every plugin the combined
stream (``streams.odometer_max_rate_hz``), so the odometer, the zero-velocity detector and
CPOEM see the same readings.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.recording import OdometerData, long_intervals

MISSING_READINGS_FACTOR = 1.5
"""A reading further than this many median intervals from the previous one has rows missing
before it (one missing row doubles the interval; a logger's jitter stays well within half)."""


def reading_intervals(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each reading's interval, from the previous reading to it (a reading is the mean speed
    over its interval); the first one, which has no predecessor, is taken as the median
    interval. Needs at least two readings. Across missing rows (:func:`after_missing_readings`)
    the reading is held over the whole gap: the travel there was not counted, and this is the
    zero-order estimate of it."""
    return np.diff(t, prepend=t[0] - float(np.median(np.diff(t))))


def after_missing_readings(t: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Per reading, whether rows are missing before it: its interval from the previous reading
    is longer than :data:`MISSING_READINGS_FACTOR` median intervals
    (:func:`fusion.recording.long_intervals`, as the reader finds IMU gaps). Missing rows are absent
    and every row is still the mean over its own sample interval (RECORDING_FORMAT.md), so
    such a reading is no mean since the previous one (a 60-s dropout's first reading taken as
    the mean over the dropout moved a coasting SINS's velocity by its mean error and set its σ
    to the encoder's: 1.3 m/s off at a σ of 1 cm/s)."""
    after = np.zeros(t.size, dtype=bool)
    after[1:] = long_intervals(t, MISSING_READINGS_FACTOR)[0]
    return after


def combine_readings(odometer: OdometerData, max_rate_hz: float) -> OdometerData:
    """Readings merged until each spans at least ``1 / max_rate_hz`` (module docstring), each
    reading over its :func:`reading_intervals`."""
    t = odometer.t
    if t.size < 2:
        return odometer
    dt = reading_intervals(t)
    travel = np.concatenate([[0.0], np.cumsum(odometer.speed * dt)])
    start = np.concatenate([[t[0] - dt[0]], t])  # start[k]: beginning of reading k's interval
    ends = _window_ends(start, 1.0 / max_rate_hz)
    if ends.size == t.size:
        return odometer
    first = np.concatenate([[0], ends[:-1] + 1])
    speed = (travel[ends + 1] - travel[first]) / (t[ends] - start[first])
    return OdometerData(t=t[ends].copy(), speed=speed)


def _window_ends(start: NDArray[np.float64], span: float) -> NDArray[np.intp]:
    """Indices of the readings that close a window: the reading whose interval end is the first
    at least ``span`` after the window's beginning (greedy, in time order), and the last one.
    ``start`` holds each reading's interval start and, last, the last reading's time."""
    ends = []
    begin = float(start[0])
    for k in range(1, start.size):
        if start[k] - begin >= span - 1e-9:
            ends.append(k - 1)
            begin = float(start[k])
    if not ends or ends[-1] != start.size - 2:
        ends.append(start.size - 2)  # the data end closes the last window, however short
    return np.asarray(ends, dtype=np.intp)
