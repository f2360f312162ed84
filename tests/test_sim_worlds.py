"""Random worlds (fusion.sim.worlds) and the simulator features they draw from."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion.cli import main as fusion_main
from fusion.recording import read_recording, validate_recording
from fusion.sim.scenario import PATTERN_RUNS, Scenario
from fusion.sim.simulate import list_scenarios, load_scenario, simulate, stream_rng
from fusion.sim.trajectory import AfcLine, Trajectory
from fusion.sim.worlds import (
    FAMILIES,
    WorldRanges,
    dipole_field,
    draw_world,
    family_world,
    ranges_markdown,
)

RANGES = WorldRanges()


def _files(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(root.iterdir())}


def _csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Times and second column (as text) of a CSV file, without the reader."""
    rows = [line.split(",") for line in path.read_text().splitlines()[1:]]
    return np.array([float(r[0]) for r in rows]), np.array([r[1] for r in rows])


def _inside(value: float, r: tuple[float, float], tol: float = 1e-6) -> bool:
    return r[0] - tol <= value <= r[1] + tol


# ----------------------------------------------------------------------------- determinism
def test_same_seed_same_world_and_bytes_different_seeds_differ(tmp_path: Path) -> None:
    assert draw_world(3) == draw_world(3)
    assert draw_world(3) != draw_world(4)
    assert draw_world(3, harsh=True) == draw_world(3, harsh=True)
    ov = ["duration_s=90"]
    a = simulate("longwall-random", tmp_path / "a", seed=5, overrides=ov)
    b = simulate("longwall-random", tmp_path / "b", seed=5, overrides=[*ov, "chunk_s=37"])
    c = simulate("longwall-random", tmp_path / "c", seed=6, overrides=ov)
    fa, fb, fc = _files(a), _files(b), _files(c)
    # byte-identical, whatever the chunking (which meta.yaml records in the world's scenario)
    assert fa == {**fb, "meta.yaml": fb["meta.yaml"].replace(b"chunk_s: 37.0", b"chunk_s: 600.0")}
    assert fa["imu.csv"] != fc["imu.csv"] and fa["meta.yaml"] != fc["meta.yaml"]
    assert set(fa) == {
        "meta.yaml",
        "imu.csv",
        "truth.csv",
        "odometer.csv",
        "magnetometer.csv",
        "uwb.csv",
        "support.csv",
    }
    assert validate_recording(a) == []


def test_meta_records_the_world_and_reproduces_it(tmp_path: Path) -> None:
    out = simulate("longwall-random-harsh", tmp_path / "h", seed=2, overrides=["duration_s=80"])
    meta = read_recording(out).meta
    world = meta.extra["world"]
    assert world["family"] == "longwall-random-harsh" and world["seed"] == 2 and world["harsh"]
    assert WorldRanges.model_validate(world["ranges"]) == RANGES
    sc = Scenario.model_validate(world["scenario"])
    assert sc.duration_s == 80.0 and sc.faults
    again = simulate(sc.model_copy(update={"extra": {}}), tmp_path / "r", seed=meta.extra["seed"])
    fa, fr = _files(out), _files(again)
    assert {k: v for k, v in fa.items() if k != "meta.yaml"} == {
        k: v for k, v in fr.items() if k != "meta.yaml"
    }


def test_ranges_round_trip_and_document() -> None:
    assert WorldRanges.from_yaml(RANGES.to_yaml()) == RANGES
    custom = WorldRanges(face_length_m=(80.0, 90.0), pattern={"three_pass": 1.0})
    assert WorldRanges.from_yaml(custom.to_yaml()) == custom
    with pytest.raises(ValueError, match="lo <= hi"):
        WorldRanges(face_length_m=(90.0, 80.0))
    text = ranges_markdown()
    for name in WorldRanges.model_fields:
        if name != "harsh":
            assert f"`{name}`" in text
    assert "`odometer_slips`" in text
    w = draw_world(0, custom)
    assert w.face is not None and 80.0 <= w.face.length_m <= 90.0
    assert w.face.pattern == "three_pass"


