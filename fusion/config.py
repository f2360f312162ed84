"""Fusion configuration: typed pydantic models loaded from (and written back to) YAML.

A configuration names the IMU tuning (defaults: the datasheet figures in the recording's
``imu.spec``), the filter options, the aiding plugins (one YAML block per sensor with its own
options and rejection gate, robot_localization style) and the outputs. Every model forbids
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


class OutputOptions(_Strict):
    """What ``fusion run`` writes."""

    rate_hz: float | None = Field(None, gt=0, description="None: every covariance step")
    plots: bool = True


class FusionConfig(_Strict):
    """A whole sensor combination."""

    name: str
    description: str = ""
    imu: ImuTuning = ImuTuning()
    filter: FilterOptions = FilterOptions()
    plugins: list[PluginBlock] = []
    smoother: SmootherOptions = SmootherOptions()
    output: OutputOptions = OutputOptions()
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


def find_config(name_or_path: str | Path) -> Path:
    """A config path as given, or ``configs/NAME.yaml`` in the working tree or the repository."""
    path = Path(name_or_path)
    if path.exists():
        return path
    for root in (Path.cwd(), Path(__file__).resolve().parents[1]):
        candidate = root / "configs" / f"{name_or_path}.yaml"
        if candidate.exists():
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
