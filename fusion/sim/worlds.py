"""Randomized longwall worlds: one seed → one :class:`~fusion.sim.scenario.Scenario`.

The presets reproduce the seed papers' experiments, each one face, one mining pattern and one
sensor grade. A filter tuned on them can still break on a face it has never seen. This module
draws *worlds* from ranges that cover what real faces (and independent simulators) contain:
the mining pattern (bidirectional, unidirectional with a cleaning run, three traversals),
re-cuts, face ends that are not square to the face, an AFC whose straightness changes at every
push, floors that dip and undulate, sites in either hemisphere at any longitude, IMUs whose
datasheet is not their realized error, sampled at different rates, an earth field that differs
from the one the site states, UWB anchors at the face ends polled in different ways, odometer
rate, scale, mounting and quantization, and recordings that end anywhere — in the middle of a
pass, or before the first AFC push.

:class:`WorldRanges` holds every range (a pydantic model: each field has a default and a
one-line description, and it round-trips through YAML). :func:`draw_world` draws one world
from a seed, deterministically: ``numpy.random.SeedSequence(seed, spawn_key=(WORLD_KEY, g))``
gives each parameter group g its own stream (see :data:`GROUP_KEYS`), so a change of one
group's ranges leaves the others' draws unchanged. The simulator then runs the world with the
same seed (its own streams, :data:`fusion.sim.simulate.STREAM_KEYS`, are keyed apart).

Conventions of the draws (also in the field descriptions): a pair ``(lo, hi)`` is drawn
uniformly unless the description says *log-uniform*; a *magnitude* gets a random sign;
a *sub-range* draws two values and uses them sorted as the scenario's own range (e.g. each
world has its own cutting-speed range, and each run draws its speed inside it); a *range* is
used as it stands (each event draws inside it); *choices* are picked with equal weight;
*weights* are relative probabilities.

Every world has an IMU, an odometer, support push rams, a magnetometer and UWB anchors
(configurations that do not use a stream ignore it). ``harsh=True`` adds a degraded IMU,
odometer slips, UWB NLOS episodes and dropouts, magnetic interference windows and sensor
dropouts (:class:`HarshRanges`); without it no fault is injected and no NLOS occurs.

The families ``longwall-random``, ``longwall-random-short`` and ``longwall-random-harsh``
(:data:`FAMILIES`) are what ``fusion simulate NAME OUT --seed N`` accepts besides the presets.
The drawn world (its ranges, and the whole scenario mapping after any ``--set`` override) is
recorded under meta.yaml ``extra.world``, so that
``Scenario.model_validate(extra["world"]["scenario"])`` simulated with ``extra["seed"]``
reproduces the recording.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator

from fusion.sim.scenario import PATTERN_RUNS, Scenario, scenario_from_mapping

WORLD_KEY = 100
"""First spawn-key element of the world streams (the simulator's streams use 1–8)."""

GROUP_KEYS = {
    "duration": 1,
    "geometry": 2,
    "motion": 3,
    "imu": 4,
    "initial": 5,
    "odometer": 6,
    "magnetometer": 7,
    "uwb": 8,
    "support": 9,
    "harsh": 10,
}
"""Second spawn-key element of each parameter group's stream."""

Range = tuple[float, float]
IntRange = tuple[int, int]


def _range(lo: float, hi: float, description: str) -> Any:
    return Field(default=(lo, hi), description=description)


class _Ranges(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="after")
    def _ordered(self) -> _Ranges:
        for name, value in self:
            if isinstance(value, tuple) and len(value) == 2 and not value[0] <= value[1]:
                raise ValueError(f"{name}: the range {value} must satisfy lo <= hi")
            if isinstance(value, dict) and (
                not value or any(w < 0 for w in value.values()) or sum(value.values()) <= 0
            ):
                raise ValueError(f"{name}: weights must be >= 0 with a positive sum")
        return self


class HarshRanges(_Ranges):
    """What ``harsh=True`` adds to a world (faults from :mod:`fusion.sim.faults`)."""

    imu_degradation: Range = _range(
        2.0, 5.0, "factor on the IMU's noise, bias instability and turn-on bias σ"
    )
    odometer_slips: IntRange = _range(1, 4, "number of odometer slip windows")
    slip_ratio: Range = _range(-0.3, 0.5, "odometer over-read of a slip (+0.2 = +20 %)")
    slip_duration_s: Range = _range(5.0, 60.0, "length of a slip window (s)")
    uwb_nlos_probability: Range = _range(0.02, 0.2, "long-run NLOS fraction per anchor")
    uwb_nlos_episode_s: Range = _range(2.0, 20.0, "mean NLOS episode length (s)")
    uwb_nlos_bias_m: Range = _range(0.3, 2.0, "range: NLOS range bias (m)")
    uwb_dropout_probability: Range = _range(0.05, 0.3, "probability that a range is missing")
    uwb_nlos_windows: IntRange = _range(0, 2, "uwb_nlos fault windows on all anchors")
    uwb_nlos_window_s: Range = _range(5.0, 60.0, "length of a uwb_nlos fault window (s)")
    mag_interference: IntRange = _range(1, 3, "magnetic interference windows")
    mag_interference_uT: Range = _range(5.0, 40.0, "interference field magnitude (µT)")
    mag_interference_s: Range = _range(10.0, 120.0, "length of an interference window (s)")
    dropouts: IntRange = _range(0, 2, "dropout windows (odometer, magnetometer or uwb)")
    dropout_s: Range = _range(2.0, 30.0, "length of a dropout window (s)")


class WorldRanges(_Ranges):
    """The ranges a random world is drawn from (conventions: module docstring)."""

    # recording span
    duration_s: Range = _range(1800.0, 3600.0, "recording length (s)")
    see_push_probability: float = Field(
        default=0.75,
        ge=0.0,
        le=1.0,
        description="chance that a recording drawn to end before the first AFC push is"
        " lengthened past it",
    )
    see_push_extra_s: Range = _range(60.0, 1800.0, "it then ends this long after the push (s)")
    max_duration_s: float = Field(default=7200.0, gt=0.0, description="longest recording (s)")
    static_start_s: Range = _range(30.0, 120.0, "static period at the start (s)")
    # site and face geometry
    # Longwall coalfields lie at 20–68° either side of the equator: India 22–24° N, Queensland
    # 21–28° S, South Africa 26–27° S, New South Wales 32–35° S, China 34–45° N, the US 37–41° N,
    # Europe 50–56° N, the Kuzbass 54° N, Vorkuta 67° N.
    lat_deg: Range = _range(20.0, 68.0, "magnitude: origin latitude (deg), north or south")
    lon_deg: Range = _range(-180.0, 180.0, "origin longitude (deg)")
    height_m: Range = _range(-1000.0, -200.0, "origin height (m)")
    face_length_m: Range = _range(60.0, 300.0, "face length (m)")
    azimuth_deg: Range = _range(0.0, 360.0, "face azimuth (deg)")
    advance_m: Range = _range(0.6, 1.0, "web depth per cycle (m)")
    advance_jitter_m: Range = _range(0.0, 0.02, "σ of the push's deviation from the web (m)")
    pattern: dict[str, float] = Field(
        default_factory=lambda: {"bidirectional": 0.4, "unidirectional": 0.35, "three_pass": 0.25},
        description="weights of the mining patterns; the push follows a run chosen uniformly",
    )
    bend_length_m: Range = _range(15.0, 35.0, "snake (bend) length at the face end (m)")
    sump_overrun_m: Range = _range(3.0, 10.0, "overrun past the bend when sumping in (m)")
    end_dwell_s: Range = _range(10.0, 60.0, "range: stop at a face end (s)")
    push_dwell_s: Range = _range(30.0, 180.0, "range: stop while the end is pushed (s)")
    maneuver_speed_mpm: Range = _range(3.0, 8.0, "face-end manoeuvre speed (m/min)")
    end_skew_deg: Range = _range(0.0, 20.0, "magnitude, per end: face-end skew (deg)")
    end_jitter_m: Range = _range(0.0, 2.0, "per-cycle end over-run/short-fall bound (m)")
    line_deviation_m: Range = _range(
        0.01, 0.15, "log-uniform: RMS of the AFC straightness change per push (m)"
    )
    line_deviation_wavelength_m: Range = _range(20.0, 100.0, "range: its wavelengths (m)")
    line_deviation_persistence: Range = _range(0.5, 0.9, "share of the deviation kept per push")
    waviness_m: Range = _range(0.0, 0.15, "AFC waviness amplitude (m)")
    waviness_wavelength_m: Range = _range(15.0, 200.0, "its three wavelengths (m)")
    waviness_decorrelation_m: Range = _range(5.0, 30.0, "advance over which waviness drifts (m)")
    floor_slope_along_deg: Range = _range(-8.0, 8.0, "floor slope along the face (deg)")
    floor_dip_across_deg: Range = _range(-8.0, 8.0, "floor dip in the advance direction (deg)")
    floor_undulation_m: Range = _range(0.0, 1.0, "floor undulation amplitude (m)")
    floor_wavelength_m: Range = _range(20.0, 150.0, "floor undulation wavelengths (m), 2-3")
    floor_across_wavelength_m: Range = _range(30.0, 120.0, "its wavelength across the face (m)")
    # motion
    cut_speed_mpm: Range = _range(2.0, 10.0, "sub-range: cutting-run speeds (m/min)")
    clean_speed_mpm: Range = _range(6.0, 15.0, "sub-range: cleaning/return-run speeds (m/min)")
    accel_mps2: Range = _range(0.01, 0.05, "haulage acceleration (m/s²)")
    speed_changes_per_hour: Range = _range(0.0, 12.0, "speed changes per hour of travel")
    stops_per_hour: Range = _range(0.0, 10.0, "random mid-face stops per hour of travel")
    stop_duration_s: Range = _range(5.0, 120.0, "range: length of a stop (s)")
    recut_probability: Range = _range(0.0, 0.3, "probability of a re-cut per run")
    recut_distance_m: Range = _range(2.0, 20.0, "range: back-up distance of a re-cut (m)")
    vibration_linear_mps2: Range = _range(0.05, 1.0, "cutting vibration, per component (m/s²)")
    vibration_angular_dps: Range = _range(0.05, 1.0, "cutting vibration, per component (deg/s)")
    vibration_freq_hz: Range = _range(3.0, 60.0, "sub-range: vibration frequencies (Hz)")
    vibration_components: IntRange = _range(1, 5, "sinusoids per axis")
    vibration_clean_scale: Range = _range(0.0, 0.5, "vibration on cleaning/return runs")
    # IMU: the realized errors. Sources (fusion.sim.sensors.IMU_GRADES and datasheets): MTi-G-700
    # (seed 000 Table 1) ARW 0.6 deg/√h, 0.08 mg/√Hz, in-run bias 10 deg/h and 0.04 mg, bias
    # repeatability 720 deg/h and 3 mg; MTi-30 (seed 003 Table 1) in-run bias 18 deg/h; the
    # seed 002 MEMS 3 deg/h and 1 mg biases, ARW 0.04 deg/√h; ADIS16488-class units 0.3 deg/√h,
    # 5 deg/h in-run bias, 0.05 mg/√Hz. A unit's turn-on bias is usually far below its
    # datasheet's repeatability, hence 10–720 deg/h and 0.2–5 mg drawn log-uniformly; scale
    # factor and misalignment: 0.1–0.15 % and 0.05–0.1° class figures of calibrated MEMS units.
    imu_rate_hz: list[float] = Field(
        default_factory=lambda: [50.0, 100.0, 200.0], description="choices"
    )
    gyro_bias_deg_h: Range = _range(10.0, 720.0, "log-uniform: turn-on gyro bias σ (deg/h)")
    accel_bias_mg: Range = _range(0.2, 5.0, "log-uniform: turn-on accel bias σ (mg)")
    gyro_arw_deg_rth: Range = _range(0.1, 1.0, "log-uniform: angle random walk (deg/√h)")
    accel_vrw_mg_rthz: Range = _range(0.03, 0.2, "log-uniform: accel noise density (mg/√Hz)")
    gyro_bias_instability_deg_h: Range = _range(2.0, 20.0, "log-uniform: gyro BI (deg/h)")
    accel_bias_instability_mg: Range = _range(0.01, 0.1, "log-uniform: accel BI (mg)")
    bias_corr_time_s: Range = _range(30.0, 600.0, "log-uniform: Gauss-Markov time (s)")
    scale_factor_ppm: Range = _range(100.0, 1500.0, "scale-factor error σ (ppm)")
    misalignment_mrad: Range = _range(0.2, 2.0, "axis misalignment σ (mrad)")
    # IMU datasheet written to meta.yaml imu.spec
    spec_gyro_bias_deg_h: Range = _range(360.0, 1080.0, "log-uniform: datasheet gyro bias")
    spec_accel_bias_mg: Range = _range(2.0, 10.0, "log-uniform: datasheet accel bias (mg)")
    spec_noise_factor: Range = _range(0.8, 1.5, "datasheet ARW/VRW ÷ realized")
    # initial state
    initial_attitude_sigma_deg: Range = _range(0.3, 1.5, "meta σ per axis (deg)")
    initial_position_sigma_m: Range = _range(0.02, 0.1, "meta σ per axis (m)")
    initial_velocity_sigma_mps: Range = _range(0.005, 0.02, "meta σ per axis (m/s)")
    # odometer
    odometer_rate_hz: list[float] = Field(
        default_factory=lambda: [1.0, 2.0, 5.0, 10.0, 20.0, 50.0],
        description="choices (a haulage speed relayed by the shearer's PLC comes at 1–5 Hz)",
    )
    odometer_scale_error: Range = _range(-0.03, 0.03, "scale-factor error δk_D")
    odometer_mounting_deg: Range = _range(-1.0, 1.0, "mounting angle, per axis (deg)")
    odometer_noise_mps: Range = _range(0.002, 0.02, "log-uniform: speed noise (m/s)")
    odometer_quantized: float = Field(
        default=0.5, ge=0.0, le=1.0, description="probability of encoder quantization"
    )
    odometer_counts_per_m: Range = _range(50.0, 2000.0, "log-uniform: encoder counts per m")
    # magnetometer
    mag_rate_hz: list[float] = Field(
        default_factory=lambda: [10.0, 20.0, 50.0], description="choices"
    )
    # The field at the coalfields above (IGRF) against the axial dipole's (:func:`dipole_field`):
    # F from 0.75× (South Africa's anomaly, 28 µT) to 1.2× (China, 54 µT); the inclination
    # departs from the dipole's by −8° (India) to +18° (South Africa), drawn up to +15° (more,
    # at mid-latitudes, is steeper than any coalfield's) and at most Vorkuta's 80°; declinations
    # of ±20°.
    field_factor: Range = _range(0.75, 1.25, "true F ÷ the dipole's F at the site's latitude")
    inclination_offset_deg: Range = _range(
        -10.0, 15.0, "true |I| − the dipole's at the site (deg), at most 80°; sign of the latitude"
    )
    declination_deg: Range = _range(-20.0, 20.0, "true declination D (deg)")
    meta_field_error: Range = _range(0.01, 0.05, "magnitude: relative error of the stated F")
    meta_inclination_error_deg: Range = _range(1.0, 4.0, "magnitude: error of the stated I")
    meta_declination_error_deg: Range = _range(0.5, 1.0, "magnitude: error of the stated D")
    hard_iron_uT: Range = _range(1.0, 2.0, "residual hard iron, random direction (µT)")
    soft_iron_diagonal: Range = _range(-0.02, 0.02, "soft-iron diagonal − 1, per axis")
    soft_iron_off_diagonal: Range = _range(-0.005, 0.005, "soft-iron off-diagonal entries")
    mag_noise_uT: Range = _range(0.05, 0.3, "white noise per sample (µT)")
    # UWB
    anchors_per_end: IntRange = _range(3, 4, "anchors at each face end (a fix needs three)")
    anchor_outward_m: Range = _range(-3.0, 8.0, "anchor beyond the face end, along it (m)")
    anchor_across_m: Range = _range(-8.0, 12.0, "anchor across the face (+: advance) (m)")
    anchor_height_m: Range = _range(0.5, 3.0, "anchor height above the floor (m)")
    anchor_max_distance_m: float = Field(
        default=15.0, gt=0.0, description="anchors lie within this of their face end (m)"
    )
    uwb_polling: dict[str, float] = Field(
        default_factory=lambda: {"staggered": 0.4, "round_robin": 0.4, "simultaneous": 0.2},
        description="weights of the polling modes (simultaneous: a round's ranges share one"
        " time stamp)",
    )
    uwb_round_rate_hz: Range = _range(5.0, 20.0, "rounds per second (round modes)")
    uwb_total_rate_hz: Range = _range(20.0, 60.0, "ranges per second (round robin)")
    uwb_noise_m: Range = _range(0.02, 0.10, "base range noise σ (m)")
    uwb_noise_factor: Range = _range(0.7, 1.4, "per-anchor factor on the noise σ")
    uwb_max_range_m: Range = _range(30.0, 80.0, "largest range the tag measures (m)")
    uwb_lever_arm_m: Range = _range(-1.0, 1.0, "tag lever arm, per axis (m)")
    uwb_dropout_probability: Range = _range(0.0, 0.05, "probability that a range is missing")
    # support push rams
    support_noise_m: Range = _range(0.003, 0.02, "push-ram advance noise σ (m)")
    support_bias_m: Range = _range(-0.02, 0.02, "push-ram advance bias (m)")
    harsh: HarshRanges = Field(default_factory=HarshRanges, description="what harsh adds")

    def to_yaml(self) -> str:
        """The ranges as YAML (read back with :meth:`from_yaml`)."""
        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False)

    @classmethod
    def from_yaml(cls, text: str) -> WorldRanges:
        """Ranges from YAML text (missing keys take their defaults)."""
        return cls.model_validate(yaml.safe_load(text) or {})


