"""Zero-velocity updates with a median-filtered stationarity detector (seed 002 §3–4).

Detector (seed 002 §3, eqs. 1–5), per IMU sample k::

    C1_k = S_a,min < ‖f̃_k‖ < S_a,max        C2_k = ‖ω̃_k‖ < S_ω        C_k = C1_k ∧ C2_k
    C_m,k = median(C_{k−l+1}, …, C_k)        (causal, real time)
    C_m,k = median(C_{k−(l−1)/2}, …, C_{k+(l−1)/2})   (offline, centred)

with ``l`` the odd number of samples in ``window_s``. The median removes the isolated wrong
labels ("salt-and-pepper", seed 002 Fig. 7) that noise and vibration produce. The causal
median over the trailing window equals the centred one ``(l − 1)/2`` samples earlier, so the
real-time label lags the offline one by ``≈ window_s/2`` at every switch:
:func:`detect_stationary` with ``causal=True`` at sample k is the offline label of sample
``k − (l − 1)/2``.

Default thresholds (:func:`default_thresholds`), from physics rather than from a recording: at
rest ``‖f̃‖ = ‖g + b_a + n_a‖ ≈ g + b_a,z + n_a,z`` (horizontal errors enter to second order)
with ``g`` the WGS84 normal gravity at the recording origin, and ``‖ω̃‖ ≤ Ω_ie + ‖b_g‖ + ‖n_g‖``.
The constant biases (datasheet 1σ ``accel_bias_mg``, ``gyro_bias_deg_h``) are covered at
99.9 % — a bias outside the band would hide every stop, and the median cannot repair a
constant offset (a unit whose bias at a start at rest lies beyond the datasheet's has the
datasheet's figure raised to it before the band is drawn: :mod:`fusion.bias_at_rest`).
The white noise of one sample (``σ = N/√Δt`` from ``accel_vrw_mg_rthz``,
``gyro_arw_deg_rth`` and the sample rate) is covered only at 90 % (two-sided normal for the
accelerometer, the χ(3) quantile for the gyro norm): the median of ``l`` samples turns a
stationary label into "moving" only when more than half of them are false alarms (for l = 51,
P(Binom(51, 0.1) ≥ 26) < 1e-12), and the tighter band recognises motion sooner. Thus::

    S_a,max/min = g ± (3.29 σ_ba + 1.64 σ_na),   S_ω = Ω_ie + 4.03 σ_bg + 2.50 σ_ng

(for seed 002's MEMS IMU at 100 Hz: g ± 0.035 m/s², S_ω = 0.026 °/s). Options override them.

What the detector cannot see: the shearer's cutting vibration and its turn rates grow with its
speed, so the first and last ≈ 0.5–0.9 s of each drive (speeds below ≈ 2 cm/s) look
stationary — measured on ``seed002-rectangle`` (tests/test_zupt_plugin.py). A ZUPT there
would pin a moving machine to zero, so a ZUPT is applied only where the label has been
stationary for ``guard_s`` on both sides (offline) or for the past ``guard_s`` (causal).

Scatter test (option ``scatter_test``): a machine that moves at a steady pace feels no
acceleration, so the two conditions above cannot tell it from one at rest, and their bands
must also cover the constant biases (tens of mg, hundreds of °/h), in which a cutting
vibration of a few mg and tenths of °/s hides: a haul taken for a stop has its velocity
pinned to zero at a σ of millimetres per second while it drives on. The scatter of the
samples about their own mean over the median window carries no bias: at rest it is the
sensor's white noise alone. With ``n`` samples in the window (trailing or centred like the
median) and ``σ`` the datasheet noise of one sample scaled by :data:`NOISE_MARGIN`, a sample
is stationary only if, for the accelerometer and the gyro each, ::

    Σ_axes Σ_window (x − x̄)² / σ²  ≤  χ²_{3(n−1)}(1 − SCATTER_FALSE_ALARM)

A stop with the conveyor running beside it may fail the test: the ZUPT is then lost, which
costs its information and nothing else.

Gait-adaptive bounds (option ``gait_fraction``, a foot): a stance is not still, and it moves
more the harder the gait. ``S_ω`` and the band's half-width become
``max(fixed, α · P90)`` of ``‖ω̃‖`` and ``|‖f̃‖ − centre|`` over a window of a few strides
(trailing or centred like the median; :func:`gait_bounds`).

Measurement (seed 002 eq. 12): at an epoch where the shearer stands, ``v = 0``, so with
``ṽ = v + δv``::

    z = ṽⁿ − 0,    H = [I₃, 0, 0, 0, 0, …],    R = σ_zv² I₃

A stopped machine in the simulator is exactly still (its vibration envelope is zero in a stop),
so ``σ_zv`` defaults to a floor of 1e-5 m/s, below the 4.5e-5 m/s the seed-002 IMU's own
velocity noise accumulates between two 10 Hz updates; on a real face with the conveyor
running, set it to the measured standstill vibration velocity.

Zero angular rate (ZARU, option ``zero_angular_rate``): at a ZUPT epoch the machine does not
turn either, so the gyro mean since the previous epoch is the earth rate plus the bias
(:mod:`fusion.aiding.zaru`): every gyro bias, the vertical one included, becomes observable at rest.
With ``zero_velocity: false`` the epoch gives the ZARU without the zero velocity (and the
motion constraint, when one is configured, at every epoch): for a machine that can creep too
smoothly for the IMU to tell it from a stop (a shearer hauling at a few m/min without
cutting), where a zero velocity would hold the position while the machine drives on. Such a
machine may still turn (creeping off a face-end stop through the conveyor's snake), so the
ZARU is left out wherever the filter's own velocity is clear of zero (:func:`_moving`), and
where its own ``H P Hᵀ + R`` does not explain it (:func:`_turning`: a turn the detector took for
a stop). A standstill whose every ZARU is so contradicted for ``zaru_persistence_s`` shows the
vertical gyro bias wrong instead: the bias, the heading and what the heading moved since the
last explained ZARU are widened to the ZARU's innovation (:func:`_heading_widening`, through
:meth:`Zupt.process_noise`), and the ZARUs that follow find the bias.

Epochs and delay: epochs are a regular grid at ``update_rate_hz`` on the IMU clock; the epoch at
``t`` uses the label of the last IMU sample at or before ``t``. In causal mode that label is
computed from samples up to ``t`` only (it lags the motion by ``window_s/2`` plus the blind
time above, so a ZUPT can still hit the first second of a drive: pair it with the block's
``gate_probability``, which rejects a ZUPT whose innovation shows the machine moving). Offline
(``causal: false``) it also uses ``window_s/2 + guard_s`` of later samples: the same decisions
a real-time filter gets by running that far behind the IMU.

With an odometer (option ``odometer_rest_mps``): the haulage encoder sees a start long before
the IMU does — a shearer that creeps off at 0.01–0.04 m/s over its first seconds shows no
acceleration the detector can separate from a stop, and a ZUPT of a few mm/s there is a 40σ
error that also trips the federated fault monitor. A ZUPT then also needs every odometer
reading of the past ``guard_s`` below the given speed (a few times the encoder's standstill
noise), the last of them at most ``odometer_rest_mps / haulage_accel_mps2`` old: a machine
starting from rest needs that long to exceed the speed, and after it the machine may be moving
with no reading yet to show it. An encoder reported at 10 Hz or faster is never that late at
0.006 m/s and 0.05 m/s²; one reported at 1 Hz had let a start run a second under ZUPTs of
1 mm/s, and the federated monitor isolate the kinematic local
(docs/design/2026-12-02-sites-clocks-and-rates.md).

Switching with the motion constraint (seed 002 eq. 18): with the ``motion_constraint`` option
(the options of the ``odometer`` plugin in ``mode: motion_constraint``, whose measurement
model this plugin reuses) an epoch that is not a ZUPT epoch applies the motion constraint
instead (zero lateral and vertical velocity in the machine frame, eq. 17), and the plugin then
owns the mounting angles δα. This is eq. 18: ZUPT while ``C_m = 1``, the constraint otherwise.
The constraint's noise models the cutting vibration, which is absent at standstill; running
both there would add nothing the exact ZUPT does not already give. A separately configured
``odometer`` plugin is not switched: it keeps running while the shearer stands, which is
consistent (zero velocity satisfies the constraint) but makes its whitened innovations small
during stops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, field_validator, model_validator
from scipy.ndimage import median_filter, minimum_filter1d, percentile_filter, uniform_filter1d
from scipy.stats import chi2, norm

from fusion.aiding.odometer import Odometer, OdometerOptions
from fusion.aiding.reference_speed import reading_noise
from fusion.aiding.zaru import ZeroAngularRate
from fusion.earth import OMEGA_IE, normal_gravity
from fusion.encoder import reading_intervals
from fusion.error_model import ATTITUDE, GYRO_BIAS, POSITION, VELOCITY, ImuNoise, StateBlock
from fusion.lock import Reacquisition, RestLevel, agrees
from fusion.plugin import (
    Measurement,
    MeasurementContext,
    MissingStream,
    Plugin,
    PluginOptions,
    ProcessNoise,
)
from fusion.recording import ImuSpec, Recording

BIAS_COVERAGE = 0.999
"""Probability with which the threshold band covers the constant IMU biases."""
SAMPLE_FALSE_ALARM = 0.1
"""Probability that white noise alone flags one stationary sample as moving."""
SCATTER_FALSE_ALARM = 1e-3
"""Probability that white noise alone fails the scatter test of a stationary window."""
NOISE_MARGIN = 1.5
"""Factor on the datasheet noise in the scatter test: a unit's white noise may exceed its
datasheet's typical figure (the random worlds' units: up to 1.25×)."""
LINEAR_ATTITUDE_SIGMA = math.radians(10.0)
"""Largest attitude σ at which a zero velocity may correct a coasted SINS through its
correlations (:meth:`Zupt.beyond_linearization`). The error state turns a vector v by
``φ × v`` where the truth rotates it by φ: at 3σ = 30° it leaves out ``1 − cos φ`` = 13 % of
|v| along v and ``1 − sin φ / φ`` = 5 % of the turn; at 3σ = 90°, 100 % and 36 %."""


@dataclass(frozen=True)
class StationaryThresholds:
    """Thresholds of seed 002 eqs. 2–3: ``S_a,min < ‖f‖ < S_a,max`` and ``‖ω‖ < S_ω``.

    Attributes
    ----------
    accel_min_mps2, accel_max_mps2
        Band of the specific-force norm (m/s²).
    gyro_max_rps
        Bound of the angular-rate norm (rad/s).
    accel_noise_mps2, gyro_noise_rps
        White noise of one sample (1σ per axis) of the scatter test; None: no scatter test.
    gait_fraction, gait_window_s
        Gait-adaptive bounds (:func:`gait_bounds`): ``S_ω`` and the band's half-width rise to
        this fraction of the 90th percentile of ``‖ω‖`` and ``|‖f‖ − centre|`` over a window
        of ``gait_window_s``; None: fixed bounds.
    """

    accel_min_mps2: float
    accel_max_mps2: float
    gyro_max_rps: float
    accel_noise_mps2: float | None = None
    gyro_noise_rps: float | None = None
    gait_fraction: float | None = None
    gait_window_s: float = 3.0


def default_thresholds(
    spec: ImuSpec, rate_hz: float, gravity_mps2: float, scatter_test: bool = False
) -> StationaryThresholds:
    """Thresholds from gravity and the IMU datasheet (see the module docstring).

    Parameters
    ----------
    spec
        Datasheet figures (meta.yaml ``imu.spec``); all four must be present.
    rate_hz
        IMU sample rate (the white noise of one sample is ``N·√rate``).
    gravity_mps2
        Gravity magnitude at the site.
    scatter_test
        Also the white noise of one sample for the scatter test, times :data:`NOISE_MARGIN`.

    Returns
    -------
    StationaryThresholds
    """
    figures = spec.model_dump()
    missing = [k for k, v in figures.items() if v is None]
    if missing:
        raise ValueError(
            f"meta.yaml imu.spec lacks {missing}: give the ZUPT thresholds"
            " (accel_min_mps2, accel_max_mps2, gyro_max_dps) in the plugin options"
        )
    imu = ImuNoise.from_datasheet(**figures)
    root_rate = math.sqrt(rate_hz)
    band = float(
        norm.ppf(0.5 + 0.5 * BIAS_COVERAGE) * imu.accel_bias
        + norm.ppf(1.0 - 0.5 * SAMPLE_FALSE_ALARM) * imu.accel_vrw * root_rate
    )
    gyro_max = float(
        OMEGA_IE
        + math.sqrt(chi2.ppf(BIAS_COVERAGE, 3)) * imu.gyro_bias
        + math.sqrt(chi2.ppf(1.0 - SAMPLE_FALSE_ALARM, 3)) * imu.gyro_arw * root_rate
    )
    return StationaryThresholds(
        gravity_mps2 - band,
        gravity_mps2 + band,
        gyro_max,
        NOISE_MARGIN * imu.accel_vrw * root_rate if scatter_test else None,
        NOISE_MARGIN * imu.gyro_arw * root_rate if scatter_test else None,
    )


def window_samples(window_s: float, rate_hz: float) -> int:
    """Odd number of samples spanning ``window_s`` at ``rate_hz`` (1 for a zero window)."""
    return 2 * round(0.5 * window_s * rate_hz) + 1


def _sliding(labels: NDArray[np.bool_], size: int, causal: bool, kind: str) -> NDArray[np.bool_]:
    """Median or minimum of boolean ``labels`` over a trailing (causal) or centred window."""
    origin = (size - 1) // 2 if causal else 0
    x = labels.astype(np.int8)
    if kind == "median":
        out = median_filter(x, size=size, origin=origin, mode="nearest")
    else:
        out = minimum_filter1d(x, size=size, origin=origin, mode="nearest")
    return np.asarray(out, dtype=bool)


def detect_stationary(
    t: NDArray[np.float64],
    gyro: NDArray[np.float64],
    accel: NDArray[np.float64],
    thresholds: StationaryThresholds,
    window_s: float,
    causal: bool = True,
) -> NDArray[np.bool_]:
    """Stationary (True) / moving labels of IMU samples (seed 002 eqs. 1–5).

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times (s); the median interval sets the window length in samples.
    gyro, accel : ndarray, shape (N, 3)
        Angular rate (rad/s) and specific force (m/s²) in any body frame.
    thresholds
        ``S_a,min``, ``S_a,max``, ``S_ω``, and the scatter test's noise when it has one.
    window_s
        Median window ``l`` in seconds (rounded to an odd number of samples; 0: no filter).
    causal
        True: median over the trailing window ending at each sample (real time; the labels
        lag by ``(l − 1)/2`` samples). False: centred window (offline, no lag).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    rate = 1.0 / float(np.median(np.diff(t)))
    size = window_samples(window_s, rate)
    f = np.linalg.norm(accel, axis=1)
    w = np.linalg.norm(gyro, axis=1)
    centre = 0.5 * (thresholds.accel_min_mps2 + thresholds.accel_max_mps2)
    offset = np.abs(f - centre)
    half_width = 0.5 * (thresholds.accel_max_mps2 - thresholds.accel_min_mps2)
    if thresholds.gait_fraction is None:
        raw = (offset < half_width) & (w < thresholds.gyro_max_rps)
    else:
        gait = window_samples(thresholds.gait_window_s, rate)
        raw = (offset < gait_bounds(offset, half_width, thresholds, gait, causal)) & (
            w < gait_bounds(w, thresholds.gyro_max_rps, thresholds, gait, causal)
        )
    noise = (thresholds.accel_noise_mps2, thresholds.gyro_noise_rps)
    if size > 1 and noise[0] is not None and noise[1] is not None:
        raw &= _quiet(accel, noise[0], size, causal) & _quiet(gyro, noise[1], size, causal)
    return _sliding(raw, size, causal, "median")


