"""Fusion configuration: typed pydantic models loaded from (and written back to) YAML.

A configuration names the IMU tuning (defaults: the datasheet figures in the recording's
``imu.spec``), the filter options, the aiding plugins (one YAML block per sensor with its own
options and rejection gate, robot_localization style), the outputs, and the limits of the
physical-plausibility screening of every stream (``screening:``, on by default; each default is
justified in its field's description; :mod:`fusion.screening`). Every model forbids
unknown keys, so a typo is an error that names its path (``filter.covariance_stp_s``) and the
nearest valid key.

An IMU's tuning shared by several configurations lives in its own YAML file, named by
``imu: {file: imu/NAME.yaml}`` (relative to the configuration's directory); keys given beside
``file`` override the file's.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from fusion.input_files import regular_file_problem
from fusion.validation import error_lines
from fusion.yaml_limits import YamlError, load_yaml


class ConfigError(ValueError):
    """A configuration file breaks a rule; the message names the file, key path and rule."""


class _Strict(BaseModel):
    """Unknown keys, non-finite numbers and out-of-range assignments are errors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=True)


def _within(
    default: Any,
    low: float,
    high: float,
    description: str,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> Any:
    """A numeric field allowed within ``[low, high]`` (an end is excluded when ``*_open``); the
    range is appended to ``description``, so the documentation states what validation
    enforces."""
    interval = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    return Field(
        default,
        gt=low if low_open else None,
        ge=None if low_open else low,
        lt=high if high_open else None,
        le=None if high_open else high,
        description=f"{description}; allowed {interval}",
    )


class ImuTuning(_Strict):
    """IMU noise figures in datasheet units; ``None`` takes the recording's ``imu.spec``, and
    where that lacks the figure too, :data:`fusion.engine.ASSUMED_IMU_SPEC` (with a warning)."""

    gyro_bias_deg_h: float | None = _within(
        None,
        0,
        1e5,
        "gyro bias 1σ (prior), deg/h; up to 28 °/s, above the turn-on bias of any gyro"
        " (consumer MEMS ≈ 1e4 deg/h)",
    )
    gyro_arw_deg_rth: float | None = _within(
        None, 0, 100, "angle random walk, deg/√h; up to 30× a consumer MEMS gyro's (0.3–3)"
    )
    accel_bias_mg: float | None = _within(
        None, 0, 1000, "accelerometer bias 1σ (prior), mg; no accelerometer is off by 1 g"
    )
    accel_vrw_mg_rthz: float | None = _within(
        None, 0, 100, "accelerometer noise density, mg/√Hz; up to 300× a MEMS part's (0.3)"
    )
    gyro_bias_instability_deg_h: float = _within(
        0.0, 0, 1e4, "gyro bias Gauss–Markov σ, deg/h; a consumer MEMS gyro's ≈ 10–100"
    )
    accel_bias_instability_mg: float = _within(
        0.0, 0, 100, "accelerometer bias Gauss–Markov σ, mg; a consumer MEMS part's ≈ 0.1–1"
    )
    bias_instability_fraction: float | None = _within(
        None,
        0,
        1,
        "in-run bias Gauss–Markov σ as a fraction of the turn-on bias (gyro and accelerometer"
        " alike), for an IMU known only by its turn-on figures; takes the place of"
        " gyro_bias_instability_deg_h and accel_bias_instability_mg",
    )
    bias_correlation_time_s: float = _within(
        3600.0,
        1,
        1e6,
        "bias correlation time τ, s; a faster 'bias' is white noise (the ARW/VRW's job), and"
        " beyond 11.6 days a Gauss–Markov bias is constant over any recording",
    )
    bias_model: Literal["gauss_markov", "random_walk"] = Field(
        "gauss_markov",
        description="in-run bias: Gauss–Markov decay of the bias state, or a random walk of the"
        " same density 2σ²/τ on top of the constant turn-on bias",
    )
    noise_at_rest: bool = Field(
        True,
        description="raise ARW and VRW to the white noise measured over the recording's first"
        " 20 s where the IMU is at rest there and its noise is white and over 1.5× its datasheet's"
        " (fusion.noise_at_rest); never lowers them, and leaves a figure set here alone",
    )
    bias_at_rest: bool = Field(
        True,
        description="raise the turn-on bias figures to the biases measured over the recording's"
        " first 20 s where the IMU is at rest there and its datasheet's do not cover them at"
        " 99.9 % (fusion.bias_at_rest); never lowers them, and leaves a figure set here alone",
    )
    noise_scale: float = _within(
        1.0,
        0.01,
        100,
        "multiplies ARW and VRW (seed 000 App. A inflates by 5); two decades either way of the"
        " datasheet",
    )

    @model_validator(mode="after")
    def _one_instability(self) -> ImuTuning:
        absolute = self.gyro_bias_instability_deg_h > 0 or self.accel_bias_instability_mg > 0
        if self.bias_instability_fraction is not None and absolute:
            raise ValueError(
                "imu.bias_instability_fraction replaces imu.gyro_bias_instability_deg_h and"
                " imu.accel_bias_instability_mg: give the fraction or the figures, not both"
            )
        return self


class FaultDetectionOptions(_Strict):
    """Fault detection and isolation of the federated master's local filters."""

    enabled: bool = True
    window_s: float = _within(
        5.0,
        0.1,
        600,
        "sliding window of the χ² test, s; it needs a few updates (0.1 s at 10–100 Hz) and a"
        " fault found after 10 min is found too late",
    )
    probability: float = _within(
        0.9999,
        0,
        1,
        "χ² quantile (≈ 1 false isolation per hour at 10 Hz), a probability",
        low_open=True,
        high_open=True,
    )
    hold_s: float = _within(
        10.0, 0, 3600, "consistent this long before re-admission, s; at most an hour"
    )
    threshold_scale: float = _within(
        1.5,
        1,
        100,
        "isolate only when the window's NIS sum exceeds this multiple of the χ² quantile: a"
        " fault is gross; mild model mismatch over hundreds of degrees of freedom is not (100×"
        " would let any fault through)",
    )
    use_indicators: bool = Field(
        True, description="a plugin's indicator, flagging for indicator_confirm_s, isolates"
    )
    indicator_confirm_s: float = _within(
        2.0,
        0,
        3600,
        "a plugin's indicator must flag this long (s) without a break before it isolates the"
        " local (a flagged epoch is down-weighted by its plugin meanwhile); at most an hour",
    )
    mean_test: bool = Field(
        True, description="also test each plugin's windowed mean whitened innovation (a bias)"
    )
    mean_probability: float = _within(
        0.99999,
        0,
        1,
        "χ² quantile of the mean test (run at every update: its false alarms scale with the"
        " update rate), a probability",
        low_open=True,
        high_open=True,
    )


class JumpDetectionOptions(_Strict):
    """GLR detection of jumps in the states plugins declare may jump (:mod:`fusion.jumps`)."""

    window_s: float = _within(
        5.0,
        0.1,
        600,
        "a hypothesis is kept this long after onset, s; a few updates at least, and a jump"
        " older than 10 min is history",
    )
    spacing_s: float = _within(
        0.5,
        0.05,
        3600,
        "a hypothesis opens this often, s; window_s / spacing_s hypotheses are tested at every"
        " update, so a finer spacing than 0.05 s multiplies the cost without finding an onset"
        " better than the updates' own spacing; one longer than window_s keeps one hypothesis"
        " at a time",
    )
    probability: float = _within(
        0.999999,
        0,
        1,
        "χ²_1 quantile of the likelihood ratio (several hypotheses are tested at every update),"
        " a probability",
        low_open=True,
        high_open=True,
    )
    return_probability: float = _within(
        0.999,
        0,
        1,
        "χ²_1 quantile η of the return test (a state held away from its rest value jumping"
        " back there, a jump of known size); a test's false alarm is at most Q(√η), a"
        " probability",
        low_open=True,
        high_open=True,
    )
    min_updates: int = _within(
        5,
        1,
        1e8,
        "no decision before this many updates; 1e8 is more than an 8-hour shift's at 1 kHz"
        " (never decide)",
    )


class FederatedOptions(_Strict):
    """The federated master (seed 003 §4): sharing, reset mode, fusion period, fault isolation."""

    mode: Literal["fusion_reset", "no_reset"] = "fusion_reset"
    sharing: Literal["equal", "trace", "inverse_trace"] = Field(
        "trace", description="β_i: equal, ∝ tr(P_i) (seed 003 eq. 33), or ∝ 1/tr(P_i)"
    )
    master_share: float = _within(
        0.0, 0, 1, "β_m, the master's own share of the information", high_open=True
    )
    fusion_period_s: float | None = _within(
        None,
        0,
        3600,
        "fusion period, s; None: every covariance step that carried an update (the CKF's"
        " feedback; fusing after a step without one changes nothing); a period shorter than"
        " the covariance step fuses at every step, and one over an hour leaves the locals"
        " unfused for a whole face",
        low_open=True,
    )
    fault_detection: FaultDetectionOptions = FaultDetectionOptions()

    @model_validator(mode="after")
    def _shares_need_resets(self) -> FederatedOptions:
        if self.mode == "no_reset" and self.sharing != "equal":
            raise ValueError(
                f"sharing {self.sharing!r} needs mode fusion_reset: a share is handed out by the"
                " reset, and without resets a local's covariance stays built on its first share;"
                " use sharing: equal with mode: no_reset"
            )
        return self


_Angle = Annotated[float, Field(ge=-180, le=180)]
_GyroBias = Annotated[float, Field(ge=-1e5, le=1e5)]


class DeadReckoningOptions(_Strict):
    """Seed 000's traditional method: odometer speed along the free SINS attitude, open loop."""

    mounting_deg: tuple[_Angle, _Angle, _Angle] = Field(
        (0.0, 0.0, 0.0),
        description="odometer-frame mounting (roll, pitch, yaw) relative to b, deg; each in"
        " [-180, 180]",
    )
    scale_error: float = _within(
        0.0,
        -1,
        1,
        "odometer scale error δk_D removed; ±100 % is no odometer at all",
        low_open=True,
        high_open=True,
    )
    gyro_bias_deg_h: tuple[_GyroBias, _GyroBias, _GyroBias] = Field(
        (0.0, 0.0, 0.0),
        description="gyro bias removed before the mechanization, deg/h; each in [-1e5, 1e5]"
        " (28 °/s, above any gyro's turn-on bias)",
    )
    scale_sigma: float = _within(0.03, 0, 1, "σ of δk_D for the error envelope; up to 100 %")
    speed_sigma_mps: float = _within(
        0.01, 0, 10, "odometer speed noise for the envelope, m/s; above any machine's speed"
    )


class FilterOptions(_Strict):
    """Options of the error-state filter (or of the filter-free dead reckoning)."""

    architecture: Literal["centralized", "federated", "dead_reckoning", "standalone"] = (
        "centralized"
    )
    federated: FederatedOptions = FederatedOptions()
    jump_detection: JumpDetectionOptions = JumpDetectionOptions()
    dead_reckoning: DeadReckoningOptions = DeadReckoningOptions()
    covariance_step_s: float = _within(
        0.1,
        0.001,
        10,
        "covariance propagation step, s; a step shorter than a 1-kHz IMU's sample interval"
        " adds nothing (F is constant across an interval) and multiplies the run time, and the"
        " series Φ = I + FΔt + … stays accurate for steps far below the 84-min Schuler period",
    )
    specific_force_time_constant_s: float = _within(
        0.0,
        0,
        60,
        "low-pass of the specific force in F against vibration, s (0: step mean;"
        " fusion.error_model.SpecificForceFilter); a minute smooths away real manoeuvres",
    )
    lock_window_s: float = _within(
        3.0,
        0.1,
        600,
        "a gated plugin whose every update over this window (s) was rejected has lost lock:"
        " the filter is re-initialized from it alone where it can (fusion.lock)",
    )
    lock_min_updates: int = _within(
        10, 1, 10000, "updates the lock window must hold before a lost lock counts"
    )
    observable_force: bool = Field(
        True,
        description="shrink the horizontal specific force in F by its own uncertainty, so that a"
        " force within its error does not observe the heading (fusion.error_model."
        "observable_force): for a slow machine; off for a car, a foot or a hand, whose"
        " accelerations are real (with it a foot's ZUPT-aided track was 4× worse)",
    )
    invariant_error: Literal["none", "heading", "full"] = Field(
        "none",
        description="keep the covariance in the right-invariant error (fusion.invariant_error)"
        " of the heading alone or of the whole attitude: a turn of the whole trajectory is then"
        " one fixed direction, the specific force drops out of its dynamics, and a source that"
        " cannot see the heading finds no heading column; the plugins' rows, the feedback and"
        " the outputs stay in the standard error. heading in the odometer-only configurations"
        " (sins_od_ckf, sins_od_cpoem*), where nothing sees the heading, and in sins_uwb,"
        " where only the track between the face ends does",
    )
    reported_covariance: Literal["filter", "invariant_analysis"] = Field(
        "filter",
        description="the covariance the outputs, the state history and the observability report"
        " give: the filter's own, or the actual error covariance of its estimate, the filter's"
        " gains analysed in the right-invariant error of the heading, in which a source that"
        " cannot see a turn does not inform the heading (fusion.covariance_analysis). The"
        " estimate is the same. For a centralized filter without a smoother where nothing sees"
        " the heading (sins_mc, sins_mc_zupt)",
    )
    discretization: Literal["series", "van_loan"] = "series"
    error_model: Literal["full", "low_speed"] = "full"
    coning_sculling: bool = True
    initial_sigma_scale: float = _within(
        1.0,
        0.001,
        1000,
        "multiplies meta.yaml's initial sigmas; three decades either way (a 5-cm σ becomes"
        " 50 m): beyond, the prior is meaningless and its variance swamps double precision",
    )

    @model_validator(mode="before")
    @classmethod
    def _replaced_keys(cls, data: Any) -> Any:
        if isinstance(data, dict) and "observability_constrained" in data:
            raise ValueError(
                "filter.observability_constrained was replaced by filter.invariant_error:"
                " heading, which keeps the same turn of the trajectory unobserved in the"
                " error's coordinates instead of projecting it out of Φ and H"
            )
        return data


class PluginBlock(BaseModel):
    """One aiding source: its registered ``type``, an optional instance ``name``, a χ² gate,
    and the plugin's own options (validated by the plugin's options model)."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False, validate_assignment=True)

    type: str
    name: str | None = None
    enabled: bool = True
    required: bool = Field(
        False,
        description="a recording without this plugin's stream (its file or meta.yaml section)"
        " is an error; false: the run goes on without the plugin, with a warning, and says so"
        " in run.json, the summary and metrics.json",
    )
    gate_probability: float | None = _within(
        None,
        0,
        1,
        "reject updates whose NIS exceeds this χ² quantile, a probability (None: no gate)",
        low_open=True,
        high_open=True,
    )
    max_rate_hz: float | None = _within(
        None,
        0.001,
        10000,
        "use at most this many epochs per second (None: every one); no aiding sensor runs"
        " faster than 10 kHz",
    )
    local: str | None = Field(
        None, description="federated: the local filter this plugin joins (default: its name)"
    )

    @property
    def options(self) -> dict[str, Any]:
        """The plugin-specific keys."""
        return dict(self.model_extra or {})

    @property
    def instance_name(self) -> str:
        """``name`` or, by default, ``type``."""
        return self.name or self.type

    @property
    def local_name(self) -> str:
        """The federated local filter of this plugin: ``local`` or its instance name."""
        return self.local or self.instance_name


class SmootherOptions(_Strict):
    """RTS smoothing (seed 000 §3.4): off, over the whole recording, or online at face ends."""

    mode: Literal["off", "whole", "online"] = "off"
    memory_budget_mb: float = _within(
        256.0,
        0,
        1e6,
        "stored output rows beyond this (MB) spill to a temporary directory; up to 1 TB",
    )
    significance_sigma: float = _within(
        1.0,
        0,
        10,
        "a window's smoothed horizontal track (and, on its own, its height) replaces the forward"
        " one only when the gain in squared position error the smoother expects exceeds this"
        " many of its standard deviations, by the smoother's own covariance"
        " (fusion.smoother.SmoothingGain); below it the two tracks are a coin toss and the"
        " forward one is kept. 0 smooths every window",
    )


class ImuScreening(_Strict):
    """Physical-plausibility limits of the IMU samples (:mod:`fusion.screening`).

    The range limits are the sensor's measurement range, or lower: the platform's own largest
    rates. The step limits bound the change between a sample and the last accepted one,
    ``|x_k − x_ref| ≤ floor + rate·(t_k − t_ref)`` per axis.
    """

    max_angular_rate_rad_s: float = _within(
        35.0,
        0,
        1000,
        "largest |ω| per axis: the widest gyro range of MTi-class MEMS IMUs (MTi-1/"
        "-600 series ±2000 °/s = 34.9 rad/s); the real data reach 12.7 (hand-held BROAD) and"
        " 9.7 rad/s (foot-mounted PyShoe), a shearer < 1 rad/s. A platform may set it lower; up"
        " to 1000 rad/s, above any gyro's range (±20000 °/s = 349 rad/s)",
        low_open=True,
    )
    max_specific_force_mps2: float = _within(
        160.0,
        0,
        10000,
        "largest |f| per axis: the MTi-1/-600 series' ±16 g (156.9 m/s²); foot-"
        "mounted PyShoe heel strikes reach 78 m/s², a shearer ≈ 11 m/s²; up to 1000 g, the range"
        " of shock-rated accelerometers",
        low_open=True,
    )
    max_angular_acceleration_rad_s2: float = _within(
        1.0e4,
        0,
        1e7,
        "largest |Δω|/Δt between a sample and the last accepted one: ≈ 6× the"
        " steepest step in the real data (a heel strike, 8.7 rad/s between two 200-Hz"
        " samples = 1760 rad/s²); a shearer's vibration stays below 20 rad/s²; up to 1000× the"
        " default",
        low_open=True,
    )
    max_jerk_mps3: float = _within(
        1.0e5,
        0,
        1e8,
        "largest |Δf|/Δt between a sample and the last accepted one: ≈ 4.5× the"
        " steepest step in the real data (a heel strike, 112 m/s² in 5 ms = 22000 m/s³); a"
        " shearer's cutting vibration stays near 100 m/s³; up to 1000× the default",
        low_open=True,
    )
    angular_rate_step_floor_rad_s: float = _within(
        0.1,
        0,
        1000,
        "step always allowed in ω (noise and vibration of one sample; 0.1 rad/s is"
        " > 50σ of an MTi's 100-Hz gyro noise); up to the largest range limit",
    )
    specific_force_step_floor_mps2: float = _within(
        1.0,
        0,
        10000,
        "step always allowed in f (one sample's noise and vibration; a shearer's"
        " cutting vibration is ≈ 0.3 m/s² per sample); up to the largest range limit",
    )
    recovery_samples: int = _within(
        5,
        1,
        1000,
        "after this many consecutive samples rejected by a step limit the next one"
        " is accepted as the new reference, so a real step never locks the screen out; up to 1000",
    )


class OdometerScreening(_Strict):
    """Physical-plausibility limits of the odometer speed (:mod:`fusion.screening`)."""

    max_speed_mps: float = _within(
        5.0,
        0,
        1000,
        "largest |speed|: 18 km/h, above the fastest machine of the simulated"
        " scenarios (70 m/min ≈ 1.2 m/s), 7× a shearer's haulage (≤ 30–40 m/min) and at the"
        " usual underground limit of rubber-tyred vehicles; a faster vehicle sets its own; up to"
        " 1000 m/s, faster than any vehicle that carries an IMU on the ground",
        low_open=True,
    )
    max_acceleration_mps2: float = _within(
        10.0,
        0,
        1000,
        "largest |Δspeed|/Δt between a reading and the last accepted one: ≈ 1 g,"
        " the tyre-friction limit of any wheeled vehicle (a shearer ramps at 0.02 m/s²); up to"
        " 100 g",
        low_open=True,
    )
    speed_step_floor_mps: float = _within(
        5.0,
        0,
        1000,
        "speed step always allowed: an encoder's count steps a reading by"
        " 1 / (counts per metre × interval), 1 m/s for 50 counts/m at 50 Hz, and its carried"
        " remainder makes the readings alternate between count levels; a rejected one would"
        " lose its travel (0.05 m/s rejected 5–10 % of a quantized encoder's readings); up to the"
        " largest speed limit",
    )
    recovery_samples: int = _within(
        3,
        1,
        1000,
        "after this many consecutive readings rejected by the acceleration limit"
        " the next one is accepted as the new reference; up to 1000",
    )


class MagnetometerScreening(_Strict):
    """Plausible band of the magnetic field norm (:mod:`fusion.screening`). Interference inside
    the band is the magnetometer plugin's indicator's business."""

    min_field_uT: float = _within(
        5.0,
        0,
        10000,
        "smallest |B|: the earth's field is 22–67 µT everywhere; steel around a"
        " sensor distorts it but does not cancel it (an all-zero reading is a dead sensor); up to"
        " 10 mT, far above any magnetometer's range",
    )
    max_field_uT: float = _within(
        1000.0,
        0,
        10000,
        "largest |B|: above the ±800 µT range of MTi-class magnetometers (the"
        " BROAD trials with a magnet 1 cm from the sensor reach 86 µT); up to 10 mT, far above"
        " any magnetometer's range",
        low_open=True,
    )

    @model_validator(mode="after")
    def _band(self) -> MagnetometerScreening:
        if not self.min_field_uT < self.max_field_uT:
            raise ValueError("min_field_uT must be smaller than max_field_uT")
        return self


class UwbScreening(_Strict):
    """Plausible UWB ranges (:mod:`fusion.screening`); negative ones the reader refuses."""

    max_range_m: float = _within(
        300.0,
        0,
        10000,
        "largest range: the reach of DW1000-class UWB at its lowest data rate in"
        " line of sight (≈ 290 m); the simulated face's anchors answer within 40 m; up to 10 km,"
        " 30× any UWB's reach",
        low_open=True,
    )


class PositionScreening(_Strict):
    """Plausibility of position fixes (:mod:`fusion.screening`)."""

    min_sigma_m: float = _within(
        1.0e-5,
        0,
        1000,
        "smallest σ per axis: 10 µm, a laser tracker's accuracy (no instrument"
        " positions better; a smaller σ would pin the filter to the fix); up to 1 km",
        low_open=True,
    )
    max_sigma_m: float = _within(
        1000.0,
        0,
        1e6,
        "largest σ per axis: a fix this vague says nothing at a site's scale, and"
        " huge values overflow the variance σ²; up to 1000 km (its variance stays far inside"
        " double precision)",
        low_open=True,
    )
    max_distance_from_origin_m: float = _within(
        1.0e5,
        0,
        1e7,
        "largest distance of a fix from the recording's origin: 100 km, beyond"
        " any site that one local ENU frame describes; up to 10000 km, the Earth's quarter"
        " circumference",
        low_open=True,
    )
    max_speed_mps: float = _within(
        100.0,
        0,
        1000,
        "largest speed between a fix and the last accepted one: 360 km/h, above"
        " any ground vehicle (the real car drive reaches 16 m/s); up to 1000 m/s, faster than any"
        " vehicle that carries an IMU on the ground",
        low_open=True,
    )
    sigma_multiple: float = _within(
        5.0,
        0,
        100,
        "the jump between two fixes may also exceed max_speed_mps·Δt by this many"
        " σ of the two fixes combined; up to 100σ",
        low_open=True,
    )
    recovery_samples: int = _within(
        3,
        1,
        1000,
        "after this many consecutive fixes rejected by the speed limit the next"
        " one is accepted as the new reference; up to 1000",
    )

    @model_validator(mode="after")
    def _band(self) -> PositionScreening:
        if not self.min_sigma_m < self.max_sigma_m:
            raise ValueError("min_sigma_m must be smaller than max_sigma_m")
        return self


class SupportScreening(_Strict):
    """Plausible AFC pushes (:mod:`fusion.screening`)."""

    max_advance_m: float = _within(
        2.0,
        0,
        10,
        "largest push: a web is at most 1.2 m deep (the simulated carrier pushes"
        " 1.19 m) and push rams have no longer stroke; a push is never negative; up to 10 m, 8×"
        " the deepest web",
        low_open=True,
    )


class ScreeningOptions(_Strict):
    """Physical-plausibility screening of every stream before the plugins read it
    (:mod:`fusion.screening`); the counts of rejected samples are reported per stream."""

    enabled: bool = Field(True, description="screen the streams (false: use every reading)")
    imu: ImuScreening = ImuScreening()
    odometer: OdometerScreening = OdometerScreening()
    magnetometer: MagnetometerScreening = MagnetometerScreening()
    uwb: UwbScreening = UwbScreening()
    position: PositionScreening = PositionScreening()
    support: SupportScreening = SupportScreening()


class StreamOptions(_Strict):
    """How streams are read before any plugin sees them."""

    odometer_max_rate_hz: float | None = _within(
        5.0,
        0.01,
        10000,
        "odometer readings are combined by their exact travel into intervals of at least 1/rate"
        " (fusion.encoder: an encoder's count quantization averages out, while a slip is still"
        " seen within a second or two); None: as recorded",
    )


class OutputOptions(_Strict):
    """What ``fusion run`` writes."""

    rate_hz: float | None = _within(
        None,
        0.01,
        1000,
        "output epochs per second; None: every covariance step. Above 1 kHz, faster than any"
        " IMU, rows would repeat; below 0.01 Hz (one row per 100 s) a shearer's pass along a"
        " face is not seen",
    )
    plots: bool = True
    states: bool = Field(
        True,
        description="record every estimated state and its 1-sigma at the output epochs"
        " (RunResult.states) and write states.csv",
    )


class FusionConfig(_Strict):
    """A whole sensor combination."""

    name: str
    description: str = ""
    imu: ImuTuning = ImuTuning()
    filter: FilterOptions = FilterOptions()
    plugins: list[PluginBlock] = []
    smoother: SmootherOptions = SmootherOptions()
    output: OutputOptions = OutputOptions()
    screening: ScreeningOptions = ScreeningOptions()
    streams: StreamOptions = StreamOptions()
    bridge_imu_gaps: bool = Field(False, description="accept IMU gaps > 5 samples, reported")

    @model_validator(mode="after")
    def _unique_names(self) -> FusionConfig:
        names = [p.instance_name for p in self.plugins]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"plugin names must be unique; repeated: {dupes}")
        if self.filter.architecture == "dead_reckoning" and self.plugins:
            raise ValueError(
                "filter.architecture dead_reckoning uses no plugins (it reads odometer.csv"
                " itself; its options are filter.dead_reckoning): remove the plugins list"
            )
        if self.filter.architecture == "standalone" and sum(p.enabled for p in self.plugins) != 1:
            raise ValueError(
                "filter.architecture standalone solves from one sensor alone: enable exactly"
                " one plugin (e.g. uwb for the UWB-only least-squares baseline)"
            )
        if self.filter.architecture == "federated" and not any(p.enabled for p in self.plugins):
            raise ValueError("filter.architecture federated needs at least one enabled plugin")
        return self

    @model_validator(mode="after")
    def _analysable(self) -> FusionConfig:
        options = self.filter
        if options.reported_covariance != "invariant_analysis":
            return self
        if options.architecture != "centralized":
            raise ValueError(
                "filter.reported_covariance invariant_analysis follows the gains of one"
                " centralized filter: set filter.architecture centralized"
            )
        if options.invariant_error != "none":
            raise ValueError(
                "filter.reported_covariance invariant_analysis analyses the standard error's"
                " gains in the invariant error: set filter.invariant_error none"
            )
        if self.smoother.mode != "off":
            raise ValueError(
                "filter.reported_covariance invariant_analysis has no smoothed counterpart: set"
                " smoother.mode off"
            )
        return self

    def to_yaml(self) -> str:
        """YAML text that :func:`load_config` reads back to an equal model."""
        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False)


def parse_config(data: Any, source: str = "<config>") -> FusionConfig:
    """Validate a mapping as a :class:`FusionConfig`; raise :class:`ConfigError`."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: the top level must be a mapping of keys")
    try:
        return FusionConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError("\n".join(error_lines(source, FusionConfig, exc))) from None


