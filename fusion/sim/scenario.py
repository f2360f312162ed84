"""Scenario schema of the longwall simulator, YAML presets and ``--set key.sub=value`` overrides.

A scenario is one YAML mapping validated by :class:`Scenario` (pydantic v2, unknown keys are
errors and every error names its dotted key path). It declares

* ``origin`` — the geodetic point whose ENU axes carry all positions (the near end of the first
  cutting line for a face, the start of a track);
* exactly one shape: ``face`` (a longwall: straight cutting passes, terminal oblique cutting at
  each end, AFC advanced by the web depth per cycle; optionally unidirectional or three-pass
  cycles with cleaning runs, re-cuts, face ends that move from cycle to cycle and an AFC
  whose straightness changes at every push) or ``track`` (a vehicle that turns: a
  closed polygon driven in laps, or an open broken line);
* ``motion`` — cruise speeds, ramps, random stops, cutting vibration;
* ``imu`` — output rate, grade preset or explicit error model, quadrature nodes, truth rate;
* ``initial`` — the 1-σ uncertainty written to meta.yaml and whether the written initial state
  is perturbed by a seeded draw from it;
* optional sensor sections (``odometer``, ``magnetometer``, ``uwb``, ``support``) whose models
  come from :mod:`fusion.sim.sensors`, and ``faults`` from :mod:`fusion.sim.faults`.

``extra`` (free-form, default empty) is copied under meta.yaml ``extra:``; the random family
of :mod:`fusion.sim.worlds` records its draw there.

Every new field defaults to the behaviour the simulator had before it existed: a preset
written before them gives byte-identical CSV files.

Every scenario starts with a static period (``static_start_s``, default 60 s, cycle index 0)
and ends with one (``static_end_s``). ``duration_s`` (optional) truncates the run or pads it
with a static tail.

A scenario file may start from another with ``extends: <preset name or path>``: its mapping is
deep-merged onto the parent's.

Overrides ``key.sub=value`` are parsed as YAML scalars (``1.5`` → float, ``false`` → bool,
``[1, 2]`` → list) and set on the dotted path of the raw mapping before validation; a path
whose parent does not exist is an error naming it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from fusion.input_files import regular_file_problem
from fusion.sim.faults import FaultSpec
from fusion.sim.sensors import (
    IMU_GRADES,
    ImuErrorModel,
    ImuSpecFigures,
    MagnetometerModel,
    OdometerModel,
    PositionFixModel,
    SupportModel,
    UwbModel,
)
from fusion.validation import error_lines
from fusion.yaml_limits import YamlError, load_yaml

SCENARIO_DIR = Path(__file__).with_name("scenarios")


class ScenarioError(ValueError):
    """A scenario file, preset name or override is invalid (message names the key path)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Origin(_Strict):
    """Geodetic origin of the ENU frame (degrees, metres)."""

    lat_deg: float = Field(default=34.25, ge=-89.0, le=89.0)
    lon_deg: float = Field(default=108.95, ge=-180.0, le=360.0)
    height_m: float = -350.0


class Waviness(_Strict):
    """Lateral straightness deviation of the AFC line (smooth sum of sinusoids).

    ``lat(s, a) = Σ_i A_i sin(2π s/λ_i + a/ℓ_i + φ_i)``: amplitude split over the wavelengths,
    random phases φ_i, and a phase drift of 1/ℓ_i per metre of advance (ℓ_i = ±decorrelation_m)
    so that consecutive cutting lines are similar but not identical.
    """

    amplitude_m: float = Field(default=0.08, ge=0.0)
    wavelengths_m: list[float] = Field(default_factory=lambda: [37.0, 83.0, 161.0])
    decorrelation_m: float = Field(default=12.0, gt=0.0)


class Floor(_Strict):
    """Floor height ``Z(ξ, η)`` in face coordinates (ξ along the face, η in the advance direction).

    ``Z = ξ tan(slope_along) + η tan(dip_across) + Σ_j B_j sin(2π ξ/λ_j + 2π η/μ_j + φ_j)``;
    pitch follows the path slope, roll the cross slope of this surface.
    """

    slope_along_deg: float = 1.5
    dip_across_deg: float = 2.0
    undulation_m: float = Field(default=0.4, ge=0.0)
    wavelengths_m: list[float] = Field(default_factory=lambda: [43.0, 97.0])
    across_wavelength_m: float = Field(default=60.0, gt=0.0)


