"""The IMU's turn-on biases measured at rest (fusion/bias_at_rest.py): what the window measures,
when the filter takes it and when it leaves the datasheet alone; and, on random worlds whose gyro
bias lies far beyond its datasheet's, the standstills it gives back to the ZUPT detector."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fusion.attitude import dcm_from_euler
from fusion.bias_at_rest import DEG_H, MG, measure, with_bias_at_rest
from fusion.config import ImuTuning, load_config
from fusion.earth import OMEGA_IE, normal_gravity
from fusion.engine import Engine
from fusion.outputs import summary
from fusion.recording import ImuData, Recording, read_recording
from fusion.sim.simulate import simulate
from tests.consistency_support import pooled_horizontal_z
from tests.plugin_support import recording_meta

RATE = 100.0
GYRO_BIAS = 500.0  # deg/h, the datasheet's 1σ
ACCEL_BIAS = 2.0  # mg
SPEC = {
    "gyro_bias_deg_h": GYRO_BIAS,
    "gyro_arw_deg_rth": 0.3,
    "accel_bias_mg": ACCEL_BIAS,
    "accel_vrw_mg_rthz": 0.1,
}
ATTITUDE = {"roll": 2.0, "pitch": -5.0, "yaw": 120.0}
REPO = Path(__file__).resolve().parents[1]


def _at_rest(
    gyro_bias_deg_h: tuple[float, float, float],
    accel_bias_mg: float = 0.0,
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0),
    seed: int = 0,
) -> Recording:
    """An IMU at rest at ATTITUDE reading the earth's rate and gravity, with the given biases
    (the accelerometer's along gravity) and white noise of SPEC."""
    meta = recording_meta(
        imu={"rate_hz": RATE, "spec": SPEC},
        initial={"attitude_deg": ATTITUDE, "velocity_enu_mps": list(velocity)},
    )
    lat = math.radians(meta.origin.lat_deg)
    c_n_b = dcm_from_euler(*np.radians(list(ATTITUDE.values()))).T
    earth = c_n_b @ (OMEGA_IE * np.array([0.0, math.cos(lat), math.sin(lat)]))
    g = float(normal_gravity(lat, meta.origin.height_m)) + accel_bias_mg * MG
    up = c_n_b @ np.array([0.0, 0.0, g])
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 1.0 / RATE)
    gyro_sigma = math.radians(SPEC["gyro_arw_deg_rth"]) / 60.0 * math.sqrt(RATE)
    accel_sigma = SPEC["accel_vrw_mg_rthz"] * MG * math.sqrt(RATE)
    gyro = (
        earth + np.asarray(gyro_bias_deg_h) * DEG_H + gyro_sigma * rng.standard_normal((t.size, 3))
    )
    accel = up + accel_sigma * rng.standard_normal((t.size, 3))
    return Recording(path=None, meta=meta, imu=ImuData(t=t, gyro=gyro, accel=accel))


def test_the_window_measures_the_gyro_bias_less_earth_rate_and_the_accelerometer_along_g() -> None:
    rest = measure(_at_rest((300.0, -700.0, 1200.0), accel_bias_mg=-1.5))
    assert rest.reason == "" and rest.gyro_deg_h is not None and rest.accel_mg is not None
    assert np.allclose(rest.gyro_deg_h, (300.0, -700.0, 1200.0), atol=4 * rest.gyro_sigma_deg_h)
    assert rest.accel_mg == pytest.approx(-1.5, abs=4 * rest.accel_sigma_mg)
    assert rest.gyro_sigma_deg_h < 10.0  # 6 000 samples of 180 deg/h each


def test_a_bias_its_datasheet_covers_keeps_the_datasheet() -> None:
    """3σ on one axis is what a unit drawn from its datasheet may show: not taken."""
    rec = _at_rest((3.0 * GYRO_BIAS, -GYRO_BIAS, 0.0), accel_bias_mg=3.0 * ACCEL_BIAS)
    measured, rest = with_bias_at_rest(rec, ImuTuning())
    assert measured is rec and rest.taken == ()
    assert "within the datasheet's" in rest.describe()


def test_a_bias_far_beyond_its_datasheet_gives_the_filter_the_measured_magnitude() -> None:
    rec = _at_rest((-800.0, 2900.0, 3500.0), accel_bias_mg=-12.0)
    measured, rest = with_bias_at_rest(rec, ImuTuning())
    assert rest.taken == ("gyro_bias_deg_h", "accel_bias_mg")
    spec = measured.meta.imu.spec
    assert spec is not None and rest.gyro_deg_h is not None
    assert spec.gyro_bias_deg_h == pytest.approx(max(abs(b) for b in rest.gyro_deg_h))
    assert spec.gyro_bias_deg_h == pytest.approx(3500.0, abs=40.0)
    assert spec.accel_bias_mg == pytest.approx(12.0, abs=0.3)
    assert spec.gyro_arw_deg_rth == SPEC["gyro_arw_deg_rth"]  # the noise is not this module's
    assert "the filter takes gyro_bias_deg_h, accel_bias_mg" in rest.describe()


def test_a_figure_the_configuration_sets_is_left_alone() -> None:
    rec = _at_rest((0.0, 0.0, 5000.0), accel_bias_mg=-12.0)
    measured, rest = with_bias_at_rest(rec, ImuTuning(gyro_bias_deg_h=GYRO_BIAS))
    assert rest.taken == ("accel_bias_mg",)
    spec = measured.meta.imu.spec
    assert spec is not None and spec.gyro_bias_deg_h == GYRO_BIAS


