"""The IMU's turn-on biases measured while the recording starts at rest, where its datasheet's
figure does not cover them.

The datasheet's turn-on biases (``meta.yaml`` ``imu.spec`` ``gyro_bias_deg_h``,
``accel_bias_mg``, 1σ) set three things: the filter's prior σ of its bias states; the ZUPT
detector's bands, which cover them at :data:`fusion.aiding.zupt.BIAS_COVERAGE`
(:func:`fusion.aiding.zupt.default_thresholds`: ``‖ω̃‖ < S_ω``, ``S_a,min < ‖f̃‖ < S_a,max``);
and, through the ZARU's own test (``_turning`` in :mod:`fusion.aiding.zupt`), whether a
standstill's angular rate is a bias or a turn. A unit whose bias lies far beyond its datasheet's
(aged, hot, a worse part than the one the datasheet was written for) breaks all three at once:
the band hides every stop of the run (no ZUPT, no ZARU), and the filter, its bias five σ from
its prior, drifts while its σ promises centimetres (docs/design/2026-12-05-bias-at-rest.md).

At rest the gyros read their bias and the earth's rate, the accelerometers gravity and their
bias, so over the recording's first seconds at rest (the first of :data:`WINDOWS_S` at rest by
the test of :mod:`fusion.noise_at_rest`, :func:`fusion.noise_at_rest.start_window`: its 20 s,
else the first 10 or 5 s of a shorter static start, as a bias needs far fewer samples than a
noise figure)::

    b̂_g = median(ω̃) − C_nᵇ ω_ieⁿ,        ω_ieⁿ = Ω_ie (0, cos L, sin L)   (ENU)
    b̂_a = ‖median(f̃)‖ − g(L, h)

with ``C_bⁿ`` the recording's initial attitude and ``g`` the normal gravity at its origin.
``b̂_a`` is the accelerometer bias along gravity; the horizontal ones cannot be told from a
tilt, and a tilt is harmless at rest. Each is known to ``√(π/2) σ/√n`` from the window's own
noise (a median of n samples), ``b̂_a`` further to the normal gravity's departure from the
site's (:data:`GRAVITY_ANOMALY_MPS2`). Where the largest ``|b̂_g|`` (or ``|b̂_a|``) exceeds
what a unit drawn from its datasheet reaches at ``BIAS_COVERAGE`` (3.29 σ for 99.9 %, the σ
being the datasheet's and the measurement's together), the datasheet's figure is replaced by
that magnitude for the whole run: the unit's bias then sits at one σ of the prior, inside the
detector's band, and the ZARU's first standstill finds it. Never lowered; a bias the datasheet
covers is left as the datasheet says, so that a unit within its datasheet runs exactly as
before. The bias itself is not subtracted: the filter's bias states, started at zero under the
widened prior, find it as they find any bias.

What a constant rate over the whole window would be taken for: about a horizontal axis it tilts
the accelerometers (the at-rest test sees it); about the vertical it is a machine turning in
place with its accelerometers still, which the ZARU's own premise rules out. A recording whose
initial velocity (``meta.yaml`` ``initial``) is clear of zero does not start at rest and
measures nothing.

A configuration that sets ``imu.gyro_bias_deg_h`` or ``imu.accel_bias_mg`` itself has said
what it wants: that figure is left alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2, norm

from fusion.aiding.zupt import BIAS_COVERAGE
from fusion.attitude import dcm_from_euler
from fusion.config import ImuTuning
from fusion.earth import OMEGA_IE, normal_gravity
from fusion.noise_at_rest import WINDOW_S, StartWindow, start_window
from fusion.recording import Recording

MG = 9.80665e-3
"""One milli-g in m/s²."""
DEG_H = math.radians(1.0) / 3600.0
"""One degree per hour in rad/s."""
GRAVITY_ANOMALY_MPS2 = 3e-3
"""How far the site's gravity may lie from the normal gravity at its origin (m/s²): 300 mGal,
the largest free-air anomalies on land, and more than the normal formula's free-air gradient
misses underground (0.2 mGal/m of the Bouguer plate: 80 mGal at 400 m)."""
WINDOWS_S = (WINDOW_S, 10.0, 5.0)
"""Windows at the start tried in turn (s): the longest at rest is taken. Five seconds of a 100-Hz
gyro with a datasheet's white noise know its bias to a few degrees per hour, far inside any
turn-on bias's σ."""
REST_VELOCITY_FLOOR_MPS = 1e-3
"""Least σ (m/s) given to the recording's initial velocity when asking whether it is zero."""
_REST_VELOCITY_THRESHOLD = float(chi2.ppf(BIAS_COVERAGE, 3))
_COVERAGE_SIGMAS = float(norm.ppf(0.5 + 0.5 * BIAS_COVERAGE))
_MEDIAN_EFFICIENCY = math.sqrt(math.pi / 2.0)  # σ of a median of n normal samples × √n / σ