def _packaged_configs() -> Path:
    installed = Path(__file__).resolve().parent / "configs"
    return installed if installed.is_dir() else Path(__file__).resolve().parents[1] / "configs"


PACKAGED_CONFIGS = _packaged_configs()
"""The configurations shipped with this copy of fusion: ``fusion/configs/`` in an installed wheel
(pyproject.toml maps the repository's ``configs/`` there), the repository's ``configs/`` in a
clone or an editable install."""


def find_config(name_or_path: str | Path) -> Path:
    """The configuration file that ``name_or_path`` names, from any working directory.

    In order: the path as given, when it exists; else ``configs/NAME.yaml`` under the working
    directory; else ``NAME.yaml`` among :data:`PACKAGED_CONFIGS`. NAME is the argument with or
    without ``.yaml``, and ``configs/NAME.yaml`` counts as NAME too, so a clone's command line
    (``fusion run --config configs/sins_only.yaml``) works anywhere fusion is installed. Any
    other path, or a name found nowhere, is returned as given: reading it then fails with one
    line naming it (:func:`load_config`).
    """
    path = Path(name_or_path)
    if path.exists() or path.is_absolute() or path.parent not in (Path("."), Path("configs")):
        return path
    name = path.name.removesuffix(".yaml")
    for directory in (Path("configs"), PACKAGED_CONFIGS):
        candidate = directory / f"{name}.yaml"
        if candidate.is_file():
            return candidate
    return path


