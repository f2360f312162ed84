"""The IMU's white noise measured at rest (fusion/noise_at_rest.py): what the window measures,
when it measures nothing, what the filter takes; and, on a random world whose IMU is noisier
than its datasheet, the σ that keeps its promise with it and breaks it without."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fusion.config import ImuTuning, load_config
from fusion.engine import Engine
from fusion.noise_at_rest import TOLERANCE, WINDOW_S, measure, with_noise_at_rest
from fusion.outputs import summary
from fusion.recording import ImuData, Recording, read_recording
from fusion.sim.simulate import simulate
from tests.consistency_support import pooled_horizontal_z
from tests.plugin_support import recording_meta

RATE = 100.0
ARW = 0.5  # deg/√h
VRW = 0.1  # mg/√Hz
GYRO_SIGMA = math.radians(ARW) / 60.0 * math.sqrt(RATE)  # per sample, rad/s
ACCEL_SIGMA = VRW * 1e-3 * 9.80665 * math.sqrt(RATE)  # per sample, m/s²
REPO = Path(__file__).resolve().parents[1]


def _at_rest(factor: float = 1.0, duration_s: float = 60.0, seed: int = 0) -> Recording:
    """A level IMU at rest whose white noise is ``factor`` × the datasheet's (ARW, VRW)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / RATE)
    gyro = np.array([1e-5, 2e-5, 5e-5]) + factor * GYRO_SIGMA * rng.standard_normal((t.size, 3))
    accel = np.array([0.01, -0.02, 9.8]) + factor * ACCEL_SIGMA * rng.standard_normal((t.size, 3))
    spec = {"gyro_arw_deg_rth": ARW, "accel_vrw_mg_rthz": VRW}
    meta = recording_meta(imu={"rate_hz": RATE, "spec": spec})
    return Recording(path=None, meta=meta, imu=ImuData(t=t, gyro=gyro, accel=accel))


def _with_imu(rec: Recording, gyro: np.ndarray, accel: np.ndarray) -> Recording:
    return replace(rec, imu=ImuData(t=rec.imu.t, gyro=gyro, accel=accel))


def test_an_imu_as_noisy_as_its_datasheet_keeps_the_datasheet() -> None:
    rec = _at_rest(1.0)
    rest = measure(rec)
    assert rest.reason == ""
    assert rest.gyro_factor == pytest.approx(1.0, abs=0.1)
    assert rest.accel_factor == pytest.approx(1.0, abs=0.1)
    measured, rest = with_noise_at_rest(rec, ImuTuning())
    assert measured is rec and rest.taken == ()


def test_an_imu_three_times_its_datasheet_gives_the_filter_the_measured_noise() -> None:
    rec = _at_rest(3.0)
    measured, rest = with_noise_at_rest(rec, ImuTuning())
    assert rest.gyro_factor == pytest.approx(3.0, rel=0.1)
    assert rest.accel_factor == pytest.approx(3.0, rel=0.1)
    assert rest.taken == ("gyro_arw_deg_rth", "accel_vrw_mg_rthz")
    spec = measured.meta.imu.spec
    assert spec is not None
    assert spec.gyro_arw_deg_rth == pytest.approx(ARW * rest.gyro_factor)
    assert spec.accel_vrw_mg_rthz == pytest.approx(VRW * rest.accel_factor)
    assert "the filter takes the measured gyro_arw_deg_rth" in rest.describe()


def test_a_figure_the_configuration_sets_is_left_alone() -> None:
    measured, rest = with_noise_at_rest(_at_rest(3.0), ImuTuning(gyro_arw_deg_rth=0.5))
    assert rest.taken == ("accel_vrw_mg_rthz",)
    spec = measured.meta.imu.spec
    assert spec is not None and spec.gyro_arw_deg_rth == ARW


def test_a_noise_within_the_tolerance_is_not_taken() -> None:
    rest = measure(_at_rest(0.9 * TOLERANCE))
    assert 1.0 < rest.gyro_factor < TOLERANCE
    assert with_noise_at_rest(_at_rest(0.9 * TOLERANCE), ImuTuning())[1].taken == ()


def test_a_start_in_motion_or_with_vibration_measures_nothing() -> None:
    """A turn in the window is motion; an idling engine's vibration is not white: neither is
    the sensor's noise, and the datasheet stays."""
    rec = _at_rest(3.0)
    t = rec.imu.t
    turning = rec.imu.gyro.copy()
    turning[:, 2] += 0.02 * np.sin(2 * np.pi * t / 15.0)  # a slow turn, 1°/s
    assert "not at rest" in measure(_with_imu(rec, turning, rec.imu.accel)).reason
    for hz, reason in ((7.0, "not"), (0.25 * RATE, "not white")):
        shaking = rec.imu.accel.copy()
        shaking[:, 0] += 9 * ACCEL_SIGMA * np.sin(2 * np.pi * hz * t)  # 3× the sensor's noise
        vibrating = _with_imu(rec, rec.imu.gyro, shaking)
        assert reason in measure(vibrating).reason  # at a quarter of the rate: by its lag 2
        assert with_noise_at_rest(vibrating, ImuTuning())[1].taken == ()


