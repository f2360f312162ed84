"""Physical-plausibility screening (fusion/screening.py): each rule, its recovery, causality,
the IMU gaps it leaves, the configuration and the reporting; then, per stream, one implausible
sample in a simulated recording leaves the full AFKF's accuracy as it was, and one 10⁶ m/s
odometer reading leaves the peak memory as it was."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fusion.config import ConfigError, FusionConfig, ScreeningOptions, load_config, parse_config
from fusion.engine import Engine, RunResult
from fusion.metrics import compute_metrics
from fusion.recording import (
    ImuData,
    MagnetometerData,
    OdometerData,
    PositionData,
    Recording,
    SupportData,
    UwbData,
)
from fusion.screening import (
    STREAMS,
    ScreeningReport,
    screen_imu,
    screen_magnetometer,
    screen_odometer,
    screen_position,
    screen_recording,
    screen_support,
    screen_uwb,
)
from tests.plugin_support import recording_meta

DEFAULTS = ScreeningOptions()


def _options(**sections: dict[str, float]) -> ScreeningOptions:
    return ScreeningOptions.model_validate(sections)


def _imu(gyro: np.ndarray, accel: np.ndarray | None = None, rate_hz: float = 100.0) -> ImuData:
    n = gyro.shape[0]
    if accel is None:
        accel = np.tile([0.0, 0.0, 9.8], (n, 1))
    return ImuData(t=np.arange(n) / rate_hz, gyro=gyro, accel=accel)


def _rejected(verdicts: np.ndarray) -> list[int]:
    return np.flatnonzero(verdicts).tolist()


# ------------------------------------------------------------------------------------------
# Rules
# ------------------------------------------------------------------------------------------


def test_imu_range_rejects_beyond_the_sensor_range_and_keeps_real_foot_rates() -> None:
    """49 rad/s and 199 m/s² are beyond an MTi-class range; a heel strike's 9.7 rad/s and
    78 m/s² are not."""
    gyro = np.zeros((6, 3))
    accel = np.tile([0.0, 0.0, 9.8], (6, 1))
    gyro[2, 1] = 49.0
    accel[4, 2] = 199.0
    verdicts, rules = screen_imu(_imu(gyro, accel), DEFAULTS)
    assert _rejected(verdicts) == [2, 4]
    assert rules[verdicts[2] - 1].startswith("|ω| >") and rules[verdicts[4] - 1].startswith("|f|")
    gyro[2, 1], accel[4, 2] = 9.7, 78.0
    gyro[3, 0] = -9.7  # a step of 19 rad/s in 10 ms is within 1e4 rad/s²
    assert not screen_imu(_imu(gyro, accel), DEFAULTS)[0].any()


def test_imu_step_rule_rejects_a_spike_within_range() -> None:
    """With a shearer's platform limits a 3 rad/s spike inside the gyro range is a step too
    steep; the samples after it are judged against the last accepted one."""
    options = _options(imu={"max_angular_acceleration_rad_s2": 20.0})
    gyro = np.zeros((10, 3))
    gyro[4, 2] = 3.0
    verdicts, rules = screen_imu(_imu(gyro), options)
    assert _rejected(verdicts) == [4]
    assert rules[verdicts[4] - 1].startswith("|Δω|")


def test_step_rule_recovers_from_a_real_step() -> None:
    """A lasting step is rejected ``recovery_samples`` times, then taken as the new reference;
    the samples at the new level after it are accepted."""
    options = _options(imu={"max_angular_acceleration_rad_s2": 20.0, "recovery_samples": 3})
    gyro = np.zeros((12, 3))
    gyro[5:, 0] = 2.0
    verdicts, _ = screen_imu(_imu(gyro), options)
    assert _rejected(verdicts) == [5, 6, 7]


def test_a_first_sample_that_was_off_does_not_lock_the_screen_out() -> None:
    options = _options(odometer={"recovery_samples": 2, "speed_step_floor_mps": 0.05})
    speed = np.full(8, 0.1)
    speed[0] = 4.9  # within the speed range, but the acceleration to 0.1 m/s is not
    odometer = OdometerData(t=np.arange(8) * 0.1, speed=speed)
    assert _rejected(screen_odometer(odometer, options)[0]) == [1, 2]


def test_odometer_speed_and_acceleration() -> None:
    """The speed limit always; the acceleration rule only beyond the step floor, which by
    default lets any step within the speed range through (an encoder's count steps)."""
    speed = np.full(10, 0.1)
    speed[3] = 1e4
    speed[6] = 3.0  # within 5 m/s, but 2.9 m/s in 0.1 s is 3 g
    odometer = OdometerData(t=np.arange(10) * 0.1, speed=speed)
    assert _rejected(screen_odometer(odometer, DEFAULTS)[0]) == [3]
    options = _options(odometer={"speed_step_floor_mps": 0.05})
    verdicts, rules = screen_odometer(odometer, options)
    assert _rejected(verdicts) == [3, 6]
    assert rules[verdicts[3] - 1] == "|speed| > 5 m/s"
    assert rules[verdicts[6] - 1].startswith("|Δspeed|")


def test_magnetometer_norm_band() -> None:
    field = np.tile([20.0, 0.0, -45.0], (5, 1))
    field[1] = 1e308
    field[2] = 0.0
    field[3] = [0.0, 0.0, 900.0]  # a magnet nearby: the plugin's matter
    verdicts, _ = screen_magnetometer(
        MagnetometerData(t=np.arange(5) * 0.02, field=field), DEFAULTS
    )
    assert _rejected(verdicts) == [1, 2]


def test_uwb_range_within_reach() -> None:
    uwb = UwbData(np.arange(4.0), np.zeros(4, np.int64), np.array([3.0, 1e6, 0.0, 299.0]), ("A",))
    assert _rejected(screen_uwb(uwb, DEFAULTS)[0]) == [1]


def test_position_sigma_distance_and_jump() -> None:
    n = 8
    enu = np.zeros((n, 3))
    enu[:, 0] = np.arange(n) * 1.0  # 1 m/s
    sigma = np.full((n, 3), 0.02)
    sigma[1] = 1e-9
    enu[3, 1] = 2e5
    enu[5, 0] += 1e4  # 10 km off, 100 km from... no: 10 km from the origin, a 10 km jump in 1 s
    fixes = PositionData(t=np.arange(n, dtype=float), enu=enu, sigma=sigma)
    verdicts, rules = screen_position(fixes, DEFAULTS)
    assert _rejected(verdicts) == [1, 3, 5]
    assert [rules[verdicts[k] - 1].split()[0] for k in (1, 3, 5)] == ["σ", "more", "jump"]


def test_position_jump_is_judged_against_the_last_accepted_fix_with_time_between() -> None:
    """After an outage of 100 s a fix 2 km away is plausible at 100 m/s."""
    fixes = PositionData(
        t=np.array([0.0, 1.0, 101.0]),
        enu=np.array([[0.0, 0, 0], [1.0, 0, 0], [2000.0, 0, 0]]),
        sigma=np.full((3, 3), 0.05),
    )
    assert not screen_position(fixes, DEFAULTS)[0].any()


def test_support_advance_band() -> None:
    support = SupportData(t=np.arange(4.0), advance=np.array([0.8, -0.1, 2.5, 0.0]))
    assert _rejected(screen_support(support, DEFAULTS)[0]) == [1, 2]


def test_screening_is_causal() -> None:
    """Appending samples never changes the verdict on earlier ones (every stateful rule)."""
    rng = np.random.default_rng(3)
    n = 400
    gyro = rng.normal(0.0, 0.05, (n, 3))
    gyro[rng.integers(0, n, 40)] += rng.choice([-1, 1], (40, 3)) * rng.uniform(0, 60, (40, 3))
    accel = rng.normal([0, 0, 9.8], 0.3, (n, 3))
    accel[rng.integers(0, n, 40), 2] = rng.uniform(-250, 250, 40)
    speed = np.cumsum(rng.normal(0, 0.3, n))
    enu = np.cumsum(rng.normal(0, 80.0, (n, 3)), axis=0)
    options = _options(imu={"max_angular_acceleration_rad_s2": 50.0, "max_jerk_mps3": 200.0})
    t = np.arange(n) * 0.01
    full = (
        screen_imu(ImuData(t, gyro, accel), options)[0],
        screen_odometer(OdometerData(t, speed), options)[0],
        screen_position(PositionData(t * 100, enu, np.full((n, 3), 1.0)), options)[0],
    )
    assert all(v.any() for v in full)
    for m in (1, 37, 150, 399):
        prefix = (
            screen_imu(ImuData(t[:m], gyro[:m], accel[:m]), options)[0],
            screen_odometer(OdometerData(t[:m], speed[:m]), options)[0],
            screen_position(PositionData(t[:m] * 100, enu[:m], np.full((m, 3), 1.0)), options)[0],
        )
        for whole, part in zip(full, prefix, strict=True):
            np.testing.assert_array_equal(whole[:m], part)


# ------------------------------------------------------------------------------------------
# The screened recording
# ------------------------------------------------------------------------------------------


def _recording(n: int = 300, **streams: object) -> Recording:
    gyro = np.zeros((n, 3))
    accel = np.tile([0.0, 0.0, 9.8], (n, 1))
    return Recording(
        path=None,
        meta=recording_meta(odometer={"rate_hz": 10.0}),
        imu=ImuData(np.arange(n) / 100.0, gyro, accel),
        **streams,  # type: ignore[arg-type]
    )


def test_rejected_imu_runs_become_gaps_and_other_streams_lose_their_rows(
    caplog: pytest.LogCaptureFixture,
) -> None:
    rec = _recording(odometer=OdometerData(np.arange(1, 30) * 0.1, np.full(29, 0.1)))
    gyro = rec.imu.gyro.copy()
    gyro[100:150] = 49.9  # half a second just under the format's limit
    gyro[200, 0] = 40.0
    speed = rec.odometer.speed.copy()  # type: ignore[union-attr]
    speed[5] = 1e4
    rec = replace(
        rec,
        imu=ImuData(rec.imu.t, gyro, rec.imu.accel),
        odometer=OdometerData(rec.odometer.t, speed),  # type: ignore[union-attr]
    )
    with caplog.at_level(logging.WARNING, logger="fusion.screening"):
        screened, report = screen_recording(rec, DEFAULTS)
    assert screened.imu.t.size == 300 - 51
    assert screened.imu_gaps == [(0.99, 1.5), (1.99, 2.01)]
    assert report.imu_gaps == ((0.99, 1.5), (1.99, 2.01))
    assert screened.odometer is not None and screened.odometer.t.size == 28
    assert (report.rejected_in("imu"), report.rejected_in("odometer"), report.rejected) == (
        51,
        1,
        52,
    )
    assert report.stream("imu").rejected_by_rule == {"|ω| > 35 rad/s": 51}  # type: ignore[union-attr]
    assert sum("screening" in r.message for r in caplog.records) == 2
    assert screened.truth is None and screened.meta is rec.meta


def test_a_logging_gap_next_to_a_rejected_run_merges_into_its_gap() -> None:
    rec = _recording()
    t = np.concatenate([rec.imu.t[:100], rec.imu.t[110:]])  # a logging gap 0.99 → 1.1
    gyro = rec.imu.gyro[np.r_[0:100, 110:300]].copy()
    gyro[100] = 45.0  # the sample closing the logging gap, 1.1
    rec = replace(
        rec,
        imu=ImuData(t, gyro, rec.imu.accel[: t.size]),
        imu_gaps=[(0.99, 1.1), (2.5, 2.6)],
    )
    screened, report = screen_recording(rec, DEFAULTS)
    assert screened.imu_gaps == [(0.99, 1.11), (2.5, 2.6)]
    assert report.imu_gaps == ((0.99, 1.11),)


def test_a_rejected_run_at_either_end_truncates_the_imu() -> None:
    rec = _recording()
    gyro = rec.imu.gyro.copy()
    gyro[:3] = 40.0
    gyro[-2:] = 40.0
    screened, report = screen_recording(
        replace(rec, imu=ImuData(rec.imu.t, gyro, rec.imu.accel)), DEFAULTS
    )
    assert screened.imu.t[0] == 0.03 and screened.imu.t[-1] == 2.97
    assert screened.imu_gaps == [] and report.rejected == 5


def test_nothing_rejected_or_disabled_returns_the_recording_itself() -> None:
    rec = _recording(odometer=OdometerData(np.arange(1, 30) * 0.1, np.full(29, 1e4)))
    screened, report = screen_recording(rec, _options(enabled=False))  # type: ignore[arg-type]
    assert screened is rec and report == ScreeningReport(enabled=False)
    clean = _recording()
    screened, report = screen_recording(clean, DEFAULTS)
    assert screened is clean and report.rejected == 0
    assert [s.stream for s in report.streams] == ["imu"]


def test_an_imu_that_fits_no_limit_is_a_config_error() -> None:
    rec = _recording()
    with pytest.raises(ConfigError, match=r"screening\.imu"):
        screen_recording(rec, _options(imu={"max_specific_force_mps2": 1.0}))


# ------------------------------------------------------------------------------------------
# Configuration and reporting
# ------------------------------------------------------------------------------------------


def test_config_section_is_on_by_default_typed_and_described() -> None:
    config = parse_config({"name": "x"})
    assert config.screening.enabled
    assert not parse_config({"name": "x", "screening": {"enabled": False}}).screening.enabled
    with pytest.raises(ConfigError, match=r"screening\.odometer\.max_sped_mps"):
        parse_config({"name": "x", "screening": {"odometer": {"max_sped_mps": 2.0}}})
    with pytest.raises(ConfigError, match="min_field_uT"):
        parse_config({"name": "x", "screening": {"magnetometer": {"min_field_uT": 2e3}}})
    assert ScreeningOptions.model_fields["enabled"].description
    for section in STREAMS:
        for name, info in type(getattr(config.screening, section)).model_fields.items():
            assert info.description, f"screening.{section}.{name} has no description"


def test_summary_and_metrics_report_the_rejections(tmp_path: Path) -> None:
    """``fusion run``'s summary has one line per stream with rejections, metrics.json a
    ``screening`` key, the result a typed field."""
    from fusion.outputs import summary, write_outputs
    from fusion.recording import read_recording
    from fusion.sim.simulate import simulate

    rec = read_recording(
        simulate("longwall-200m", tmp_path / "rec", seed=4, overrides=["duration_s=70"])
    )
    assert rec.odometer is not None
    speed = rec.odometer.speed.copy()
    speed[300] = 1e4
    rec = replace(rec, odometer=OdometerData(rec.odometer.t, speed))
    config = parse_config({"name": "od", "plugins": [{"type": "odometer"}]})
    result = Engine(config, rec).run()
    assert result.screening.rejected_in("odometer") == 1
    text = summary(result, rec)
    n = rec.odometer.t.size
    assert (
        f"screened   odometer: 1 of {n} samples rejected as implausible (|speed| > 5 m/s)" in text
    )
    assert "screened   imu" not in text
    write_outputs(result, rec, tmp_path / "out", plots=False)
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["screening"]["streams"]["odometer"]["rejected"] == 1
    assert metrics["screening"]["streams"]["uwb"]["rejected"] == 0
    assert "solution.csv" in metrics


# ------------------------------------------------------------------------------------------
# One implausible sample per stream, the full AFKF on a simulated face
# ------------------------------------------------------------------------------------------

FIXES = "position={rate_hz: 1.0, sigma_m: [0.02, 0.02, 0.03], lever_arm_b_m: [0.3, 0.8, 0.4]}"
CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.fixture(scope="module")
def face(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    """60 s of ``longwall-200m`` (20 s static, then cutting) with 1-Hz position fixes; the
    unscreened figures in the docstrings below are measured on it (clean: 0.014 m horizontal
    RMS, 0.008 m with the fixes)."""
    from fusion.recording import read_recording
    from fusion.sim.simulate import simulate

    out = tmp_path_factory.mktemp("face") / "rec"
    return read_recording(
        simulate(
            "longwall-200m", out, seed=5, overrides=["duration_s=60", "static_start_s=20", FIXES]
        )
    )


def _config(with_position: bool) -> FusionConfig:
    data = load_config(CONFIGS / "full_afkf.yaml").model_dump()
    if not with_position:  # the face's fixes left unused
        data["plugins"] = [p for p in data["plugins"] if p["type"] != "position"]
    return parse_config(data)


@pytest.fixture(scope="module")
def clean_rms() -> dict[bool, float]:
    """Horizontal RMS of the clean face, with and without the position plugin (filled when
    first needed)."""
    return {}


def _horizontal_rms(recording: Recording, with_position: bool = False) -> tuple[float, RunResult]:
    result = Engine(_config(with_position), recording).run()
    assert recording.truth is not None
    return float(compute_metrics(result.solution, recording.truth)["horizontal_rms"]), result


def _assert_harmless(
    clean_rms: dict[bool, float],
    face: Recording,
    hostile: Recording,
    stream: str,
    rejected: int,
    *,
    with_position: bool = False,
) -> None:
    """The hostile copy's horizontal RMS within 10 % + 1 cm of the clean one's, and the samples
    counted as rejected in their stream."""
    if with_position not in clean_rms:
        clean_rms[with_position] = _horizontal_rms(face, with_position)[0]
    clean = clean_rms[with_position]
    rms, result = _horizontal_rms(hostile, with_position)
    assert abs(rms - clean) <= 0.1 * clean + 0.01, (stream, rms, clean)
    assert result.screening.rejected_in(stream) == rejected
    assert result.screening.rejected == rejected


def _late(n: int) -> int:
    """A row 80 % into a stream: the shearer is cutting."""
    return n * 4 // 5


def test_one_odometer_reading_at_1e4_mps(face: Recording, clean_rms: dict[bool, float]) -> None:
    """Unscreened: 2.9 km horizontal RMS."""
    assert face.odometer is not None
    speed = face.odometer.speed.copy()
    speed[_late(speed.size)] = 1e4
    hostile = replace(face, odometer=OdometerData(face.odometer.t, speed))
    _assert_harmless(clean_rms, face, hostile, "odometer", 1)


@pytest.mark.parametrize("value", [1e308, 0.0])
def test_one_magnetometer_reading_of_1e308_or_zero(
    face: Recording, clean_rms: dict[bool, float], value: float
) -> None:
    assert face.magnetometer is not None
    field = face.magnetometer.field.copy()
    field[_late(field.shape[0])] = value
    hostile = replace(face, magnetometer=MagnetometerData(face.magnetometer.t, field))
    _assert_harmless(clean_rms, face, hostile, "magnetometer", 1)


def test_one_uwb_range_of_1e6_m(face: Recording, clean_rms: dict[bool, float]) -> None:
    uwb = face.uwb
    assert uwb is not None
    ranges = uwb.range.copy()
    ranges[_late(ranges.size)] = 1e6
    hostile = replace(face, uwb=UwbData(uwb.t, uwb.anchor_index, ranges, uwb.anchor_ids))
    _assert_harmless(clean_rms, face, hostile, "uwb", 1)


def test_one_position_fix_10_km_off(face: Recording, clean_rms: dict[bool, float]) -> None:
    fixes = face.position
    assert fixes is not None
    enu = fixes.enu.copy()
    enu[_late(enu.shape[0]), 0] += 1e4
    hostile = replace(face, position=PositionData(fixes.t, enu, fixes.sigma))
    _assert_harmless(clean_rms, face, hostile, "position", 1, with_position=True)


def _imu_with(face: Recording, rows: slice, gyro: float | None, accel: float | None) -> Recording:
    g, a = face.imu.gyro.copy(), face.imu.accel.copy()
    if gyro is not None:
        g[rows, 2] = gyro
    if accel is not None:
        a[rows, 0] = accel
    return replace(face, imu=ImuData(face.imu.t, g, a))


def test_one_gyro_sample_of_49_rad_s(face: Recording, clean_rms: dict[bool, float]) -> None:
    """Unscreened: 0.067 m."""
    k = _late(face.imu.t.size)
    _assert_harmless(clean_rms, face, _imu_with(face, slice(k, k + 1), 49.0, None), "imu", 1)


def test_one_accelerometer_sample_of_199_mps2(
    face: Recording, clean_rms: dict[bool, float]
) -> None:
    """Unscreened: 5.3 m."""
    k = _late(face.imu.t.size)
    _assert_harmless(clean_rms, face, _imu_with(face, slice(k, k + 1), None, 199.0), "imu", 1)


def test_one_second_of_imu_just_under_the_format_limits(
    face: Recording, clean_rms: dict[bool, float]
) -> None:
    """100 samples at 49.9 rad/s and 199.9 m/s² are bridged as a 1-s gap; unscreened they
    left 2.3 km."""
    k = _late(face.imu.t.size)
    _assert_harmless(clean_rms, face, _imu_with(face, slice(k, k + 100), 49.9, 199.9), "imu", 100)


def test_an_odometer_reading_at_1e6_mps_leaves_the_peak_memory_as_it_was(tmp_path: Path) -> None:
    """Unscreened, CPOEM stored a point every 2 m of the 100 km that one reading claims and
    asked for a 168 GB covariance. Peak RSS of ``benchmarks.measure`` (a child process each,
    its address space capped so that a regression fails instead of swapping)."""
    from fusion.recording import read_recording, write_recording
    from fusion.sim.simulate import simulate

    clean = simulate("longwall-200m", tmp_path / "clean", seed=2, overrides=["duration_s=90"])
    rec = read_recording(clean)
    assert rec.odometer is not None
    speed = rec.odometer.speed.copy()
    speed[_late(speed.size)] = 1e6
    write_recording(replace(rec, odometer=OdometerData(rec.odometer.t, speed)), tmp_path / "bad")
    peaks = [
        _peak_rss_mb(CONFIGS / "sins_od_cpoem.yaml", path) for path in (clean, tmp_path / "bad")
    ]
    assert peaks[1] <= 1.1 * peaks[0], peaks


def _peak_rss_mb(config: Path, recording: Path) -> float:
    def cap() -> None:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))

    out = subprocess.run(
        [sys.executable, "-m", "benchmarks.measure", str(config), str(recording)],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
        preexec_fn=cap,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return float(json.loads(out.stdout.splitlines()[-1])["peak_rss_mb"])