def gait_bounds(
    x: NDArray[np.float64],
    floor: float,
    thresholds: StationaryThresholds,
    size: int,
    causal: bool,
) -> NDArray[np.float64]:
    """A bound that follows the gait: ``max(floor, α · P90(x))`` over a window of ``size``
    samples (trailing when causal, else centred), α = ``thresholds.gait_fraction``.

    A foot in stance is not still: it rolls from heel to toe, and the harder the gait the more
    it moves, in proportion to the swing (a run's stance turns faster than a staircase's
    swing), so no fixed bound serves both. The window's 90th percentile is the swing's level
    whenever the window holds a stride. Measured on PyShoe's trials:
    docs/design/2026-11-27-standstill-zaru.md."""
    assert thresholds.gait_fraction is not None
    origin = (size - 1) // 2 if causal else 0
    level = percentile_filter(x, 90, size=size, origin=origin, mode="nearest")
    return np.maximum(floor, thresholds.gait_fraction * level)


def _quiet(x: NDArray[np.float64], sigma: float, size: int, causal: bool) -> NDArray[np.bool_]:
    """Samples whose window of ``size`` (trailing or centred) scatters about its own mean no
    more than white noise of ``sigma`` per axis would (the module's scatter test)."""
    origin = (size - 1) // 2 if causal else 0
    centred = x - np.median(x, axis=0)  # running sums of small numbers: no cancellation
    mean = uniform_filter1d(centred, size, axis=0, origin=origin, mode="nearest")
    square = uniform_filter1d(centred**2, size, axis=0, origin=origin, mode="nearest")
    scatter = size * np.sum(np.maximum(square - mean**2, 0.0), axis=1) / sigma**2
    return np.asarray(scatter <= chi2.ppf(1.0 - SCATTER_FALSE_ALARM, 3 * (size - 1)))


