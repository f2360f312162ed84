"""Fault injection through the federated master: detection, isolation, re-admission, error bound.

Short seeded recordings of the simulator's fault cases. The plain CKF of seed 003 is the
magnetometer without adaptive noise and without a gate; the AFKF is configs/sins_od_mag_afkf.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusion.config import FusionConfig, load_config, parse_config
from fusion.engine import Engine, RunResult
from fusion.fault_detection import ISOLATE, READMIT
from fusion.metrics import interpolate_truth
from fusion.recording import Recording, read_recording
from fusion.sim.simulate import simulate

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SHORT = ["static_start_s=30", "duration_s=125"]


def _max_horizontal(result: RunResult, rec: Recording) -> float:
    assert rec.truth is not None
    inside, position, *_ = interpolate_truth(rec.truth, result.solution.t)
    err = result.solution.position[inside] - position
    return float(np.max(np.hypot(err[:, 0], err[:, 1])))


def _plain_ckf() -> FusionConfig:
    data = load_config(CONFIGS / "sins_od_mag_ckf.yaml").model_dump()
    for block in data["plugins"]:
        if block["type"] == "magnetometer":
            block["adaptive_noise"] = "off"
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

    clean = _max_horizontal(Engine(afkf, recordings["seed003-brokenline"]).run(), disturbed)
    afkf_max = _max_horizontal(result, disturbed)
    ckf_max = _max_horizontal(Engine(_plain_ckf(), disturbed).run(), disturbed)
    print(f"max horizontal: AFKF {afkf_max:.2f} m (clean {clean:.2f}), plain CKF {ckf_max:.2f} m")
    assert afkf_max <= 1.3 * clean
    assert afkf_max <= 0.5 * ckf_max


def test_odometer_slip_isolated_and_readmitted(
    recordings: dict[str, Recording], tmp_path: Path
) -> None:
    """A 30 % over-reading wheel for 15 s: the kinematic local is isolated at once and re-admitted
    after window + hold, and the AFKF's max error stays below the CKF's, which takes the slip
    into its odometer scale (11.0 m against 16.2 m). With the odometer the only velocity aid the
    free SINS drifts while it is isolated: far from the 1.3× of the clean run the issue hopes
    for (see the closing note)."""
    fault = "faults=[{kind: odometer_slip, t_start: 60, t_end: 75, slip_ratio: 0.3}]"
    simulate("seed003-brokenline", tmp_path / "slip", seed=2, overrides=[*SHORT, fault])
    slipping = read_recording(tmp_path / "slip")
    afkf = load_config(CONFIGS / "sins_od_mag_afkf.yaml")
    opts = afkf.filter.federated.fault_detection
    result = Engine(afkf, slipping).run()
    events = [(e.local, e.action, e.t) for e in result.faults]
    assert [(loc, act) for loc, act, _ in events] == [
        ("kinematic", ISOLATE),
        ("kinematic", READMIT),
    ]
    assert 60.0 <= events[0][2] <= 62.0
    assert 75.0 + opts.hold_s <= events[1][2] <= 75.0 + opts.window_s + opts.hold_s + 2.0
    ckf = Engine(load_config(CONFIGS / "sins_od_mag_ckf.yaml"), slipping).run()
    afkf_max, ckf_max = _max_horizontal(result, slipping), _max_horizontal(ckf, slipping)
    print(f"max horizontal under slip: AFKF {afkf_max:.2f} m, CKF {ckf_max:.2f} m")
    assert afkf_max < ckf_max
