"""The state history: every estimated state and its 1-σ at the output epochs, states.csv."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fusion.attitude import dcm_from_euler, euler_from_dcm, euler_jacobian, skew
from fusion.config import load_config, parse_config
from fusion.engine import Engine, RunResult
from fusion.error_model import ATTITUDE, STATE_UNITS, StateBlock
from fusion.outputs import write_outputs
from fusion.recording import Recording, read_recording
from fusion.sim.simulate import simulate
from fusion.solution import SOLUTION_COLUMNS
from fusion.state_history import NOMINAL_COLUMNS, column_name

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
UNITS = tuple(u for u in STATE_UNITS if u)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    """20 s of a random longwall world: IMU, odometer, support pushes, truth."""
    out = tmp_path_factory.mktemp("states") / "rec"
    simulate("longwall-random-short", out, seed=1, overrides=["duration_s=20"])
    return read_recording(out)


def _run(recording: Recording, architecture: str, states: bool = True) -> RunResult:
    data = load_config(CONFIGS / "sins_od_cpoem.yaml").model_dump()
    data["filter"]["architecture"] = architecture
    data["output"]["states"] = states
    return Engine(parse_config(data), recording).run()


@pytest.fixture(scope="module", params=["centralized", "federated"])
def result(request: pytest.FixtureRequest, recording: Recording) -> RunResult:
    return _run(recording, request.param)


def test_one_row_per_output_epoch_and_sigmas_match_the_filter(result: RunResult) -> None:
    """The history has the solution's epochs; its position σ is the solution's; at the last
    epoch every estimate (IMU biases whole, odometer states) and σ is the final one."""
    states = result.states
    assert states is not None
    assert len(states) == len(result.solution) > 100
    assert states.t is result.solution.t
    for k, axis in enumerate("enu"):
        np.testing.assert_allclose(
            states.sigma_of(f"position.{axis}"), result.solution.sigma_position[:, k], rtol=1e-6
        )
    final_sigma = np.sqrt(np.diag(result.final_covariance))
    np.testing.assert_allclose(states.sigma[-1], final_sigma, rtol=1e-6)
    assert "odometer.scale_error.k" in states.estimated
    labels = result.layout.labels
    for label in ("gyro_bias.z", "accel_bias.x", "odometer.scale_error.k"):
        index = labels.index(label)
        assert states.sigma_of(label)[-1] == pytest.approx(final_sigma[index], rel=1e-6)
        assert states.estimate_of(label)[-1] == pytest.approx(
            result.final_state[index], rel=1e-6, abs=1e-12
        )
    assert states.sigma_of("gyro_bias.z")[-1] < states.sigma_of("gyro_bias.z")[0]


def test_the_gyro_bias_column_is_the_whole_bias_in_deg_h(
    result: RunResult, recording: Recording
) -> None:
    """The IMU biases are shown whole (the part the SINS already compensates included) in
    deg/h: the MEMS gyro's biases of some 200-600 deg/h, recovered within 15 %."""
    assert result.states is not None
    table = result.states.columns()
    truth = recording.meta.extra["imu_errors_realized"]["gyro_bias_deg_h"]
    for axis, true in zip("xyz", truth, strict=True):
        assert table[f"gyro_bias_{axis}_deg_h"][-1] == pytest.approx(true, rel=0.15)


def test_geodetic_columns_round_trip_to_enu_and_attitude_sigma(result: RunResult) -> None:
    """lat/lon/h back through the recording's origin give e/n/u within 1 mm; yaw's σ is the
    attitude misalignment's covariance carried through the Euler Jacobian."""
    states = result.states
    assert states is not None
    table = states.columns()
    enu = states.frame.to_enu(
        np.deg2rad(table["lat_deg"]), np.deg2rad(table["lon_deg"]), table["h_m"]
    )
    np.testing.assert_allclose(
        enu, np.stack([table[c] for c in ("e_m", "n_m", "u_m")], -1), atol=1e-3
    )
    np.testing.assert_allclose(table["yaw_deg"], np.rad2deg(result.solution.attitude[:, 2]))
    att = result.layout.slice(ATTITUDE)
    jacobian = euler_jacobian(result.solution.attitude[-1])
    euler = jacobian @ result.final_covariance[att, att] @ jacobian.T
    sigma = np.rad2deg(np.sqrt(np.diag(euler)))
    last = [table[f"sigma_{a}_deg"][-1] for a in ("roll", "pitch", "yaw")]
    np.testing.assert_allclose(last, sigma, rtol=1e-5)


