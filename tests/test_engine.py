"""The engine end to end: free inertial and position-aided runs, consistency, CLI, config errors."""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from analytic_truth import ShearerMotion, Synthetic, synthesize

from fusion.aiding.zupt import Zupt
from fusion.attitude import dcm_from_euler, wrap_angle
from fusion.cli import EXIT_BAD_INPUT, main
from fusion.config import ConfigError, load_config, parse_config
from fusion.engine import Engine
from fusion.error_model import ImuNoise
from fusion.metrics import interpolate_truth
from fusion.plugin import Measurement, MissingStream, PluginError
from fusion.recording import (
    ImuData,
    InitialSigma,
    PositionData,
    Recording,
    RecordingMeta,
    TruthData,
    read_recording,
    write_recording,
)
from fusion.sim.simulate import simulate
from tests.plugin_support import static_recording

SPEC = {
    "gyro_bias_deg_h": 20.0,
    "gyro_arw_deg_rth": 0.2,
    "accel_bias_mg": 2.0,
    "accel_vrw_mg_rthz": 0.1,
}
SIGMA = {"position_m": [0.05] * 3, "velocity_mps": [0.01] * 3, "attitude_deg": [0.3, 0.3, 1.0]}
LEVER_ARM = np.array([0.2, 0.5, 0.8])
CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@lru_cache(maxsize=2)
def _truth(duration: float) -> Synthetic:
    return synthesize(ShearerMotion().trajectory(), duration, 100.0)


def make_recording(seed: int, duration: float = 300.0, fixes: bool = True) -> Recording:
    """Shearer-like motion, MEMS IMU errors drawn from SPEC, 1 Hz fixes off the IMU grid."""
    syn = _truth(duration)
    rng = np.random.default_rng(seed)
    imu = ImuNoise.from_datasheet(**SPEC)
    n = len(syn.t)
    gyro_bias = imu.gyro_bias * rng.standard_normal(3)
    accel_bias = imu.accel_bias * rng.standard_normal(3)
    gyro = syn.gyro + gyro_bias + imu.gyro_arw * 10.0 * rng.standard_normal((n, 3))
    accel = syn.accel + accel_bias + imu.accel_vrw * 10.0 * rng.standard_normal((n, 3))
    att0 = np.rad2deg(syn.attitude[0]) + np.multiply(SIGMA["attitude_deg"], rng.standard_normal(3))
    meta = {
        "format": "shearer-recording/1",
        "name": f"engine-test-{seed}",
        "origin": dict(zip(("lat_deg", "lon_deg", "height_m"), syn.origin_deg, strict=True)),
        "initial": {
            "position_enu_m": (syn.position_enu[0] + 0.05 * rng.standard_normal(3)).tolist(),
            "velocity_enu_mps": (syn.velocity[0] + 0.01 * rng.standard_normal(3)).tolist(),
            "attitude_deg": dict(zip(("roll", "pitch", "yaw"), att0.tolist(), strict=True)),
            "sigma": SIGMA,
        },
        "imu": {"rate_hz": 100.0, "spec": SPEC},
        "extra": {"gyro_bias": gyro_bias.tolist(), "accel_bias": accel_bias.tolist()},
    }
    position = None
    if fixes:
        meta["position"] = {"lever_arm_b_m": LEVER_ARM.tolist()}
        tf = np.arange(1.0, syn.t[-1] - 1.0, 1.0) + 0.37
        idx = np.searchsorted(syn.t, tf)
        enu = np.stack([np.interp(tf, syn.t, syn.position_enu[:, k]) for k in range(3)], -1)
        c = dcm_from_euler(*syn.attitude[idx].T)
        enu += c @ LEVER_ARM + 0.05 * rng.standard_normal((len(tf), 3))
        position = PositionData(t=tf, enu=enu, sigma=np.full((len(tf), 3), 0.05))
    truth = TruthData(
        t=syn.t,
        position=syn.position_enu,
        velocity=syn.velocity,
        attitude=syn.attitude,
        cycle=np.ones(n, dtype=np.int64),
    )
    return Recording(
        path=None,
        meta=RecordingMeta.model_validate(meta),
        imu=ImuData(t=syn.t, gyro=gyro, accel=accel),
        position=position,
        truth=truth,
    )