SHORT_DURATION_S: Range = (300.0, 600.0)
"""Recording length of the short family (CI smoke tests; never lengthened past a push)."""

FAMILIES: dict[str, str] = {
    "longwall-random": "random longwall world drawn from the seed (fusion.sim.worlds)",
    "longwall-random-short": "random longwall world, 300-600 s (smoke tests)",
    "longwall-random-harsh": "random longwall world with a degraded IMU and sensor faults",
}
"""The random families accepted wherever a preset name is, with their descriptions."""


def family_world(name: str, seed: int, duration_s: float | None = None) -> Scenario:
    """The world of family ``name`` (a key of :data:`FAMILIES`) for ``seed``."""
    if name not in FAMILIES:
        raise KeyError(name)
    ranges = WorldRanges()
    if name.endswith("-short"):
        ranges = ranges.model_copy(
            update={"duration_s": SHORT_DURATION_S, "see_push_probability": 0.0}
        )
    return draw_world(
        seed, ranges, duration_s=duration_s, harsh=name.endswith("-harsh"), family=name
    )


# ----------------------------------------------------------------------------- drawing
class _Draw:
    """Draw helpers over one group's generator."""

    def __init__(self, seed: int, group: str) -> None:
        seq = np.random.SeedSequence(seed, spawn_key=(WORLD_KEY, GROUP_KEYS[group]))
        self.rng = np.random.default_rng(seq)

    def u(self, r: Range) -> float:
        return float(self.rng.uniform(r[0], r[1]))

    def log(self, r: Range) -> float:
        return float(math.exp(self.rng.uniform(math.log(r[0]), math.log(r[1]))))

    def signed(self, r: Range) -> float:
        return self.u(r) * (1.0 if self.rng.random() < 0.5 else -1.0)

    def sub(self, r: Range) -> tuple[float, float]:
        a, b = sorted(self.rng.uniform(r[0], r[1], size=2).tolist())
        return float(a), float(b)

    def integer(self, r: IntRange) -> int:
        return int(self.rng.integers(r[0], r[1] + 1))

    def choice(self, options: list[float]) -> float:
        return float(options[int(self.rng.integers(len(options)))])

    def weighted(self, weights: dict[str, float]) -> str:
        names = list(weights)
        p = np.asarray([weights[n] for n in names], float)
        return names[int(self.rng.choice(len(names), p=p / p.sum()))]

    def unit(self) -> np.ndarray:
        v = self.rng.standard_normal(3)
        return np.asarray(v / np.linalg.norm(v))


