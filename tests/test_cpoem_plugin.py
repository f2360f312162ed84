"""CPOEM: the stations and their visits on a synthetic face (any traversal pattern, a
recording that stops anywhere), H against numerical differentiation, the stored points' noise,
the self-suspension, and the filter on ``seed000-carrier`` (accuracy against odometer + motion
constraint alone, consistency)."""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from fusion.aiding.cpoem import Cpoem, CpoemOptions
from fusion.attitude import dcm_from_euler
from fusion.config import FusionConfig, load_config, parse_config
from fusion.engine import Engine, RunResult
from fusion.metrics import interpolate_truth
from fusion.plugin import Measurement, MeasurementContext
from fusion.recording import (
    OdometerData,
    Recording,
    RecordingMeta,
    SupportData,
    TruthData,
    read_recording,
)
from fusion.sim.simulate import simulate
from tests.plugin_support import (
    group_rms,
    layout_with,
    normalized_errors,
    numerical_jacobian,
    perturbed_context,
    recording_meta,
    still_imu,
)

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

# A 10 m face at azimuth 30°: pass 1 out, terminal oblique cut (6 m back in, push, out again),
# pass 2 back to the start.
AZIMUTH = np.deg2rad(30.0)
ATTITUDE = dcm_from_euler(0.02, 0.0, AZIMUTH)  # rolled across the face, level along it
ALONG = ATTITUDE[:, 1]
ADVANCE_M = 1.0
PROFILE = [(2.0, 0.0), (20.0, 0.5), (2.0, 0.0), (12.0, -0.5), (4.0, 0.0), (12.0, 0.5)]
PROFILE += [(2.0, 0.0), (20.0, -0.5), (2.0, 0.0)]
PUSH_T = 38.0
TOLERANCE = {"end_tolerance_m": 2.0}
"""A stop within 2 m of a face end visits it (the default 5 m is half this short face)."""


def _meta() -> RecordingMeta:
    return recording_meta(
        initial={"attitude_deg": {"roll": 0, "pitch": 0, "yaw": 30}},
        odometer={"rate_hz": 10.0},
        face={
            "length_m": 10.0,
            "advance_m": ADVANCE_M,
            "ends_enu_m": [[0.0, 0.0, 0.0], (10.0 * ALONG).tolist()],
        },
    )


def _odometer(profile: list[tuple[float, float]]) -> OdometerData:
    """10 Hz odometer whose interval means follow the piecewise-constant speed ``profile``."""
    speeds = np.concatenate([np.full(round(d * 10), v) for d, v in profile])
    return OdometerData(t=0.1 * np.arange(1.0, speeds.size + 1.0), speed=speeds)


def _recording(
    profile: list[tuple[float, float]] = PROFILE, advances: tuple[float, ...] | None = (ADVANCE_M,)
) -> Recording:
    """The synthetic face; ``advances`` logged at PUSH_T (None: no support.csv)."""
    odo = _odometer(profile)
    support = None
    if advances is not None:
        support = SupportData(t=np.full(len(advances), PUSH_T), advance=np.array(advances))
    return Recording(
        path=None,
        meta=_meta(),
        imu=still_imu(odo.t[-1] + 1e-9),
        odometer=odo,
        support=support,
    )


def _true_position(rec: Recording, t: float, moved: float = ADVANCE_M) -> np.ndarray:
    """Truth of the synthetic face: mileage along the face line, shifted by ``moved`` along the
    body x axis (level along the face, rolled: square to the face line) after the push."""
    assert rec.odometer is not None
    dt = 0.1
    mileage = np.concatenate([[0.0], np.cumsum(rec.odometer.speed * dt)])
    along = np.interp(t, np.concatenate([[0.0], rec.odometer.t]), mileage)
    return along * ALONG + (moved * ATTITUDE[:, 0] if t > PUSH_T else 0.0)