def _normalized_errors(result, rec: Recording) -> np.ndarray:  # type: ignore[no-untyped-def]
    sol, truth = result.solution, rec.truth
    ref = np.stack([np.interp(sol.t, truth.t, truth.position[:, k]) for k in range(3)], -1)
    return (sol.position - ref) / sol.sigma_position


def test_free_inertial_run_grows_sigma_and_stays_within_it() -> None:
    rec = make_recording(1, fixes=False)
    result = Engine(load_config(CONFIGS / "sins_only.yaml"), rec).run()
    sol = result.solution
    assert np.allclose(np.diff(sol.t), 0.1)
    assert sol.t[0] == rec.imu.t[0] and sol.t[-1] == pytest.approx(rec.imu.t[-1])
    assert np.all(np.diff(sol.sigma_position[:, 0]) >= 0)
    assert sol.sigma_position[-1, 0] > 10 * sol.sigma_position[0, 0]
    assert np.max(np.abs(_normalized_errors(result, rec))) < 4.0
    # Attitude stays within its initial uncertainty band (yaw 1°) for a free 5 min.
    yaw_err = wrap_angle(sol.attitude[-1, 2] - rec.truth.attitude[-1, 2])
    assert abs(np.rad2deg(yaw_err)) < 4.0


def test_position_aided_runs_are_consistent_over_seeded_runs() -> None:
    """20 seeded runs: NEES-style RMS(err/σ) and whitened innovations near 1."""
    config = parse_config({"name": "sins_position", "plugins": [{"type": "position"}]})
    ratios, whitened = [], []
    for seed in range(20):
        rec = make_recording(100 + seed)
        result = Engine(config, rec).run()
        keep = result.solution.t > 30.0
        ratios.append(_normalized_errors(result, rec)[keep])
        whitened.append(result.innovations["position"].whitened_rms())
    rms = np.sqrt(np.mean(np.concatenate(ratios) ** 2))
    print(f"position RMS(err/σ) {rms:.3f}, whitened innovation RMS {np.mean(whitened):.3f}")
    assert 0.7 <= rms <= 1.3
    assert 0.7 <= np.mean(whitened) <= 1.3


def test_position_fixes_estimate_the_biases_within_their_sigma() -> None:
    """Closed loop: the SINS bias compensation plus the residual estimate vs the drawn bias."""
    config = parse_config({"name": "sins_position", "plugins": [{"type": "position"}]})
    rec = make_recording(7, duration=600.0)
    result = Engine(config, rec).run()
    prior = ImuNoise.from_datasheet(**SPEC)
    # Level gyros (through the tilt the fixes reveal) and the vertical accelerometer become
    # observable within 10 min; horizontal accelerometer biases stay tied to the tilt.
    for block, prior_sd, observable in (
        ("gyro_bias", prior.gyro_bias, [0, 1]),
        ("accel_bias", prior.accel_bias, [2]),
    ):
        est, sd = result.state_estimate(block)
        truth = np.array(rec.meta.extra[block])
        assert np.all(np.abs(est - truth) < 3 * sd), (block, est, truth, sd)
        assert np.all(sd[observable] < 0.5 * prior_sd), (block, sd, prior_sd)


def test_cli_run_validate_and_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec_dir = tmp_path / "rec"
    write_recording(make_recording(3, duration=60.0), rec_dir)
    assert main(["validate", str(rec_dir)]) == 0
    config = tmp_path / "c.yaml"
    config.write_text("name: pos\nplugins:\n  - type: position\n")
    assert main(["run", "--config", str(config), "--recording", str(rec_dir), "--check"]) == 0
    out = tmp_path / "out"
    code = main(["run", "--config", str(config), "--recording", str(rec_dir), "--out", str(out)])
    assert code == 0
    for name in ("solution.csv", "metrics.json", "plan.png", "errors.png"):
        assert (out / name).exists(), name
    text = capsys.readouterr().out
    assert "horizontal RMS" in text and "position: 5" in text
    assert read_recording(rec_dir).imu.t.size == 6001