DIPOLE_EQUATOR_UT = 30.1
"""The geomagnetic axial dipole's field at the equator (µT; IGRF's g₁⁰)."""


def dipole_field(lat_deg: float) -> tuple[float, float]:
    """The axial dipole's total intensity F (µT) and inclination I (deg, down > 0) at latitude
    ``lat_deg``: ``F = B₀ √(1 + 3 sin²φ)``, ``tan I = 2 tan φ``."""
    phi = math.radians(lat_deg)
    f = DIPOLE_EQUATOR_UT * math.sqrt(1.0 + 3.0 * math.sin(phi) ** 2)
    return f, math.degrees(math.atan(2.0 * math.tan(phi)))


def _r(x: float, digits: int = 6) -> float:
    return round(float(x), digits)


def draw_world(
    seed: int,
    ranges: WorldRanges | None = None,
    *,
    duration_s: float | None = None,
    harsh: bool = False,
    family: str = "longwall-random",
) -> Scenario:
    """Draw one world (a :class:`Scenario`) from ``ranges``, deterministically from ``seed``.

    Parameters
    ----------
    seed
        Seed of the draw (and the scenario is meant to be simulated with the same seed).
    ranges
        The ranges (default :class:`WorldRanges`).
    duration_s
        Fix the recording length instead of drawing it from ``ranges.duration_s`` (the draw
        is still made, so every other parameter is the same).
    harsh
        Add the faults and degradations of ``ranges.harsh``.
    family
        Name recorded in the scenario (``name`` and ``extra.world.family``).
    """
    rg = ranges if ranges is not None else WorldRanges()
    span = _Draw(seed, "duration")
    drawn_duration = span.u(rg.duration_s)
    static_start = span.u(rg.static_start_s)
    see_push = span.rng.random() < rg.see_push_probability
    past_push = span.u(rg.see_push_extra_s)
    duration = float(duration_s) if duration_s is not None else drawn_duration

    g = _Draw(seed, "geometry")
    length = g.u(rg.face_length_m)
    pattern = g.weighted(rg.pattern)
    runs = PATTERN_RUNS[pattern]
    push_after = int(g.rng.integers(len(runs)))
    n_floor = g.integer((2, 3))
    face: dict[str, Any] = {
        "length_m": _r(length, 3),
        "azimuth_deg": _r(g.u(rg.azimuth_deg), 4),
        "advance_m": _r(g.u(rg.advance_m), 4),
        "advance_jitter_m": _r(g.u(rg.advance_jitter_m)),
        "pattern": pattern,
        "push_after_run": push_after,
        "bend_length_m": _r(min(g.u(rg.bend_length_m), 0.4 * length), 3),
        "sump_overrun_m": _r(g.u(rg.sump_overrun_m), 3),
        "end_dwell_s": list(rg.end_dwell_s),
        "push_dwell_s": list(rg.push_dwell_s),
        "maneuver_speed_mpm": _r(g.u(rg.maneuver_speed_mpm), 3),
        "end_skew_deg": [_r(g.signed(rg.end_skew_deg), 4), _r(g.signed(rg.end_skew_deg), 4)],
        "end_jitter_m": _r(g.u(rg.end_jitter_m), 4),
        "line_deviation": {
            "sigma_m": _r(g.log(rg.line_deviation_m)),
            "wavelengths_m": list(rg.line_deviation_wavelength_m),
            "components": 3,
            "persistence": _r(g.u(rg.line_deviation_persistence), 4),
        },
        "waviness": {
            "amplitude_m": _r(g.u(rg.waviness_m)),
            "wavelengths_m": [
                _r(x, 3) for x in sorted(g.rng.uniform(*rg.waviness_wavelength_m, size=3))
            ],
            "decorrelation_m": _r(g.u(rg.waviness_decorrelation_m), 3),
        },
        "floor": {
            "slope_along_deg": _r(g.u(rg.floor_slope_along_deg), 4),
            "dip_across_deg": _r(g.u(rg.floor_dip_across_deg), 4),
            "undulation_m": _r(g.u(rg.floor_undulation_m)),
            "wavelengths_m": [_r(g.u(rg.floor_wavelength_m), 3) for _ in range(n_floor)],
            "across_wavelength_m": _r(g.u(rg.floor_across_wavelength_m), 3),
        },
    }
    origin = {
        "lat_deg": _r(g.signed(rg.lat_deg)),
        "lon_deg": _r(g.u(rg.lon_deg)),
        "height_m": _r(g.u(rg.height_m), 2),
    }

    mo = _Draw(seed, "motion")
    cut = mo.sub(rg.cut_speed_mpm)
    clean = mo.sub(rg.clean_speed_mpm)
    face["recut"] = {
        "probability": _r(mo.u(rg.recut_probability), 4),
        "distance_m": list(rg.recut_distance_m),
    }
    motion = {
        "speed_mpm": [_r(cut[0], 4), _r(cut[1], 4)],
        "clean_speed_mpm": [_r(clean[0], 4), _r(clean[1], 4)],
        "accel_mps2": _r(mo.u(rg.accel_mps2)),
        "speed_changes_per_hour": _r(mo.u(rg.speed_changes_per_hour), 4),
        "stops": {
            "rate_per_hour": _r(mo.u(rg.stops_per_hour), 4),
            "duration_s": list(rg.stop_duration_s),
        },
        "vibration": {
            "enabled": True,
            "linear_mps2": _r(mo.u(rg.vibration_linear_mps2), 4),
            "angular_dps": _r(mo.u(rg.vibration_angular_dps), 4),
            "freq_hz": [_r(x, 3) for x in mo.sub(rg.vibration_freq_hz)],
            "components": mo.integer(rg.vibration_components),
            "clean_scale": _r(mo.u(rg.vibration_clean_scale), 4),
        },
    }
    # enough cycles to fill the longest span at the fastest speeds (the recording is cut there)
    fastest = {"cut": cut[1], "clean": clean[1], "return": clean[1]}
    t_cycle = sum(length / (fastest[k] / 60.0) for k in runs)
    longest = max(duration, drawn_duration, rg.max_duration_s)
    face["cycles"] = max(1, math.ceil(longest / t_cycle) + 1)

    im = _Draw(seed, "imu")
    hd = _Draw(seed, "harsh") if harsh else None
    degrade = hd.u(rg.harsh.imu_degradation) if hd is not None else 1.0
    arw = im.log(rg.gyro_arw_deg_rth)
    vrw = im.log(rg.accel_vrw_mg_rthz)
    tau = im.log(rg.bias_corr_time_s)
    errors = {
        "source": "random world (fusion.sim.worlds)" + (", degraded" if harsh else ""),
        "gyro_bias_deg_h": _r(im.log(rg.gyro_bias_deg_h) * degrade, 4),
        "gyro_arw_deg_rth": _r(arw * degrade),
        "gyro_bias_instability_deg_h": _r(im.log(rg.gyro_bias_instability_deg_h) * degrade, 4),
        "gyro_bias_corr_time_s": _r(tau, 3),
        "gyro_scale_factor_ppm": _r(im.u(rg.scale_factor_ppm), 3),
        "gyro_misalignment_mrad": _r(im.u(rg.misalignment_mrad), 4),
        "accel_bias_mg": _r(im.log(rg.accel_bias_mg) * degrade),
        "accel_vrw_mg_rthz": _r(vrw * degrade),
        "accel_bias_instability_mg": _r(im.log(rg.accel_bias_instability_mg) * degrade),
        "accel_bias_corr_time_s": _r(tau, 3),
        "accel_scale_factor_ppm": _r(im.u(rg.scale_factor_ppm), 3),
        "accel_misalignment_mrad": _r(im.u(rg.misalignment_mrad), 4),
    }
    meta_spec = {
        "gyro_bias_deg_h": _r(im.log(rg.spec_gyro_bias_deg_h), 3),
        "gyro_arw_deg_rth": _r(arw * im.u(rg.spec_noise_factor)),
        "accel_bias_mg": _r(im.log(rg.spec_accel_bias_mg), 4),
        "accel_vrw_mg_rthz": _r(vrw * im.u(rg.spec_noise_factor)),
    }
    imu = {
        "rate_hz": im.choice(rg.imu_rate_hz),
        "errors": errors,
        "meta_spec": meta_spec,
        "quadrature_nodes": 6,
    }

    ini = _Draw(seed, "initial")
    initial = {
        "sigma": {
            "position_m": [_r(ini.u(rg.initial_position_sigma_m), 4) for _ in range(3)],
            "velocity_mps": [_r(ini.u(rg.initial_velocity_sigma_mps), 5) for _ in range(3)],
            "attitude_deg": [_r(ini.u(rg.initial_attitude_sigma_deg), 4) for _ in range(3)],
        },
        "perturb": True,
    }

    od = _Draw(seed, "odometer")
    odometer: dict[str, Any] = {
        "rate_hz": od.choice(rg.odometer_rate_hz),
        "scale_factor_error": _r(od.u(rg.odometer_scale_error)),
        "mounting_angles_deg": [_r(od.u(rg.odometer_mounting_deg), 5) for _ in range(3)],
        "noise_sigma_mps": _r(od.log(rg.odometer_noise_mps)),
        "counts_per_m": None,
    }
    quantized = od.rng.random() < rg.odometer_quantized
    counts = od.log(rg.odometer_counts_per_m)
    if quantized:
        odometer["counts_per_m"] = _r(counts, 3)

    mg = _Draw(seed, "magnetometer")
    dipole_f, dipole_i = dipole_field(origin["lat_deg"])
    f_true = dipole_f * mg.u(rg.field_factor)
    offset = mg.u(rg.inclination_offset_deg)
    i_true = math.copysign(min(max(abs(dipole_i) + offset, 0.0), 80.0), origin["lat_deg"])
    d_true = mg.u(rg.declination_deg)
    hard = mg.unit() * mg.u(rg.hard_iron_uT)
    soft = np.eye(3) + np.diag([mg.u(rg.soft_iron_diagonal) for _ in range(3)])
    for i in range(3):
        for j in range(3):
            if i != j:
                soft[i, j] = mg.u(rg.soft_iron_off_diagonal)
    magnetometer = {
        "rate_hz": mg.choice(rg.mag_rate_hz),
        "field_uT": _r(f_true, 4),
        "inclination_deg": _r(i_true, 4),
        "declination_deg": _r(d_true, 4),
        "hard_iron_uT": [_r(x, 4) for x in hard],
        "soft_iron": [[_r(x, 6) for x in row] for row in soft],
        "noise_sigma_uT": _r(mg.u(rg.mag_noise_uT), 4),
        "meta_field_uT": _r(f_true * (1.0 + mg.signed(rg.meta_field_error)), 4),
        "meta_inclination_deg": _r(i_true + mg.signed(rg.meta_inclination_error_deg), 4),
        "meta_declination_deg": _r(d_true + mg.signed(rg.meta_declination_error_deg), 4),
    }

    uw = _Draw(seed, "uwb")
    anchors: dict[str, list[float]] = {}
    for end, tag in ((0, "A"), (1, "B")):
        for i in range(uw.integer(rg.anchors_per_end)):
            while True:
                out = uw.u(rg.anchor_outward_m)
                across = uw.u(rg.anchor_across_m)
                if math.hypot(out, across) <= rg.anchor_max_distance_m:
                    break
            along = -out if end == 0 else length + out
            anchors[f"{tag}{i + 1}"] = [
                _r(along, 3),
                _r(across, 3),
                _r(uw.u(rg.anchor_height_m), 3),
            ]
    polling = uw.weighted(rg.uwb_polling)
    round_rate = uw.u(rg.uwb_round_rate_hz)
    total_rate = uw.u(rg.uwb_total_rate_hz)
    base_noise = uw.u(rg.uwb_noise_m)
    uwb: dict[str, Any] = {
        "anchors_frame": "face",
        "anchors": anchors,
        "tag_lever_arm_b_m": [_r(uw.u(rg.uwb_lever_arm_m), 3) for _ in range(3)],
        "polling": polling,
        "rate_hz": _r(total_rate if polling == "round_robin" else round_rate, 3),
        "max_range_m": _r(uw.u(rg.uwb_max_range_m), 3),
        "noise_sigma_m": _r(base_noise, 5),
        "noise_factors": {a: _r(uw.u(rg.uwb_noise_factor), 4) for a in anchors},
        "dropout_probability": _r(uw.u(rg.uwb_dropout_probability), 5),
    }

    su = _Draw(seed, "support")
    support = {
        "noise_sigma_m": _r(su.u(rg.support_noise_m), 5),
        "bias_m": _r(su.u(rg.support_bias_m), 5),
    }

    faults: list[dict[str, Any]] = []
    if hd is not None:
        faults, uwb_harsh = _harsh(hd, rg.harsh, static_start, duration)
        uwb.update(uwb_harsh)

    data: dict[str, Any] = {
        "name": family,
        "description": f"{FAMILIES.get(family, 'random longwall world')}, seed {seed}",
        "origin": origin,
        "static_start_s": _r(static_start, 3),
        "static_end_s": 30.0,
        "duration_s": _r(duration, 3),
        "face": face,
        "motion": motion,
        "imu": imu,
        "initial": initial,
        "odometer": odometer,
        "magnetometer": magnetometer,
        "uwb": uwb,
        "support": support,
        "faults": faults,
        "extra": {
            "world": {
                "family": family,
                "seed": seed,
                "harsh": harsh,
                "ranges": rg.model_dump(mode="json"),
            }
        },
    }
    if duration_s is None and see_push:
        data["duration_s"] = _r(_past_first_push(data, seed, duration, past_push, rg), 3)
    return scenario_from_mapping(data, f"{family} seed {seed}")