def test_families_are_listed_and_load() -> None:
    listed = dict(list_scenarios())
    assert set(FAMILIES) <= set(listed)
    short = load_scenario("longwall-random-short", seed=4)
    assert 300.0 <= (short.duration_s or 0) <= 600.0
    assert load_scenario("longwall-random", ["duration_s=700"], seed=4).duration_s == 700.0
    assert family_world("longwall-random", 4) == load_scenario("longwall-random", seed=4)
    assert not draw_world(4).faults and draw_world(4, harsh=True).faults


# ----------------------------------------------------------------------------- ranges
def test_every_drawn_parameter_lies_in_its_range() -> None:
    rg = RANGES
    patterns, pollings, quantized, hemispheres = set(), set(), 0, set()
    for seed in range(50):
        w = draw_world(seed)
        f, m, imu, od, mag, uwb = w.face, w.motion, w.imu, w.odometer, w.magnetometer, w.uwb
        assert f is not None and imu.errors is not None and imu.meta_spec is not None
        assert od is not None and mag is not None and uwb is not None and w.support is not None
        assert w.duration_s is not None
        assert _inside(w.duration_s, rg.duration_s) or (
            rg.duration_s[1] <= w.duration_s <= rg.max_duration_s
        )
        assert _inside(w.static_start_s, rg.static_start_s)
        assert _inside(abs(w.origin.lat_deg), rg.lat_deg)
        assert _inside(w.origin.lon_deg, rg.lon_deg) and _inside(w.origin.height_m, rg.height_m)
        hemispheres.add(math.copysign(1.0, w.origin.lat_deg))
        assert _inside(f.length_m, rg.face_length_m) and _inside(f.azimuth_deg, rg.azimuth_deg)
        assert _inside(f.advance_m, rg.advance_m)
        patterns.add(f.pattern)
        assert f.push_after_run is not None and f.push_after_run < len(PATTERN_RUNS[f.pattern])
        assert all(_inside(abs(x), rg.end_skew_deg) for x in f.end_skew_deg)
        assert _inside(f.end_jitter_m, rg.end_jitter_m)
        assert _inside(f.line_deviation.sigma_m, rg.line_deviation_m)
        assert _inside(f.line_deviation.persistence, rg.line_deviation_persistence)
        assert _inside(f.waviness.amplitude_m, rg.waviness_m)
        assert _inside(f.floor.slope_along_deg, rg.floor_slope_along_deg)
        assert _inside(f.floor.dip_across_deg, rg.floor_dip_across_deg)
        assert _inside(f.floor.undulation_m, rg.floor_undulation_m)
        assert _inside(f.recut.probability, rg.recut_probability)
        assert m.speed_mpm[0] <= m.speed_mpm[1] and m.clean_speed_mpm is not None
        assert all(_inside(v, rg.cut_speed_mpm) for v in m.speed_mpm)
        assert all(_inside(v, rg.clean_speed_mpm) for v in m.clean_speed_mpm)
        vib = m.vibration
        assert all(_inside(v, rg.vibration_freq_hz) for v in vib.freq_hz)
        assert _inside(vib.linear_mps2, rg.vibration_linear_mps2)
        assert _inside(vib.angular_dps, rg.vibration_angular_dps)
        assert rg.vibration_components[0] <= vib.components <= rg.vibration_components[1]
        assert _inside(m.stops.rate_per_hour, rg.stops_per_hour)
        e = imu.errors
        assert _inside(e.gyro_bias_deg_h, rg.gyro_bias_deg_h)
        assert _inside(e.accel_bias_mg, rg.accel_bias_mg)
        assert _inside(e.gyro_arw_deg_rth, rg.gyro_arw_deg_rth)
        assert _inside(e.accel_vrw_mg_rthz, rg.accel_vrw_mg_rthz)
        assert _inside(e.gyro_bias_instability_deg_h, rg.gyro_bias_instability_deg_h)
        assert _inside(e.accel_bias_instability_mg, rg.accel_bias_instability_mg)
        assert _inside(e.gyro_scale_factor_ppm, rg.scale_factor_ppm)
        assert _inside(e.gyro_misalignment_mrad, rg.misalignment_mrad)
        s = imu.meta_spec
        assert _inside(s.gyro_bias_deg_h, rg.spec_gyro_bias_deg_h)
        assert _inside(s.accel_bias_mg, rg.spec_accel_bias_mg)
        assert _inside(s.gyro_arw_deg_rth / e.gyro_arw_deg_rth, rg.spec_noise_factor, 1e-3)
        assert imu.rate_hz in rg.imu_rate_hz
        sig = w.initial.sigma
        assert all(_inside(x, rg.initial_attitude_sigma_deg) for x in sig.attitude_deg)
        assert all(_inside(x, rg.initial_position_sigma_m) for x in sig.position_m)
        assert od.rate_hz in rg.odometer_rate_hz
        assert _inside(od.scale_factor_error, rg.odometer_scale_error)
        assert all(_inside(x, rg.odometer_mounting_deg) for x in od.mounting_angles_deg)
        assert _inside(od.noise_sigma_mps, rg.odometer_noise_mps)
        if od.counts_per_m is not None:
            quantized += 1
            assert _inside(od.counts_per_m, rg.odometer_counts_per_m, 1e-3)
        assert mag.rate_hz in rg.mag_rate_hz
        assert _inside(mag.declination_deg, rg.declination_deg)
        dipole_f, dipole_i = dipole_field(w.origin.lat_deg)
        assert _inside(mag.field_uT / dipole_f, rg.field_factor, 1e-4)
        offset = abs(mag.inclination_deg) - abs(dipole_i)
        assert _inside(offset, rg.inclination_offset_deg, 1e-3) or abs(mag.inclination_deg) == 80
        assert mag.inclination_deg * w.origin.lat_deg > 0.0  # down in the north, up in the south
        assert mag.meta_field_uT is not None and mag.meta_declination_deg is not None
        assert mag.meta_inclination_deg is not None
        assert _inside(abs(mag.meta_field_uT / mag.field_uT - 1.0), rg.meta_field_error, 1e-4)
        d_err = abs(mag.meta_declination_deg - mag.declination_deg)
        assert _inside(d_err, rg.meta_declination_error_deg, 1e-3)
        i_err = abs(mag.meta_inclination_deg - mag.inclination_deg)
        assert _inside(i_err, rg.meta_inclination_error_deg, 1e-3)
        assert _inside(float(np.linalg.norm(mag.hard_iron_uT)), rg.hard_iron_uT, 1e-3)
        soft = np.asarray(mag.soft_iron)
        assert all(_inside(x - 1.0, rg.soft_iron_diagonal) for x in np.diag(soft))
        off = soft[~np.eye(3, dtype=bool)]
        assert all(_inside(x, rg.soft_iron_off_diagonal) for x in off)
        assert uwb.anchors_frame == "face"
        pollings.add(uwb.polling)
        ends = {"A": 0.0, "B": f.length_m}
        for end in "AB":
            mine = {k: v for k, v in uwb.anchors.items() if k.startswith(end)}
            assert rg.anchors_per_end[0] <= len(mine) <= rg.anchors_per_end[1]
            for along, across, height in mine.values():
                assert math.hypot(along - ends[end], across) <= rg.anchor_max_distance_m + 1e-3
                assert _inside(height, rg.anchor_height_m, 1e-3)
        assert all(_inside(x, rg.uwb_noise_factor, 1e-3) for x in uwb.noise_factors.values())
        assert _inside(uwb.noise_sigma_m, rg.uwb_noise_m)
        rate_range = rg.uwb_total_rate_hz if uwb.polling == "round_robin" else rg.uwb_round_rate_hz
        assert _inside(uwb.rate_hz, rate_range, 1e-3)
        assert _inside(uwb.max_range_m, rg.uwb_max_range_m, 1e-3)
        assert uwb.nlos_probability == 0.0 and not w.faults
        assert _inside(w.support.noise_sigma_m, rg.support_noise_m)
    assert patterns == {"bidirectional", "unidirectional", "three_pass"}
    assert pollings == {"staggered", "round_robin", "simultaneous"}
    assert hemispheres == {1.0, -1.0}
    assert 10 <= quantized <= 40