def test_cli_names_the_plugin_and_recording_when_a_sensor_is_missing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A configuration none of whose plugins has its sensor file in the recording: bad input
    (3) and one line naming the configuration key, the plugin, the recording and the file (no
    traceback, nothing run)."""
    rec_dir = tmp_path / "rec"
    write_recording(make_recording(5, duration=20.0, fixes=False), rec_dir)
    config = tmp_path / "c.yaml"
    config.write_text("name: uwb\nplugins:\n  - type: uwb\n")
    out = tmp_path / "out"
    code = main(["run", "--config", str(config), "--recording", str(rec_dir), "--out", str(out)])
    assert code == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "key plugins[0] (uwb)" in err and str(rec_dir) in err and "uwb.csv" in err
    assert not (out / "solution.csv").exists()


def test_a_plugin_whose_sensor_is_missing_is_left_out_and_said_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every aiding file is optional in the format: a configuration with position fixes and
    UWB runs on a recording without uwb.csv as position fixes alone, and the summary,
    metrics.json and run.json (the plugin disabled) say what was left out. With
    ``required: true`` on the UWB block the same recording is bad input."""
    rec_dir = tmp_path / "rec"
    write_recording(make_recording(6, duration=30.0), rec_dir)
    config = tmp_path / "c.yaml"
    config.write_text("name: pos_uwb\nplugins:\n  - type: position\n  - type: uwb\n")
    out = tmp_path / "out"
    code = main(["run", "--config", str(config), "--recording", str(rec_dir), "--out", str(out)])
    assert code == 0
    text = capsys.readouterr()
    assert "left out   configuration: key plugins[1] (uwb)" in text.out
    assert "uwb.csv" in text.err
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(metrics["left_out"]["plugins"]) == 1
    used = json.loads((out / "run.json").read_text())["config"]["plugins"]
    assert [(p["type"], p["enabled"]) for p in used] == [("position", True), ("uwb", False)]
    result = Engine(load_config(config), read_recording(rec_dir)).run()
    assert list(result.innovations) == ["position"] and len(result.left_out) == 1

    config.write_text(
        "name: pos_uwb\nplugins:\n  - type: position\n  - {type: uwb, required: true}\n"
    )
    out = tmp_path / "out_required"
    code = main(["run", "--config", str(config), "--recording", str(rec_dir), "--out", str(out)])
    assert code == EXIT_BAD_INPUT
    assert "key plugins[1] (uwb)" in capsys.readouterr().err
    assert not (out / "solution.csv").exists()


def test_the_flagship_runs_on_a_face_without_odometer_and_magnetometer(tmp_path: Path) -> None:
    """``full_afkf_rts`` on a recording with UWB alone among its aiding files: the odometer,
    the ZUPT (it needs the encoder's stops), CPOEM, the magnetometer and the position fixes are
    left out, and the online smoother, whose windows CPOEM ended, smooths the whole recording
    instead."""
    path = simulate("longwall-random-short", tmp_path / "rec", seed=1, overrides=["duration_s=60"])
    for name in ("odometer.csv", "magnetometer.csv"):
        (path / name).unlink()
    rec = read_recording(path)
    meta = rec.meta.model_copy(update={"odometer": None, "magnetometer": None})
    rec = replace(rec, meta=meta, odometer=None, magnetometer=None)
    result = Engine(load_config(CONFIGS / "full_afkf_rts.yaml"), rec).run()
    assert list(result.innovations) == ["uwb"]
    assert [r.split("(")[1].split(")")[0] for r in result.left_out] == [
        "odometer",
        "zupt",
        "cpoem",
        "magnetometer",
        "position",
    ]
    assert result.smoothed is not None and np.isfinite(result.smoothed.position).all()


