"""Fault injection through the federated master: detection, isolation, re-admission, error bound
(magnetic interference, odometer slip, UWB NLOS).

Short seeded recordings of the simulator's fault cases. The plain CKF of seed 003 is the
magnetometer without adaptive noise and without a gate; the AFKF is configs/sins_od_mag_afkf.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fusion.config import FusionConfig, load_config, parse_config
from fusion.engine import Engine
from fusion.fault_detection import ISOLATE, READMIT
from fusion.jumps import JUMP
from fusion.metrics import interpolate_truth
from fusion.recording import Recording, read_recording
from fusion.sim.simulate import simulate
from tests.fault_support import clean_and_faulty, max_horizontal, without_nlos_test

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SHORT = ["static_start_s=30", "duration_s=125"]


def _plain_ckf() -> FusionConfig:
    """Seed 003's CKF: the magnetometer at its sensor noise, without the adaptive R, without
    the disturbance indicator (whose flagged epochs the plugin down-weights) and ungated."""
    data = load_config(CONFIGS / "sins_od_mag_ckf.yaml").model_dump()
    for block in data["plugins"]:
        if block["type"] == "magnetometer":
            block["adaptive_noise"] = "off"
            block["disturbance_indicator"] = False
            block["gate_probability"] = None
    return parse_config(data)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Recording]:
    root = tmp_path_factory.mktemp("faults")
    out = {}
    for name in ("seed003-brokenline", "seed003-brokenline-maginterf"):
        simulate(name, root / name, seed=2, overrides=SHORT)
        out[name] = read_recording(root / name)
    return out


def test_magnetic_interference_isolated_readmitted_and_bounded(
    recordings: dict[str, Recording],
) -> None:
    disturbed = recordings["seed003-brokenline-maginterf"]
    window = disturbed.meta.extra["faults"][0]
    t_start, t_end = float(window["t_start"]), float(window["t_end"])
    afkf = load_config(CONFIGS / "sins_od_mag_afkf.yaml")
    hold = afkf.filter.federated.fault_detection.hold_s

    result = Engine(afkf, disturbed).run()
    events = [(e.local, e.action, e.t) for e in result.faults]
    assert [(loc, act) for loc, act, _ in events] == [("magnetic", ISOLATE), ("magnetic", READMIT)]
    assert t_start <= events[0][2] <= t_start + 3.0  # flagged within a few seconds of onset
    # Back after the hold, once the isolated local's own estimate (dragged by the interference
    # while it filtered alone) has re-converged and its mean innovation is unbiased again.
    window = afkf.filter.federated.fault_detection.window_s
    assert t_end + hold <= events[1][2] <= t_end + hold + window + 5.0

    clean = max_horizontal(Engine(afkf, recordings["seed003-brokenline"]).run(), disturbed)
    afkf_max = max_horizontal(result, disturbed)
    ckf_max = max_horizontal(Engine(_plain_ckf(), disturbed).run(), disturbed)
    print(f"max horizontal: AFKF {afkf_max:.2f} m (clean {clean:.2f}), plain CKF {ckf_max:.2f} m")
    assert afkf_max <= 1.3 * clean
    assert afkf_max <= 0.5 * ckf_max


def test_persistently_biased_magnetometer_is_not_isolated(recordings: dict[str, Recording]) -> None:
    """meta.yaml's earth field is 4 % weaker and 2° shallower than the site's and its
    declination 0.7° off (a field model that does not fit the site): the magnetometer's
    indicator learns the site's field instead of flagging every sample, the declination and
    hard-iron states take the heading bias, and the AFKF keeps the magnetometer in the fusion
    (it isolated it at its first epoch and never re-admitted it, 2.5 m against 0.6 m on a
    longwall)."""
    clean = recordings["seed003-brokenline"]
    assert clean.meta.magnetometer is not None and clean.truth is not None
    site = clean.meta.magnetometer
    off = site.model_copy(
        update={
            "field_uT": 0.96 * float(site.field_uT or 0.0),
            "inclination_deg": float(site.inclination_deg or 0.0) - 2.0,
            "declination_deg": site.declination_deg + 0.7,
        }
    )
    biased = replace(clean, meta=clean.meta.model_copy(update={"magnetometer": off}))
    result = Engine(load_config(CONFIGS / "sins_od_mag_afkf.yaml"), biased).run()
    log = result.innovations["magnetometer"]
    yaw_sigma = math.degrees(math.sqrt(result.final_covariance[5, 5]))
    sol = result.solution
    _, _, _, attitude, _ = interpolate_truth(clean.truth, sol.t[-1:])
    yaw_error = math.degrees(
        (sol.attitude[-1, 2] - attitude[0, 2] + math.pi) % (2 * math.pi) - math.pi
    )
    print(
        f"faults {result.faults}; flagged {np.mean(log.suspect):.1%};"
        f" final yaw error {yaw_error:.2f}° ± {yaw_sigma:.2f}°"
    )
    assert result.faults == []
    assert not np.any(log.suspect)
    assert abs(yaw_error) < 3.0 * yaw_sigma


def test_odometer_slip_taken_in_as_a_jump(recordings: dict[str, Recording], tmp_path: Path) -> None:
    """A 30 % over-reading wheel for 15 s at 0.86 m/s. The kinematic local fails its χ² window
    at the first slipping reading; the AFKF waits for the jump detector, which takes the slip in
    at its onset and sets it back to rest at its end, and the local is never isolated.
    Without slip detection the odometer's adaptive noise soaks the slip up (its innovations
    inflate R) and the CKF takes it into the odometer scale: both drift further (3.5 m and
    4.0 m against 2.1 m; 2.1 m without the slip; before the adaptive noise the AFKF isolated
    the kinematic local instead, 11.2 m). The issue's bound is 1.3× the
    clean run: seeds 0–7 give 0.77–1.2× except seed 3, 2.0× (1.9 m against 1.0 m; its onset
    estimate 0.269 ± 0.008 against 0.303 leaves 3 cm/s in the velocity during the slip).
    Before the odometer's reference windows were split at a slip's onset and end
    (fusion.aiding.reference_speed) this seed gave 5.6 m, 1.7×."""
    fault = "faults=[{kind: odometer_slip, t_start: 60, t_end: 75, slip_ratio: 0.3}]"
    simulate("seed003-brokenline", tmp_path / "slip", seed=2, overrides=[*SHORT, fault])
    slipping = read_recording(tmp_path / "slip")
    afkf = load_config(CONFIGS / "sins_od_mag_afkf.yaml")
    result = Engine(afkf, slipping).run()
    events = [(e.local, e.action, e.t, e.reason) for e in result.faults]
    assert [(loc, act) for loc, act, *_ in events] == [("odometer.slip", JUMP)] * 2
    assert 60.0 <= events[0][2] <= 60.5 and 75.0 <= events[1][2] <= 75.5
    assert "back to rest" in events[1][3]

    isolating = afkf.model_dump()
    isolating["plugins"][0]["slip_detection"] = False
    runs = {
        "AFKF": result,
        "AFKF isolating": Engine(parse_config(isolating), slipping).run(),
        "CKF": Engine(load_config(CONFIGS / "sins_od_mag_ckf.yaml"), slipping).run(),
    }
    worst = {name: max_horizontal(run, slipping) for name, run in runs.items()}
    clean = max_horizontal(Engine(afkf, recordings["seed003-brokenline"]).run(), slipping)
    print(f"max horizontal under slip: {worst} (clean AFKF {clean:.2f} m)")
    assert worst["AFKF"] <= 1.3 * clean
    assert worst["AFKF"] < min(worst["AFKF isolating"], worst["CKF"])


def test_uwb_nlos_withheld_or_isolated_and_bounded(tmp_path: Path) -> None:
    """30 s of NLOS on every anchor (bias 0.3–1.5 m on each range, σ 5 cm) 17 m from the gate.
    The UWB plugin's NLOS test withholds the ranges from the onset, so full_afkf has nothing to
    isolate. Without the test the master isolates the UWB local at the onset and has it back
    after the burst. Either way the maximum horizontal error stays within 1.3× that of the
    same run without NLOS (each anchor at 10 Hz). The recordings end at 280 s, 35 s after the
    re-admission (at 400 s every figure was the same)."""
    nlos = "faults=[{kind: uwb_nlos, t_start: 200, t_end: 230, bias_m: [0.3, 1.5]}]"
    clean, disturbed = clean_and_faulty(tmp_path, nlos, duration_s=280.0)
    config = load_config(CONFIGS / "full_afkf.yaml")
    nominal = max_horizontal(Engine(config, clean).run(), clean)

    result = Engine(config, disturbed).run()
    log = result.innovations["uwb"]
    t, accepted = np.asarray(log.t), np.asarray(log.accepted, dtype=bool)
    burst = (t > 200.5) & (t < 230.0)
    worst = max_horizontal(result, disturbed)
    print(f"withheld in the burst: {np.mean(~accepted[burst]):.4f}; max horizontal {worst:.3f} m")
    assert np.mean(~accepted[burst]) > 0.99
    assert not [e for e in result.faults if e.action == ISOLATE]
    assert worst <= 1.3 * nominal

    result = Engine(without_nlos_test(config), disturbed).run()
    events = [(e.local, e.action, e.t) for e in result.faults]
    worst = max_horizontal(result, disturbed)
    print(events, f"max horizontal: {worst:.3f} m with NLOS, {nominal:.3f} m without")
    assert {loc for loc, _, _ in events} == {"uwb"}
    assert events[0][1] == ISOLATE and 200.0 <= events[0][2] <= 201.0
    assert events[-1][1] == READMIT and events[-1][2] >= 230.0
    assert worst <= 1.3 * nominal


def test_slip_that_ends_during_a_stop_is_restarted_at_rest(tmp_path: Path) -> None:
    """+20 % slip from 100 s to 150 s; the shearer (longwall-200m seed 2) stops at ≈ 142 s and
    starts again at ≈ 159 s. At a standstill the slip has no effect on any reading, so its end
    cannot be detected; the odometer reports the slip state at rest and the AFKF restarts it
    there. Before, it kept +0.2 through the stop and the restart had to reveal the end
    (ablation seed 1: the UWB local was isolated first, 7.4 m RMS against 0.03 m)."""
    short = ["static_start_s=30", "duration_s=200", "uwb.rate_hz=20"]  # 40 Hz: twice the work
    slip = "faults=[{kind: odometer_slip, t_start: 100, t_end: 150, ramp_s: 2, slip_ratio: 0.2}]"
    simulate("longwall-200m", tmp_path / "clean", seed=2, overrides=short)
    simulate("longwall-200m", tmp_path / "slip", seed=2, overrides=[*short, slip])
    clean, slipping = read_recording(tmp_path / "clean"), read_recording(tmp_path / "slip")
    assert slipping.truth is not None
    speed = np.linalg.norm(slipping.truth.velocity, axis=1)
    stopped = slipping.truth.t[(slipping.truth.t > 120) & (speed < 1e-3)]
    stop, restart = float(stopped[0]), float(stopped[-1])
    config = load_config(CONFIGS / "full_afkf.yaml")
    result = Engine(config, slipping).run()
    events = [(e.local, e.action, e.t, e.reason) for e in result.faults]
    print(events, stop, restart)
    assert [(loc, act) for loc, act, *_ in events] == [("odometer.slip", JUMP)] * 2
    assert 100.0 <= events[0][2] <= 108.0  # onset seen through the UWB: 6.6 s at 20 Hz, < 5 at 40
    assert stop - 3.0 <= events[1][2] <= restart and "at a standstill" in events[1][3]
    nominal = max_horizontal(Engine(config, clean).run(), clean)
    assert max_horizontal(result, slipping) <= 1.3 * nominal