def _past_first_push(
    data: dict[str, Any], seed: int, duration: float, past: float, rg: WorldRanges
) -> float:
    """``duration``, or when the world's first AFC push comes after it, ``past`` seconds after
    that push (at most ``rg.max_duration_s``; the push is planned on the trajectory that
    :func:`fusion.sim.simulate.simulate` draws with the same seed)."""
    from fusion.sim.simulate import stream_rng
    from fusion.sim.trajectory import Trajectory

    plan = scenario_from_mapping({**data, "duration_s": None}, "world plan")
    pushes = Trajectory(plan, stream_rng(seed, "trajectory")).push_events
    if not pushes or pushes[0].t <= duration:
        return duration
    return max(duration, min(pushes[0].t + past, rg.max_duration_s))


def _harsh(
    h: _Draw, hr: HarshRanges, t0: float, duration: float
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Fault windows (uniform in time after the static start) and UWB NLOS/dropout settings."""
    earliest = t0 + 30.0

    def window(length: Range) -> tuple[float, float]:
        n = h.u(length)
        lo, hi = earliest, max(earliest + 1.0, duration - n - 1.0)
        start = h.u((lo, hi))
        return _r(start, 3), _r(min(start + n, duration - 0.5), 3)

    faults: list[dict[str, Any]] = []
    for _ in range(h.integer(hr.odometer_slips)):
        a, b = window(hr.slip_duration_s)
        ratio = h.u(hr.slip_ratio)
        if b - a > 4.0:
            faults.append(
                {"kind": "odometer_slip", "t_start": a, "t_end": b, "ramp_s": 1.0,
                 "slip_ratio": _r(ratio, 4)}
            )  # fmt: skip
    for _ in range(h.integer(hr.mag_interference)):
        a, b = window(hr.mag_interference_s)
        vec = h.unit() * h.u(hr.mag_interference_uT)
        if b - a > 4.0:
            faults.append(
                {"kind": "magnetic_interference", "t_start": a, "t_end": b, "ramp_s": 2.0,
                 "field_uT": [_r(x, 4) for x in vec]}
            )  # fmt: skip
    for _ in range(h.integer(hr.uwb_nlos_windows)):
        a, b = window(hr.uwb_nlos_window_s)
        if b > a:
            faults.append(
                {"kind": "uwb_nlos", "t_start": a, "t_end": b, "bias_m": list(hr.uwb_nlos_bias_m)}
            )
    sensors: list[Literal["odometer", "magnetometer", "uwb"]] = ["odometer", "magnetometer", "uwb"]
    for _ in range(h.integer(hr.dropouts)):
        a, b = window(hr.dropout_s)
        sensor = sensors[int(h.rng.integers(3))]
        if b > a:
            faults.append({"kind": "dropout", "t_start": a, "t_end": b, "sensor": sensor})
    uwb = {
        "nlos_probability": _r(h.u(hr.uwb_nlos_probability), 4),
        "nlos_mean_duration_s": _r(h.u(hr.uwb_nlos_episode_s), 3),
        "nlos_bias_range_m": list(hr.uwb_nlos_bias_m),
        "dropout_probability": _r(h.u(hr.uwb_dropout_probability), 4),
    }
    return faults, uwb


# ----------------------------------------------------------------------------- documentation
def _describe(value: Any) -> str:
    if isinstance(value, tuple):
        return f"{value[0]:g} – {value[1]:g}"
    if isinstance(value, dict):
        return ", ".join(f"{k} {v:g}" for k, v in value.items())
    if isinstance(value, list):
        return ", ".join(f"{v:g}" for v in value)
    return f"{value:g}"


def ranges_markdown(ranges: WorldRanges | None = None) -> str:
    """A Markdown table of the ranges (field, range, meaning), the harsh additions after it."""
    rg = ranges if ranges is not None else WorldRanges()
    lines = ["| parameter | range | meaning |", "|---|---|---|"]
    for name, field in type(rg).model_fields.items():
        if name == "harsh":
            continue
        lines.append(f"| `{name}` | {_describe(getattr(rg, name))} | {field.description or ''} |")
    lines += ["", "With `harsh`:", "", "| parameter | range | meaning |", "|---|---|---|"]
    for name, field in HarshRanges.model_fields.items():
        lines.append(
            f"| `{name}` | {_describe(getattr(rg.harsh, name))} | {field.description or ''} |"
        )
    return "\n".join(lines) + "\n"