def test_a_datasheet_stating_no_bias_takes_the_measured_one() -> None:
    """meta.yaml may state a bias of 0 (the format allows it): that covers nothing, and the
    measured bias is taken instead of failing."""
    rec = _at_rest((0.0, 0.0, 800.0)).with_imu_figures({"gyro_bias_deg_h": 0.0})
    measured, rest = with_bias_at_rest(rec, ImuTuning())
    assert rest.taken == ("gyro_bias_deg_h",)
    spec = measured.meta.imu.spec
    assert spec is not None and spec.gyro_bias_deg_h == pytest.approx(800.0, abs=40.0)


def test_a_start_that_is_not_at_rest_measures_nothing() -> None:
    """A stated initial velocity clear of zero (its σ is 1 m/s here) or a turn in the window."""
    moving = _at_rest((0.0, 0.0, 5000.0), velocity=(4.0, 1.0, 0.0))
    assert "initial velocity" in measure(moving).reason
    assert with_bias_at_rest(moving, ImuTuning())[1].taken == ()
    rec = _at_rest((0.0, 0.0, 5000.0))
    turning = rec.imu.gyro.copy()
    turning[:, 0] += 0.02 * np.sin(2 * np.pi * rec.imu.t / 15.0)  # a roll to and fro, 1°/s
    rolled = replace(rec, imu=ImuData(t=rec.imu.t, gyro=turning, accel=rec.imu.accel))
    assert "not at rest" in measure(rolled).reason


def test_a_short_static_start_is_measured_over_its_first_seconds() -> None:
    """At rest for 4 s, then rolling: the 20-s and 10-s windows are not at rest, the 5-s one
    is (its last second moves, which its medians leave out), and a bias beyond the datasheet's
    is taken from it."""
    rec = _at_rest((0.0, 0.0, 5000.0))
    gyro = rec.imu.gyro.copy()
    moving = rec.imu.t >= 4.0
    gyro[moving, 0] += 0.02 * np.sin(2 * np.pi * (rec.imu.t[moving] - 4.0) / 4.0)
    short = replace(rec, imu=ImuData(t=rec.imu.t, gyro=gyro, accel=rec.imu.accel))
    rest = with_bias_at_rest(short, ImuTuning())[1]
    assert rest.window_s == 5.0 and rest.taken == ("gyro_bias_deg_h",)
    assert rest.gyro_deg_h is not None
    assert rest.gyro_deg_h[2] == pytest.approx(5000.0, abs=4 * rest.gyro_sigma_deg_h)
    assert measure(rec).window_s == 20.0


def test_the_run_reports_what_it_measured_and_took() -> None:
    """The summary's ``IMU bias`` line, ``metrics.json``'s ``imu_bias_at_rest`` and
    ``RunResult.rest_bias``; ``imu.bias_at_rest: false`` measures nothing."""
    rec = _at_rest((0.0, 0.0, 5000.0))
    config = load_config(REPO / "configs" / "sins_only.yaml")
    result = Engine(config, rec).run()
    assert result.rest_bias.taken == ("gyro_bias_deg_h",)
    assert f"IMU bias   {result.rest_bias.describe()}" in summary(result, rec)
    reported = json.loads(json.dumps(result.rest_bias.to_dict()))
    assert reported["taken"] == ["gyro_bias_deg_h"]
    assert reported["gyro_deg_h"][2] == pytest.approx(5000.0, abs=40.0)
    config.imu.bias_at_rest = False
    off = Engine(config, rec).run()
    assert off.rest_bias.taken == () and "off" in off.rest_bias.reason
    assert "IMU bias" not in summary(off, rec)


# ------------------------------------------------------------ σ on a gyro far beyond its datasheet
def _beyond(path: Path, factor: float, seed: int) -> Recording:
    """The recording with a constant bias of ``factor`` × the datasheet's turn-on σ, of random
    sign, added to each gyro axis (the simulator's unit is drawn from its datasheet)."""
    rec = read_recording(path)
    spec = rec.meta.imu.spec
    assert spec is not None and spec.gyro_bias_deg_h
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], 3)
    gyro = rec.imu.gyro + factor * spec.gyro_bias_deg_h * DEG_H * signs
    return replace(rec, imu=ImuData(t=rec.imu.t, gyro=gyro, accel=rec.imu.accel))


def _pooled_z(config_name: str, recordings: list[Recording], at_rest: bool) -> float:
    runs = []
    for rec in recordings:
        config = load_config(REPO / "configs" / f"{config_name}.yaml")
        config.imu.bias_at_rest = at_rest
        result = Engine(config, rec).run()
        assert (result.rest_bias.taken == ("gyro_bias_deg_h",)) == at_rest
        runs.append((result, rec))
    return pooled_horizontal_z(runs)


@pytest.mark.slow
def test_the_measured_bias_keeps_the_sigma_of_a_gyro_far_beyond_its_datasheet(
    tmp_path: Path,
) -> None:
    """Random worlds whose gyros are biased 6× their datasheet's σ: beyond the ZUPT detector's
    band, which then finds no standstill in the whole run. With the bias measured at rest,
    ``sins_zupt`` and ``sins_uwb`` keep RMS(ε/σ) within 1.5; with the datasheet's, the same
    filters claim far more than they keep."""
    recordings = []
    for seed in (0, 1):
        path = simulate(
            "longwall-random-short", tmp_path / f"w{seed}", seed=seed, overrides=["duration_s=300"]
        )
        recordings.append(_beyond(path, 6.0, seed))
    for config_name, worse in (("sins_zupt", 3.0), ("sins_uwb", 1.3)):
        measured = _pooled_z(config_name, recordings, at_rest=True)
        stated = _pooled_z(config_name, recordings, at_rest=False)
        assert measured <= 1.5, f"{config_name}: RMS(ε/σ) {measured:.2f} with the bias measured"
        assert stated > worse * measured, (
            f"{config_name}: RMS(ε/σ) {stated:.2f} with the datasheet's"
        )