def test_harsh_worlds_add_faults_within_the_recording() -> None:
    for seed in range(10):
        w = draw_world(seed, duration_s=1200.0, harsh=True)
        assert w.uwb is not None and w.imu.errors is not None
        p_nlos = w.uwb.nlos_probability
        assert isinstance(p_nlos, float) and _inside(p_nlos, RANGES.harsh.uwb_nlos_probability)
        kinds = {f.kind for f in w.faults}
        assert {"odometer_slip", "magnetic_interference"} <= kinds
        assert all(w.static_start_s < f.t_start < f.t_end <= 1200.0 for f in w.faults)
        calm = draw_world(seed, duration_s=1200.0)
        assert calm.imu.errors is not None
        assert w.imu.errors.gyro_arw_deg_rth > calm.imu.errors.gyro_arw_deg_rth


# ----------------------------------------------------------------------------- features
def _face(overrides: list[str], seed: int = 1) -> tuple[Trajectory, np.ndarray, np.ndarray]:
    sc = load_scenario(
        "longwall-200m",
        [
            "face.length_m=30",
            "face.bend_length_m=8",
            "face.sump_overrun_m=3",
            "motion.stops.rate_per_hour=0",
            "motion.vibration=false",
            "motion.speed_mpm=[8, 10]",
            "motion.clean_speed_mpm=[12, 15]",
            *overrides,
        ],
    )
    traj = Trajectory(sc, stream_rng(seed, "trajectory"))
    t = np.arange(0.0, traj.duration, 0.25)
    st = traj.evaluate(t)
    az = traj.azimuth
    along = st.position[:, 0] * math.sin(az) + st.position[:, 1] * math.cos(az)
    return traj, t, along


