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

from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from fusion.validation import error_lines


class ConfigError(ValueError):
    """A configuration file breaks a rule; the message names the file, key path and rule."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ImuTuning(_Strict):
    """IMU noise figures in datasheet units; ``None`` takes the recording's ``imu.spec``."""

    gyro_bias_deg_h: float | None = Field(None, ge=0, description="bias 1σ (prior)")
    gyro_arw_deg_rth: float | None = Field(None, ge=0, description="angle random walk")
    accel_bias_mg: float | None = Field(None, ge=0, description="bias 1σ (prior)")
    accel_vrw_mg_rthz: float | None = Field(None, ge=0, description="noise density")
    gyro_bias_instability_deg_h: float = Field(0.0, ge=0, description="Gauss–Markov σ")
    accel_bias_instability_mg: float = Field(0.0, ge=0, description="Gauss–Markov σ")
    bias_correlation_time_s: float = Field(3600.0, gt=0)
    bias_model: Literal["gauss_markov", "random_walk"] = Field(
        "gauss_markov",
        description="in-run bias: Gauss–Markov decay of the bias state, or a random walk of the"
        " same density 2σ²/τ on top of the constant turn-on bias",
    )
    noise_scale: float = Field(
        1.0, gt=0, description="multiplies ARW and VRW (seed 000 App. A inflates by 5)"
    )


class FaultDetectionOptions(_Strict):
    """Fault detection and isolation of the federated master's local filters."""

    enabled: bool = True
    window_s: float = Field(5.0, gt=0, description="sliding window of the χ² test")
    probability: float = Field(
        0.9999, gt=0, lt=1, description="χ² quantile (≈ 1 false isolation per hour at 10 Hz)"
    )
    hold_s: float = Field(10.0, ge=0, description="consistent this long before re-admission")
    threshold_scale: float = Field(
        1.5,
        ge=1,
        description="isolate only when the window's NIS sum exceeds this multiple of the χ²"
        " quantile: a fault is gross; mild model mismatch over hundreds of degrees of freedom"
        " is not",
    )
    use_indicators: bool = Field(
        True, description="a plugin's indicator, flagging for indicator_confirm_s, isolates"
    )
    indicator_confirm_s: float = Field(
        2.0,
        ge=0,
        description="a plugin's indicator must flag this long without a break before it isolates"
        " the local (a flagged epoch is down-weighted by its plugin meanwhile)",
    )
    mean_test: bool = Field(
        True, description="also test each plugin's windowed mean whitened innovation (a bias)"
    )
    mean_probability: float = Field(
        0.99999,
        gt=0,
        lt=1,
        description="χ² quantile of the mean test (run at every update: its false alarms scale"
        " with the update rate)",
    )


class JumpDetectionOptions(_Strict):
    """GLR detection of jumps in the states plugins declare may jump (:mod:`fusion.jumps`)."""

    window_s: float = Field(5.0, gt=0, description="a hypothesis is kept this long after onset")
    spacing_s: float = Field(0.5, gt=0, description="a hypothesis opens this often")
    probability: float = Field(
        0.999999,
        gt=0,
        lt=1,
        description="χ²_1 quantile of the likelihood ratio (several hypotheses are tested at"
        " every update)",
    )
    min_updates: int = Field(5, ge=1, description="no decision before this many updates")


class FederatedOptions(_Strict):
    """The federated master (seed 003 §4): sharing, reset mode, fusion period, fault isolation."""

    mode: Literal["fusion_reset", "no_reset"] = "fusion_reset"
    sharing: Literal["equal", "trace", "inverse_trace"] = Field(
        "trace", description="β_i: equal, ∝ tr(P_i) (seed 003 eq. 33), or ∝ 1/tr(P_i)"
    )
    master_share: float = Field(0.0, ge=0, lt=1, description="β_m (the master's own share)")
    fusion_period_s: float | None = Field(
        None,
        gt=0,
        description="None: every covariance step that carried an update (the CKF's feedback;"
        " fusing after a step without one changes nothing)",
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


class DeadReckoningOptions(_Strict):
    """Seed 000's traditional method: odometer speed along the free SINS attitude, open loop."""

    mounting_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="odometer-frame mounting (roll, pitch, yaw) relative to b"
    )
    scale_error: float = Field(0.0, gt=-1, description="odometer scale error δk_D removed")
    gyro_bias_deg_h: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="gyro bias removed before the mechanization"
    )
    scale_sigma: float = Field(0.03, ge=0, description="σ of δk_D for the error envelope")
    speed_sigma_mps: float = Field(0.01, ge=0, description="odometer speed noise, envelope")


