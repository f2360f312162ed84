"""Lost lock and re-acquisition (fusion.lock): the monitor's rule, and sins_uwb coasting through
a UWB outage long enough for every range to be rejected when the anchors answer again."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion.aiding.odometer import Odometer, OdometerOptions
from fusion.attitude import dcm_from_euler
from fusion.config import load_config, load_config_data, parse_config
from fusion.earth import normal_gravity
from fusion.engine import Engine, _holds
from fusion.error_model import GYRO_BIAS, POSITION, VELOCITY
from fusion.kalman import KalmanFilter
from fusion.lock import (
    DISPUTED,
    LOST_LOCK,
    MAX_FADING,
    MAX_INFLATED_ATTITUDE_SIGMA,
    REACQUIRE,
    LockMonitor,
    RestLevel,
    fading_factor,
    inflation_variances,
)
from fusion.metrics import interpolate_truth
from fusion.recording import ImuData, OdometerData, Recording, read_recording
from fusion.sim.simulate import simulate
from tests.plugin_support import layout_with, perturbed_context, recording_meta

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_monitor_needs_a_whole_window_of_rejections() -> None:
    monitor = LockMonitor(window_s=3.0, min_updates=10)
    times = np.arange(0.0, 10.0, 0.1)
    lost = [monitor.observe(t, accepted=t < 2.0) for t in times]
    first = times[lost.index(True)]
    assert first == pytest.approx(5.0, abs=0.11)  # the last acceptance at 1.9 s left the window
    monitor.reset()
    again = [monitor.observe(t, accepted=False) for t in times + 10.0]
    assert times[again.index(True)] == pytest.approx(3.0, abs=0.11)  # a full window after reset
    assert monitor.last_accepted == pytest.approx(1.9)


def test_only_updates_that_fix_velocity_or_position_hold_the_filter() -> None:
    """Lost lock is declared only while no other source holds the filter (Engine._holders): a
    motion constraint (two velocity rows) with a ZARU does not, since the SINS drifts along
    the track under it (sins_uwb never re-acquired at the far face end: 34 km off for an hour
    on a random world); an odometer with its constraint rows, a zero velocity and a position
    fix do."""
    layout = layout_with(())
    v, p, bg = (layout.slice(b) for b in (VELOCITY, POSITION, GYRO_BIAS))
    constraint_and_zaru = np.zeros((5, layout.dim))
    constraint_and_zaru[0, v] = [0.0, 1.0, 0.0]
    constraint_and_zaru[1, v] = [0.0, 0.0, 1.0]
    constraint_and_zaru[2:, bg] = np.eye(3)
    odometer = np.zeros((3, layout.dim))
    odometer[:, v] = dcm_from_euler(0.1, 0.2, 0.3)
    fix = np.zeros((3, layout.dim))
    fix[:, p] = np.eye(3)
    one_range = np.zeros((1, layout.dim))
    one_range[0, p] = [0.6, 0.8, 0.0]
    assert not _holds(constraint_and_zaru, layout) and not _holds(one_range, layout)
    assert _holds(odometer, layout) and _holds(fix, layout)


def test_sins_uwb_reacquires_after_an_outage(tmp_path: Path) -> None:
    """longwall-200m near the gate, the UWB dropped from 100 to 220 s: the SINS, held only by the
    constraint and the shearer's top speed, drifts 7 m. When the anchors answer again a range
    linearized that far from the truth would claim centimetres, so the UWB plugin asks for a
    re-acquisition: the ranges of the next two seconds put the filter back within a metre.
    (Without the top speed the drift was 43 m, and the heading the outage cost, 22–36°, left
    the IMU point 0.3–1 m off through the tag lever arm after the re-acquisition.)"""
    outage = "faults=[{kind: dropout, sensor: uwb, t_start: 100, t_end: 220}]"
    path = simulate("longwall-200m", tmp_path / "rec", seed=1, overrides=["duration_s=300", outage])
    rec = read_recording(path)
    assert rec.truth is not None
    result = Engine(load_config(CONFIGS / "sins_uwb.yaml"), rec).run()
    events = [(e.action, e.t, e.statistic) for e in result.faults]
    print(events)
    reacquired = [t for action, t, _ in events if action == REACQUIRE]
    assert len(reacquired) == 1 and 220.0 < reacquired[0] < 225.0
    # The fix agrees with the coasting filter: an update, not a restart (Engine._take_in_fix).
    assert "taken in as a position update" in result.faults[-1].reason
    sol = result.solution
    inside, position, *_ = interpolate_truth(rec.truth, sol.t)
    error = np.hypot(*(sol.position[inside, :2] - position[:, :2]).T)
    t = sol.t[inside]
    assert error[(t > 210) & (t < 220)].max() > 5.0  # coasting
    assert error[t > reacquired[0] + 1.0].max() < 2.0


def test_a_filter_confidently_off_restarts_at_the_fix(tmp_path: Path) -> None:
    """meta.yaml's initial position 15 m off at its σ of centimetres: every range is rejected,
    the lock is lost within seconds, and the fix, which the filter's covariance cannot explain,
    replaces its position instead of being averaged with it."""
    path = simulate("longwall-200m", tmp_path / "rec", seed=1, overrides=["duration_s=30"])
    meta = yaml.safe_load((path / "meta.yaml").read_text())
    meta["initial"]["position_enu_m"][0] += 15.0
    (path / "meta.yaml").write_text(yaml.safe_dump(meta))
    rec = read_recording(path)
    assert rec.truth is not None
    result = Engine(load_config(CONFIGS / "sins_uwb.yaml"), rec).run()
    restarts = [e for e in result.faults if e.action == REACQUIRE]
    assert len(restarts) == 1 and restarts[0].t < 5.0
    assert "alone moved the position by 15 m" in restarts[0].reason
    sol = result.solution
    inside, position, *_ = interpolate_truth(rec.truth, sol.t)
    error = np.hypot(*(sol.position[inside, :2] - position[:, :2]).T)
    assert error[sol.t[inside] > 10.0].max() < 0.1


def test_fading_factor_makes_the_innovation_one_sigma() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3, 3))
    predicted = a @ a.T + 0.1 * np.eye(3)
    noise = np.diag([0.2, 0.5, 0.1])
    innovation = 20.0 * rng.normal(size=3)
    lam = fading_factor(innovation, predicted, noise)
    statistic = innovation @ np.linalg.solve(lam * predicted + noise, innovation)
    assert lam > 1.0 and statistic == pytest.approx(3.0, rel=1e-6)
    assert fading_factor(0.01 * innovation, predicted, noise) == 1.0
    flat = np.diag([1.0, 0.0, 0.0])  # the third row's innovation: no inflation explains it
    assert fading_factor(np.array([0.0, 0.0, 100.0]), flat, noise) == MAX_FADING


def test_inflation_adds_uncorrelated_variance_to_the_block() -> None:
    rng = np.random.default_rng(4)
    a = rng.normal(size=(6, 6))
    p = a @ a.T
    kf = KalmanFilter(np.zeros(6), p, stored_errors=2)
    kf.columns = rng.normal(size=(6, 2))
    columns = kf.columns.copy()
    kf.add_variances(slice(0, 3), 8.0 * np.diagonal(kf.P)[:3])
    assert np.allclose(np.diagonal(kf.P)[:3], 9.0 * np.diagonal(p)[:3])
    off_diagonal = ~np.eye(6, dtype=bool)
    assert np.allclose(kf.P[off_diagonal], p[off_diagonal]) and np.allclose(kf.P[3:, 3:], p[3:, 3:])
    assert np.allclose(kf.columns, columns)
    assert np.linalg.eigvalsh(kf.P).min() >= np.linalg.eigvalsh(p).min() - 1e-12


def test_inflation_stops_the_attitude_at_its_bound() -> None:
    """Every common variance grows by the factor, the attitude's only up to a σ of
    MAX_INFLATED_ATTITUDE_SIGMA, and one already beyond it is left as it is."""
    variances = np.full(15, 1e-4)
    variances[5] = (2.0 * MAX_INFLATED_ATTITUDE_SIGMA) ** 2
    added = inflation_variances(variances, MAX_FADING)
    np.testing.assert_allclose(added[[0, 1, 2, 6, 7, 8, 9, 14]], (MAX_FADING - 1.0) * 1e-4)
    np.testing.assert_allclose(variances[3:5] + added[3:5], MAX_INFLATED_ATTITUDE_SIGMA**2)
    assert added[5] == 0.0
    small = inflation_variances(variances, 2.0)
    np.testing.assert_allclose(small[3:5], 1e-4)


def test_a_second_lost_lock_inflates_only_after_the_lock_came_back() -> None:
    monitor = LockMonitor(window_s=3.0, min_updates=10)
    assert monitor.first_inflation() and not monitor.first_inflation()
    for t in np.arange(0.0, 2.0, 0.1):  # one update in two accepted: no full window yet
        monitor.observe(t, accepted=bool(round(t * 10) % 2))
    assert not monitor.first_inflation()
    for t in np.arange(2.0, 4.0, 0.1):  # a full window with half its updates accepted
        monitor.observe(t, accepted=bool(round(t * 10) % 2))
    assert monitor.first_inflation()


def test_a_slow_sensor_s_window_reaches_back_to_its_min_updates() -> None:
    """An encoder at 2 Hz has 6 readings in a 3-s window: a window of 3 s alone never held the
    10 a lost lock needs, and every reading rejected was never reported."""
    monitor = LockMonitor(window_s=3.0, min_updates=10)
    t = 0.0
    while not monitor.observe(t := t + 0.5, accepted=False):
        assert t < 20.0
    assert t == pytest.approx(5.0)  # the 10th reading
    assert monitor.span_s(t) == pytest.approx(4.5)


def test_an_odometer_at_rest_levels_a_sins_the_inflation_did_not_bring_back(
    tmp_path: Path,
) -> None:
    """Random world 27 starts at rest with a pitch 3.9° off; here meta.yaml states a pitch σ
    of 0.42° (9σ). Every zero speed is rejected; the inflation at the first lost lock does not
    bring them back, and at the second the encoder, which shows the machine standing since the
    start, restarts the velocity at zero, the tilt from the accelerometers and the position
    where the filter first agreed with it (it coasted 10 km in 30 s before
    :meth:`fusion.aiding.odometer.Odometer.reacquire`)."""
    path = simulate("longwall-random", tmp_path / "rec", seed=27, overrides=["duration_s=30"])
    meta = yaml.safe_load((path / "meta.yaml").read_text(encoding="utf-8"))
    meta["initial"]["sigma"]["attitude_deg"] = [0.42, 0.42, 1.32]
    (path / "meta.yaml").write_text(yaml.safe_dump(meta), encoding="utf-8")
    recording = read_recording(path)
    result = Engine(load_config(CONFIGS / "sins_od_ckf.yaml"), recording).run()
    actions = [e.action for e in result.faults]
    assert actions == [LOST_LOCK, REACQUIRE]
    assert "levelled" in result.faults[1].reason
    assert recording.truth is not None
    inside, truth, *_ = interpolate_truth(recording.truth, result.solution.t)
    error = result.solution.position[inside, :2] - truth[:, :2]
    assert np.hypot(*error[-1]) < 0.5


def test_a_level_in_motion_takes_out_the_known_acceleration() -> None:
    """A level IMU (body = ENU) hauled at 0.05 m/s² along its x axis reads that acceleration
    beside gravity: taken for a standstill, it is a tilt of a/g (0.29°); with the acceleration
    known, the level is zero, and its variance grows by (a/g)² for how far it may have changed."""
    acceleration = np.array([0.05, 0.0, 0.0])
    meta = recording_meta()
    gravity = float(normal_gravity(math.radians(meta.origin.lat_deg), meta.origin.height_m))
    t = np.arange(1, 101) / 100.0
    force = np.tile(acceleration + np.array([0.0, 0.0, gravity]), (t.size, 1))
    imu = ImuData(t=t, gyro=np.zeros((t.size, 3)), accel=force)
    rest = RestLevel(Recording(path=None, meta=meta, imu=imu))
    standing = rest.over(0.0, 1.0, np.eye(3), np.zeros(3))
    hauled = rest.over(0.0, 1.0, np.eye(3), np.zeros(3), acceleration)
    assert standing is not None and hauled is not None
    assert np.linalg.norm(standing.attitude_error) == pytest.approx(0.05 / gravity, rel=1e-3)
    assert np.linalg.norm(hauled.attitude_error) < 1e-12
    assert hauled.variance - standing.variance == pytest.approx((0.05 / gravity) ** 2)


def test_an_odometer_in_motion_restarts_a_sins_that_lost_its_tilt() -> None:
    """A SINS lost while the shearer hauls: its second lost lock since the filter last agreed
    with the encoder (the inflation at the first did not bring the readings back). The encoder
    says how the machine moves, and :meth:`fusion.aiding.odometer.Odometer.reacquire` restarts
    the velocity at its speed along the travel axis, the tilt from the accelerometers and the
    position at the last reading the filter agreed with, widened by the travel since. (Before,
    only a machine at rest was restarted: a SINS that had lost its tilt while hauling coasted
    14.6 km at a σ of 1.3 km on a harsh world; docs/design/2026-12-04-confident-after-an-
    odometer-dropout.md.) Here a level IMU hauled north at 0.2 m/s; the SINS 1 m/s off and 5°
    tilted at 6 s."""
    meta = recording_meta(odometer={"rate_hz": 10.0})
    gravity = float(normal_gravity(math.radians(meta.origin.lat_deg), meta.origin.height_m))
    t_imu = np.arange(1, 1001) / 100.0
    force = np.tile([0.0, 0.0, gravity], (t_imu.size, 1))
    imu = ImuData(t=t_imu, gyro=np.zeros((t_imu.size, 3)), accel=force)
    t = np.arange(1, 101) / 10.0
    odometer = OdometerData(t=t, speed=np.full(t.size, 0.2))
    plugin = Odometer("odometer", OdometerOptions(), Recording(None, meta, imu, odometer=odometer))
    layout = layout_with(plugin.state_blocks())
    agreed = perturbed_context(layout, np.zeros(layout.dim), t=2.0, velocity=[0.0, 0.2, 0.0])
    plugin.measure(19, agreed)  # the filter agrees with the reading at 2 s, at the origin
    lost = np.zeros(layout.dim)
    lost[0:3] = [0.0, 1.0, 0.0]  # velocity 1 m/s off
    lost[3:6] = [math.radians(5.0), 0.0, 0.0]  # tilted 5°
    lost[6:9] = [0.0, 3.0, 0.0]
    ctx = perturbed_context(layout, lost, t=6.0, position_enu=[0.0, 0.8, 0.0])
    assert plugin.reacquire(6.0, ctx) is None  # a first loss: the inflation's turn
    restart = plugin.reacquire(6.0, ctx)
    assert restart is not None
    np.testing.assert_allclose(restart.velocity_enu, [0.0, 0.2, 0.0], atol=1e-3)
    np.testing.assert_allclose(restart.level.attitude_error, lost[3:6], atol=1e-3)
    np.testing.assert_allclose(restart.position_enu, agreed.position_enu, atol=1e-6)
    reach = 0.2 * (6.0 - 2.0) * (1.0 + 3.0 * plugin.options.scale_sigma)
    assert np.sqrt(restart.covariance[1, 1] - agreed.covariance[7, 7]) == pytest.approx(
        reach / np.sqrt(3.0), rel=0.05
    )


def test_odometer_lost_lock_inflates_instead_of_coasting(tmp_path: Path) -> None:
    """Harsh random world 9: a gyro bias of 2700 °/h against a prior of ≈ 720 °/h tilts the
    SINS faster than its covariance allows; every odometer update is rejected from the static
    start's first seconds, and the SINS coasted (55 km after 600 s). The odometer cannot say
    where the machine is, so the lost lock inflates the SINS covariance by the fading factor
    and the odometer holds the filter again. The bias measured at rest (fusion.bias_at_rest)
    removes the cause here; the lock is what is left where it cannot be measured (a start that
    is not at rest), so it is tested without it, and the measured bias is checked to need no
    lock at all."""
    out = simulate("longwall-random-harsh", tmp_path / "rec", seed=9, overrides=["duration_s=150"])
    recording = read_recording(out)
    assert recording.truth is not None
    for at_rest in (False, True):
        config = load_config(CONFIGS / "sins_od_mag_ckf.yaml")
        config.imu.bias_at_rest = at_rest
        result = Engine(config, recording).run()
        lost = [e for e in result.faults if e.action == LOST_LOCK]
        if at_rest:
            assert result.rest_bias.taken == ("gyro_bias_deg_h",) and not lost
        else:
            assert lost and "inflated" in lost[0].reason and lost[0].t < 10.0
        inside, truth, *_ = interpolate_truth(recording.truth, result.solution.t)
        error = result.solution.position[inside] - truth
        assert np.hypot(error[:, 0], error[:, 1]).max() < 2.0


def test_a_sensor_rejected_while_another_holds_the_filter_is_disputed_once(
    tmp_path: Path,
) -> None:
    """Every anchor reads 1 m long from 60 s to 75 s (NLOS on all of them): every range is
    withheld, but the odometer holds the filter, so nothing is re-acquired from the ranges.
    One ``disputed`` line says that the UWB or the filter is wrong; the filter stays right."""
    from dataclasses import replace

    path = simulate("longwall-random", tmp_path / "rec", seed=3, overrides=["duration_s=150"])
    config = load_config(Path(__file__).resolve().parents[1] / "configs" / "full_ckf.yaml")
    rec = read_recording(path)
    assert rec.uwb is not None and rec.truth is not None
    nlos = (rec.uwb.t >= 60.0) & (rec.uwb.t < 75.0)
    result = Engine(config, replace(rec, uwb=replace(rec.uwb, range=rec.uwb.range + nlos))).run()
    rows = [(e.t, e.local, e.action) for e in result.faults]
    disputed = [r for r in rows if r[2] == DISPUTED]
    assert len(disputed) == 1 and disputed[0][1] == "uwb" and 60.0 < disputed[0][0] < 75.0
    assert not [r for r in rows if r[2] in (REACQUIRE, LOST_LOCK)]
    inside, pos, *_ = interpolate_truth(rec.truth, result.solution.t)
    error = np.linalg.norm(result.solution.position[inside, :2] - pos[:, :2], axis=1)
    assert np.max(error) < 0.1


def _steady_drive(speed: float, duration: float) -> Recording:
    """A noise-free IMU on a level vehicle driving due north at ``speed`` on the equator: it
    reads gravity and the earth's and the transport rate only, a standstill to any norm
    detector."""
    from fusion.earth import OMEGA_IE, normal_gravity, radii

    meridian, _ = radii(0.0)
    rate = 100.0
    t = np.arange(1, int(duration * rate) + 1) / rate
    gyro = np.tile([-speed / meridian, OMEGA_IE, 0.0], (t.size, 1))  # ω_ie + ω_en, body = ENU
    force = np.tile([0.0, 0.0, normal_gravity(0.0, 0.0) - speed**2 / meridian], (t.size, 1))
    meta = recording_meta(
        origin={"lat_deg": 0.0, "lon_deg": 0.0, "height_m": 0.0},
        initial={
            "velocity_enu_mps": [0.0, speed, 0.0],
            "sigma": {
                "position_m": [0.1] * 3,
                "velocity_mps": [0.05] * 3,
                "attitude_deg": [0.1, 0.1, 0.5],
            },
        },
        imu={
            "rate_hz": rate,
            "spec": {
                "gyro_bias_deg_h": 10.0,
                "gyro_arw_deg_rth": 0.2,
                "accel_bias_mg": 1.0,
                "accel_vrw_mg_rthz": 0.05,
            },
        },
    )
    return Recording(path=None, meta=meta, imu=ImuData(t=t, gyro=gyro, accel=force))


def test_a_zupt_on_the_imu_alone_does_not_inflate_a_moving_filter_to_admit_it() -> None:
    """A car at a steady 10 m/s looks still to a norm detector; the χ² gate rejects every
    zero velocity, and the lock is lost. With nothing but the IMU saying the machine stands and
    no top speed known, the IMU cannot tell a lost SINS from a false standstill: the lost lock
    is reported and the SINS is not inflated. Inflated, its velocity σ admitted the next zero
    velocity and the car stopped in the filter, 31 m along its 200-m drive."""
    config = load_config_data(CONFIGS / "sins_zupt.yaml")
    zupt = config["plugins"][0]
    del zupt["max_speed_mps"]
    zupt["sigma_zero_velocity_mps"] = 0.01
    result = Engine(parse_config(config), _steady_drive(speed=10.0, duration=20.0)).run()
    lost = [e for e in result.faults if e.action == LOST_LOCK]
    assert lost and all("not inflated: the standstill rests on" in e.reason for e in lost)
    end = result.solution.position[-1]
    assert end[1] == pytest.approx(10.0 * result.solution.t[-1], abs=1.0)