MOVING_PROBABILITY = 0.999
"""A SINS velocity beyond this quantile of χ²(3) under its own covariance is a moving machine."""
_MOVING_THRESHOLD = float(chi2.ppf(MOVING_PROBABILITY, 3))


def _turning(zaru: Measurement, ctx: MeasurementContext) -> bool:
    """Whether the gyros show a turn: the ZARU's innovation beyond the χ²₃ quantile
    :data:`MOVING_PROBABILITY` of its own ``H P Hᵀ + R`` (the filter's gyro bias σ does not
    explain it).

    A shearer hauling smoothly after the UWB anchors fell behind looks still to the detector,
    and its SINS velocity σ has grown past its speed (:func:`_moving` no longer fires); it
    still turns with the waviness of the face, at hundreds of °/h. A ZARU there took the
    motion constraint's rows down with it at the gate, every update of the plugin was
    rejected for 3 s, and the engine, taking that for a lost lock, inflated the SINS
    variances ×434: tilt then ran 1.5–3° off and yaw up to 12° (sins_uwb, random world 0
    at its own length). Dropped, the ZARU leaves the constraint to be gated alone.
    """
    s = zaru.H @ ctx.covariance @ zaru.H.T + zaru.R
    try:
        statistic = float(zaru.z @ np.linalg.solve(s, zaru.z))
    except np.linalg.LinAlgError:
        return False
    return statistic > _MOVING_THRESHOLD


