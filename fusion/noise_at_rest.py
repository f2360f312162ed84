"""The IMU's white noise measured while the recording starts at rest, where it is worse than the
datasheet's.

A datasheet states a typical unit when new. A unit in a shearer can be worse: aged, hot, shaken
loose on its mount, or simply a worse part than the one the datasheet was written for. The
filter's angle and velocity random walks (``Q``), the ZARU's noise and the ZUPT's thresholds are
all derived from the datasheet's figures (``meta.yaml`` ``imu.spec``), so an IMU twice as noisy
as stated makes every one of them half what it should be: the filter's σ then promises twice
what it keeps (docs/design/2026-12-01-noise-at-rest.md).

The white noise of a sensor at rest is directly measurable (it is the short-τ branch of the
Allan deviation: IEEE Std 952-1997 App. C, El-Sheimy, Hou & Niu, *IEEE Trans. Instrum. Meas.*
57(1), 2008). Over the first :data:`WINDOW_S` seconds of the recording, each of the six axes
gives

    σ̂_white = 1.4826 · MAD(x_{k+1} − x_k) / √2,

the per-sample σ of white noise from successive differences (which remove the earth rate,
gravity and any bias), robust to a stray sample through the median absolute deviation. The
window is at rest when no axis moves beyond its noise: the spread of x about its median,
``1.4826 · MAD(x)``, stays within :data:`AT_REST_RATIO` × σ̂_white on every axis (a turn, a
tilt or a start adds a signal that differences remove and the spread does not); and what it
holds is white noise when its successive differences are correlated as white noise's are, one
to three samples apart (:data:`WHITE_CORRELATION`: a vibration is not a random walk, and an
idling engine's is no sensor's noise). At rest, the
median of the three axes over the datasheet's per-sample σ (``N·√rate`` for an ARW or VRW
``N``) is the sensor's factor; where it exceeds :data:`TOLERANCE`, the datasheet figure is
replaced by the measured one for the whole run, as an INS's static alignment measures before it
navigates (a live engine holds its first output for the window). Never lowered: a quiet
window is no evidence that the datasheet's in-run figures are too large. Beyond :data:`CAP`
it is not taken: no unit is that far off its own datasheet, and such a window holds
vibration, not a sensor's noise.

A configuration that sets ``imu.gyro_arw_deg_rth`` or ``imu.accel_vrw_mg_rthz`` itself has
said what it wants: that figure is left alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from fusion.config import ImuTuning
from fusion.error_model import ImuNoise
from fusion.recording import ImuData, Recording

WINDOW_S = 20.0
"""Length of the window at the recording's start (s): 2 000 samples at 100 Hz, a σ known to
about 2 % (a median of three axes, each 1/√(2N) relative)."""
MIN_SAMPLES = 200
"""Fewer samples in the window measure nothing."""
AT_REST_RATIO = 2.0
"""An axis whose spread about its median exceeds this many σ̂_white is moving."""
WHITE_CORRELATION = 0.15
"""Largest departure of the differences' correlation at lags 1 … :data:`WHITE_LAGS` from white
noise's (for white noise its σ is √(1.5/N), 0.027 for 2 000 samples: 0.15 is 5.5σ, as 18 such
figures are tested): beyond it the window holds a vibration (an engine idling, a conveyor
running), whose variance is no random walk."""
WHITE_LAGS = 3
"""Lags tested: a sinusoid at a quarter of the sample rate looks white at lag 1 but not at lag
2, and no frequency looks white at all three."""
TOLERANCE = 1.5
"""A noise within 1.5× the datasheet's is taken as the datasheet says: a σ off by less is within
the band [0.6, 1.5] of RMS(ε/σ) that the project holds a consistent filter to, and within the
spread between a datasheet's typical and maximum figures. The check is for a datasheet that is
grossly wrong for the unit."""
CLIP = 10.0
"""A difference beyond this many σ̂ is a stray sample: :func:`whiteness` clips it there."""
CAP = 10.0
"""A factor beyond this is vibration or motion, not a sensor's white noise."""
_MAD = 1.4826  # σ of a normal distribution per median absolute deviation


@dataclass(frozen=True)
class RestNoise:
    """What the window at the start measured (module docstring)."""

    gyro_factor: float = math.nan
    """Measured white noise of the gyros ÷ the datasheet's ARW (NaN: not measured)."""
    accel_factor: float = math.nan
    """The same for the accelerometers against the VRW."""
    taken: tuple[str, ...] = ()
    """``imu.spec`` figures replaced by the measured ones."""
    reason: str = ""
    """Why nothing was measured (empty when it was)."""

    def describe(self) -> str:
        """One line for the run summary."""
        if self.reason:
            return f"not measured: {self.reason}"
        figures = f"gyros {self.gyro_factor:.2f}×, accelerometers {self.accel_factor:.2f}×"
        if not self.taken:
            return f"{figures} the datasheet's white noise: the datasheet's figures are kept"
        taken = ", ".join(self.taken)
        return f"{figures} the datasheet's white noise: the filter takes the measured {taken}"

    def to_dict(self) -> dict[str, object]:
        """For ``metrics.json``."""
        return {
            "window_s": WINDOW_S,
            "gyro_factor": None if math.isnan(self.gyro_factor) else self.gyro_factor,
            "accel_factor": None if math.isnan(self.accel_factor) else self.accel_factor,
            "taken": list(self.taken),
            "reason": self.reason,
        }