def _traversals(traj: Trajectory, t: np.ndarray, along: np.ndarray, cycle: int) -> list[float]:
    """Direction (+1/−1) of each stretch of motion of a cycle, in time order."""
    st = traj.evaluate(t)
    sel = (st.cycle == cycle) & (np.abs(st.s_dot) > 1e-3)
    dirs = np.sign(st.s_dot[sel])
    return [float(d) for i, d in enumerate(dirs) if i == 0 or d != dirs[i - 1]]


@pytest.mark.parametrize(
    ("pattern", "push_after"), [("unidirectional", 1), ("unidirectional", 0), ("three_pass", 1)]
)
def test_patterns_traverse_the_face_and_push_between_runs(pattern: str, push_after: int) -> None:
    runs = len(PATTERN_RUNS[pattern])
    traj, t, along = _face(
        [f"face.pattern={pattern}", f"face.push_after_run={push_after}", "face.cycles=3"]
    )
    st = traj.evaluate(t)
    for cycle in (1, 2, 3):
        dirs = _traversals(traj, t, along, cycle)
        assert len(dirs) == runs  # cut, cleaning (, return): one traversal each
        assert all(dirs[i] == -dirs[i - 1] for i in range(1, runs))
        sel = st.cycle == cycle
        assert along[sel].min() < 0.5 and along[sel].max() > 29.5  # whole face each time
    # the first cut is A -> B; the pushes fall between the runs, after run push_after
    assert _traversals(traj, t, along, 1)[0] == 1.0
    assert [e.cycle for e in traj.push_events] == [1, 2, 3][: len(traj.push_events)]
    for e in traj.push_events:
        runs_before = st.cycle[t < e.t]
        runs_after = st.cycle[t > e.t]
        assert not traj.evaluate(np.array([e.t])).moving[0]
        assert (runs_before == e.cycle).any()
        if push_after == runs - 1:  # after the cycle's last run: the next cycle follows
            assert not (runs_before == e.cycle + 1).any()
            assert (runs_after == e.cycle + 1).any()
        else:  # mid-cycle: the rest of this cycle's runs follow
            assert (runs_after == e.cycle).any()
    # the cleaning runs are faster than the cutting runs
    sel1 = (st.cycle == 1) & (np.abs(st.s_dot) > 1e-3)
    fwd, back = st.s_dot[sel1 & (st.s_dot > 0)], -st.s_dot[sel1 & (st.s_dot < 0)]
    assert np.median(back) > np.median(fwd)