@pytest.fixture(scope="module")
def short_world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 60-s random world with every sensor."""
    out = tmp_path_factory.mktemp("world") / "rec"
    return simulate("longwall-random-short", out, seed=1, overrides=["duration_s=60"])


def test_a_stream_too_short_to_use_is_taken_as_absent(
    short_world: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A uwb.csv of its header only (a tag never in range) is a missing stream: ``full_afkf``
    runs without its UWB plugin, and ``uwb_only`` refuses with a clear error instead of the
    IndexError its least-squares solution raised on an empty stream. A single odometer reading,
    which has no interval, is absent too (it stopped the odometer plugin with 'cannot convert
    float NaN to integer')."""
    rec = read_recording(short_world)
    assert rec.uwb is not None
    uwb = rec.uwb
    silent = replace(uwb, t=uwb.t[:0], anchor_index=uwb.anchor_index[:0], range=uwb.range[:0])
    rec = replace(rec, uwb=silent)
    with caplog.at_level(logging.WARNING, logger="fusion.engine"):
        result = Engine(load_config(CONFIGS / "full_afkf.yaml"), rec).run()
    assert "uwb.csv holds 0 reading(s): taken as absent" in caplog.text
    assert "uwb" not in result.innovations and any("(uwb)" in r for r in result.left_out)
    assert np.isfinite(result.solution.position).all()
    with pytest.raises(MissingStream, match="no plugin of the configuration has its stream"):
        Engine(load_config(CONFIGS / "uwb_only.yaml"), rec)
    assert rec.odometer is not None
    one = replace(rec.odometer, t=rec.odometer.t[:1], speed=rec.odometer.speed[:1])
    with caplog.at_level(logging.WARNING, logger="fusion.engine"):
        Engine(load_config(CONFIGS / "sins_od_cpoem.yaml"), replace(rec, odometer=one))
    assert "odometer.csv holds 1 reading(s): taken as absent" in caplog.text


def test_python_api_accepts_paths_and_mappings(tmp_path: Path) -> None:
    import fusion

    rec_dir = tmp_path / "rec"
    write_recording(make_recording(4, duration=20.0, fixes=False), rec_dir)
    result = fusion.run({"name": "free"}, rec_dir)
    assert result.solution.position.shape == (201, 3)  # type: ignore[attr-defined]