def _heading_widening(
    zaru: Measurement, ctx: MeasurementContext, elapsed_s: float, travel_m: float
) -> dict[str, NDArray[np.float64]] | None:
    """What a ZARU that contradicts the vertical gyro bias for a whole standstill shows the
    filter missed (the variances to add, by block), or None where its vertical row is
    explained (the contradiction is a rotation about a horizontal axis: the machine moves).

    With ``ν`` and ``S`` the vertical row's innovation and predicted variance, the bias was
    off by about ``ν`` since the last ZARU the filter could explain, ``elapsed_s`` ago: its
    variance takes ``ν² − S``, the heading's ``(ν² − S) elapsed_s²`` (integrated over that
    span; at most π²), the horizontal velocity's that heading variance × speed² and the horizontal
    position's (travel/2)² × the heading variance (a heading error growing along
    ``travel_m``), at most travel² (a heading off by more than a radian). The vertical gyro
    bias is the one nothing but the ZARU observes; the horizontal ones the tilt holds against
    gravity throughout, so a horizontal residual is a pitching or rolling machine, and
    widening those biases would turn a smooth haul's roll into a tilt error
    (docs/design/2026-11-29-zaru-contradicting-the-bias.md).
    """
    row = 2  # the body z gyro: the heading's, within the tilt of a face
    s = float(zaru.H[row] @ ctx.covariance @ zaru.H[row] + zaru.R[row, row])
    nu2 = float(zaru.z[row]) ** 2
    if nu2 <= _VERTICAL_THRESHOLD * s:
        return None
    bias = nu2 - s
    heading = min(bias * elapsed_s**2, math.pi**2)  # at most anywhere on the circle
    speed2 = float(ctx.velocity[:2] @ ctx.velocity[:2])
    position = travel_m**2 * min(heading / 4.0, 1.0)
    return {
        GYRO_BIAS: np.array([0.0, 0.0, bias]),
        ATTITUDE: np.array([0.0, 0.0, heading]),
        VELOCITY: np.array([speed2 * min(heading, 1.0)] * 2 + [0.0]),
        POSITION: np.array([position, position, 0.0]),
    }


_VERTICAL_THRESHOLD = float(chi2.ppf(MOVING_PROBABILITY, 1))


def _moving(ctx: MeasurementContext) -> bool:
    """Whether the SINS velocity is clear of zero under its own covariance,
    ``vᵀ P_v⁻¹ v > χ²₃(`` :data:`MOVING_PROBABILITY` ``)``: the filter knows the machine moves.

    Without a zero velocity the detector's "stationary" may be a slow haul, and a shearer
    creeping off from a face-end stop through the snake of the conveyor turns while the IMU
    shows no acceleration: on a random world it started at 0.01 m/s² and turned at up to
    146 °/h within 13 s, and ZARUs at that "standstill" walked the vertical gyro bias 146 °/h,
    the heading then ran 30° off and the UWB-aided filter diverged. Where an aiding source
    (UWB) knows the velocity to millimetres per second, it shows the start within a second;
    where nothing does (the constraint alone), the test never fires.
    """
    rows = ctx.layout.slice(VELOCITY)
    v = ctx.velocity
    try:
        statistic = float(v @ np.linalg.solve(ctx.covariance[rows, rows], v))
    except np.linalg.LinAlgError:
        return False
    return statistic > _MOVING_THRESHOLD