def load_config(path: str | Path) -> FusionConfig:
    """Read and validate a YAML configuration file."""
    return parse_config(load_config_data(path), str(path))


def load_config_data(path: str | Path) -> Any:
    """A configuration file's YAML before validation, with its ``imu.file`` read in (for
    callers that edit the mapping, e.g. with overrides, before :func:`parse_config`)."""
    path = Path(path)
    data = _read_yaml(path)
    if isinstance(data, dict) and isinstance(data.get("imu"), dict) and "file" in data["imu"]:
        data["imu"] = _imu_from_file(data["imu"], path)
    return data


def _read_yaml(path: Path) -> Any:
    """A configuration file's YAML, read by the limited loader (:mod:`fusion.yaml_limits`:
    UTF-8, no duplicate key, bounded nesting and aliases); only a regular file is opened."""
    kind = regular_file_problem(path) if os.path.lexists(path) else None
    if kind is not None:
        raise ConfigError(f"{path}: cannot read the configuration ({kind})")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the configuration ({exc.strerror})") from None
    try:
        return load_yaml(raw).data
    except YamlError as exc:
        where = f", line {exc.line}" if exc.line is not None else ""
        raise ConfigError(f"{path}{where}: {exc.rule}") from None


def _imu_from_file(block: dict[str, Any], config: Path) -> dict[str, Any]:
    """The ``imu`` block with its ``file`` (relative to ``config``'s directory) read in; the
    block's other keys override the file's."""
    rest = dict(block)
    name = rest.pop("file")
    if not isinstance(name, str):
        raise ConfigError(f"{config}: config key imu.file must be a path to a YAML file")
    shared = _read_yaml(config.parent / name)
    if not isinstance(shared, dict) or "file" in shared:
        raise ConfigError(
            f"{config}: imu.file {name!r} must hold a mapping of imu keys (and no file key)"
        )
    return {**shared, **rest}