def test_misspelled_config_key_is_named_with_a_suggestion(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("name: x\nfilter:\n  covariance_stp_s: 0.2\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert "bad.yaml" in msg and "filter.covariance_stp_s" in msg
    assert "unknown key" in msg and "covariance_step_s" in msg


def test_imu_file_is_read_relative_to_the_config_and_overridden_beside_it(tmp_path: Path) -> None:
    (tmp_path / "imu").mkdir()
    (tmp_path / "imu" / "grade.yaml").write_text("gyro_arw_deg_rth: 0.6\nnoise_scale: 2.0\n")
    path = tmp_path / "c.yaml"
    path.write_text("name: x\nimu: {file: imu/grade.yaml, noise_scale: 5.0}\n")
    imu = load_config(path).imu
    assert (imu.gyro_arw_deg_rth, imu.noise_scale) == (0.6, 5.0)
    path.write_text("name: x\nimu: {file: imu/none.yaml}\n")
    with pytest.raises(ConfigError, match=r"none\.yaml: cannot read"):
        load_config(path)
    (tmp_path / "imu" / "grade.yaml").write_text("- 1\n")
    path.write_text("name: x\nimu: {file: imu/grade.yaml}\n")
    with pytest.raises(ConfigError, match=r"c\.yaml: imu\.file .imu/grade\.yaml. must hold"):
        load_config(path)


@pytest.mark.parametrize(
    "name", [p.stem for p in sorted(CONFIGS.glob("*.yaml")) if not p.stem.startswith("real_")]
)
def test_every_shipped_configuration_runs_without_a_datasheet(
    name: str, short_world: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """meta.yaml's ``imu.spec`` is optional in the format; a recording without it was refused by
    every shipped configuration (the filter's noise, the ZUPT's thresholds and the ZARU's noise
    all come from it). The assumed industrial MEMS figures are taken, with a warning naming
    them, and the run is finite."""
    rec = read_recording(short_world)
    meta = rec.meta.model_copy(update={"imu": rec.meta.imu.model_copy(update={"spec": None})})
    with caplog.at_level(logging.WARNING, logger="fusion.engine"):
        result = Engine(load_config(CONFIGS / f"{name}.yaml"), replace(rec, meta=meta)).run()
    assert "gyro_arw_deg_rth 0.6" in caplog.text and "accel_vrw_mg_rthz 0.08" in caplog.text
    assert np.isfinite(result.solution.position).all()


def test_a_figure_the_datasheet_lacks_is_the_configurations_or_the_assumed_one(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Where meta.yaml's ``imu.spec`` lacks a figure, the configuration's ``imu`` figure fills
    it, else :data:`fusion.engine.ASSUMED_IMU_SPEC`'s, and only an assumed figure is warned
    about; a stated figure is kept."""
    from fusion.config import ImuTuning
    from fusion.engine import ASSUMED_IMU_SPEC, with_imu_spec
    from fusion.recording import ImuSpec

    rec = make_recording(5, duration=10.0, fixes=False)
    partial = ImuSpec(gyro_bias_deg_h=50.0)
    meta = rec.meta.model_copy(update={"imu": rec.meta.imu.model_copy(update={"spec": partial})})
    with caplog.at_level(logging.WARNING, logger="fusion.engine"):
        filled = with_imu_spec(replace(rec, meta=meta), ImuTuning(accel_bias_mg=7.0))
    spec = filled.meta.imu.spec
    assert spec is not None
    assert (spec.gyro_bias_deg_h, spec.accel_bias_mg) == (50.0, 7.0)
    assert spec.gyro_arw_deg_rth == ASSUMED_IMU_SPEC["gyro_arw_deg_rth"]
    assert spec.accel_vrw_mg_rthz == ASSUMED_IMU_SPEC["accel_vrw_mg_rthz"]
    assert "gives gyro_arw_deg_rth, accel_vrw_mg_rthz:" in caplog.text
    assert with_imu_spec(filled, ImuTuning()) is filled


def test_the_assumed_imu_is_the_simulators_mti_g_700() -> None:
    """The engine states the assumed datasheet itself (it does not import the simulator); the
    figures are those the simulator writes for the MTi-G-700 it is named after."""
    from fusion.engine import ASSUMED_IMU_SPEC
    from fusion.sim.sensors import IMU_GRADES, spec_for_meta

    assert ASSUMED_IMU_SPEC == spec_for_meta(IMU_GRADES["mti-g-700"])


def test_imu_figures_of_zero_are_raised_to_the_floor_with_a_warning(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """An error-free accelerometer (seed 000's grade par5) must not leave the velocity without
    process noise, nor a bias of σ 0 the covariance singular; a figure above the floor is taken
    as it is."""
    from fusion.config import ImuTuning
    from fusion.engine import IMU_FIGURE_FLOOR, resolve_imu_noise
    from fusion.recording import ImuSpec

    spec = ImuSpec(
        gyro_bias_deg_h=0.0, gyro_arw_deg_rth=2.0, accel_bias_mg=0.0, accel_vrw_mg_rthz=0.0
    )
    with caplog.at_level(logging.WARNING, logger="fusion.engine"):
        noise = resolve_imu_noise(ImuTuning(), spec)
    floor = ImuNoise.from_datasheet(
        **{k: v for k, v in IMU_FIGURE_FLOOR.items() if k != "gyro_arw_deg_rth"},
        gyro_arw_deg_rth=2.0,
    )
    assert floor.accel_vrw > 0.0 and floor.gyro_bias > 0.0 and floor.accel_bias > 0.0
    assert noise == floor
    assert "imu.accel_vrw_mg_rthz: 0 is below any inertial sensor's" in caplog.text
    assert "gyro_arw" not in caplog.text


def test_the_federated_filter_runs_from_a_start_known_exactly(short_world: Path) -> None:
    """meta.yaml may state σ 0 for the initial state and for the turn-on biases (a simulator's
    known start, a field left at 0): the filter takes its floors and every output is finite.
    ``full_afkf_rts`` stopped with a traceback: the federated master's information fusion divided
    by the zero variances."""
    rec = read_recording(short_world)
    zero = InitialSigma(position_m=(0, 0, 0), velocity_mps=(0, 0, 0), attitude_deg=(0, 0, 0))
    assert rec.meta.imu.spec is not None
    spec = rec.meta.imu.spec.model_copy(update={"gyro_bias_deg_h": 0.0, "accel_bias_mg": 0.0})
    meta = rec.meta.model_copy(
        update={
            "initial": rec.meta.initial.model_copy(update={"sigma": zero}),
            "imu": rec.meta.imu.model_copy(update={"spec": spec}),
        }
    )
    result = Engine(load_config(CONFIGS / "full_afkf_rts.yaml"), replace(rec, meta=meta)).run()
    assert result.smoothed is not None
    for track in (result.solution, result.smoothed):
        assert np.isfinite(track.position).all() and np.isfinite(track.sigma_position).all()


def test_bias_instability_fraction_follows_the_turn_on_bias_of_either_place() -> None:
    from fusion.config import ImuTuning
    from fusion.engine import resolve_imu_noise
    from fusion.recording import ImuSpec

    spec = ImuSpec(
        gyro_bias_deg_h=720.0, gyro_arw_deg_rth=0.6, accel_bias_mg=3.0, accel_vrw_mg_rthz=0.08
    )
    tuning = ImuTuning(bias_instability_fraction=0.02, bias_correlation_time_s=100.0)
    noise = resolve_imu_noise(tuning, spec)
    assert noise.gyro_bias_instability == pytest.approx(0.02 * noise.gyro_bias)
    assert noise.accel_bias_instability == pytest.approx(0.02 * noise.accel_bias)
    own = resolve_imu_noise(tuning.model_copy(update={"gyro_bias_deg_h": 3.0}), spec)
    assert own.gyro_bias_instability == pytest.approx(0.02 * 3.0 * np.pi / 180.0 / 3600.0)
    with pytest.raises(ConfigError, match=r"imu\.bias_instability_fraction replaces"):
        parse_config(
            {
                "name": "x",
                "imu": {"bias_instability_fraction": 0.02, "gyro_bias_instability_deg_h": 10.0},
            }
        )


def test_unknown_plugin_and_bad_plugin_option_are_named() -> None:
    from fusion.plugin import PluginError

    rec = make_recording(6, duration=10.0)
    with pytest.raises(PluginError, match=r"plugins\[0\]\.type: no plugin 'odometr'"):
        Engine(parse_config({"name": "x", "plugins": [{"type": "odometr"}]}), rec)
    with pytest.raises(PluginError, match=r"plugins\[0\]\.sigma_scal: unknown key"):
        Engine(parse_config({"name": "x", "plugins": [{"type": "position", "sigma_scal": 2}]}), rec)


def test_max_rate_thins_epochs_and_keeps_shared_time_stamps_together() -> None:
    from fusion.engine import _at_most

    epochs = np.array([0.0, 0.02, 0.02, 0.04, 0.1, 0.1, 0.12, 0.2, 0.31])
    kept = _at_most(epochs, 10.0)
    np.testing.assert_array_equal(epochs[kept], [0.0, 0.1, 0.1, 0.2, 0.31])
    assert _at_most(epochs, None).all()


def test_validate_config_checks_plugin_options(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nplugins:\n  - {type: odometer, sigma_sped_mps: 0.01}\n")
    assert main(["validate-config", str(bad)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "plugins[0].sigma_sped_mps" in err and "sigma_speed_mps" in err


# ------------------------------------------------------- plugin measurements the engine refuses
def test_a_non_finite_measurement_is_a_plugin_error_naming_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    measure = Zupt.measure

    def broken(self: Zupt, index: int, ctx: Any) -> Measurement | None:
        m = measure(self, index, ctx)
        return None if m is None else replace(m, z=np.full_like(m.z, np.nan))

    monkeypatch.setattr(Zupt, "measure", broken)
    config = parse_config({"name": "z", "plugins": [{"type": "zupt"}]})
    with pytest.raises(PluginError, match=r"plugin 'zupt' returned a measurement with a NaN"):
        Engine(config, static_recording()).run()


def test_an_update_whose_innovation_covariance_is_not_positive_definite_is_rejected(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """S = H P Hᵀ + R not positive definite (a plugin's R, or a stored error's cross terms gone
    inconsistent after an isolation): the update is counted as rejected, the run goes on
    (a harsh random world stopped ``full_afkf`` with a LinAlgError at a CPOEM update)."""
    measure = Zupt.measure

    def indefinite(self: Zupt, index: int, ctx: Any) -> Measurement | None:
        m = measure(self, index, ctx)
        return None if m is None else replace(m, R=-1e3 * np.eye(m.z.size))

    monkeypatch.setattr(Zupt, "measure", indefinite)
    config = parse_config({"name": "z", "plugins": [{"type": "zupt"}]})
    result = Engine(config, static_recording()).run()
    log = result.innovations["zupt"]
    assert log.count > 0 and log.rejected == log.count
    assert np.isfinite(result.solution.position).all()


@pytest.mark.parametrize("config", ["full_afkf_rts", "sins_mc_zupt", "sins_od_cpoem_rts"])
def test_an_engine_run_twice_gives_the_same_solution(
    tmp_path_factory: pytest.TempPathFactory, config: str
) -> None:
    """Every plugin forgets at ``start_run`` what a run taught it (adaptive noise, stored
    points, reference travel, rest scatter), so a second run of one engine is the first one
    again, forward and smoothed, to the last bit."""
    directory = tmp_path_factory.mktemp("twice") / "rec"
    simulate("longwall-random", directory, seed=3, overrides=("duration_s=120",))
    recording = read_recording(directory, bridge_imu_gaps=True)
    engine = Engine(load_config(CONFIGS / f"{config}.yaml"), recording)
    first, second = engine.run(), engine.run()
    np.testing.assert_array_equal(first.solution.position, second.solution.position)
    np.testing.assert_array_equal(first.solution.sigma_position, second.solution.sigma_position)
    if first.smoothed is not None:
        assert second.smoothed is not None
        np.testing.assert_array_equal(first.smoothed.position, second.smoothed.position)


def test_a_start_facing_south_with_a_pitch_less_certain_than_the_roll_holds(
    tmp_path: Path,
) -> None:
    """meta.yaml's attitude σ are the roll's, pitch's and yaw's; the filter's are the
    misalignment's about east, north and up. Random world 27 starts facing south (yaw 183°)
    with σ 0.42° / 1.31° / 1.32° and a pitch 3.9° off: read as φ's σ, east's was the roll's
    0.42°, the odometer's zero speeds were rejected from the first (NIS 62 on 3 rows), and the
    SINS coasted 137 m within the 30-s standstill (900 km by 600 s)."""
    directory = tmp_path / "rec"
    simulate("longwall-random", directory, seed=27, overrides=("duration_s=30",))
    recording = read_recording(directory)
    result = Engine(load_config(CONFIGS / "sins_od_ckf.yaml"), recording).run()
    odometer = result.innovations["odometer"]
    assert odometer.rejected <= 0.05 * odometer.count
    assert recording.truth is not None
    inside, position, *_ = interpolate_truth(recording.truth, result.solution.t)
    error = result.solution.position[inside, :2] - position[:, :2]
    assert np.hypot(*error.T).max() < 0.5