@dataclass(frozen=True)
class RestBias:
    """What the window at the start measured (module docstring)."""

    window_s: float = math.nan
    """Length of the window at rest measured over (s; NaN: none)."""
    gyro_deg_h: tuple[float, float, float] | None = None
    """``b̂_g`` per body axis (deg/h); None: not measured."""
    accel_mg: float | None = None
    """``b̂_a``, along gravity (mg)."""
    gyro_sigma_deg_h: float = math.nan
    """σ of ``b̂_g`` from the window's own noise, its largest axis (deg/h)."""
    accel_sigma_mg: float = math.nan
    """σ of ``b̂_a`` from the window's own noise (mg)."""
    taken: tuple[str, ...] = ()
    """``imu.spec`` figures replaced by the measured magnitudes."""
    reason: str = ""
    """Why nothing was measured (empty when it was)."""

    def describe(self) -> str:
        """One line for the run summary."""
        if self.reason or self.gyro_deg_h is None or self.accel_mg is None:
            return f"not measured: {self.reason}"
        gyro = ", ".join(f"{b:.0f}" for b in self.gyro_deg_h)
        figures = f"gyros ({gyro}) deg/h, accelerometer {self.accel_mg:.2f} mg along gravity"
        if not self.taken:
            return f"{figures}: within the datasheet's, which is kept"
        return f"{figures}: beyond the datasheet's; the filter takes {', '.join(self.taken)}"

    def to_dict(self) -> dict[str, object]:
        """For ``metrics.json``."""
        return {
            "window_s": _finite(self.window_s),
            "gyro_deg_h": None if self.gyro_deg_h is None else list(self.gyro_deg_h),
            "accel_mg": self.accel_mg,
            "gyro_sigma_deg_h": _finite(self.gyro_sigma_deg_h),
            "accel_sigma_mg": _finite(self.accel_sigma_mg),
            "taken": list(self.taken),
            "reason": self.reason,
        }


def _finite(x: float) -> float | None:
    return None if math.isnan(x) else x


def measure(recording: Recording) -> RestBias:
    """``b̂_g`` and ``b̂_a`` over the window at the recording's start, or why there are none."""
    meta = recording.meta
    initial = meta.initial
    sigma = np.maximum(np.asarray(initial.sigma.velocity_mps), REST_VELOCITY_FLOOR_MPS)
    whitened = np.asarray(initial.velocity_enu_mps) / sigma
    if float(whitened @ whitened) > _REST_VELOCITY_THRESHOLD:
        return RestBias(reason="the recording's initial velocity is clear of zero")
    window_s, start = _at_rest(recording)
    if start.reason:
        return RestBias(reason=start.reason)
    lat = math.radians(meta.origin.lat_deg)
    attitude = initial.attitude_deg
    c_b_n = dcm_from_euler(*np.radians([attitude.roll, attitude.pitch, attitude.yaw]))
    earth_rate_b = c_b_n.T @ (OMEGA_IE * np.array([0.0, math.cos(lat), math.sin(lat)]))
    median = np.median(start.samples, axis=0)
    gyro = (median[:3] - earth_rate_b) / DEG_H
    accel = float(np.linalg.norm(median[3:])) - float(normal_gravity(lat, meta.origin.height_m))
    sigma = _MEDIAN_EFFICIENCY * start.white / math.sqrt(start.samples.shape[0])
    return RestBias(
        window_s=window_s,
        gyro_deg_h=(float(gyro[0]), float(gyro[1]), float(gyro[2])),
        accel_mg=accel / MG,
        gyro_sigma_deg_h=float(np.max(sigma[:3])) / DEG_H,
        accel_sigma_mg=float(np.max(sigma[3:])) / MG,
    )


def _at_rest(recording: Recording) -> tuple[float, StartWindow]:
    """The longest of :data:`WINDOWS_S` at the start that is at rest, else the last tried."""
    for window_s in WINDOWS_S:
        start = start_window(recording.imu, window_s)
        if not start.reason:
            break
    return window_s, start


def with_bias_at_rest(recording: Recording, tuning: ImuTuning) -> tuple[Recording, RestBias]:
    """``recording`` whose ``imu.spec`` turn-on biases are the measured magnitudes where the
    datasheet's do not cover them (module docstring); and what was measured. ``imu.spec`` must
    hold both bias figures (:func:`fusion.engine.with_imu_spec`)."""
    rest = measure(recording)
    if rest.gyro_deg_h is None or rest.accel_mg is None:
        return recording, rest
    spec = recording.meta.imu.spec
    assert spec is not None  # with_imu_spec: every figure given, a zero among them
    assert spec.gyro_bias_deg_h is not None and spec.accel_bias_mg is not None
    gyro = float(np.max(np.abs(rest.gyro_deg_h)))
    gyro_sigma = math.hypot(spec.gyro_bias_deg_h, rest.gyro_sigma_deg_h)
    accel = abs(rest.accel_mg)
    accel_sigma = math.hypot(spec.accel_bias_mg, rest.accel_sigma_mg)
    update: dict[str, float] = {}
    for key, value, bound, configured in (
        ("gyro_bias_deg_h", gyro, _COVERAGE_SIGMAS * gyro_sigma, tuning.gyro_bias_deg_h),
        (
            "accel_bias_mg",
            accel,
            _COVERAGE_SIGMAS * accel_sigma + GRAVITY_ANOMALY_MPS2 / MG,
            tuning.accel_bias_mg,
        ),
    ):
        if configured is None and value > bound:
            update[key] = value
    if not update:
        return recording, rest
    return recording.with_imu_figures(update), replace(rest, taken=tuple(update))