def test_recut_reverses_mid_face() -> None:
    traj, t, along = _face(["face.recut.probability=1.0", "face.cycles=2"])
    for cycle in (1, 2):
        dirs = _traversals(traj, t, along, cycle)
        assert len(dirs) == 3 and dirs[0] == -dirs[1] == dirs[2]
    st = traj.evaluate(t)
    sel = (st.cycle == 1) & (np.abs(st.s_dot) > 1e-3)
    turn = np.flatnonzero(np.diff(np.sign(st.s_dot[sel])) != 0)[0]
    assert 0.2 * 30 - 0.5 < along[sel][turn] < 0.8 * 30 + 0.5  # not at a face end


def test_face_end_skew_and_overrun_move_the_extremes() -> None:
    traj, t, along = _face(
        ["face.end_skew_deg=[20, -10]", "face.cycles=6", "face.pattern=unidirectional"]
    )
    st = traj.evaluate(t)
    for cycle in range(1, 7):
        sel = st.cycle == cycle
        a = traj.face_lines[cycle - 1] if cycle - 1 < len(traj.face_lines) else None
        assert a is not None
        # the first cycle's ends are the surveyed 0 and L; then they follow a·tan(skew)
        assert along[sel].min() == pytest.approx(a * math.tan(math.radians(20.0)), abs=0.03)
        assert along[sel].max() == pytest.approx(30 + a * math.tan(math.radians(-10.0)), abs=0.03)
    traj2, t2, along2 = _face(["face.end_jitter_m=2", "face.cycles=6"])
    st2 = traj2.evaluate(t2)
    lows = [along2[st2.cycle == c].min() for c in range(1, 7)]
    assert lows[0] == pytest.approx(0.0, abs=0.03)
    assert 0.05 < max(abs(x) for x in lows[1:]) <= 2.03


def test_line_deviation_changes_the_afc_at_every_push() -> None:
    sigma = 0.1
    traj, _, _ = _face(
        [f"face.line_deviation.sigma_m={sigma}", "face.waviness.amplitude_m=0", "face.cycles=6"]
    )
    s = np.linspace(0.0, 30.0, 301)
    straight = [leg for leg in traj.legs if isinstance(leg, AfcLine) and leg.s0 == leg.s1]
    lines: dict[float, np.ndarray] = {}
    for leg in straight:
        lines.setdefault(leg.a0, leg.plan(s)[1].v - leg.a0)
    shapes = list(lines.values())
    assert len(shapes) == 6 and np.all(shapes[0] == 0.0)  # the first line is the reference
    steps = [float(np.sqrt(np.mean((b - a) ** 2))) for a, b in itertools.pairwise(shapes)]
    assert all(0.2 * sigma < x < 3.0 * sigma for x in steps)
    off, _, _ = _face(["face.waviness.amplitude_m=0", "face.cycles=3"])
    assert all(leg.dev0 is None for leg in off.legs if isinstance(leg, AfcLine))


def test_uwb_round_robin_shares_a_total_rate(tmp_path: Path) -> None:
    ov = [
        "duration_s=120",
        "face.length_m=20",
        "uwb.polling=round_robin",
        "uwb.rate_hz=40",
        "uwb.noise_factors={N1: 1.4, N2: 0.7}",
    ]
    out = simulate("longwall-200m", tmp_path / "rr", seed=3, overrides=ov)
    assert validate_recording(out) == []
    t, anchor = _csv(out / "uwb.csv")
    assert len(t) / (t[-1] - t[0]) == pytest.approx(40.0, rel=0.01)  # always some anchor in range
    assert np.all(np.diff(t) > 0)
    near = {"N1", "N2", "N3", "N4"}
    assert set(anchor) == near  # the far end's anchors are out of range
    for a in near:
        ta = t[anchor == a]
        assert np.all(np.diff(ta) > 0)
        assert len(ta) == pytest.approx(len(t) / 4, abs=2)  # ~ rate / n_in_range each
    meta = yaml.safe_load((out / "meta.yaml").read_text())
    assert meta["uwb"]["rate_hz"] == 40.0  # the nominal total