def test_a_recording_shorter_than_the_window_or_without_a_datasheet_measures_nothing() -> None:
    short = _at_rest(3.0, duration_s=0.5 * WINDOW_S)
    assert "fewer than" in measure(short).reason
    rec = _at_rest(3.0)
    bare = replace(rec, meta=recording_meta(imu={"rate_hz": RATE}))
    assert "no white noise" in measure(bare).reason


def test_a_hostile_sample_in_the_window_does_not_move_the_measurement() -> None:
    """The measurement runs before the screening: a stray sample, however large, is one of
    2 000 and neither moves the factors nor hides a vibration."""
    rec = _at_rest(3.0)
    gyro, accel = rec.imu.gyro.copy(), rec.imu.accel.copy()
    gyro[500] = [30.0, -30.0, 30.0]
    accel[700] = [1e300, -1e300, 1e300]
    rest = measure(_with_imu(rec, gyro, accel))
    assert rest.gyro_factor == pytest.approx(measure(rec).gyro_factor, rel=0.02)
    assert rest.accel_factor == pytest.approx(measure(rec).accel_factor, rel=0.02)
    accel[:, 0] += 9 * ACCEL_SIGMA * np.sin(2 * np.pi * 0.25 * RATE * rec.imu.t)
    assert "not white" in measure(_with_imu(rec, gyro, accel)).reason


def test_the_run_reports_what_it_measured_and_took() -> None:
    """The summary's ``IMU noise`` line, ``metrics.json``'s ``imu_noise_at_rest`` and
    ``RunResult.rest_noise``; ``imu.noise_at_rest: false`` measures nothing."""
    rec = _at_rest(3.0, duration_s=30.0)
    config = load_config(REPO / "configs" / "sins_only.yaml")
    result = Engine(config, rec).run()
    assert result.rest_noise.taken == ("gyro_arw_deg_rth", "accel_vrw_mg_rthz")
    assert f"IMU noise  {result.rest_noise.describe()}" in summary(result, rec)
    reported = json.loads(json.dumps(result.rest_noise.to_dict()))
    assert reported["taken"] == ["gyro_arw_deg_rth", "accel_vrw_mg_rthz"]
    assert reported["gyro_factor"] == pytest.approx(3.0, rel=0.1)
    config.imu.noise_at_rest = False
    off = Engine(config, rec).run()
    assert off.rest_noise.taken == () and "off" in off.rest_noise.reason
    assert "IMU noise" not in summary(off, rec)


# ------------------------------------------------------------------ σ on a noisier-than-stated IMU
def _noisier(path: Path, factor: float, seed: int) -> Recording:
    """The recording with white noise added to its IMU so that its total is ``factor`` × the
    datasheet's (the simulator's IMU is as its datasheet, within 2 %)."""
    rec = read_recording(path)
    spec = rec.meta.imu.spec
    assert spec is not None and spec.gyro_arw_deg_rth and spec.accel_vrw_mg_rthz
    root_rate = math.sqrt(rec.meta.imu.rate_hz)
    gyro = math.radians(spec.gyro_arw_deg_rth) / 60.0 * root_rate
    accel = spec.accel_vrw_mg_rthz * 1e-3 * 9.80665 * root_rate
    extra = math.sqrt(factor**2 - 1.0)
    rng = np.random.default_rng(seed)
    n = rec.imu.t.size
    return _with_imu(
        rec,
        rec.imu.gyro + extra * gyro * rng.standard_normal((n, 3)),
        rec.imu.accel + extra * accel * rng.standard_normal((n, 3)),
    )


def _pooled_z(config_name: str, recordings: list[Recording], at_rest: bool) -> float:
    runs = []
    for rec in recordings:
        config = load_config(REPO / "configs" / f"{config_name}.yaml")
        config.imu.noise_at_rest = at_rest
        result = Engine(config, rec).run()
        assert (result.rest_noise.taken != ()) == at_rest
        runs.append((result, rec))
    return pooled_horizontal_z(runs)


@pytest.mark.slow
def test_the_measured_noise_keeps_the_sigma_of_an_imu_noisier_than_its_datasheet(
    tmp_path: Path,
) -> None:
    """Random worlds whose IMU is 4× noisier than meta.yaml says: ``full_ckf`` keeps RMS(ε/σ)
    in [0.6, 1.5] with the noise measured at rest; with the datasheet's, the same filter claims
    far more than it keeps."""
    recordings = []
    for seed in (0, 1, 2):
        path = simulate(
            "longwall-random-short", tmp_path / f"w{seed}", seed=seed, overrides=["duration_s=300"]
        )
        recordings.append(_noisier(path, 4.0, seed))
    measured = _pooled_z("full_ckf", recordings, at_rest=True)
    stated = _pooled_z("full_ckf", recordings, at_rest=False)
    assert 0.6 <= measured <= 1.5, f"RMS(ε/σ) {measured:.2f} with the noise measured at rest"
    assert stated > 1.3 * measured, f"RMS(ε/σ) {stated:.2f} with the datasheet's"