REST_NOISE_WINDOW_S = 10.0
"""How far back (s) a release takes the encoder's noise at rest from: a short stop of a
shearer's, tens of readings."""


class ZuptOptions(PluginOptions):
    """Options of the ZUPT plugin (thresholds left out default from physics)."""

    accel_min_mps2: float | None = Field(None, gt=0, description="S_a,min")
    accel_max_mps2: float | None = Field(None, gt=0, description="S_a,max")
    gyro_max_dps: float | None = Field(None, gt=0, description="S_ω in deg/s")
    window_s: float = Field(0.5, ge=0, description="median window l (0: no median filter)")
    gait_fraction: float | None = Field(
        None,
        gt=0,
        lt=1,
        description="gait-adaptive bounds: S_ω and the accelerometer band's half-width rise to"
        " this fraction of the 90th percentile of ‖ω‖ and |‖f‖ − g| over gait_window_s (a"
        " foot: its stance moves more the harder the gait); None: fixed bounds",
    )
    gait_window_s: float = Field(
        3.0, gt=0, le=60, description="window of the gait-adaptive bounds (s): a few strides"
    )
    causal: bool = Field(True, description="trailing windows (real time) or centred (offline)")
    guard_s: float = Field(1.0, ge=0, description="stationary this long around a ZUPT epoch")
    update_rate_hz: float = Field(10.0, gt=0, description="epoch grid on the IMU clock")
    sigma_zero_velocity_mps: float = Field(1e-5, gt=0, description="ZUPT noise, 1σ per axis")
    scatter_test: bool = Field(
        False,
        description="stationary also needs the samples' scatter over window_s within the"
        " datasheet white noise (a machine moving steadily with a little vibration)",
    )
    zero_angular_rate: bool = Field(
        False, description="also a zero-angular-rate update (ZARU) on the gyro biases at rest"
    )
    zero_velocity: bool = Field(
        True, description="false: only the ZARU at a detected standstill (needs zero_angular_rate)"
    )
    angular_rate_floor_dps: float = Field(
        0.002, ge=0, description="ZARU noise added to the averaged ARW (standstill vibration)"
    )
    zaru_persistence_s: float = Field(
        3.0,
        gt=0,
        description="zero_velocity: false: a standstill whose every ZARU for this long contradicts"
        " the vertical gyro bias shows that bias wrong, and widens it and the heading (the"
        " engine's lost-lock window, filter.lock_window_s)",
    )
    motion_constraint: OdometerOptions | None = Field(
        None, description="odometer motion_constraint options: apply it while moving (eq. 18)"
    )
    max_speed_mps: float | None = Field(
        None,
        gt=0,
        description="the machine's top speed: a standstill whose every ZUPT the filter rejects"
        " (a lost lock, filter.lock_window_s) then restarts the velocity at zero, the tilt at"
        " the accelerometers' gravity, and the position at the last standstill the filter"
        " agreed with, anywhere within max_speed·Δt of it (Zupt.reacquire); needs"
        " zero_velocity. None: the lost lock is only reported and the SINS variances inflated",
    )
    odometer_rest_mps: float | None = Field(
        None,
        gt=0,
        description="also require every odometer reading of the past guard_s below this speed"
        " (needs odometer.csv); None: the IMU detector alone",
    )
    haulage_accel_mps2: float = Field(
        0.05,
        gt=0,
        description="with odometer_rest_mps: the machine's largest haulage acceleration; an"
        " odometer reading at rest holds for odometer_rest_mps / haulage_accel_mps2 after it (a"
        " start takes that long to exceed the speed), later epochs wait for the next reading",
    )
    release_at_motion: bool = Field(
        True,
        description="with odometer_rest_mps: when the encoder ends a run of ZUPTs, add the"
        " readings' speed² to the horizontal velocity variances and their travel² to the"
        " position's (the creep the ZUPTs held at zero before the encoder could count it)",
    )

    @field_validator("motion_constraint", mode="before")
    @classmethod
    def _constraint_mode(cls, value: Any) -> Any:
        """The switched constraint is the odometer plugin in ``mode: motion_constraint``."""
        if not isinstance(value, dict):
            return value
        if value.get("mode", "motion_constraint") != "motion_constraint":
            raise ValueError("mode must be motion_constraint (the odometer speed is not switched)")
        if "constraint_rate_hz" in value:
            raise ValueError("constraint_rate_hz is not used here: update_rate_hz sets the epochs")
        return {**value, "mode": "motion_constraint"}

    @model_validator(mode="after")
    def _band(self) -> ZuptOptions:
        lo, hi = self.accel_min_mps2, self.accel_max_mps2
        if lo is not None and hi is not None and lo >= hi:
            raise ValueError(f"accel_min_mps2 ({lo}) must be below accel_max_mps2 ({hi})")
        if not self.zero_velocity and not self.zero_angular_rate:
            raise ValueError("zero_velocity: false leaves nothing to update: set zero_angular_rate")
        if self.max_speed_mps is not None and not self.zero_velocity:
            raise ValueError("max_speed_mps re-acquires at a zero velocity: needs zero_velocity")
        return self