def test_uwb_simultaneous_rounds_share_a_stamp(tmp_path: Path) -> None:
    ov = ["duration_s=60", "face.length_m=20", "uwb.polling=simultaneous", "uwb.rate_hz=10"]
    out = simulate("longwall-200m", tmp_path / "sim", seed=3, overrides=ov)
    t, anchor = _csv(out / "uwb.csv")
    stamps, counts = np.unique(t, return_counts=True)
    assert counts.max() == 4 and np.median(counts) == 4  # the four near anchors per round
    assert np.allclose(np.diff(stamps), 0.1)
    for a in set(anchor):
        assert np.all(np.diff(t[anchor == a]) > 0)
    meta = yaml.safe_load((out / "meta.yaml").read_text())
    assert meta["uwb"]["rate_hz"] == 80.0  # 10 rounds/s x 8 anchors, nominal


def test_stated_field_and_datasheet_differ_from_the_truth(tmp_path: Path) -> None:
    out = simulate("longwall-random", tmp_path / "w", seed=11, overrides=["duration_s=80"])
    meta = read_recording(out).meta
    sc = meta.extra["world"]["scenario"]
    true_mag, stated = sc["magnetometer"], meta.magnetometer
    assert stated is not None and stated.field_uT is not None
    assert abs(stated.field_uT / true_mag["field_uT"] - 1.0) >= 0.01 - 1e-6
    assert abs(stated.declination_deg - true_mag["declination_deg"]) >= 0.5 - 1e-6
    # the magnetometer reads the true field (hard iron ≤ 2 µT, soft iron ≤ 2 %), not the stated one
    rec = read_recording(out)
    assert rec.magnetometer is not None
    norm = float(np.median(np.linalg.norm(rec.magnetometer.field, axis=1)))
    assert abs(norm - true_mag["field_uT"]) < 0.03 * true_mag["field_uT"] + 2.0
    spec = meta.imu.spec
    realized = np.abs(meta.extra["imu_errors_realized"]["gyro_bias_deg_h"])
    assert spec is not None and spec.gyro_bias_deg_h is not None
    assert spec.gyro_bias_deg_h == sc["imu"]["meta_spec"]["gyro_bias_deg_h"]
    assert spec.gyro_bias_deg_h != sc["imu"]["errors"]["gyro_bias_deg_h"]
    assert not np.allclose(realized, spec.gyro_bias_deg_h)


def test_a_world_that_ends_before_the_first_push_has_no_support_rows(tmp_path: Path) -> None:
    out = simulate("longwall-random-short", tmp_path / "s", seed=1, overrides=["duration_s=100"])
    rec = read_recording(out)
    assert rec.meta.extra["push_events"] == []
    assert (out / "support.csv").read_text() == "t,advance\n"  # header only: the reader accepts it
    assert rec.support is not None and rec.support.t.size == 0


def test_worlds_often_end_mid_pass_and_some_before_a_push() -> None:
    no_push = mid_run = 0
    for seed in range(40):
        w = draw_world(seed)
        traj = Trajectory(w, stream_rng(seed, "trajectory"))
        no_push += not traj.push_events
        end = traj.evaluate(np.array([traj.duration - 1e-6]))
        mid_run += bool(end.cycle[0] > 0)
    assert 1 <= no_push <= 20 and mid_run >= 25


def test_cli_simulates_a_family(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cli"
    assert (
        fusion_main(
            ["simulate", "longwall-random", str(out), "--seed", "9", "--set", "duration_s=70"]
        )
        == 0
    )
    assert validate_recording(out) == []
    assert read_recording(out).meta.extra["world"]["seed"] == 9
    assert fusion_main(["scenarios"]) == 0
    assert "longwall-random-harsh" in capsys.readouterr().out
