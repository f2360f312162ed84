"""Scenario schema, presets, overrides and the chunked recording writer of the simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion.recording import read_recording, validate_recording
from fusion.sim.scenario import ScenarioError, apply_overrides, parse_override
from fusion.sim.simulate import list_scenarios, load_scenario, simulate, stream_rng
from fusion.sim.trajectory import Trajectory

PRESETS = {
    "longwall-200m",
    "longwall-shift",
    "seed000-carrier",
    "seed002-rectangle",
    "seed002-rectangle-718",
    "seed002-rectangle-calibrated",
    "seed003-brokenline",
    "seed003-brokenline-maginterf",
    "seed003-brokenline-calibrated",
    "seed004-face-end",
    "seed004-face-end-calibrated",
}


def test_list_scenarios_has_every_preset_with_a_description() -> None:
    listed = dict(list_scenarios())
    assert PRESETS <= set(listed)
    assert all(listed[n] for n in PRESETS)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_validate_and_plan(name: str) -> None:
    sc = load_scenario(name)
    assert sc.name == name
    traj = Trajectory(sc, stream_rng(0, "trajectory"))
    seg = traj._seg
    motion_end = seg["t0"][-2] + seg["dur"][-2]
    assert traj.duration >= sc.static_start_s
    if sc.duration_s is not None and name != "longwall-shift":
        # the fixed-length seed experiments finish their motion inside the run
        assert motion_end <= sc.duration_s
    # every run starts with a static period
    m = traj.evaluate(np.linspace(0.0, sc.static_start_s - 1e-6, 50))
    assert not m.moving.any()
    assert (m.cycle == 0).all()


def test_preset_shapes() -> None:
    assert load_scenario("longwall-shift").duration_s == 8 * 3600
    carrier = load_scenario("seed000-carrier")
    assert carrier.face is not None
    assert (carrier.face.length_m, carrier.face.advance_m, carrier.face.cycles) == (44.6, 1.2, 4)
    assert carrier.imu.grade == "mti-g-700" and carrier.odometer and carrier.support
    lw = load_scenario("longwall-200m")
    assert lw.face is not None and lw.face.length_m == 200 and lw.face.advance_m == 0.8
    assert lw.face.cycles == 6
    assert lw.odometer and lw.magnetometer and lw.uwb and lw.support
    end = load_scenario("seed004-face-end")
    assert end.uwb is not None and len(end.uwb.anchors) == 4 and end.uwb.rate_hz == 40
    mag = load_scenario("seed003-brokenline-maginterf")
    assert [f.kind for f in mag.faults] == ["magnetic_interference"]
    assert load_scenario("seed002-rectangle-718").track.laps == 4  # type: ignore[union-attr]


def test_override_parsing() -> None:
    assert parse_override("face.length_m=50") == (["face", "length_m"], 50)
    assert parse_override("motion.vibration.enabled=false")[1] is False
    assert parse_override("motion.speed_mpm=[2, 4]")[1] == [2, 4]
    assert parse_override("name=abc")[1] == "abc"
    with pytest.raises(ScenarioError, match=r"key\.sub=value"):
        parse_override("face.length_m")


def test_overrides_apply_and_name_bad_paths() -> None:
    sc = load_scenario("longwall-200m", ["face.length_m=120", "motion.vibration.enabled=false"])
    assert sc.face is not None and sc.face.length_m == 120
    assert not sc.motion.vibration.enabled
    # a section absent from the file but known to the schema can be set
    sc2 = load_scenario("seed002-rectangle", ["odometer.rate_hz=20"])
    assert sc2.odometer is not None and sc2.odometer.rate_hz == 20
    with pytest.raises(ScenarioError, match=r"face\.lenght_m"):
        load_scenario("longwall-200m", ["face.lenght_m=3"])
    with pytest.raises(ScenarioError, match=r"'face\.foo'"):
        apply_overrides({"name": "x", "face": {}}, ["face.foo.bar=1"])
    with pytest.raises(ScenarioError, match=r"face\.length_m"):
        load_scenario("longwall-200m", ["face.length_m=-5"])


def test_vibration_switch_shorthand_and_scenario_object_overrides(tmp_path: Path) -> None:
    sc = load_scenario("longwall-200m", ["motion.vibration=false"])
    assert not sc.motion.vibration.enabled
    base = load_scenario("seed003-brokenline")
    out = simulate(base, tmp_path / "s", seed=2, overrides=["duration_s=70", "odometer.rate_hz=5"])
    rec = read_recording(out)
    assert rec.meta.odometer is not None and rec.meta.odometer.rate_hz == 5
    assert rec.imu.t[-1] == pytest.approx(70.0)


def test_yaml_errors_name_the_key_path(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        yaml.safe_dump({"name": "x", "face": {"length_m": 50, "webb": 1}, "imu": {"grade": "?"}})
    )
    with pytest.raises(ScenarioError) as err:
        load_scenario(bad)
    text = str(err.value)
    assert "face.webb" in text and "imu" in text
    with pytest.raises(ScenarioError, match="exactly one of 'face' and 'track'"):
        load_scenario("longwall-200m", ["track.waypoints_m=[[0, 0], [1, 0]]"])
    with pytest.raises(ScenarioError, match="unknown scenario"):
        load_scenario("no-such-preset")


def test_extends_merges_onto_the_parent(tmp_path: Path) -> None:
    child = tmp_path / "child.yaml"
    child.write_text("extends: longwall-200m\nname: child\nface: {cycles: 2}\n")
    sc = load_scenario(child)
    assert sc.name == "child"
    assert sc.face is not None and sc.face.cycles == 2 and sc.face.length_m == 200


def _files(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(root.iterdir())}


def test_simulate_writes_a_valid_deterministic_recording(tmp_path: Path) -> None:
    ov = [
        "face.length_m=10",
        "face.cycles=2",
        "face.bend_length_m=3",
        "face.sump_overrun_m=1",
        "static_start_s=10",
        "motion.speed_mpm=[6, 8]",
    ]
    a = simulate("longwall-200m", tmp_path / "a", seed=7, overrides=ov)
    assert validate_recording(a) == []
    b = simulate("longwall-200m", tmp_path / "b", seed=7, overrides=[*ov, "chunk_s=13"])
    c = simulate("longwall-200m", tmp_path / "c", seed=8, overrides=ov)
    fa, fb, fc = _files(a), _files(b), _files(c)
    assert set(fa) == {
        "meta.yaml",
        "imu.csv",
        "truth.csv",
        "odometer.csv",
        "magnetometer.csv",
        "uwb.csv",
        "support.csv",
    }
    # the same seed gives byte-identical files, whatever the chunk length
    assert fa == fb
    assert fa["imu.csv"] != fc["imu.csv"]

    rec = read_recording(a)
    meta = rec.meta
    assert meta.extra["scenario"] == "longwall-200m" and meta.extra["seed"] == 7
    true0 = meta.extra["true_initial"]
    assert rec.truth is not None
    np.testing.assert_allclose(rec.truth.position[0], true0["position_enu_m"])
    # the written initial state is perturbed from the truth by a draw of the stated sigma
    p0 = np.asarray(meta.initial.position_enu_m)
    assert 0.0 < np.abs(p0 - true0["position_enu_m"]).max() < 5 * 0.05
    assert meta.face is not None and meta.face.advance_m == 0.8
    assert meta.face.ends_enu_m is not None
    assert meta.face.ends_enu_m[0] == (0.0, 0.0, 0.0)
    assert rec.support is not None and len(rec.support.t) == 1
    assert rec.support.advance[0] == pytest.approx(0.8, abs=0.05)
    assert set(np.unique(rec.truth.cycle)) == {0, 1, 2}


def test_simulate_faults_and_unperturbed_initial(tmp_path: Path) -> None:
    out = simulate(
        "seed003-brokenline-maginterf",
        tmp_path / "m",
        seed=1,
        overrides=["initial.perturb=false", "imu.grade=ideal"],
    )
    assert validate_recording(out) == []
    rec = read_recording(out)
    extra = rec.meta.extra
    assert extra["faults"][0]["type"] == "magnetic_interference"
    assert extra["faults"][0]["t_start"] == 70.0 and extra["faults"][0]["t_end"] == 90.0
    assert rec.meta.initial.position_enu_m == (0.0, 0.0, 0.0)
    att = rec.meta.initial.attitude_deg
    true_att = extra["true_initial"]["attitude_deg"]
    assert att.yaw == pytest.approx(true_att["yaw"])
    # the interference shows in the magnetometer: the field norm departs from the earth field
    assert rec.magnetometer is not None
    norm = np.linalg.norm(rec.magnetometer.field, axis=1)
    inside = (rec.magnetometer.t > 75) & (rec.magnetometer.t < 85)
    assert np.abs(norm[inside] - 53.0).min() > 3.0
    assert np.abs(norm[~inside & (rec.magnetometer.t < 60)] - 53.0).max() < 1.0


def test_recording_files_reproduce_truth_with_imu_mounting(tmp_path: Path) -> None:
    """File-level acceptance: the written error-free imu.csv mechanizes to truth.csv.

    The IMU is mounted with the odometer's residual mounting angles (0.5°, 0°, 1°): the truth
    attitude is the IMU's, the body velocity has the corresponding small x/z parts, and an
    error-free odometer still reads the travel speed exactly.
    """
    from fusion.attitude import dcm_from_euler, wrap_angle
    from fusion.earth import LocalFrame
    from fusion.strapdown import NavState, mechanize

    out = simulate(
        "seed000-carrier",
        tmp_path / "c",
        seed=4,
        overrides=[
            "imu.grade=ideal",
            "initial.perturb=false",
            "duration_s=400",
            "motion.vibration=false",
            "odometer.scale_factor_error=0",
            "odometer.noise_sigma_mps=0",
        ],
    )
    rec = read_recording(out)
    tr = rec.truth
    assert tr is not None and rec.odometer is not None
    o = rec.meta.origin
    frame = LocalFrame(o.lat_deg, o.lon_deg, o.height_m)
    init = NavState.from_enu(frame, tr.position[0], tr.velocity[0], *tr.attitude[0])
    res = mechanize(rec.imu.t, rec.imu.gyro, rec.imu.accel, init, frame=frame)
    assert np.abs(res.position_enu - tr.position).max() < 1e-3
    assert np.rad2deg(np.abs(wrap_angle(res.attitude - tr.attitude))).max() < 1e-6
    # body velocity v^b = C_m^b [0, v, 0] ≈ [−δα_z v, v, δα_x v] (C_b^m = exp(−δα×))
    c = dcm_from_euler(tr.attitude[:, 0], tr.attitude[:, 1], tr.attitude[:, 2])
    v_b = np.einsum("nji,nj->ni", c, tr.velocity)
    k = np.argmax(np.abs(v_b[:, 1]))
    np.testing.assert_allclose(
        v_b[k, [0, 2]] / v_b[k, 1], [-np.deg2rad(1.0), np.deg2rad(0.5)], atol=2e-4
    )
    # the ideal odometer reads the travel speed along the track
    # (interval means over (t_j − 0.1 s, t_j], from the travel along the track)
    from scipy.integrate import cumulative_trapezoid

    travel = cumulative_trapezoid(np.linalg.norm(tr.velocity, axis=1), tr.t, initial=0.0)
    t_od = rec.odometer.t
    mean_speed = (np.interp(t_od, tr.t, travel) - np.interp(t_od - 0.1, tr.t, travel)) / 0.1
    np.testing.assert_allclose(np.abs(rec.odometer.speed), mean_speed, rtol=1e-3, atol=1e-5)


def test_face_end_anchors_in_face_coordinates(tmp_path: Path) -> None:
    out = simulate("seed004-face-end", tmp_path / "u", seed=0, overrides=["duration_s=120"])
    rec = read_recording(out)
    assert rec.meta.uwb is not None and rec.uwb is not None
    anchors = rec.meta.uwb.anchors
    assert set(anchors) == {"A1", "A2", "A3", "A4"}
    # the face runs west (azimuth 270°): the anchors lie ≈ 11-14 m west of the start
    east = np.array([a[0] for a in anchors.values()])
    assert np.all((east < -10.0) & (east > -15.5))
    assert set(rec.uwb.anchor_ids) <= set(anchors)


def test_plot_truth(tmp_path: Path) -> None:
    from fusion.sim.plot import plot_truth

    out = simulate("seed002-rectangle", tmp_path / "r", seed=0, overrides=["duration_s=150"])
    png = plot_truth(out, tmp_path / "truth.png")
    assert png.exists() and png.stat().st_size > 10_000
    out2 = simulate(
        "longwall-200m",
        tmp_path / "f",
        seed=0,
        overrides=[
            "face.length_m=20",
            "face.cycles=2",
            "static_start_s=10",
            "uwb.rate_hz=5",  # the figure is of the truth: the sensors only cost time
            "imu.rate_hz=50",
        ],
    )
    png2 = plot_truth(out2, tmp_path / "face.png")
    assert png2.exists() and png2.stat().st_size > 10_000


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_writes_a_recording_that_validates(name: str, tmp_path: Path) -> None:
    """Each preset (its first 150 s: the same generation path as a full run) passes the reader."""
    from fusion.recording import validate_recording

    out = simulate(name, tmp_path / name, seed=1, overrides=["duration_s=150"])
    assert validate_recording(out) == []