class Zupt(Plugin):
    """Zero velocity while the detector says stationary; optionally the motion constraint
    while moving (seed 002 eq. 18)."""

    Options = ZuptOptions
    options: ZuptOptions

    def __init__(self, name: str, options: ZuptOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        imu = recording.imu
        self.thresholds = self._thresholds(options, recording)
        self.stationary = detect_stationary(
            imu.t, imu.gyro, imu.accel, self.thresholds, options.window_s, options.causal
        )
        rate = 1.0 / float(np.median(np.diff(imu.t)))
        # causal: stationary over the past guard_s; offline: over ±guard_s
        guard = window_samples(options.guard_s if options.causal else 2 * options.guard_s, rate)
        self.usable = _sliding(self.stationary, guard, options.causal, "minimum")
        self._epochs = np.arange(imu.t[0], imu.t[-1], 1.0 / options.update_rate_hz)[1:]
        sample = np.searchsorted(imu.t, self._epochs, side="right") - 1
        self.zupt_epoch = self.usable[sample]
        self.releases: dict[int, tuple[float, float]] = {}
        if options.odometer_rest_mps is not None:
            at_rest = self._odometer_at_rest(options.odometer_rest_mps)
            if options.release_at_motion:
                self.releases = self._releases(self.zupt_epoch, at_rest)
            self.zupt_epoch &= at_rest & self._odometer_current(options.odometer_rest_mps)
        self.variance = options.sigma_zero_velocity_mps**2
        self.zero_rate = (
            ZeroAngularRate(recording, options.angular_rate_floor_dps, name)
            if options.zero_angular_rate
            else None
        )
        self.constraint = (
            Odometer(name, options.motion_constraint, recording)
            if options.motion_constraint is not None
            else None
        )
        self._rest_level = RestLevel(recording)
        self.start_run()

    def _odometer_at_rest(self, speed_mps: float) -> NDArray[np.bool_]:
        """Epochs with at least one odometer reading in the past ``guard_s`` (the epoch
        included) and all of them below ``speed_mps``."""
        odometer = self.recording.odometer
        if odometer is None:
            raise MissingStream(
                f"plugin {self.name!r}: odometer_rest_mps needs odometer.csv in the recording"
            )
        moving = np.concatenate([[0], np.cumsum(np.abs(odometer.speed) >= speed_mps)])
        last = np.searchsorted(odometer.t, self._epochs, side="right")
        first = np.searchsorted(odometer.t, self._epochs - self.options.guard_s, side="right")
        return (last > first) & (moving[last] == moving[first])

    def _odometer_current(self, speed_mps: float) -> NDArray[np.bool_]:
        """Epochs at most ``speed_mps / haulage_accel_mps2`` after the last odometer reading:
        a machine starting from rest cannot exceed ``speed_mps`` sooner, so a reading at rest
        still holds; later the machine may be moving with no reading to show it."""
        odometer = self.recording.odometer
        assert odometer is not None
        last = np.searchsorted(odometer.t, self._epochs, side="right") - 1
        age = self._epochs - odometer.t[np.maximum(last, 0)]
        return (last >= 0) & (age <= speed_mps / self.options.haulage_accel_mps2)

    def _releases(
        self, stationary: NDArray[np.bool_], at_rest: NDArray[np.bool_]
    ) -> dict[int, tuple[float, float]]:
        """Epochs whose encoder ends a run of ZUPTs (the IMU still says stationary) with a
        reading beyond 3σ̂ of the encoder's noise at rest, with the largest speed and the
        travel of the readings since the previous epoch.

        σ̂ is the noise of the readings of the :data:`REST_NOISE_WINDOW_S` before the previous
        epoch, from their successive differences
        (:func:`fusion.aiding.reference_speed.reading_noise`), not of the ZUPTs' own
        ``guard_s``, whose readings the rest check selects below ``odometer_rest_mps``. An
        encoder noisier than that threshold ends runs of ZUPTs on noise alone, and a release
        there only loosens a velocity that such readings then hold badly
        (docs/design/2026-11-28-starts-and-seed000.md)."""
        assert self.recording.odometer is not None
        odometer = self.recording.odometer
        applied = stationary & at_rest
        ended = np.flatnonzero(applied[:-1] & stationary[1:] & ~at_rest[1:]) + 1
        interval = reading_intervals(odometer.t)
        before = self._epochs[ended - 1]
        rest = np.searchsorted(odometer.t, before - REST_NOISE_WINDOW_S, side="right")
        first = np.searchsorted(odometer.t, before, side="right")
        last = np.searchsorted(odometer.t, self._epochs[ended], side="right")
        noise = reading_noise(odometer.speed, rest, first)
        releases = {}
        for k, epoch in enumerate(ended.tolist()):
            speeds = np.abs(odometer.speed[first[k] : last[k]])
            if speeds.size and speeds.max() > 3.0 * noise[k]:
                releases[epoch] = (
                    float(speeds.max()),
                    float(speeds @ interval[first[k] : last[k]]),
                )
        return releases

    def process_noise(self, index: int) -> ProcessNoise | None:
        """After a standstill whose ZARUs contradicted the vertical gyro bias
        (:meth:`_contradicted`): that bias's and the heading's widening, with its
        ``faults.csv`` reason. Where the encoder ends a run of ZUPTs (option
        ``release_at_motion``, :meth:`_releases`): the largest speed² of its new readings on the
        horizontal velocity variances, their travel² on the position's (no reason: a start).

        The machine began to move at an instant neither sensor can tell: a quantized encoder
        counts nothing until the first count's worth of travel, and a shearer's gentle start
        (a few mg) is below what the IMU detector can separate from a stop. Until the encoder
        showed it, the ZUPTs held the velocity at zero within their σ; the speed reached (at
        most about the readings') and the travel (at most theirs) are what they missed.
        Without the release the filter ran centimetres off at a σ of millimetres after such a
        start, and the federated fault monitor isolated a healthy UWB
        (docs/design/2026-11-28-starts-and-seed000.md). Only the ZUPT releases: an odometer's
        own zero readings (σ of a centimetre per second) do not pin the velocity so hard, and
        releasing after every odometer start cost the odometer-only filters accuracy."""
        widening = self._widening.pop(index, None)
        if widening is not None:
            return widening
        release = self.releases.get(index)
        if release is None:
            return None
        speed, travel = release
        return ProcessNoise(
            {
                VELOCITY: np.array([speed**2, speed**2, 0.0]),
                POSITION: np.array([travel**2, travel**2, 0.0]),
            }
        )

    @staticmethod
    def _thresholds(options: ZuptOptions, recording: Recording) -> StationaryThresholds:
        given = (options.accel_min_mps2, options.accel_max_mps2, options.gyro_max_dps)
        if all(v is not None for v in given) and not options.scatter_test:
            lo, hi, w = (float(v) for v in given if v is not None)
            return StationaryThresholds(
                lo,
                hi,
                math.radians(w),
                gait_fraction=options.gait_fraction,
                gait_window_s=options.gait_window_s,
            )
        meta = recording.meta
        if meta.imu.spec is None:
            raise ValueError(
                "meta.yaml has no imu.spec to derive the ZUPT thresholds from: give"
                " accel_min_mps2, accel_max_mps2 and gyro_max_dps in the plugin options"
                " (scatter_test needs the datasheet noise)"
            )
        gravity = float(normal_gravity(math.radians(meta.origin.lat_deg), meta.origin.height_m))
        d = default_thresholds(meta.imu.spec, meta.imu.rate_hz, gravity, options.scatter_test)
        return StationaryThresholds(
            d.accel_min_mps2 if options.accel_min_mps2 is None else options.accel_min_mps2,
            d.accel_max_mps2 if options.accel_max_mps2 is None else options.accel_max_mps2,
            d.gyro_max_rps if options.gyro_max_dps is None else math.radians(options.gyro_max_dps),
            d.accel_noise_mps2,
            d.gyro_noise_rps,
            options.gait_fraction,
            options.gait_window_s,
        )

    def state_blocks(self) -> tuple[StateBlock, ...]:
        """The mounting angles δα of the switched motion constraint, if configured."""
        return self.constraint.state_blocks() if self.constraint is not None else ()

    def start_run(self) -> None:
        """Forget a run's rest scatter, the constraint's learned noise and the ZARUs' record."""
        self._contradicted_since: float | None = None
        self._explained_at = float(self._epochs[0]) if self._epochs.size else 0.0
        self._travel_m = 0.0
        self._widening: dict[int, ProcessNoise] = {}
        self._agreed: tuple[float, NDArray[np.float64], NDArray[np.float64]] | None = None
        if self.zero_rate is not None:
            self.zero_rate.start_run()
        if self.constraint is not None:
            self.constraint.start_run()

    def epochs(self) -> NDArray[np.float64]:
        """A regular grid at ``update_rate_hz`` on the IMU clock."""
        return self._epochs

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        """Zero velocity (and/or angular rate) at a ZUPT epoch; else the motion constraint (if
        configured) or None."""
        self._travel_m += float(np.hypot(*ctx.velocity[:2])) / self.options.update_rate_hz
        if not self.zupt_epoch[index]:
            self._contradicted_since = None
            return self.constraint.measure(index, ctx) if self.constraint is not None else None
        zupt = self._zero_velocity(ctx)
        if self.options.max_speed_mps is not None and agrees(zupt, ctx.covariance):
            self._agreed = (ctx.t, ctx.position_enu, ctx.position_covariance_enu)
        if self.zero_rate is None:
            return zupt
        t = self._epochs[index]
        zaru = self.zero_rate.measure(t - 1.0 / self.options.update_rate_hz, t, ctx)
        if self.options.zero_velocity:
            return zupt.stacked_with(zaru)
        # The detector may be wrong about a creeping machine: the constraint holds either way,
        # and the ZARU only while the filter's own velocity does not show it moving.
        constraint = self.constraint.measure(index, ctx) if self.constraint is not None else None
        if _moving(ctx):
            self._contradicted_since = None
            return constraint
        if _turning(zaru, ctx):
            self._contradicted(index, t, zaru, ctx)
            return constraint
        self._contradicted_since = None
        self._explained_at = t
        self._travel_m = 0.0
        return zaru if constraint is None else constraint.stacked_with(zaru)

    def _zero_velocity(self, ctx: MeasurementContext) -> Measurement:
        """The ZUPT, ``z = ṽⁿ``, ``H = [I₃ 0 …]``, ``R = σ_zv² I₃``."""
        h = np.zeros((3, ctx.layout.dim))
        h[:, ctx.layout.slice(VELOCITY)] = np.eye(3)
        return Measurement(
            ctx.velocity.copy(), h, np.eye(3) * self.variance, velocity_at=np.zeros(3)
        )

    def beyond_linearization(self, index: int, ctx: MeasurementContext) -> bool:
        """With ``max_speed_mps``: a ZUPT epoch at which the filter's speed exceeds the
        machine's top speed while its attitude σ exceeds :data:`LINEAR_ATTITUDE_SIGMA`. The
        SINS then coasted on a tilt and a heading beyond the first-order model, and a zero
        velocity taken in through its correlations is overconfident (a 157-m/s ZUPT
        innovation accepted at a heading σ of 70° left the position 3.4 σ off; on random
        world 12, redrawn at c91e26b, one at 27 m/s and a heading σ of 29.6°, 31.6° off,
        swung the heading to −8° and left the position 339 m off at a σ of 48 m, where the
        30° of a lock's inflation had been the bound): the engine asks :meth:`reacquire`
        instead. A SINS a few m/s off at a heading σ of a degree (``seed002-rectangle``) is
        within the model, and the zero velocity corrects its position better than a restart
        would."""
        limit = self.options.max_speed_mps
        if limit is None or not self.zupt_epoch[index]:
            return False
        if float(np.linalg.norm(ctx.velocity)) <= limit:
            return False
        attitude = ctx.layout.slice(ATTITUDE)
        largest = float(np.max(np.diagonal(ctx.covariance[attitude, attitude])))
        return largest > LINEAR_ATTITUDE_SIGMA**2

    def _zupt_epoch_at(self, t: float) -> int | None:
        """The index of the epoch at ``t`` if it is a ZUPT epoch, else None."""
        index = int(np.searchsorted(self._epochs, t - 1e-9))
        if index >= self._epochs.size or not self.zupt_epoch[index]:
            return None
        return index

    def lost_lock_doubt(self, t: float, ctx: MeasurementContext) -> str | None:
        """A lost lock at a ZUPT epoch whose zero velocity the filter's covariance does not
        explain (:func:`_agrees`), when nothing but the IMU says the machine stands (no
        ``odometer_rest_mps``) and no top speed is known (no ``max_speed_mps``, whose
        re-acquisition deals with it): the filter's velocity or the detector is wrong, and
        the IMU cannot tell which. Steady driving looks like a standstill to a norm detector,
        and an inflation to the car's speed would admit the next false zero velocity
        (docs/design/2026-12-01-a-zupt-on-the-imu-alone.md). Otherwise no doubt (the odometer
        confirms the rest, or the lost lock is the stacked ZARU's)."""
        options = self.options
        if options.odometer_rest_mps is not None or options.max_speed_mps is not None:
            return None
        if self._zupt_epoch_at(t) is None or agrees(self._zero_velocity(ctx), ctx.covariance):
            return None
        return (
            "the standstill rests on the IMU's detector alone, and the filter's velocity"
            " contradicts it (a moving machine can look still to the detector)"
        )

    def reacquire(self, t: float, ctx: MeasurementContext) -> Reacquisition | None:
        """At a standstill (a ZUPT epoch at ``t``) where the filter is beyond its first-order
        model (:meth:`beyond_linearization`) or its covariance does not explain the zero
        velocity: what the machine's rest says alone
        (option ``max_speed_mps``), or None (a lost lock of a ZARU stacked with the ZUPT is
        the gyro bias's, inflated as any other).

        - Velocity zero, with the ZUPT's variance.
        - The tilt from the accelerometers over the standstill's last ``guard_s``
          (:class:`fusion.lock.RestLevel`).
        - The position of the last standstill the filter agreed with (the ZUPT within
          χ²₃(:data:`fusion.lock.FIX_GATE_PROBABILITY`) of its velocity covariance), with that
          epoch's covariance plus ``(v_max Δt)²/3`` per axis: the machine is anywhere within
          ``v_max Δt`` of it, the variance of a uniform spread over ``±v_max Δt`` (as the
          motion constraint's speed state, :mod:`fusion.aiding.odometer`).

        A SINS coasting a pass with no aiding tilts and turns with its gyro biases; at the next
        standstill its velocity is metres per second off at a σ that its linearized model kept
        far below that, every ZUPT is rejected, and without this it coasted on for the rest of
        the recording, 10⁶ m off (random worlds at their own length)."""
        options = self.options
        if options.max_speed_mps is None or self._agreed is None:
            return None
        index = self._zupt_epoch_at(t)
        if index is None:
            return None
        if not self.beyond_linearization(index, ctx) and agrees(
            self._zero_velocity(ctx), ctx.covariance
        ):
            return None  # the velocity is not what the filter lost
        level = self._rest_level.over(t - options.guard_s, t, ctx.c_b_n, ctx.accel_bias)
        if level is None:
            return None
        since, position, covariance = self._agreed
        spread = (options.max_speed_mps * (t - since)) ** 2 / 3.0
        return Reacquisition(
            position,
            covariance + spread * np.eye(3),
            np.zeros(3),
            self.variance * np.eye(3),
            level,
        )

    def _contradicted(
        self, index: int, t: float, zaru: Measurement, ctx: MeasurementContext
    ) -> None:
        """Count a ZARU left out as a turn; after ``zaru_persistence_s`` of them in one
        standstill, widen what its vertical row shows wrong (:func:`_heading_widening`) at the
        next epoch, from which on the ZARU is explained again.

        A turn the detector took for a stop is left out; but so was every ZARU of a real
        standstill once the vertical gyro bias had walked off during a haul, and the bias then
        stayed wrong for good while the heading ran off at a σ of degrees. A smooth haul that
        looks still mostly does so for seconds between the detector's flickers; a standstill
        lasts minutes (docs/design/2026-11-29-zaru-contradicting-the-bias.md)."""
        if self._contradicted_since is None:
            self._contradicted_since = t
        if t - self._contradicted_since < self.options.zaru_persistence_s:
            return
        elapsed = t - self._explained_at
        widening = _heading_widening(zaru, ctx, elapsed, self._travel_m)
        if widening is not None:
            bias = math.degrees(math.sqrt(float(widening[GYRO_BIAS][2]))) * 3600.0
            heading = math.degrees(math.sqrt(float(widening[ATTITUDE][2])))
            reason = (
                f"every ZARU for {self.options.zaru_persistence_s:g} s of a standstill contradicts"
                f" the vertical gyro bias: widened by a σ of {bias:.3g} °/h, the heading by one of"
                f" {heading:.3g}° (the bias off since the last explained ZARU, {elapsed:.0f} s ago)"
            )
            self._widening[index + 1] = ProcessNoise(widening, reason)
            self._contradicted_since = None