class FilterOptions(_Strict):
    """Options of the error-state filter (or of the filter-free dead reckoning)."""

    architecture: Literal["centralized", "federated", "dead_reckoning", "standalone"] = (
        "centralized"
    )
    federated: FederatedOptions = FederatedOptions()
    jump_detection: JumpDetectionOptions = JumpDetectionOptions()
    dead_reckoning: DeadReckoningOptions = DeadReckoningOptions()
    covariance_step_s: float = Field(0.1, gt=0, description="covariance propagation step")
    specific_force_time_constant_s: float = Field(
        0.0,
        ge=0,
        description="low-pass of the specific force in F against vibration (0: step mean;"
        " fusion.error_model.SpecificForceFilter)",
    )
    lock_window_s: float = Field(
        3.0,
        gt=0,
        description="a gated plugin whose every update over this window was rejected has lost"
        " lock: the filter is re-initialized from it alone where it can (fusion.lock)",
    )
    lock_min_updates: int = Field(
        10, ge=1, description="updates the lock window must hold before a lost lock counts"
    )
    observable_force: bool = Field(
        True,
        description="shrink the horizontal specific force in F by its own uncertainty, so that a"
        " force within its error does not observe the heading (fusion.error_model."
        "observable_force): for a slow machine; off for a car, a foot or a hand, whose"
        " accelerations are real (with it a foot's ZUPT-aided track was 4× worse)",
    )
    observability_constrained: bool = Field(
        False,
        description="keep a turn of the whole trajectory about the vertical unobservable to the"
        " sources that cannot see one (ZUPT, ZARU, odometer, motion constraint): the heading"
        " column of Φ and of their H is constrained (fusion.yaw_nullspace); for MEMS IMUs, which"
        " cannot find north from the Earth's rate. Off in every shipped config: with a motion"
        " constraint it was far worse (docs/design/2026-11-27-observability.md)",
    )
    discretization: Literal["series", "van_loan"] = "series"
    error_model: Literal["full", "low_speed"] = "full"
    coning_sculling: bool = True
    initial_sigma_scale: float = Field(1.0, gt=0, description="multiplies meta.yaml sigmas")