def _context(
    plugin: Cpoem, rec: Recording, t: float, moved: float = ADVANCE_M
) -> MeasurementContext:
    """The truth as the SINS state, with the covariance of a filter that knows its position
    and attitude to a centimetre and a milliradian."""
    layout = layout_with(plugin.state_blocks())
    return perturbed_context(
        layout,
        np.zeros(layout.dim),
        t=t,
        position_enu=_true_position(rec, t, moved),
        c_b_n=ATTITUDE,
        covariance=1e-6 * np.eye(layout.dim) + np.diag([0.0] * 6 + [1e-4] * 3 + [0.0] * 6),
    )


@dataclass(frozen=True)
class Check:
    """One check of the walk: time, the station visited (None: no visit), the measurement."""

    t: float
    station: int | None
    measurement: Measurement | None


def _walk(
    plugin: Cpoem, rec: Recording, moved: float = ADVANCE_M, stop: int | None = None
) -> list[Check]:
    """Every check up to ``stop`` with the true SINS state, measured then stored (as the engine
    calls them)."""
    out = []
    for k, t in enumerate(plugin.epochs()[:stop]):
        ctx = _context(plugin, rec, float(t), moved)
        m = plugin.measure(k, ctx)
        visit = plugin._visit
        plugin.store(k, ctx)
        out.append(Check(float(t), None if visit is None else visit.station, m))
    return out


def test_stations_bounded_by_the_face_and_visits_of_a_cycle() -> None:
    """Stations every 2 m between the surveyed ends, three stored-error variables each,
    whatever the travel; pass 1 stores its crossings; the arrival at the far end is measured
    against the survey; the crossings back in along the bend wait for the push; after it, each
    crossing and end stop is measured against its previous visit plus the advance (z = 0 at
    the truth); every face-end stop closes a smoothing window."""
    rec = _recording()
    plugin = Cpoem("cpoem", CpoemOptions(**TOLERANCE), rec)
    np.testing.assert_allclose(plugin.stations, [0, 2, 4, 6, 8, 10])
    assert plugin.stored_errors() == 3 * 6
    assert plugin.epochs().size == plugin.store_epochs().size == round(76.0 * 5)
    checks = _walk(plugin, rec)
    visits = [
        (round(c.t, 1), c.station, c.measurement is not None)
        for c in checks
        if c.station is not None
    ]
    stations = [station for _, station, _ in visits]
    assert stations == [1, 2, 3, 4, 5, 3, 4, 5, 4, 3, 2, 1, 0]
    measured = [station for _, station, m in visits if m]
    assert measured == [5, 3, 4, 5, 4, 3, 2, 1, 0]  # not pass 1, not the bend before the push
    for c in checks:
        if c.measurement is not None:
            assert c.measurement.z.shape == (2,)
            np.testing.assert_allclose(c.measurement.z, 0.0, atol=1e-5)
    ends = [t for t, station, _ in visits if station in (0, 5)]
    assert [plugin.window_end_due(t) for t in ends] == [True] * len(ends)
    assert not plugin.window_end_due(ends[-1] + 1.0)