def test_euler_jacobian_is_the_derivative_of_the_angles() -> None:
    rng = np.random.default_rng(2)
    for euler in ([0.1, -0.2, 2.5], [-0.03, 0.6, 5.9]):
        c = dcm_from_euler(*euler)
        phi = 1e-7 * rng.standard_normal(3)
        moved = euler_from_dcm((np.eye(3) - skew(phi)) @ c) - euler
        np.testing.assert_allclose(moved, euler_jacobian(euler) @ phi, rtol=1e-4, atol=1e-13)


def test_states_csv_carries_units_and_the_history(
    result: RunResult, recording: Recording, tmp_path: Path
) -> None:
    """states.csv is written beside solution.csv, each column's unit in its name, its values
    the history's (7 significant digits)."""
    assert result.states is not None
    files = write_outputs(result, recording, tmp_path, plots=False)
    assert files["states"] == tmp_path / "states.csv"
    table = pd.read_csv(files["states"])
    names = list(table.columns)
    assert names == result.states.column_names()
    assert names[: len(NOMINAL_COLUMNS)] == list(NOMINAL_COLUMNS)
    assert all(n.endswith(tuple("_" + u for u in UNITS)) for n in names[1:])
    for name in ("gyro_bias_z_deg_h", "accel_bias_x_mg", "odometer_scale_error_ppm"):
        assert name in names and "sigma_" + name in names
    assert {"sigma_yaw_deg", "sigma_e_m", "sigma_vu_m_s", "odometer_mounting_angles_z_deg"} <= set(
        names
    )
    expected = result.states.columns()
    assert len(table) == len(result.solution)
    for name in names:
        np.testing.assert_allclose(table[name], expected[name], rtol=1e-6, atol=1e-30)


def test_output_states_false_records_and_writes_none(recording: Recording, tmp_path: Path) -> None:
    result = _run(recording, "centralized", states=False)
    assert result.states is None
    files = write_outputs(result, recording, tmp_path, plots=False)
    assert "states" not in files and not (tmp_path / "states.csv").exists()
    assert (tmp_path / "solution.csv").exists()


def test_to_pandas_and_its_error_without_pandas(
    result: RunResult, monkeypatch: pytest.MonkeyPatch
) -> None:
    states = result.states
    assert states is not None
    frame = states.to_pandas()
    assert list(frame.columns) == states.column_names() and len(frame) == len(states)
    solution = result.solution.to_pandas()
    assert list(solution.columns) == list(SOLUTION_COLUMNS)
    np.testing.assert_array_equal(solution["yaw"], result.solution.attitude[:, 2])
    monkeypatch.setitem(sys.modules, "pandas", None)  # what an environment without it imports
    for owner in (states, result.solution):
        with pytest.raises(ImportError, match=r"pip install 'shearer-fusion\[pandas\]'"):
            owner.to_pandas()


def test_column_names_and_units_of_plugin_states() -> None:
    assert column_name("odometer.scale_error", "k", 1, "ppm") == "odometer_scale_error_ppm"
    assert column_name("uwb.range_bias", "A1", 4, "m") == "uwb_range_bias_A1_m"
    assert column_name("height_fix.datum_offset", "u", 1, "") == "height_fix_datum_offset"
    with pytest.raises(ValueError, match=r"state block 'mine\.x': unit 'furlong' is not one of"):
        StateBlock("mine.x", ("a",), (1.0,), unit="furlong")