class PluginBlock(BaseModel):
    """One aiding source: its registered ``type``, an optional instance ``name``, a χ² gate,
    and the plugin's own options (validated by the plugin's options model)."""

    model_config = ConfigDict(extra="allow")

    type: str
    name: str | None = None
    enabled: bool = True
    gate_probability: float | None = Field(
        None, gt=0, lt=1, description="reject updates whose NIS exceeds this χ² quantile"
    )
    max_rate_hz: float | None = Field(
        None, gt=0, description="use at most this many epochs per second (None: every one)"
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
    memory_budget_mb: float = Field(
        256.0, ge=0, description="stored output rows beyond this spill to a temporary directory"
    )


class ImuScreening(_Strict):
    """Physical-plausibility limits of the IMU samples (:mod:`fusion.screening`).

    The range limits are the sensor's measurement range, or lower: the platform's own largest
    rates. The step limits bound the change between a sample and the last accepted one,
    ``|x_k − x_ref| ≤ floor + rate·(t_k − t_ref)`` per axis.
    """

    max_angular_rate_rad_s: float = Field(
        35.0,
        gt=0,
        description="largest |ω| per axis: the widest gyro range of MTi-class MEMS IMUs (MTi-1/"
        "-600 series ±2000 °/s = 34.9 rad/s); the real data reach 12.7 (hand-held BROAD) and"
        " 9.7 rad/s (foot-mounted PyShoe), a shearer < 1 rad/s. A platform may set it lower",
    )
    max_specific_force_mps2: float = Field(
        160.0,
        gt=0,
        description="largest |f| per axis: the MTi-1/-600 series' ±16 g (156.9 m/s²); foot-"
        "mounted PyShoe heel strikes reach 78 m/s², a shearer ≈ 11 m/s²",
    )
    max_angular_acceleration_rad_s2: float = Field(
        1.0e4,
        gt=0,
        description="largest |Δω|/Δt between a sample and the last accepted one: ≈ 6× the"
        " steepest step in the real data (a heel strike, 8.7 rad/s between two 200-Hz"
        " samples = 1760 rad/s²); a shearer's vibration stays below 20 rad/s²",
    )
    max_jerk_mps3: float = Field(
        1.0e5,
        gt=0,
        description="largest |Δf|/Δt between a sample and the last accepted one: ≈ 4.5× the"
        " steepest step in the real data (a heel strike, 112 m/s² in 5 ms = 22000 m/s³); a"
        " shearer's cutting vibration stays near 100 m/s³",
    )
    angular_rate_step_floor_rad_s: float = Field(
        0.1,
        ge=0,
        description="step always allowed in ω (noise and vibration of one sample; 0.1 rad/s is"
        " > 50σ of an MTi's 100-Hz gyro noise)",
    )
    specific_force_step_floor_mps2: float = Field(
        1.0,
        ge=0,
        description="step always allowed in f (one sample's noise and vibration; a shearer's"
        " cutting vibration is ≈ 0.3 m/s² per sample)",
    )
    recovery_samples: int = Field(
        5,
        ge=1,
        description="after this many consecutive samples rejected by a step limit the next one"
        " is accepted as the new reference, so a real step never locks the screen out",
    )


class OdometerScreening(_Strict):
    """Physical-plausibility limits of the odometer speed (:mod:`fusion.screening`)."""

    max_speed_mps: float = Field(
        5.0,
        gt=0,
        description="largest |speed|: 18 km/h, above the fastest machine of the simulated"
        " scenarios (70 m/min ≈ 1.2 m/s), 7× a shearer's haulage (≤ 30–40 m/min) and at the"
        " usual underground limit of rubber-tyred vehicles; a faster vehicle sets its own",
    )
    max_acceleration_mps2: float = Field(
        10.0,
        gt=0,
        description="largest |Δspeed|/Δt between a reading and the last accepted one: ≈ 1 g,"
        " the tyre-friction limit of any wheeled vehicle (a shearer ramps at 0.02 m/s²)",
    )
    speed_step_floor_mps: float = Field(
        5.0,
        ge=0,
        description="speed step always allowed: an encoder's count steps a reading by"
        " 1 / (counts per metre × interval), 1 m/s for 50 counts/m at 50 Hz, and its carried"
        " remainder makes the readings alternate between count levels; a rejected one would"
        " lose its travel (0.05 m/s rejected 5–10 % of a quantized encoder's readings)",
    )
    recovery_samples: int = Field(
        3,
        ge=1,
        description="after this many consecutive readings rejected by the acceleration limit"
        " the next one is accepted as the new reference",
    )


class MagnetometerScreening(_Strict):
    """Plausible band of the magnetic field norm (:mod:`fusion.screening`). Interference inside
    the band is the magnetometer plugin's indicator's business."""

    min_field_uT: float = Field(
        5.0,
        ge=0,
        description="smallest |B|: the earth's field is 22–67 µT everywhere; steel around a"
        " sensor distorts it but does not cancel it (an all-zero reading is a dead sensor)",
    )
    max_field_uT: float = Field(
        1000.0,
        gt=0,
        description="largest |B|: above the ±800 µT range of MTi-class magnetometers (the"
        " BROAD trials with a magnet 1 cm from the sensor reach 86 µT)",
    )

    @model_validator(mode="after")
    def _band(self) -> MagnetometerScreening:
        if not self.min_field_uT < self.max_field_uT:
            raise ValueError("min_field_uT must be smaller than max_field_uT")
        return self


class UwbScreening(_Strict):
    """Plausible UWB ranges (:mod:`fusion.screening`); negative ones the reader refuses."""

    max_range_m: float = Field(
        300.0,
        gt=0,
        description="largest range: the reach of DW1000-class UWB at its lowest data rate in"
        " line of sight (≈ 290 m); the simulated face's anchors answer within 40 m",
    )


class PositionScreening(_Strict):
    """Plausibility of position fixes (:mod:`fusion.screening`)."""

    min_sigma_m: float = Field(
        1.0e-5,
        gt=0,
        description="smallest σ per axis: 10 µm, a laser tracker's accuracy (no instrument"
        " positions better; a smaller σ would pin the filter to the fix)",
    )
    max_sigma_m: float = Field(
        1000.0,
        gt=0,
        description="largest σ per axis: a fix this vague says nothing at a site's scale, and"
        " huge values overflow the variance σ²",
    )
    max_distance_from_origin_m: float = Field(
        1.0e5,
        gt=0,
        description="largest distance of a fix from the recording's origin: 100 km, beyond"
        " any site that one local ENU frame describes",
    )
    max_speed_mps: float = Field(
        100.0,
        gt=0,
        description="largest speed between a fix and the last accepted one: 360 km/h, above"
        " any ground vehicle (the real car drive reaches 16 m/s)",
    )
    sigma_multiple: float = Field(
        5.0,
        gt=0,
        description="the jump between two fixes may also exceed max_speed_mps·Δt by this many"
        " σ of the two fixes combined",
    )
    recovery_samples: int = Field(
        3,
        ge=1,
        description="after this many consecutive fixes rejected by the speed limit the next"
        " one is accepted as the new reference",
    )

    @model_validator(mode="after")
    def _band(self) -> PositionScreening:
        if not self.min_sigma_m < self.max_sigma_m:
            raise ValueError("min_sigma_m must be smaller than max_sigma_m")
        return self


class SupportScreening(_Strict):
    """Plausible AFC pushes (:mod:`fusion.screening`)."""

    max_advance_m: float = Field(
        2.0,
        gt=0,
        description="largest push: a web is at most 1.2 m deep (the simulated carrier pushes"
        " 1.19 m) and push rams have no longer stroke; a push is never negative",
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

    odometer_max_rate_hz: float | None = Field(
        5.0,
        gt=0,
        description="odometer readings are combined by their exact travel into intervals of at"
        " least 1/rate (fusion.encoder: an encoder's count quantization averages out, while a slip"
        " is still seen within a second or two); None: as recorded",
    )


class OutputOptions(_Strict):
    """What ``fusion run`` writes."""

    rate_hz: float | None = Field(None, gt=0, description="None: every covariance step")
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
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the configuration ({exc.strerror})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{path}{where}: not valid YAML ({exc})") from None


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