@pytest.mark.parametrize("direction", ["face", "attitude"])
@pytest.mark.parametrize("station", [2, 0])
def test_h_matches_numerical_differentiation(direction: str, station: int) -> None:
    """z(δx) − z(0) = H δx to first order at a pass-2 station and at the face end it returns
    to, through a perturbed SINS state."""
    rec = _recording()
    options = CpoemOptions(advance_direction=direction, **TOLERANCE)
    plugin = Cpoem("cpoem", options, rec)
    checks = _walk(copy.deepcopy(plugin), rec)
    index = max(k for k, c in enumerate(checks) if c.station == station)
    _walk(plugin, rec, stop=index)
    layout = layout_with(plugin.state_blocks())
    t = checks[index].t
    # 3 cm past the station along the travel, so that a perturbed position crosses it too
    p_true = _true_position(rec, t) - 0.03 * ALONG
    c_b_n = dcm_from_euler(0.02, 0.015, AZIMUTH + 0.01)  # a pitch and a yaw off the face normal

    def measure(dx: np.ndarray) -> Measurement:
        probe = copy.deepcopy(plugin)
        m = probe.measure(
            index, perturbed_context(layout, dx, t=t, position_enu=p_true, c_b_n=c_b_n)
        )
        assert m is not None
        return m

    steps = np.array([1e-3] * 3 + [1e-5] * 3 + [1e-2] * 3 + [0.0] * 6)
    numeric = numerical_jacobian(lambda dx: measure(dx).z, layout.dim, steps)
    m = measure(np.zeros(layout.dim))
    # δp is applied along the origin's ENU axes, 1.6e-6 rad off the local ones at 10 m
    np.testing.assert_allclose(m.H, numeric, atol=1e-5)
    assert np.all(np.linalg.eigvalsh(m.R) > 0)
    if direction == "face":  # the heading error does not turn the advance square to the face
        np.testing.assert_allclose(m.H[0, 5], 0.0, atol=1e-12)
    else:  # eq. 6: across row −d nᵀ (u×) = d (u × n)ᵀ, u the body x axis
        u = c_b_n[:, 0]
        np.testing.assert_allclose(
            m.H[0, 3:6], ADVANCE_M * np.cross(u, plugin.face.normal), atol=1e-6
        )


