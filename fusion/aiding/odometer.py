"""Odometer + motion constraint (seed 000 §2.1, eqs. 1–4, 10, 18–20; seed 003 eqs. 7–17).

The odometer frame m is the IMU body frame turned by the mounting matrix ``C_b^m``; the shearer
moves along the m-frame y axis only (motion constraint: no lateral, no vertical velocity), and
the haulage encoder measures that speed with a scale error: ``s̃ = (1 + δk_D) v^m_y``.

With the nominal mounting ``C̃_b^m = C_b^m (I + δα×)`` (seed 000 eq. 10) and the SINS attitude
``C̃_n^b = C_n^b (I + φ×)``, the SINS velocity in m is, to first order,

    ṽ^m = C̃_b^m C̃_n^b ṽ^n = v^m + C_b^m C_n^b δv − C_b^m C_n^b (v^n×) φ − C_b^m (v^b×) δα

and the true ``v^m = [0, s̃ (1 − δk_D), 0]``. The measurement (mode ``odometer``) is

    z = ṽ^m − [0, s̃, 0]
    H = [C_b^m C_n^b,  −C_b^m C_n^b (v^n×),  0,  0,  0,  …,  −C_b^m (v^b×),  [0, −v^m_y, 0]ᵀ]

where the attitude and parameter columns take the vehicle velocity ``v^m = [0, s̄ / (1 + δk̂_D),
0]`` (``v^n = C_b^n C_m^b v^m``) with s̄ a mean of readings *before* this one: of the steady
segment ending 2 s earlier while the speed is steady, of the last second while it changes,
zero while the machine stands (``rest_guard_s`` of still readings, :func:`still_readings`;
:mod:`fusion.aiding.reference_speed` says why). The
SINS velocity in the attitude columns also carried the cutting vibration that is in z: with
the encoder's 2–3 mm/s as R, yaw RMS(ε/σ) 2.4 against 2.1 at the reference (``longwall-200m``,
8 seeds of 300 s; see also ``filter.specific_force_time_constant_s`` in
:mod:`fusion.error_model`). Without an odometer (mode ``motion_constraint``) the attitude
columns take the SINS's mean velocity over the last ``column_window_s``, which the vibration
in z is not in (:class:`TravelWindow`), as far as it is known: on a slow machine shrunk by its
own uncertainty, otherwise zeroed while its speed is below 1σ of it
(``_attitude_column_velocity``).

An encoder reading is the travel counted over its sample interval divided by its length, so ṽ^n
is the *mean* nominal velocity over the same interval, ``(∫ v^n dt)`` between the previous
reading and this one over their spacing (``MeasurementContext.travel``); its error is δv at the
epoch to first order (the interval is 0.1 s). Against the velocity at the epoch instead, 5–30 Hz
cutting vibration (±1 cm/s) enters z as coloured noise (7 mm/s against the encoder's 2), and
with the previous reading in the columns its correlation walked δk_D to −0.57 within 15 min
(``longwall-200m`` seed 0, 700 s, odometer alone: 27.9 m horizontal RMS, RMS(ε/σ) 18; with the
1-s column mean 2.6 m; with the interval mean as well 1.06 m and 1.08 — 1.02 m without
vibration). When the previous reading was not measured (rate cap) the epoch's velocity stands in.

(columns δv, φ, δp, ε, ∇, then this plugin's δα (3) and δk_D). Mode ``motion_constraint``
keeps only the x and z rows and needs no odometer (seed 002 eq. 17); it runs at the rate given
in the options on the IMU clock and owns only δα — and, given the machine's top speed
(``max_speed_mps``), its speed along the track u, against which it keeps the y row as
``z_y = ṽ^m_y`` with ``H_u = 1`` (:meth:`Odometer._speed_block`). Its mounting columns take the
same mean velocity, or zero while the speed is within 3σ of the velocity's uncertainty (nothing
observes the speed along the track at a standstill; see ``_constrained_velocity``). The odometer
lever arm is neglected (the shearer turns at < 0.1°/s, so ω × l is below 1 mm/s for a lever arm
of a metre).
δα_y does not enter any row (a rotation about the travel direction leaves v^m unchanged), so its
σ stays at its prior — the seed's observability analysis (§3.3).

Where nothing else gives the direction of the velocity (``heading_untouched``, mode
``motion_constraint``) the update leaves the heading and the vertical gyro bias alone: they are
Schmidt consider states (:attr:`fusion.plugin.Measurement.consider`), whose uncertainty enters S
and the other gains and whose own gain is zero. A turn of the whole trajectory is invisible to
the constraint; what its rows said about the heading came from the covariance of the heading
and the bias with the velocity, and the rows' noise, the machine's vibration velocity, is
correlated with the vibration that ``fⁿ × φ`` pairs with the heading in F: the rows walked the
vertical gyro bias, and the yaw with it, over a long pass without a stop
(docs/design/2026-12-01-vibration-in-f-for-the-constraint.md).

Wheel slip (option ``slip_detection``): a wheel that slips over-reads by a ratio s from one
sample to the next, ``s̃ = (1 + δk_D)(1 + s) v``. The plugin then owns a slip state s (its
column in H is δk_D's: to first order only their sum is seen), zero and constant except for
jumps, which :mod:`fusion.jumps` detects, estimates and takes in: the velocity and position the
slip had pulled are put back, and the odometer keeps aiding with the slipping scale (isolating
it would leave a MEMS SINS to coast, which drifts further than the slip pulls). The wheel's
grip returning is the jump back to s = 0 (the state's rest), where s is then set exactly, so a
slip does not leave its estimation error in δk_D. A held slip may also end unseen, so it
decays towards zero and its σ grows as those of a state that may have returned
(``slip_mean_duration_s``; :meth:`fusion.jumps.JumpDetector.held_return`). A standstill
(every reading of the past ``rest_guard_s`` a still one, :func:`still_readings`) ends a slip
episode for certain: the measurement reports s at rest, and a slip still held is restarted at
zero (:meth:`fusion.jumps.JumpDetector.rest`).

By default (``slip_sign: any``) s leaves rest either way: a driven wheel that spins reads long,
and one that skids, slides locked or loses encoder counts reads short, and either is taken in.
With ``slip_sign: positive`` (a wheel that can only read long) s leaves rest upwards only, so
that the end of a slip whose onset went unnoticed (at a crawl the step is within the encoder
noise) is not taken for a negative slip. An under-reading wheel is then left to the fault
monitor: in the federated filter the jump detector's hypothesis against the slip's direction
names the odometer's local, which is isolated instead of the sensors that disagree with it
(:class:`fusion.federated.FederatedFilter`), and which stays in the fusion where it is the last
source holding the SINS. The one-way state suits a filter in which only the IMU sees a slip's
onset (docs/design/2026-11-30-skids-taken-in.md).

Zero angular rate at standstill (option ``zero_angular_rate``, mode ``odometer``): while every
odometer reading of the past ``rest_guard_s`` is a still one the machine stands, and the
gyro mean since the previous reading is the earth rate plus the bias
(:mod:`fusion.aiding.zaru`). The encoder knows a stop the moment it begins, without the IMU
detector's lag; this is the static gyro calibration a MEMS alignment starts with, repeated at
every stop, and the only thing that observes the vertical gyro bias before the heading has
drifted on a slow, straight machine.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator
from scipy.spatial.transform import Rotation

from fusion.aiding.reference_speed import ReferenceSpeed, reading_noise
from fusion.aiding.zaru import ZeroAngularRate
from fusion.attitude import dcm_from_euler, skew
from fusion.encoder import after_missing_readings, reading_intervals
from fusion.error_model import ATTITUDE, GYRO_BIAS, KNOWN_SIGMAS, VELOCITY, StateBlock
from fusion.lock import Level, Reacquisition, RestLevel, agrees
from fusion.plugin import Measurement, MeasurementContext, MissingStream, Plugin, PluginOptions
from fusion.recording import Recording

SLIP_PRIOR_SIGMA = 1e-4  # no slip at the start; a jump opens it (fusion.jumps)
SLIP_BOUND = 1.0
"""Largest slip ratio taken in: a wheel that turns twice as far as the machine travels is not
slipping but broken (left to the fault monitor). On a harsh random world the slip state, held
by nothing else, took in jumps of +0.7, +1.6, +3.7 … +1.9·10⁴ within 20 s and the run ended
17 m off."""
CHI2_1_MEDIAN = 0.4549364  # median of χ²₁


def reading_jitter(
    speed: NDArray[np.float64], window: int, still: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """Each reading's noise variance as the readings themselves show it (causal).

    Over the last ``window`` differences up to this reading, ``mean((s_k − s_{k−1})²) / 2``: a
    machine's speed hardly changes between readings, so consecutive differences are the
    difference of two readings' noise (white noise, or an encoder's count quantization, whose
    carried remainder alternates the reading between two count levels). A mean, not a median:
    the first count steps of a start raise it at once (a median waited for half a window of
    them, and the scale was learnt from the unweighted ones meanwhile); speed changes can only
    make it larger. The first readings use the differences there are.

    A difference between two ``still`` readings is left out: a standing encoder shows only its
    electrical noise, not the count quantization it has again from its first movement on. With
    the standstill's differences in the window, a start after a stop weighed its first readings
    (zero counts while the machine already moved at 2–6 cm/s, a count being 7 cm/s) at the
    configured 1 cm/s, and each start moved δk_D by −0.1 … −0.35 % (random full-length world 0,
    72 counts/m: −4.4 % over 166 such readings against a true +0.4 %). Left out, the jitter
    learned while the machine last moved carries over the stop (:meth:`Odometer._jitter`).
    """
    moving = np.concatenate([[False], ~(still[1:] & still[:-1])])
    squares = np.concatenate([[0.0], np.diff(speed) ** 2]) * moving
    total = np.cumsum(squares)
    counted = np.cumsum(moving)
    start = np.searchsorted(counted, counted - window, side="left")
    count = counted - counted[start]
    out = np.zeros(speed.size)
    np.divide(total - total[start], 2.0 * count, out=out, where=count > 0)
    return out


def still_readings(
    t: NDArray[np.float64], speed: NDArray[np.float64], options: OdometerOptions
) -> NDArray[np.bool_]:
    """Readings at which the machine may stand: the reading within 3σ of zero (σ the configured
    ``sigma_speed_mps``), and so is the mean of the readings over the last
    ``reference_window_s`` (this one included) within 3σ/√n, σ there the larger of the
    configured one and the readings' own noise (from their successive differences).

    A single reading within 3σ of zero is not a standstill: a shearer cuts at 2–3 m/min
    (0.03–0.05 m/s), within 3σ of an encoder whose σ is 1 cm/s. Taken as standing, such
    readings had their columns zeroed while the machine moved, and δk_D walked to −0.24 ± 0.01
    against a true +0.03 on a random world cutting at 2.1–3.1 m/min (sins_od_ckf: along-face
    error 7.9 m at a σ of 0.4 m after 900 s). The mean of a second of readings separates such a
    crawl from a stand by a factor √n."""
    n_readings = t.size
    if n_readings == 0:
        return np.empty(0, bool)
    first = np.searchsorted(t, t - options.reference_window_s, side="right")
    last = np.arange(1, n_readings + 1)
    count = last - first
    total = np.concatenate([[0.0], np.cumsum(speed)])
    mean = (total[last] - total[first]) / count
    sigma = np.maximum(options.sigma_speed_mps, reading_noise(speed, first, last))
    reading_still = np.abs(speed) < 3.0 * options.sigma_speed_mps
    return reading_still & (np.abs(mean) <= 3.0 * sigma / np.sqrt(count))


_MODE_ONLY: dict[str, tuple[str, str]] = {
    "zero_angular_rate": ("odometer", "the encoder shows the stops"),
    "heading_untouched": (
        "motion_constraint",
        "an odometer's speed gives the direction of the velocity",
    ),
    "column_window_s": (
        "motion_constraint",
        "with an odometer the encoder's reference speed builds the columns: reference_window_s",
    ),
    "max_speed_mps": ("motion_constraint", "an odometer measures it"),
    "speed_correlation_time_s": ("motion_constraint", "the speed state of max_speed_mps"),
    "constraint_rate_hz": ("motion_constraint", "an odometer's epochs are its readings"),
}
"""The options that only one mode uses, with the mode and why. Writing one on the other mode is
an error, whatever its value: the key would be silently ignored."""


class OdometerOptions(PluginOptions):
    """Options of the odometer / motion-constraint plugin."""

    mode: Literal["odometer", "motion_constraint"] = "odometer"
    sigma_speed_mps: float = Field(0.01, gt=0, description="odometer speed noise, 1σ")
    sigma_lateral_mps: float = Field(0.01, gt=0, description="motion-constraint noise, 1σ")
    sigma_vertical_mps: float = Field(0.01, gt=0, description="motion-constraint noise, 1σ")
    mounting_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="nominal m-frame mounting (roll, pitch, yaw) relative to b"
    )
    mounting_sigma_deg: float = Field(2.0, gt=0, description="prior σ of each δα")
    scale_sigma: float = Field(0.03, gt=0, description="prior σ of δk_D")
    slip_detection: bool = Field(
        False,
        description="own a slip-ratio state whose jumps (a wheel starting and stopping to slip)"
        " are detected, estimated and taken in (fusion.jumps; options filter.jump_detection)",
    )
    slip_sign: Literal["any", "positive"] = Field(
        "any",
        description="with slip_detection: the signs a slip may take from rest. any: a wheel"
        " reading long (spinning) or short (skidding, lost counts); positive: long only, an"
        " under-reading wheel is left to the fault monitor",
    )
    slip_mean_duration_s: float | None = Field(
        30.0,
        gt=0,
        description="with slip_detection: how long a slip lasts on average, s (a wheel grips"
        " again after seconds to a minute). A held slip decays towards zero and its σ grows as"
        " those of one that may have ended unseen; null: a slip ends only when its end is"
        " detected or the machine stops",
    )
    constraint_rate_hz: float = Field(10.0, gt=0, description="motion_constraint mode only")
    max_speed_mps: float | None = Field(
        None,
        gt=0,
        description="motion_constraint mode only: the machine's top speed along the track. The"
        " plugin then owns that speed as a state, a Gauss–Markov process of σ max_speed/√3"
        " (anywhere in ±max_speed), so that without an odometer the SINS speed stays within"
        " what the machine can do (a shearer hauls at ≤ 30–40 m/min); None: no such state",
    )
    speed_correlation_time_s: float = Field(
        600.0,
        gt=0,
        description="correlation time of that speed: a shearer holds its haulage speed for"
        " minutes (a pass along a face takes tens of minutes)",
    )
    heading_untouched: bool = Field(
        False,
        description="motion_constraint mode only: the update leaves the heading and the vertical"
        " gyro bias alone (Schmidt consider states), for a configuration in which nothing else"
        " gives the direction of the velocity; the constraint then only informed them through"
        " a linearization at an erroneous state and through the cutting vibration, which its"
        " noise shares (docs/design/2026-12-01-vibration-in-f-for-the-constraint.md)",
    )
    column_window_s: float = Field(
        1.0,
        ge=0,
        description="motion_constraint mode only: the attitude and mounting columns take the"
        " SINS's mean velocity over this window (TravelWindow), which the cutting vibration in"
        " the innovation is not in; 0: the instantaneous velocity, for a vehicle whose speed"
        " dwarfs its vibration, such as a car, where the window cost accuracy"
        " (docs/design/2026-12-04-vibration-walks-sins-uwb-heading.md)",
    )
    zero_angular_rate: bool = Field(
        False, description="ZARU while the odometer shows standstill (mode odometer only)"
    )
    reference_window_s: float = Field(
        1.0,
        gt=0,
        description="while the speed changes, the parameter and attitude columns take the mean"
        " odometer speed of this window before the reading (fusion.aiding.reference_speed)",
    )
    steady_window_s: float = Field(
        10.0,
        ge=0,
        description="while the speed is steady they take the mean of the steady segment, which"
        " starts with (and is tested against) a window of this length (0: never)",
    )
    steady_lag_s: float = Field(
        2.0, ge=0, description="the steady window ends this long before the reading"
    )
    rest_guard_s: float = Field(
        1.0, ge=0, description="standstill this long before a ZARU or ending a slip"
    )
    angular_rate_floor_dps: float = Field(
        0.002, ge=0, description="ZARU noise added to the averaged ARW (standstill vibration)"
    )
    adaptive_noise: bool = Field(
        True,
        description="learn each row's noise from the last adaptive_window innovations (robust"
        " Sage–Husa), at least the configured σ",
    )
    adaptive_window: int = Field(50, ge=2, description="innovations of the adaptive noise")
    adaptive_max_factor: float = Field(
        10.0,
        ge=1.0,
        description="the learned σ of a row is at most this multiple of its configured σ (the"
        " encoder's jitter aside): innovations beyond that are the filter's error, not the"
        " sensor's, and are left to the gate and the lost-lock inflation",
    )

    @model_validator(mode="after")
    def _options_of_the_other_mode(self) -> OdometerOptions:
        for key in sorted(self.model_fields_set & _MODE_ONLY.keys()):
            mode, reason = _MODE_ONLY[key]
            if self.mode != mode:
                raise ValueError(f"{key} needs mode: {mode} ({reason})")
        return self

    @model_validator(mode="after")
    def _windows_apart(self) -> OdometerOptions:
        if self.steady_window_s > 0 and self.steady_lag_s < self.reference_window_s:
            raise ValueError(
                f"steady_lag_s ({self.steady_lag_s}) must be at least reference_window_s "
                f"({self.reference_window_s}): the steady and short windows must not overlap"
            )
        return self


class TravelWindow:
    """Mean nominal velocity over a trailing window, from the SINS travel
    (:attr:`fusion.plugin.MeasurementContext.travel`):

        v̄ⁿ(t) = (T(t) − T(t₀)) / (t − t₀),   t₀ the oldest epoch within ``span_s`` before t

    — the velocity at which the motion constraint's attitude and mounting columns are built
    without an odometer (``column_window_s``). The lateral innovation is the instantaneous SINS
    velocity and carries the cutting vibration; columns built from that same velocity carry it
    too, and the mean of their product walks the heading off its σ while the track stays right
    (docs/design/2026-12-04-vibration-walks-sins-uwb-heading.md). A box of span T passes a
    vibration of frequency f at ≤ 1/(π f T) of its amplitude (≤ 11 % at 3 Hz for T = 1 s).
    Until the window holds half its span (a run's start, a gap in the epochs) the
    instantaneous velocity stands in."""

    def __init__(self, span_s: float) -> None:
        self.span_s = span_s
        self._epochs: deque[tuple[float, NDArray[np.float64]]] = deque()

    def clear(self) -> None:
        """Forget the epochs of a previous run."""
        self._epochs.clear()

    def mean_velocity(self, ctx: MeasurementContext) -> NDArray[np.float64]:
        """Record the epoch's travel; the mean velocity over the window ending at it (the
        instantaneous one with a window of zero)."""
        self._epochs.append((ctx.t, ctx.travel.copy()))
        while len(self._epochs) > 1 and self._epochs[0][0] < ctx.t - self.span_s - 1e-9:
            self._epochs.popleft()
        t0, travel0 = self._epochs[0]
        if self.span_s == 0.0 or ctx.t - t0 < 0.5 * self.span_s:
            return ctx.velocity
        mean: NDArray[np.float64] = (ctx.travel - travel0) / (ctx.t - t0)
        return mean


class Odometer(Plugin):
    """Odometer speed along the travel axis plus zero lateral and vertical velocity."""

    Options = OdometerOptions
    options: OdometerOptions

    def __init__(self, name: str, options: OdometerOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        self.use_speed = options.mode == "odometer"
        if self.use_speed and recording.odometer is None:
            raise MissingStream(
                f"plugin {name!r} (mode odometer) needs odometer.csv; "
                "use mode: motion_constraint without one"
            )
        r, p, y = np.deg2rad(options.mounting_deg)
        # C_b^m from the mounting angles in the recording's attitude convention (m relative to b).
        self.c_b_m = dcm_from_euler(r, p, y).T
        self.speed = recording.odometer.speed if recording.odometer is not None else np.empty(0)
        self.still = (
            still_readings(recording.odometer.t, self.speed, options)
            if recording.odometer is not None
            else np.empty(0, bool)
        )
        self.reference = ReferenceSpeed(
            recording.odometer.t if recording.odometer is not None else np.empty(0),
            self.speed,
            options.reference_window_s,
            options.steady_window_s,
            options.steady_lag_s,
        )
        self._speed_state = options.max_speed_mps is not None
        self.rows = np.array([0, 1, 2]) if self.use_speed or self._speed_state else np.array([0, 2])
        along = options.sigma_speed_mps if self.use_speed else options.sigma_lateral_mps
        self.variance = (
            np.array([options.sigma_lateral_mps, along, options.sigma_vertical_mps])[self.rows] ** 2
        )
        self._excess: deque[NDArray[np.float64]] = deque(maxlen=options.adaptive_window)
        self._column_window = TravelWindow(options.column_window_s)
        self._index = 0
        self.zero_rate = (
            ZeroAngularRate(recording, options.angular_rate_floor_dps, name)
            if options.zero_angular_rate
            else None
        )
        self.at_rest = self._standstill() if self.use_speed else np.empty(0, bool)
        """Readings at which the encoder shows the machine standing: the ZARU, the slip's rest
        and the columns' zero speed (:meth:`_reference_speed`) all read it."""
        self.jitter = self._jitter(options.adaptive_window)
        self._travel = (
            np.cumsum(np.abs(self.speed) * reading_intervals(recording.odometer.t))
            if self.use_speed and recording.odometer is not None and self.speed.size > 1
            else np.zeros(self.speed.size)
        )
        self._after_gap = (
            after_missing_readings(recording.odometer.t)
            if recording.odometer is not None
            else np.zeros(self.speed.size, bool)
        )
        """Per reading, whether rows are missing before it: its SINS velocity is the epoch's."""
        self._rest_level = RestLevel(recording)
        still = self.still if self.use_speed else np.zeros(self.speed.size, bool)
        readings = np.arange(still.size)
        started = still & ~np.concatenate([[False], still[:-1]])
        run_start = np.maximum.accumulate(np.where(started, readings, 0))
        self._still_since = np.where(still, run_start, readings + 1)
        """Per reading, the first reading of the still run it belongs to (after it if moving)."""
        self.start_run()

    def start_run(self) -> None:
        """Forget a run's learned noise, reference travel and rest scatter."""
        self._excess.clear()
        self._column_window.clear()
        self._index = 0
        self._agreed: tuple[int, NDArray[np.float64], NDArray[np.float64]] | None = None
        self._lost_at: int | None = None  # the reading of the last lost lock left to inflation
        self.reference.start_run()
        if self.zero_rate is not None:
            self.zero_rate.start_run()

    def _standstill(self) -> NDArray[np.bool_]:
        """Readings preceded by ``rest_guard_s`` of still readings (this one too)."""
        assert self.recording.odometer is not None
        t = self.recording.odometer.t
        moving = ~self.still
        span = round(self.options.rest_guard_s / float(np.median(np.diff(t))))
        moved = np.concatenate([[0], np.cumsum(moving)])
        first = np.maximum(np.arange(t.size) - span, 0)
        rest: NDArray[np.bool_] = (moved[1:] - moved[first]) == 0
        rest[: max(span, 1)] = False  # no interval before the first reading, no past to check
        return rest

    def _jitter(self, window: int) -> NDArray[np.float64]:
        """The speed row's noise floor per reading (:func:`reading_jitter`): the jitter of the
        readings while the machine may move, standstill pairs left out, and of all readings
        where the encoder shows it standing (``at_rest``), whose readings of zero counts carry
        only the encoder's electrical noise and hold the velocity at zero as firmly as that."""
        if not self.use_speed:
            return np.zeros(self.speed.size)
        moving = reading_jitter(self.speed, window, self.still)
        standing = reading_jitter(self.speed, window, np.zeros(self.speed.size, bool))
        return np.where(self.at_rest, standing, moving)

    def state_blocks(self) -> tuple[StateBlock, ...]:
        """Mounting angles δα (3) and, with an odometer, its scale factor error δk_D."""
        sig = np.deg2rad(self.options.mounting_sigma_deg)
        blocks = [
            StateBlock(f"{self.name}.mounting_angles", ("x", "y", "z"), (sig,) * 3, unit="deg")
        ]
        if self._speed_state:
            blocks.append(self._speed_block())
        if self.use_speed:
            blocks.append(
                StateBlock(
                    f"{self.name}.scale_error", ("k",), (self.options.scale_sigma,), unit="ppm"
                )
            )
        if self.use_speed and self.options.slip_detection:
            blocks.append(
                StateBlock(
                    f"{self.name}.slip",
                    ("s",),
                    (SLIP_PRIOR_SIGMA,),
                    may_jump=True,
                    rest=0.0,
                    leaves_rest=1 if self.options.slip_sign == "positive" else 0,
                    rest_return_s=self.options.slip_mean_duration_s,
                    bound=SLIP_BOUND,
                    unit="pct",
                )
            )
        return tuple(blocks)

    def _speed_block(self) -> StateBlock:
        """The machine's speed along the track u (mode ``motion_constraint`` with a top speed):
        first-order Gauss–Markov, σ_u = v_max/√3 (a speed anywhere in ±v_max), correlation
        time τ = ``speed_correlation_time_s``, driving noise 2σ_u²/τ. The along-track row of
        the constraint then reads ``ṽ^m_y = u``: the SINS speed is the machine's, up to the
        cutting vibration (that row takes the lateral σ).

        Without an odometer nothing else observes that speed: the SINS drifted along the track
        at its accelerometer bias, metres per second, and once the bends of the track had seen
        some of it the filter took its velocity for known. Why a state and not a bound applied
        at each epoch: ``docs/design/2026-11-27-speed-state.md``. The top speed is also the
        state's physical bound (:attr:`fusion.error_model.StateBlock.bound`): an estimate the
        SINS drags past it is projected back (``sins_mc`` on ``longwall-200m`` seed 7: −1.31 m/s
        at a σ of 0.11 m/s, the machine cutting at +0.09 m/s)."""
        assert self.options.max_speed_mps is not None
        sigma = self.options.max_speed_mps / math.sqrt(3.0)
        tau = self.options.speed_correlation_time_s
        return StateBlock(
            f"{self.name}.speed",
            ("u",),
            (sigma,),
            (2.0 * sigma**2 / tau,),
            tau,
            bound=self.options.max_speed_mps,
            unit="m_s",
        )

    def epochs(self) -> NDArray[np.float64]:
        """Odometer times, or a regular grid on the IMU clock for the constraint alone."""
        if self.use_speed:
            assert self.recording.odometer is not None
            return self.recording.odometer.t
        t = self.recording.imu.t
        return np.arange(t[0], t[-1], 1.0 / self.options.constraint_rate_hz)[1:]

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement:
        """Residual of the SINS velocity in m against the odometer and the constraint, plus
        the zero angular rate at a standstill if configured."""
        velocity = self._velocity(index, ctx)
        if self.use_speed and (self._agreed is None or self._may_agree(index, velocity, ctx)):
            self._agreed = (index, ctx.position_enu, ctx.position_covariance_enu)
        if not self.at_rest.size or not self.at_rest[index]:
            return velocity
        if self.options.slip_detection:
            velocity = replace(velocity, at_rest=(f"{self.name}.slip",))
        if self.zero_rate is None:
            return velocity
        t = self.recording.odometer.t  # type: ignore[union-attr]
        return velocity.stacked_with(self.zero_rate.measure(t[index - 1], t[index], ctx))

    def _may_agree(self, index: int, velocity: Measurement, ctx: MeasurementContext) -> bool:
        """Whether reading ``index`` is a newer position to go back to (:meth:`reacquire`): the
        filter agrees with it, and it is not a later reading of a standstill whose earlier one
        the filter already agreed with (the machine has not moved since; a filter whose
        inflated variances admit a reading after its SINS drifted agrees with a worse one)."""
        assert self._agreed is not None
        if self._agreed[0] >= self._still_since[index]:
            return False
        return agrees(velocity, ctx.covariance)

    def reacquire(self, t: float, ctx: MeasurementContext) -> Reacquisition | None:
        """What the encoder says alone (mode ``odometer``), for a filter that rejected every
        reading of it: the machine stands, or moves along its travel axis at the speed it reads,
        whatever the SINS says.

        - Velocity: zero at a standstill, with the encoder's speed variance; in motion the
          reading along the travel axis, less the estimated scale and slip, at the levelled
          attitude (:meth:`_travel_velocity`).
        - The tilt from the accelerometers over the last ``rest_guard_s``
          (:class:`fusion.lock.RestLevel`), in motion less the acceleration the readings show
          along the travel axis (a shearer's haulage accelerates by centimetres per second
          squared: its specific force is gravity to within a few tenths of a degree).
        - The position at the last reading the filter agreed with (χ² within
          :data:`fusion.lock.FIX_GATE_PROBABILITY`; the first reading of the run if none did),
          with that reading's covariance plus ``(d (1 + 3 σ_k))²/3`` per axis for the travel d
          the encoder counted since: the machine is anywhere within that reach of it.

        Only for a lock lost again after the variances' inflation (:mod:`fusion.lock`) did not
        bring the readings back: a gyro bias far beyond its prior tilts a levelled SINS away
        again within seconds, and the inflation lets the filter learn it (harsh random world 9,
        2700 °/h against 720 °/h: levelled every 3 s, 25 m off after 150 s). But the inflation
        catches up with a velocity error that grows by g·tilt every second only by chance: a
        SINS that starts at rest on a pitch 3.9° off at a σ of 0.4° coasted 900 km
        (docs/design/2026-12-02-initial-attitude-covariance.md), and one that lost its tilt
        while hauling (a degraded IMU coasting through a dropout into a slip) 14 km in 150 s
        (docs/design/2026-12-04-confident-after-an-odometer-dropout.md). None before any
        reading and at a lock's first loss since the filter last agreed."""
        if not self.use_speed or self._agreed is None:
            return None
        odometer_t = self.recording.odometer.t  # type: ignore[union-attr]
        index = int(np.searchsorted(odometer_t, t, side="right")) - 1
        if index < 0:
            return None
        if self._lost_at is None or self._lost_at < self._agreed[0]:
            self._lost_at = index  # a first loss: the inflation's turn
            return None
        start = t - self.options.rest_guard_s
        resting = bool(self.at_rest[index])
        speed, acceleration = (0.0, 0.0) if resting else self._haulage(index, start, ctx)
        along = self.c_b_m.T @ np.array([0.0, 1.0, 0.0])  # the travel axis, body frame
        level = self._rest_level.over(start, t, ctx.c_b_n, ctx.accel_bias, acceleration * along)
        if level is None:
            return None
        velocity, velocity_covariance = (
            (np.zeros(3), self.options.sigma_speed_mps**2 * np.eye(3))
            if resting
            else self._travel_velocity(speed, level, ctx)
        )
        since, position, covariance = self._agreed
        reach = (self._travel[index] - self._travel[since]) * (1.0 + 3.0 * self.options.scale_sigma)
        return Reacquisition(
            position, covariance + reach**2 / 3.0 * np.eye(3), velocity, velocity_covariance, level
        )

    def _haulage(self, index: int, start: float, ctx: MeasurementContext) -> tuple[float, float]:
        """The speed (m/s) of reading ``index`` less the estimated scale and slip, and the
        acceleration (m/s²) the readings show from the last one at or before ``start`` to it
        (zero with none before it), for a re-acquisition in motion."""
        odometer_t = self.recording.odometer.t  # type: ignore[union-attr]
        scale = float(np.sum(ctx.x[self._scale_states(ctx)]))  # δk_D and the slip s
        speed = float(self.speed[index]) / (1.0 + scale)
        before = min(int(np.searchsorted(odometer_t, start, side="right")) - 1, index - 1)
        if before < 0:
            return speed, 0.0
        change = speed - float(self.speed[before]) / (1.0 + scale)
        return speed, change / float(odometer_t[index] - odometer_t[before])

    def _travel_velocity(
        self, speed: float, level: Level, ctx: MeasurementContext
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The ENU velocity of a machine moving at ``speed`` along its travel axis, at the
        nominal attitude turned by ``level``'s tilt, and its covariance: the configured speed,
        lateral and vertical σ, the speed's also ``(3 σ_k s)²/3`` for the scale's prior."""
        c_m_n = Rotation.from_rotvec(level.attitude_error).as_matrix() @ ctx.c_b_n @ self.c_b_m.T
        options = self.options
        scale_variance = (3.0 * options.scale_sigma * speed) ** 2 / 3.0
        sigmas = [options.sigma_lateral_mps, options.sigma_speed_mps, options.sigma_vertical_mps]
        variances = np.square(sigmas) + np.array([0.0, scale_variance, 0.0])
        velocity = c_m_n @ np.array([0.0, speed, 0.0])
        return velocity, c_m_n @ np.diag(variances) @ c_m_n.T

    def _velocity(self, index: int, ctx: MeasurementContext) -> Measurement:
        """Residual of the SINS velocity in m against the odometer and the constraint."""
        self._index = index
        c_n_b = ctx.c_b_n.T
        c_n_m = self.c_b_m @ c_n_b
        measured = np.zeros(3)
        velocity = self._mean_velocity(index, ctx)
        if self.use_speed:
            scale_states = self._scale_states(ctx)
            measured[1] = self.speed[index]
            speed = self._reference_speed(index, ctx.x[scale_states], c_n_m[1])
            v_b = self.c_b_m.T @ np.array([0.0, speed, 0.0])
            column_velocity = ctx.c_b_n @ v_b  # attitude columns at the encoder's reference
        else:
            mean = self._column_window.mean_velocity(ctx)
            v_b = self._constrained_velocity(c_n_b @ mean, ctx)
            column_velocity = self._attitude_column_velocity(mean, ctx)
        z = c_n_m @ velocity - measured
        h = np.zeros((3, ctx.layout.dim))
        h[:, ctx.layout.slice(VELOCITY)] = c_n_m
        h[:, ctx.layout.slice(ATTITUDE)] = -c_n_m @ skew(column_velocity)
        h[:, ctx.layout.slice(f"{self.name}.mounting_angles")] = -self.c_b_m @ skew(v_b)
        if self.use_speed:
            h[1, scale_states] = -(self.c_b_m @ v_b)[1]
        if self._speed_state:
            h[1, ctx.layout.slice(f"{self.name}.speed")] = 1.0
        z, h = z[self.rows], h[self.rows]
        consider: tuple[int, ...] = ()
        if self.options.heading_untouched:
            consider = (
                ctx.layout.slice(ATTITUDE).start + 2,
                ctx.layout.slice(GYRO_BIAS).start + 2,
            )
        return Measurement(
            z,
            h,
            np.diag(self._noise(z, h, ctx)),
            consider=consider,
            velocity_at=column_velocity.copy(),
        )

    def _noise(
        self, z: NDArray[np.float64], h: NDArray[np.float64], ctx: MeasurementContext
    ) -> NDArray[np.float64]:
        """Each row's variance: the configured one, or learned from the last innovations.

        ``R = max(σ², median(ν² − H P Hᵀ) / 0.455)`` per row over the last ``adaptive_window``
        updates (0.455: the median of χ²₁, so that a slip's or a stop's few wild innovations
        neither inflate it). The configured σ is a floor: a quantized encoder (one count per
        reading is 0.03–0.3 m/s at 5 Hz), a machine whose vibration moves it sideways by
        centimetres per second, a track that is not where the constraint says: each gets the
        noise its innovations show, instead of a filter that believes 1 cm/s. The speed row
        also takes at least the encoder's own jitter (:func:`reading_jitter`), which its readings
        show from the start of the motion on — the innovations teach R only after a window of
        them, and a quantized encoder's first readings had set the scale 5 % off by then.
        The learned σ stops at ``adaptive_max_factor`` times the configured one: a SINS worse
        than its datasheet (a harsh world's IMU) drifted faster than its covariance said, the
        excess taught R a lateral σ of 1 m/s, the odometer then held nothing and the filter ran
        10 m off with every update accepted; beyond that ceiling the gate rejects and a lost
        lock inflates the SINS covariance instead (:mod:`fusion.lock`)."""
        if not self.options.adaptive_noise:
            return self.variance
        innovation = z - h @ ctx.x
        excess = innovation**2 - np.einsum("ij,jk,ik->i", h, ctx.covariance, h)
        self._excess.append(excess)
        variance = self.variance.copy()
        if self.use_speed:  # the encoder's own jitter, known from its first readings on
            variance[1] = max(variance[1], float(self.jitter[self._index]))
        if len(self._excess) < self.options.adaptive_window:
            return variance
        learned = np.median(np.array(self._excess), axis=0) / CHI2_1_MEDIAN
        ceiling = self.options.adaptive_max_factor**2 * self.variance
        return np.maximum(variance, np.minimum(learned, ceiling))

    @staticmethod
    def _constrained_velocity(
        v_b: NDArray[np.float64], ctx: MeasurementContext
    ) -> NDArray[np.float64]:
        """Body velocity at which the mounting columns are evaluated without an odometer: the
        SINS velocity, or zero while its speed is within 3σ of the velocity's own uncertainty.

        The columns ``−C_b^m (v^b×)`` are a derivative taken at the SINS velocity; with the
        constraint alone nothing observes the speed along the track, so during a standstill its
        σ grows with the accelerometer bias (0.7 m/s after 60 s on ``seed002-rectangle``). When
        the machine then moves, columns built from a velocity that is mostly error turned the
        lateral residual into a 65° mounting yaw and the filter diverged (NaN attitude; 1.8 km
        horizontal RMS in 240 s on another seed).
        """
        rows = ctx.layout.slice(VELOCITY)
        sigma = math.sqrt(float(np.trace(ctx.covariance[rows, rows])))
        if float(np.linalg.norm(v_b)) < 3.0 * sigma:
            return np.zeros(3)
        return v_b

    @staticmethod
    def _attitude_column_velocity(
        velocity: NDArray[np.float64], ctx: MeasurementContext
    ) -> NDArray[np.float64]:
        """Velocity of the attitude columns ``−C (v^n×)`` without an odometer: the SINS's mean
        velocity over the window (:class:`TravelWindow`), as far as it is known.

        The columns are the derivative at the *true* velocity, of which the SINS velocity is an
        estimate; where it is mostly its own error, the lateral row reads that error × the
        heading error and turns the constraint into a false heading fix. At the 60-s standstill
        of ``seed002-rectangle`` the SINS drifted 1–2 m/s along the track (sins_mc, 20 seeds:
        worst horizontal error 73.8 m over 718 s; 44.3 m with the columns zeroed below 1σ).

        With ``filter.observable_force`` (a slow machine) the velocity is shrunk by its own
        uncertainty, ``v |v|² / (|v|² + k² σ²)``, σ² its variance along v, ``k`` =
        :data:`fusion.error_model.KNOWN_SIGMAS`, as the specific force is: the zeroing below 1σ
        still let a MEMS SINS drifting from a random world's static start (the horizontal gyro
        biases tilting it) align its heading with its own drift — yaw σ 0.1° at an error of 80°,
        position RMS(err/σ) 74 and 112 on random worlds 6 and 0 (900 s, sins_mc); shrunk, 3.6
        and 6.4. Without it (a car, a foot) the columns are zeroed below 1σ only: a car's speed
        in a 60-s GNSS outage is known to a few σ, and shrunk by k = 10 its mean drift there
        grew from 23 to 35 m (``benchmarks real``).
        """
        rows = ctx.layout.slice(VELOCITY)
        speed_sq = float(velocity @ velocity)
        if speed_sq == 0.0:
            return velocity
        variance = float(velocity @ ctx.covariance[rows, rows] @ velocity) / speed_sq
        if ctx.observable_force:
            return velocity * (speed_sq / (speed_sq + KNOWN_SIGMAS**2 * variance))
        return velocity if speed_sq >= variance else np.zeros(3)

    def _mean_velocity(self, index: int, ctx: MeasurementContext) -> NDArray[np.float64]:
        """Mean nominal velocity over the reading's interval, from the travel at the previous
        reading; the velocity at the epoch when that reading was not measured or when rows are
        missing before this one (:func:`fusion.encoder.after_missing_readings`: the reading is
        the mean over its own interval, not over the gap, whose start the SINS travel does not
        hold)."""
        if not self.use_speed:
            return ctx.velocity
        travel = self.reference.travel  # the SINS travel at every reading measured so far
        travel[index] = ctx.travel
        if index == 0 or np.isnan(travel[index - 1, 0]) or self._after_gap[index]:
            return ctx.velocity
        t = self.recording.odometer.t  # type: ignore[union-attr]
        mean: NDArray[np.float64] = (ctx.travel - travel[index - 1]) / (t[index] - t[index - 1])
        return mean

    def _reference_speed(
        self, index: int, scale: NDArray[np.float64], along: NDArray[np.float64]
    ) -> float:
        """Vehicle speed of the parameter and attitude columns
        (:mod:`fusion.aiding.reference_speed`) with the scale estimates ``scale`` (δk_D and,
        with slip detection, s) and the travel axis ``along`` in n; zero while the machine
        stands (the previous reading ends ``rest_guard_s`` of still readings).

        Not zero after one still reading: a coarse encoder crawling between its counts reads
        zero in some intervals and one count in the next. With the columns zeroed after each
        zero, only the readings below the SINS speed moved δk_D, and every start and stop
        pushed it the same way (random full-length world 0, 72 counts/m: −0.7 → −2.9 % against
        a true +0.4 % across one stop, along-face error 0.5 → 2.4 m;
        ``test_a_coarse_encoder_keeps_its_scale``)."""
        if self.at_rest[max(index - 1, 0)]:
            return 0.0
        slip = float(scale[1]) if scale.size > 1 else 0.0
        return self.reference.at(index, float(scale[0]), slip, along)

    def state_jumped(self, state: str, onset: float, before: float) -> None:
        """A slip's onset or end: the reference window splits there."""
        self.reference.jumped(onset, before)

    def _scale_states(self, ctx: MeasurementContext) -> list[int]:
        """Indices of δk_D and, with slip detection, s in the filter's layout."""
        names = [f"{self.name}.scale_error"]
        if self.options.slip_detection:
            names.append(f"{self.name}.slip")
        return [ctx.layout.slice(n).start for n in names]