def robust_sigma(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per column of ``x`` (samples × axes), its σ from the median absolute deviation about its
    median: a normal distribution's σ, unmoved by a stray sample."""
    return _MAD * np.median(np.abs(x - np.median(x, axis=0)), axis=0)


def whiteness(d: NDArray[np.float64], lags: int = WHITE_LAGS) -> NDArray[np.float64]:
    """Per column of the successive differences ``d`` of a window, how far they are from those
    of white noise: the correlation of d with itself 1 … ``lags`` samples on, less white
    noise's (−½ at lag 1, 0 beyond), as a lags × columns array (each ±√(1.5/N) for white
    noise). Differences leave out a slow drift (a bias wandering over the window), which is no
    vibration; a stray sample is clipped to :data:`CLIP` σ̂ so that it cannot carry the sums."""
    d = d - np.median(d, axis=0)
    bound = CLIP * robust_sigma(d)
    d = np.clip(d, -bound, bound)
    power = np.sum(d * d, axis=0)
    rho = np.array([np.sum(d[k:] * d[:-k], axis=0) / power for k in range(1, lags + 1)])
    rho[0] += 0.5
    return rho


class StartWindow(NamedTuple):
    """The IMU's first :data:`WINDOW_S` seconds (:func:`start_window`)."""

    samples: NDArray[np.float64]
    """Gyro then accelerometer axes (samples × 6)."""
    white: NDArray[np.float64]
    """Per axis, σ̂_white of one sample (module docstring)."""
    rate_hz: float
    reason: str
    """Why the window is not at rest (empty when it is)."""


def start_window(imu: ImuData, window_s: float = WINDOW_S) -> StartWindow:
    """The first ``window_s`` seconds of ``imu``, and whether it is at rest there: enough
    samples, noise on every axis, and no axis spread about its median beyond
    :data:`AT_REST_RATIO` × its σ̂_white (module docstring)."""
    window = imu.t < imu.t[0] + window_s
    samples = np.hstack([imu.gyro[window], imu.accel[window]])
    if int(window.sum()) < MIN_SAMPLES or imu.t[-1] - imu.t[0] < window_s:
        reason = f"fewer than {MIN_SAMPLES} samples in the first {window_s:g} s"
        return StartWindow(samples, np.full(6, np.nan), math.nan, reason)
    white = robust_sigma(np.diff(samples, axis=0)) / math.sqrt(2.0)  # per sample
    rate = 1.0 / float(np.median(np.diff(imu.t[window])))
    reason = ""
    if not np.all(white > 0):
        reason = "an axis shows no noise (quantized below its resolution)"
    elif np.any(robust_sigma(samples) > AT_REST_RATIO * white):
        reason = f"the IMU is not at rest in the first {window_s:g} s"
    return StartWindow(samples, white, rate, reason)


def measure(recording: Recording) -> RestNoise:
    """The factors of the window at the recording's start, or why there are none."""
    spec = recording.meta.imu.spec
    if spec is None or not spec.gyro_arw_deg_rth or not spec.accel_vrw_mg_rthz:
        return RestNoise(reason="meta.yaml states no white noise to compare with")
    start = start_window(recording.imu)
    if start.reason:
        return RestNoise(reason=start.reason)
    if np.any(np.abs(whiteness(np.diff(start.samples, axis=0))) > WHITE_CORRELATION):
        return RestNoise(reason=f"the IMU's noise in the first {WINDOW_S:g} s is not white")
    stated = ImuNoise.from_datasheet(
        gyro_arw_deg_rth=spec.gyro_arw_deg_rth,
        accel_vrw_mg_rthz=spec.accel_vrw_mg_rthz,
        gyro_bias_deg_h=0.0,
        accel_bias_mg=0.0,
    )
    root_rate = math.sqrt(start.rate_hz)
    return RestNoise(
        gyro_factor=float(np.median(start.white[:3]) / (stated.gyro_arw * root_rate)),
        accel_factor=float(np.median(start.white[3:]) / (stated.accel_vrw * root_rate)),
    )


def with_noise_at_rest(recording: Recording, tuning: ImuTuning) -> tuple[Recording, RestNoise]:
    """``recording`` whose ``imu.spec`` white noise is the measured one where the window at
    rest found it worse than :data:`TOLERANCE` × the datasheet's (module docstring); and what
    was measured. ``imu.spec`` must hold both white-noise figures
    (:func:`fusion.engine.with_imu_spec`)."""
    rest = measure(recording)
    if rest.reason:
        return recording, rest
    spec = recording.meta.imu.spec
    assert spec is not None and spec.gyro_arw_deg_rth and spec.accel_vrw_mg_rthz
    update: dict[str, float] = {}
    for key, factor, configured in (
        ("gyro_arw_deg_rth", rest.gyro_factor, tuning.gyro_arw_deg_rth),
        ("accel_vrw_mg_rthz", rest.accel_factor, tuning.accel_vrw_mg_rthz),
    ):
        if configured is None and TOLERANCE < factor <= CAP:
            update[key] = float(getattr(spec, key)) * factor
    if not update:
        return recording, rest
    return recording.with_imu_figures(update), replace(rest, taken=tuple(update))