def test_stored_noise_face_end_chain_and_refresh() -> None:
    """A face end's chain is the survey plus the advance, its covariance growing by the advance
    and line noise. A station's noise carries its stored error (its three stored-error
    variables, mixed by −T R_local, T across and up) with its stored covariance counted once;
    refreshed by the smoother, whose smoothed error's correlation is unknown, it counts n times
    (k = n) as independent noise."""
    rec = _recording()
    opts = CpoemOptions(**TOLERANCE)
    plugin = Cpoem("cpoem", opts, rec)
    checks = _walk(copy.deepcopy(plugin), rec)
    second_far_end = [k for k, c in enumerate(checks) if c.station == 5][-1]
    _walk(plugin, rec, stop=second_far_end + 1)
    _, p, cov = plugin.stored_points()
    np.testing.assert_allclose(p[5], 10.0 * ALONG + ADVANCE_M * ATTITUDE[:, 0], atol=1e-9)
    expected = opts.survey_sigma_m**2 + 2 * opts.geometry_sigma_m**2
    assert np.trace(cov[5]) == pytest.approx(3 * expected + opts.advance_sigma_m**2)
    station = next(k for k, c in enumerate(checks) if k > second_far_end and c.station == 4)
    _walk(plugin, rec, stop=station)  # measure is reached below
    plugin2 = copy.deepcopy(plugin)
    ctx = _context(plugin, rec, checks[station].t)
    m = plugin.measure(station, ctx)
    assert m is not None and m.correlated is not None
    np.testing.assert_array_equal(m.correlated.columns, [12, 13, 14])
    rows = np.vstack([plugin.face.normal, [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(m.correlated.mixing, -rows, atol=1e-5)
    stored_cov = rows @ cov[4] @ rows.T
    assert np.all(np.linalg.eigvalsh(m.R - stored_cov) > 0)  # advance, line deviation
    t_stored = plugin2.stored_points()[0][4]
    times = np.array([t_stored - 1.0, t_stored + 1.0])
    assert plugin2.refresh_points(times, np.stack([p[4], p[4]]), np.stack([cov[4], cov[4]])) == 1
    refreshed = plugin2.measure(station, ctx)
    assert refreshed is not None and refreshed.correlated is None
    np.testing.assert_allclose(refreshed.R - m.R, 3 * stored_cov, atol=1e-6)  # k = n = 4


def test_refresh_points_replaces_the_points_visited_in_the_window() -> None:
    rec = _recording()
    plugin = Cpoem("cpoem", CpoemOptions(**TOLERANCE), rec)
    _walk(plugin, rec)
    stored_t, before, _ = plugin.stored_points()
    times = np.linspace(stored_t[1:5].min() - 1.0, stored_t[1:5].max() + 1.0, 50)
    offset = np.array([0.1, -0.2, 0.05])
    smoothed = np.array([_true_position(rec, t) + offset for t in times])
    covariances = np.broadcast_to(0.01**2 * np.eye(3), (times.size, 3, 3))
    assert plugin.refresh_points(times, smoothed, covariances) == 4
    _, after, cov = plugin.stored_points()
    np.testing.assert_allclose(after[1:5], before[1:5] + offset, atol=1e-9)
    np.testing.assert_allclose(cov[1:5], np.broadcast_to(0.01**2 * np.eye(3), (4, 3, 3)))
    np.testing.assert_array_equal(after[[0, 5]], before[[0, 5]])  # surveyed ends untouched
    assert plugin.refresh_points(times - 100.0, smoothed, covariances) == 0
    plugin.receive_smoothed(times, smoothed - offset, covariances)
    np.testing.assert_allclose(plugin.stored_points()[1][1:5], before[1:5], atol=1e-9)
    with pytest.raises(ValueError, match="strictly increasing"):
        plugin.refresh_points(times[::-1], smoothed, covariances)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        plugin.refresh_points(times, smoothed[:, :2], covariances)


def test_any_traversal_pattern_and_a_recording_that_stops_mid_pass() -> None:
    """Stops and a 1 m back-up mid-face (a re-cut), a cleaning run back over the same line
    before the push, and data ending in the middle of a pass: every measured visit is the same
    place of the same line (z = 0 at the truth), and the end of the data is no face end."""
    profile = [(2.0, 0.0), (6.0, 0.5), (5.0, 0.0), (2.0, -0.5), (2.0, 0.5), (12.0, 0.5)]
    profile += [(3.0, 0.0), (18.0, -0.5), (2.0, 0.0), (2.0, 0.0), (20.0, 0.5), (2.0, 0.0)]
    profile += [(11.0, -0.5)]  # data end 5.5 m into the last pass
    rec = _recording(profile)
    plugin = Cpoem("cpoem", CpoemOptions(**TOLERANCE), rec)
    checks = _walk(plugin, rec)
    measured = [c for c in checks if c.measurement is not None]
    assert len(measured) >= 8
    for c in measured:
        np.testing.assert_allclose(c.measurement.z, 0.0, atol=1e-5)  # type: ignore[union-attr]
    assert checks[-1].station is None or checks[-1].station not in (0, 5)


def test_waits_without_support_and_suspends_itself_when_the_model_does_not_fit() -> None:
    """Without support.csv no push is known: nothing is measured. When the line moves by 0.5 m
    at a push logged as 0 (a push the rams did not log), the learned line deviation soon
    exceeds max_geometry_sigma_m and CPOEM stops measuring instead of pulling the filter."""
    rec = _recording(advances=None)
    assert all(
        c.measurement is None for c in _walk(Cpoem("cpoem", CpoemOptions(**TOLERANCE), rec), rec)
    )
    unlogged = _recording(advances=(0.0,))
    plugin = Cpoem(
        "cpoem", CpoemOptions(adaptive_window=2, max_geometry_sigma_m=0.2, **TOLERANCE), unlogged
    )
    checks = _walk(plugin, unlogged, moved=0.5)
    after_push = [c for c in checks if c.station not in (None, 0, 5) and c.t > PUSH_T]
    assert any(c.measurement is not None for c in after_push)
    assert plugin.suspended and after_push[-1].measurement is None


def test_bad_input_is_named() -> None:
    rec = _recording()
    with pytest.raises(ValueError, match=r"odometer\.csv"):
        Cpoem("cpoem", CpoemOptions(**TOLERANCE), replace(rec, odometer=None))
    no_face = rec.meta.model_copy(update={"face": None})
    with pytest.raises(ValueError, match=r"face\.ends_enu_m"):
        Cpoem("cpoem", CpoemOptions(**TOLERANCE), replace(rec, meta=no_face))
    with pytest.raises(ValueError, match="interval_m"):
        Cpoem("cpoem", CpoemOptions(interval_m=6.0, **TOLERANCE), rec)


# --------------------------------------------------------------------------------------------
# The filter on seed000-carrier (slow: simulated recordings, several seeds)

# seed000-carrier shortened for Monte Carlo (dwells, maneuvers, speeds; 4 cycles kept) with a
# MEMS grade whose heading does not run away during the static start (seed 002 Table 1).
SHORT_MEMS = [
    "imu.grade=seed002-mems",
    "imu.rate_hz=50",
    "static_start_s=20",
    "static_end_s=5",
    "face.end_dwell_s=[3,6]",
    "face.push_dwell_s=[5,10]",
    "face.maneuver_speed_mpm=16",
    "motion.speed_mpm=[20,30]",
]
MC_SEEDS = range(20)  # with the simulator's noise: its position RMS(err/σ) over 0–9 is 1.65
SHIPPED_SEEDS = range(3)  # the shipped configurations: position RMS(err/σ) ≤ 0.88, whitened
# ≤ 0.47, cycles 2–4 cut 5–30× on each of seeds 0–5 (bounds 1.5, 1.3, 2×)
PRESET_SEEDS = range(1)


@dataclass(frozen=True)
class CarrierRun:
    """One recording fused with the shipped configurations, with and without CPOEM."""

    across_baseline: np.ndarray  # (4,) RMS error across the face, cycles 1–4, sins_od_ckf.yaml
    across_cpoem: np.ndarray  # (4,) the same with configs/sins_od_cpoem.yaml
    squared_normalized: np.ndarray  # (N, 3) (err/σ)² of the CPOEM run
    nis_dof: tuple[float, int]  # Σ NIS and Σ m of all CPOEM updates


@dataclass(frozen=True)
class MatchedRun:
    """One recording fused with the simulator's noise (:func:`_matched_config`)."""

    ratios: np.ndarray  # (M, 9) err/σ of velocity, attitude, position (every 10th epoch)
    nis_dof: tuple[float, int]  # Σ NIS and Σ m of all CPOEM updates


def _fuse(rec: Recording, config: str | FusionConfig) -> tuple[Engine, RunResult]:
    engine = Engine(
        config if isinstance(config, FusionConfig) else load_config(CONFIGS / config), rec
    )
    return engine, engine.run()


def _matched_config() -> FusionConfig:
    """configs/sins_od_cpoem.yaml with the noise the simulated SHORT_MEMS carrier has: its IMU
    grade's biases are constant (no in-run instability), the odometer's speed noise is the
    scenario's 3 mm/s, and the body's lateral and vertical velocity (the carrier's vibration
    once the mounting is estimated) is 2.5–4.4 mm/s RMS in truth.csv (seeds 0 and 5), taken as
    4 mm/s, at the simulator's 10 Hz readings (the encoder is not quantized: no need to combine
    them), without the odometer's learned noise (never below σ, it can only add); its AFC line
    deviates from the previous one plus the advance by ≈ 4 mm (0.05 m of waviness whose phase
    drifts by 1.2 m / 15 m per advance), its lines' slope across and up is ≈ 0.015 (waviness,
    floor undulation and slope), its face ends are exact and its push rams read the advance to
    7 mm. ``filter.observable_force`` is off: the carrier's accelerations here are known to
    many σ, and the heading information they carry is withheld by that option (with it the
    whitened RMS was 0.64). ``filter.invariant_error`` is none for the same reason: with
    biases that do not wander, the Earth's rate and the carrier's turns do tell the heading
    here, and the shipped invariant error withholds it (with it the whitened RMS was 0.54, as
    with the observability-constrained EKF it replaced). The shipped face heading is left out:
    its σ is a real face's snake and waviness, which the carrier's track has little of, and
    with it the whitened RMS was 0.70. The shipped values are those of a real face:
    pessimistic here."""
    data = load_config(CONFIGS / "sins_od_cpoem.yaml").model_dump()
    data["plugins"] = [p for p in data["plugins"] if p["type"] != "face_heading"]
    data["imu"].update(gyro_bias_instability_deg_h=0.0, accel_bias_instability_mg=0.0)
    data["streams"]["odometer_max_rate_hz"] = None
    data["filter"]["observable_force"] = False
    data["filter"]["invariant_error"] = "none"
    data["plugins"][0].update(
        sigma_speed_mps=0.003,
        sigma_lateral_mps=0.004,
        sigma_vertical_mps=0.004,
        adaptive_noise=False,
    )
    data["plugins"][1].update(
        geometry_sigma_m=0.005,
        line_slope_sigma=0.015,
        survey_sigma_m=0.001,
        advance_sigma_m=0.007,
    )
    return parse_config(data)


def _squared_normalized(result: RunResult, truth: TruthData) -> np.ndarray:
    inside, position, *_ = interpolate_truth(truth, result.solution.t)
    err = result.solution.position[inside] - position
    return (err / result.solution.sigma_position[inside]) ** 2


def _nis_dof(result: RunResult) -> tuple[float, int]:
    log = result.innovations["cpoem"]
    return float(log.nis.sum()), int(log.dof.sum())


def _across_per_cycle(result: RunResult, rec: Recording, plugin: Cpoem) -> np.ndarray:
    """RMS position error across the face (the surveyed face line's normal) in cycles 1–4."""
    assert rec.truth is not None
    inside, position, *_ = interpolate_truth(rec.truth, result.solution.t)
    across = (result.solution.position[inside] - position) @ plugin.face.normal
    cycle = np.interp(result.solution.t[inside], rec.truth.t, rec.truth.cycle).round()
    return np.array([np.sqrt(np.mean(across[cycle == c] ** 2)) for c in (1, 2, 3, 4)])


def _carrier_run(rec: Recording) -> CarrierRun:
    """The shipped runs of one recording."""
    assert rec.truth is not None
    _, base = _fuse(rec, "sins_od_ckf.yaml")
    engine, fused = _fuse(rec, "sins_od_cpoem.yaml")
    plugin = engine.plugins[1]
    assert isinstance(plugin, Cpoem)
    return CarrierRun(
        across_baseline=_across_per_cycle(base, rec, plugin),
        across_cpoem=_across_per_cycle(fused, rec, plugin),
        squared_normalized=_squared_normalized(fused, rec.truth),
        nis_dof=_nis_dof(fused),
    )


@pytest.fixture(scope="module")
def mems_recordings(tmp_path_factory: pytest.TempPathFactory) -> list[Recording]:
    root = tmp_path_factory.mktemp("cpoem_mems")
    return [
        read_recording(simulate("seed000-carrier", root / str(s), seed=s, overrides=SHORT_MEMS))
        for s in MC_SEEDS
    ]


@pytest.fixture(scope="module")
def mems_runs(mems_recordings: list[Recording]) -> list[CarrierRun]:
    return [_carrier_run(mems_recordings[seed]) for seed in SHIPPED_SEEDS]


@pytest.fixture(scope="module")
def matched_runs(mems_recordings: list[Recording]) -> list[MatchedRun]:
    runs = []
    for rec in mems_recordings:
        result, ratios = normalized_errors(_matched_config(), rec, lambda i, _: i % 10 == 0)
        runs.append(MatchedRun(ratios, _nis_dof(result)))
    return runs


@pytest.fixture(scope="module")
def preset_runs(tmp_path_factory: pytest.TempPathFactory) -> list[CarrierRun]:
    root = tmp_path_factory.mktemp("cpoem_preset")
    return [
        _carrier_run(read_recording(simulate("seed000-carrier", root / str(seed), seed=seed)))
        for seed in PRESET_SEEDS
    ]


@pytest.mark.slow
@pytest.mark.parametrize("grade", ["seed002-mems", "mti-g-700"])
def test_cpoem_reduces_the_error_across_the_face(
    grade: str, mems_runs: list[CarrierRun], preset_runs: list[CarrierRun]
) -> None:
    """CPOEM against odometer + motion constraint alone (configs/sins_od_ckf.yaml), RMS error
    across the face averaged over the seeds: cycles 2–4, measured against earlier visits, at
    most half; with the MEMS grade (three short runs) every one of them; with the preset's
    MTi-G-700 (one full run), whose 0.2 °/s turn-on gyro bias turns the heading by tens of
    degrees in the first pass, the first correction (cycle 2) is only partial, so each of
    them must merely be lower. Along the face CPOEM measures nothing (fusion/aiding/cpoem.py)."""
    runs, per_cycle = (mems_runs, 0.5) if grade == "seed002-mems" else (preset_runs, 1.0)
    base = np.mean([r.across_baseline for r in runs], axis=0)
    fused = np.mean([r.across_cpoem for r in runs], axis=0)
    print(
        f"{grade}: across RMS per cycle, SINS/OD {np.round(base, 3)}, + CPOEM {np.round(fused, 3)}"
    )
    assert np.all(fused[1:] < per_cycle * base[1:])
    assert fused[1:].mean() <= 0.5 * base[1:].mean()


@pytest.mark.slow
def test_consistency_over_20_seeds(
    mems_runs: list[CarrierRun], matched_runs: list[MatchedRun]
) -> None:
    """With the noise the simulator used (:func:`_matched_config`), pooled over 20 seeds: the
    CPOEM innovations' whitened RMS in [0.6, 1.3] and RMS(err/σ) < 1.5 for velocity, attitude
    and position (at every tenth odometer epoch). The lower bound is issue 29's: it was 0.7
    until the low-passed force in F followed the feedback (e861cae), which took the whitened
    RMS from 0.704 to 0.628 with the state's RMS(err/σ) the same to 2 % (1.15 / 1.14 / 1.36):
    the force a removed tilt left in the low-pass had told this filter a heading too. The stored
    points' errors are correlated with the filter's (fusion/aiding/cpoem.py); taken as
    independent noise, R × n (the weighting before the cross-covariances were tracked) gave a
    whitened RMS of 0.20. With the shipped
    configuration, pessimistic on this simulator, the position must still be within 1.5σ and
    the innovations not optimistic (whitened ≤ 1.3), over the first three seeds."""
    nis, dof = np.sum([r.nis_dof for r in matched_runs], axis=0)
    whitened = np.sqrt(nis / dof)  # RMS of the whitened components (‖w‖² = NIS)
    ratios = group_rms(np.concatenate([r.ratios for r in matched_runs]))
    print(f"simulator's noise: CPOEM whitened RMS {whitened:.3f}, RMS(err/σ) {ratios}")
    assert 0.6 <= whitened <= 1.3
    assert max(ratios.values()) < 1.5
    squared = np.concatenate([r.squared_normalized for r in mems_runs])
    position = np.sqrt(squared.mean(axis=0))
    nis, dof = np.sum([r.nis_dof for r in mems_runs], axis=0)
    whitened = np.sqrt(nis / dof)
    print(f"shipped: CPOEM whitened RMS {whitened:.3f}, position RMS(err/σ) {position}")
    assert np.all(position < 1.5)
    assert whitened <= 1.3


def test_a_recording_before_the_first_push_runs_without_support_csv(tmp_path: Path) -> None:
    """The start of a shift, before any AFC push: no support.csv. Every configuration with
    CPOEM refused such a recording; now CPOEM records its stations, waits for a push and
    measures nothing."""
    path = simulate("seed000-carrier", tmp_path / "rec", seed=0, overrides=["duration_s=200"])
    (path / "support.csv").unlink()
    rec = read_recording(path)
    assert rec.support is None
    result = Engine(load_config(CONFIGS / "sins_od_cpoem_rts.yaml"), rec).run()
    assert result.innovations["cpoem"].count == 0
    assert result.smoothed is not None and np.all(np.isfinite(result.smoothed.position))