class LineDeviation(_Strict):
    """Independent straightness change of the AFC at every push (on top of :class:`Waviness`).

    Line j (j = 0 before the first push) gets the lateral deviation
    ``δ_j(s) = ρ δ_{j−1}(s) + ε_j(s)``, ``δ_0 = 0``, where every push draws a new smooth
    ``ε_j(s) = Σ_i C_i sin(2π s/λ_i + φ_i)`` of ``components`` sinusoids with wavelengths
    uniform in ``wavelengths_m``, random phases and ``C_i = σ √(2/components)`` (RMS σ). So each
    line differs from the previous line plus the advance by about σ (``√(1 + (1−ρ)/(1+ρ)) σ``),
    and ρ < 1 (``persistence``) keeps the accumulated deviation bounded
    (stationary RMS ``σ/√(1 − ρ²)``), as the face crew steers the line back.
    ``sigma_m = 0`` (default) switches it off.
    """

    sigma_m: float = Field(default=0.0, ge=0.0, description="RMS of each push's new deviation")
    wavelengths_m: tuple[float, float] = (20.0, 100.0)
    components: int = Field(default=3, ge=1)
    persistence: float = Field(default=0.7, ge=0.0, le=1.0)

    @model_validator(mode="after")
    def _check(self) -> LineDeviation:
        lo, hi = self.wavelengths_m
        if not 0.0 < lo <= hi:
            raise ValueError(f"wavelengths_m must satisfy 0 < lo <= hi, got {(lo, hi)}")
        return self


class Recut(_Strict):
    """Re-cuts: with ``probability`` per run the shearer stops mid-face (between 20 % and 80 %
    of the run), backs up a distance uniform in ``distance_m`` (at most 90 % of the way it
    came), stops again and drives on to the end of the run. Each stop lasts ``dwell_s``
    (uniform). A reversal in the middle of the face that is not a face end."""

    probability: float = Field(default=0.0, ge=0.0, le=1.0)
    distance_m: tuple[float, float] = (2.0, 20.0)
    dwell_s: tuple[float, float] = (3.0, 20.0)


FacePattern = Literal["bidirectional", "unidirectional", "three_pass"]

PATTERN_RUNS: dict[str, tuple[str, ...]] = {
    "bidirectional": ("cut",),
    "unidirectional": ("cut", "clean"),
    "three_pass": ("cut", "clean", "return"),
}
"""The face traversals of one cutting cycle of each pattern (directions alternate)."""


class Face(_Strict):
    """Longwall face: the AFC line, the web depth and the mining cycle.

    ``pattern`` (see :data:`PATTERN_RUNS`): ``bidirectional`` cuts on every traversal (the
    default, one run per cycle); ``unidirectional`` cuts one way and runs back cleaning
    (``cut, clean``); ``three_pass`` cuts, cleans back and returns (``cut, clean, return``).
    Every traversal reverses the direction of the previous one. The AFC is pushed (the terminal
    oblique-cut manoeuvre at the face end where the shearer stands, with its push event) after
    run ``push_after_run`` of each cycle (index into the pattern's runs; default the last run);
    the other runs end with a plain stop (``end_dwell_s``) before reversing.

    Face ends: the run extremes along the face are ``ξ_A = a tan(end_skew_deg[0]) + j_A`` and
    ``ξ_B = L + a tan(end_skew_deg[1]) + j_B`` on the line of advance offset a (ends not square
    to the face), with ``j`` uniform in ``±end_jitter_m`` per cycle and end (over-run / short
    fall); the first cycle's ends are exactly 0 and L (the surveyed ends of meta.yaml).
    """

    length_m: float = Field(default=200.0, gt=1.0)
    azimuth_deg: float = 92.0
    advance_m: float = Field(default=0.8, gt=0.0)
    advance_jitter_m: float = Field(default=0.0, ge=0.0)
    cycles: int = Field(default=6, ge=1)
    bend_length_m: float = Field(default=25.0, gt=0.0)
    sump_overrun_m: float = Field(default=8.0, ge=0.0)
    end_dwell_s: tuple[float, float] = (20.0, 40.0)
    push_dwell_s: tuple[float, float] = (60.0, 120.0)
    maneuver_speed_mpm: float = Field(default=4.0, gt=0.0)
    waviness: Waviness = Waviness()
    floor: Floor = Floor()
    pattern: FacePattern = "bidirectional"
    push_after_run: int | None = Field(
        default=None, ge=0, description="run index of the cycle after which the AFC is pushed"
    )
    end_skew_deg: tuple[float, float] = Field(
        default=(0.0, 0.0), description="skew of the face ends A and B (deg, +: towards +ξ)"
    )
    end_jitter_m: float = Field(default=0.0, ge=0.0, description="per-cycle end over-run (m)")
    line_deviation: LineDeviation = LineDeviation()
    recut: Recut = Recut()

    @model_validator(mode="after")
    def _check_pattern(self) -> Face:
        runs = len(PATTERN_RUNS[self.pattern])
        if self.push_after_run is not None and self.push_after_run >= runs:
            raise ValueError(
                f"push_after_run must be below {runs} (the runs of a {self.pattern} cycle)"
            )
        if any(abs(a) >= 60.0 for a in self.end_skew_deg):
            raise ValueError("end_skew_deg must lie in (-60, 60)")
        return self

    @property
    def runs(self) -> tuple[str, ...]:
        """The kinds of the runs of one cycle (``cut``, ``clean``, ``return``)."""
        return PATTERN_RUNS[self.pattern]


class Track(_Strict):
    """A vehicle track that turns: waypoints (along ξ, right η in the azimuth frame, metres).

    The heading turns smoothly over ``corner_length_m`` around each vertex (quintic
    smoothstep of the heading), the curve is integrated and represented by a quintic spline in
    arc length. ``closed`` tracks return to the first waypoint and are driven ``laps`` times
    (the cycle index is the lap number).
    """

    waypoints_m: list[tuple[float, float]]
    closed: bool = False
    laps: int = Field(default=1, ge=1)
    corner_length_m: float = Field(default=2.0, gt=0.0)
    azimuth_deg: float = 0.0
    floor: Floor = Floor(slope_along_deg=0.0, dip_across_deg=0.0, undulation_m=0.05)

    @model_validator(mode="after")
    def _check(self) -> Track:
        if len(self.waypoints_m) < 2:
            raise ValueError("a track needs at least two waypoints")
        return self


class Stops(_Strict):
    """Random stops while cutting: Poisson in time (or exactly ``count`` per drive), uniform
    position and duration."""

    rate_per_hour: float = Field(default=4.0, ge=0.0)
    duration_s: tuple[float, float] = (10.0, 90.0)
    count: int | None = Field(
        default=None, ge=0, description="exact number of stops per drive instead of Poisson"
    )


class Vibration(_Strict):
    """Cutting vibration, on only while moving (smooth envelope following the speed ramps).

    Each axis gets ``components`` sinusoids at frequencies uniform in ``freq_hz``; the linear
    part is a displacement in n with acceleration amplitude ``linear_mps2`` per component, the
    angular part is added to each Euler angle with rate amplitude ``angular_dps``.
    """

    enabled: bool = True
    linear_mps2: float = Field(default=0.3, ge=0.0)
    angular_dps: float = Field(default=0.3, ge=0.0)
    freq_hz: tuple[float, float] = (5.0, 30.0)
    components: int = Field(default=3, ge=1)
    clean_scale: float = Field(
        default=0.3, ge=0.0, le=1.0, description="envelope on cleaning and return runs"
    )


class Motion(_Strict):
    """Speed profile: cruise speeds, ramps, speed changes and stops.

    Each run (and each piece of a run between stops) draws its cruise speed uniformly in
    ``speed_mpm`` (cutting runs, track drives) or ``clean_speed_mpm`` (cleaning and return runs).
    """

    speed_mpm: tuple[float, float] = (2.0, 8.0)
    clean_speed_mpm: tuple[float, float] | None = Field(
        default=None, description="speed of cleaning and return runs; None: speed_mpm"
    )
    accel_mps2: float = Field(default=0.02, gt=0.0)
    min_ramp_s: float = Field(default=2.0, gt=0.0)
    speed_changes_per_hour: float = Field(default=6.0, ge=0.0)
    stops: Stops = Stops()
    vibration: Vibration = Vibration()

    @field_validator("vibration", mode="before")
    @classmethod
    def _vibration_switch(cls, v: Any) -> Any:
        """``vibration: false`` / ``true`` is shorthand for ``vibration: {enabled: …}``."""
        return {"enabled": v} if isinstance(v, bool) else v


class Imu(_Strict):
    """IMU output: rate, error grade, exact-mean quadrature, truth rate.

    ``grade`` names a preset of :data:`fusion.sim.sensors.IMU_GRADES`; ``errors`` (an explicit
    :class:`~fusion.sim.sensors.ImuErrorModel`) replaces it when given. ``truth_rate_hz``
    (default: the IMU rate) must divide the IMU rate. ``meta_spec`` states the datasheet
    figures written to meta.yaml ``imu.spec`` apart from the error model the simulator uses (a
    real unit's turn-on biases are usually far below its datasheet's repeatability); by default
    they are derived from the error model (:func:`fusion.sim.sensors.spec_for_meta`).
    """

    rate_hz: float = Field(default=100.0, gt=0.0)
    grade: str = "mti-g-700"
    errors: ImuErrorModel | None = None
    meta_spec: ImuSpecFigures | None = Field(
        default=None, description="datasheet figures for meta.yaml; None: from the error model"
    )
    quadrature_nodes: int = Field(default=6, ge=1, le=16)
    truth_rate_hz: float | None = Field(default=None, ge=10.0)

    @model_validator(mode="after")
    def _check(self) -> Imu:
        if self.errors is None and self.grade not in IMU_GRADES:
            raise ValueError(f"unknown IMU grade {self.grade!r} (known: {sorted(IMU_GRADES)})")
        if self.truth_rate_hz is not None:
            ratio = self.rate_hz / self.truth_rate_hz
            if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                raise ValueError("truth_rate_hz must divide rate_hz")
        return self

    @property
    def error_model(self) -> ImuErrorModel:
        """The IMU error model in effect."""
        return self.errors if self.errors is not None else IMU_GRADES[self.grade]


class Uwb(UwbModel):
    """UWB section: :class:`~fusion.sim.sensors.UwbModel` plus the frame of ``anchors``.

    ``anchors_frame: face`` gives each anchor as (along ξ, right η, height above the floor) in
    face coordinates (converted to ENU with the scenario's floor); ``enu`` as ENU metres.
    """

    anchors_frame: Literal["enu", "face"] = "enu"


class InitialSigma(_Strict):
    """1-σ uncertainty of the initial state written to meta.yaml."""

    position_m: tuple[float, float, float] = (0.05, 0.05, 0.05)
    velocity_mps: tuple[float, float, float] = (0.01, 0.01, 0.01)
    attitude_deg: tuple[float, float, float] = (0.3, 0.3, 1.0)


class Initial(_Strict):
    """Initial state given to filters: the truth perturbed by a seeded draw from ``sigma``."""

    sigma: InitialSigma = InitialSigma()
    perturb: bool = True


class Scenario(_Strict):
    """A complete simulator scenario (see the module docstring)."""

    name: str
    description: str = ""
    origin: Origin = Origin()
    static_start_s: float = Field(default=60.0, ge=0.0)
    static_end_s: float = Field(default=30.0, ge=0.0)
    duration_s: float | None = Field(default=None, gt=0.0)
    chunk_s: float = Field(default=600.0, gt=0.0)
    face: Face | None = None
    track: Track | None = None
    motion: Motion = Motion()
    imu: Imu = Imu()
    initial: Initial = Initial()
    odometer: OdometerModel | None = None
    magnetometer: MagnetometerModel | None = None
    uwb: Uwb | None = None
    support: SupportModel | None = None
    position: PositionFixModel | None = None
    faults: list[FaultSpec] = Field(default_factory=list)
    extra: dict[str, Any] = Field(
        default_factory=dict,
        description="free-form record copied under meta.yaml extra (e.g. a drawn world)",
    )

    @model_validator(mode="after")
    def _one_shape(self) -> Scenario:
        if (self.face is None) == (self.track is None):
            raise ValueError("exactly one of 'face' and 'track' must be given")
        return self


def parse_override(text: str) -> tuple[list[str], Any]:
    """Split ``key.sub=value`` into the key path and the YAML-parsed scalar value."""
    if "=" not in text:
        raise ScenarioError(f"override {text!r}: expected key.sub=value")
    key, raw = text.split("=", 1)
    path = [p for p in key.strip().split(".")]
    if not key.strip() or any(not p for p in path):
        raise ScenarioError(f"override {text!r}: empty key path")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError as exc:
        raise ScenarioError(f"override {text!r}: value is not valid YAML ({exc})") from exc
    return path, value


def _known_fields(path: list[str]) -> bool:
    """Whether ``path`` names a field of the schema (used to allow setting unset sections).

    Any key below a mapping-typed field (e.g. ``uwb.anchors.A9``) is allowed.
    """
    model: Any = Scenario
    for part in path:
        if model is dict:
            return True
        fields = getattr(model, "model_fields", None)
        if fields is None or part not in fields:
            return False
        ann = fields[part].annotation
        args = [ann, *getattr(ann, "__args__", ())]
        nested = [a for a in args if isinstance(a, type) and issubclass(a, BaseModel)]
        is_map = any(a is dict or getattr(a, "__origin__", None) is dict for a in args)
        model = nested[0] if nested else (dict if is_map else None)
    return True


def apply_overrides(data: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """Apply ``key.sub=value`` overrides onto a raw scenario mapping (returns a new mapping)."""
    import copy

    out = copy.deepcopy(data)
    for text in overrides:
        path, value = parse_override(text)
        node: Any = out
        for i, part in enumerate(path[:-1]):
            where = ".".join(path[: i + 1])
            if isinstance(node, dict):
                if part not in node or node[part] is None:
                    if not _known_fields(path[: i + 1]):
                        raise ScenarioError(f"override {text!r}: no key {where!r} in the scenario")
                    node[part] = {}
                node = node[part]
            elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
                node = node[int(part)]
            else:
                raise ScenarioError(f"override {text!r}: {where!r} is not a mapping")
        last = path[-1]
        if isinstance(node, dict):
            if last not in node and not _known_fields(path):
                raise ScenarioError(f"override {text!r}: no key {'.'.join(path)!r} in the scenario")
            node[last] = value
        elif isinstance(node, list) and last.isdigit() and int(last) < len(node):
            node[int(last)] = value
        else:
            raise ScenarioError(f"override {text!r}: cannot set {'.'.join(path)!r}")
    return out


def scenario_from_mapping(data: Any, source: str = "<mapping>") -> Scenario:
    """Validate a raw mapping into a :class:`Scenario` (errors name the key path)."""
    if not isinstance(data, dict):
        raise ScenarioError(f"invalid scenario {source}: top level must be a mapping")
    try:
        return Scenario.model_validate(data)
    except ValidationError as err:
        raise ScenarioError("\n".join(error_lines(f"scenario {source}", Scenario, err))) from None


def preset_path(name: str) -> Path:
    """Path of the preset YAML called ``name``."""
    return SCENARIO_DIR / f"{name}.yaml"


def read_scenario_mapping(name_or_path: str | Path, _depth: int = 0) -> tuple[dict[str, Any], str]:
    """Raw mapping of a preset name or a YAML path, and a label for messages.

    A top-level ``extends: <preset or path>`` merges the file onto that scenario (mappings
    recursively, other values replaced).
    """
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        path = p
    else:
        path = preset_path(str(name_or_path))
        if not path.exists():
            known = ", ".join(n for n, _ in list_presets())
            raise ScenarioError(f"unknown scenario {name_or_path!r} (presets: {known})")
    problem = regular_file_problem(path) if os.path.lexists(path) else None
    if problem is not None:
        raise ScenarioError(f"cannot read scenario {path}: {problem}")
    try:
        data = load_yaml(path.read_bytes()).data
    except OSError as exc:
        raise ScenarioError(f"cannot read scenario {path}: {exc.strerror or exc}") from None
    except YamlError as exc:
        where = f", line {exc.line}" if exc.line is not None else ""
        raise ScenarioError(f"scenario {path}{where}: {exc.rule}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"invalid scenario {path}: top level must be a mapping")
    base = data.pop("extends", None)
    if base is not None:
        if _depth > 8:
            raise ScenarioError(f"scenario {path}: 'extends' nests too deep")
        parent, _ = read_scenario_mapping(str(base), _depth=_depth + 1)
        data = _deep_merge(parent, data)
    return data, str(path)


def _deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``over`` merged onto ``base`` (mappings recursively, everything else replaced)."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def load_scenario(name_or_path: str | Path, overrides: Sequence[str] = ()) -> Scenario:
    """Load a preset (by name) or a YAML file, apply overrides, validate."""
    data, source = read_scenario_mapping(name_or_path)
    return scenario_from_mapping(apply_overrides(data, overrides), source)


def list_presets() -> list[tuple[str, str]]:
    """``(name, one-line description)`` of every preset, sorted by name."""
    out = []
    for path in sorted(SCENARIO_DIR.glob("*.yaml"), key=lambda p: p.stem):
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except yaml.YAMLError:
            data = {}
        desc = str(data.get("description", "")).strip().splitlines()
        out.append((path.stem, desc[0] if desc else ""))
    return out


ShapeKind = Literal["face", "track"]
