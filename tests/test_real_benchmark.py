"""The scoring helpers of the real-data benchmark (benchmarks/real.py), on synthetic inputs."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from benchmarks.real import (
    BEGIN,
    END,
    Section,
    heading_rmse_deg,
    isolated_seconds,
    least_squares_rmse_2d,
    outage_windows,
    pyshoe_armse,
    withhold_fixes,
    write_results,
)
from fusion.attitude import dcm_from_euler, euler_from_dcm
from fusion.fault_detection import ISOLATE, READMIT, FaultEvent
from fusion.recording import (
    ImuData,
    PositionData,
    Recording,
    RecordingMeta,
    TruthData,
)
from fusion.solution import Solution


def _rotate(xy: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return xy @ np.array([[c, -s], [s, c]]).T


def _track(n: int = 400) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * np.pi, n)
    return np.column_stack([2.0 * np.cos(t) - 2.0, np.sin(2.0 * t), 0.1 * t])


def test_outage_windows_are_spaced_by_the_recovery_and_end_in_time() -> None:
    windows = outage_windows(30.0, 60.0, 548.0)
    assert windows[0] == (60.0, 90.0)
    assert all(b - a == 30.0 for a, b in windows)
    assert all(w2[0] - w1[1] == 30.0 for w1, w2 in itertools.pairwise(windows))
    assert windows[-1][1] <= 548.0 and len(windows) == 8


def test_withheld_fixes_are_exactly_those_inside_the_windows() -> None:
    meta = RecordingMeta.model_validate(
        {
            "format": "shearer-recording/1",
            "origin": {"lat_deg": 40.0, "lon_deg": -105.0, "height_m": 1600.0},
            "initial": {
                "position_enu_m": [0, 0, 0],
                "velocity_enu_mps": [0, 0, 0],
                "attitude_deg": {"roll": 0, "pitch": 0, "yaw": 0},
                "sigma": {
                    "position_m": [1, 1, 1],
                    "velocity_mps": [1, 1, 1],
                    "attitude_deg": [1, 1, 1],
                },
            },
            "imu": {"rate_hz": 100.0},
            "position": {},
        }
    )
    t = np.arange(0.0, 20.0, 0.25)
    rec = Recording(
        path=None,
        meta=meta,
        imu=ImuData(t=np.arange(0, 20, 0.01), gyro=np.zeros((2000, 3)), accel=np.zeros((2000, 3))),
        position=PositionData(t=t, enu=np.zeros((t.size, 3)), sigma=np.ones((t.size, 3))),
    )
    out = withhold_fixes(rec, [(2.0, 4.0), (10.0, 12.0)])
    assert out.position is not None
    kept = out.position.t
    assert not np.any(((kept > 2.0) & (kept <= 4.0)) | ((kept > 10.0) & (kept <= 12.0)))
    assert kept.size == t.size - 16
    assert out.imu is rec.imu


def test_pyshoe_armse_ignores_yaw_and_start_offset_but_not_shape_errors() -> None:
    ref = _track()
    est = ref.copy()
    est[:, :2] = _rotate(ref[:, :2], 0.7) + np.array([3.0, -1.0])
    assert pyshoe_armse(est, ref) == pytest.approx(0.0, abs=1e-9)
    est[:, :2] += np.column_stack([np.zeros(len(ref)), np.linspace(0.0, 0.2, len(ref))])
    assert 0.01 < pyshoe_armse(est, ref) < 0.2


def test_pyshoe_armse_is_the_rms_over_the_two_axes_not_the_error_norm() -> None:
    # A straight walk east; the estimate's second half 0.2 m north of it. The bearing at 0.8 m
    # is untouched, so each epoch of the second half is 0.2 m off: 0.2/√2 by PyShoe's
    # compute_error, half the epochs.
    x = np.linspace(0.0, 5.0, 501)
    ref = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    est = ref.copy()
    est[x > 2.5, 1] += 0.2
    assert pyshoe_armse(est, ref) == pytest.approx(0.5 * 0.2 / np.sqrt(2.0), rel=0.01)


def test_least_squares_alignment_recovers_rotation_and_translation() -> None:
    ref = _track()
    rng = np.random.default_rng(0)
    noise = 0.01 * rng.standard_normal((len(ref), 2))
    est = ref.copy()
    est[:, :2] = _rotate(ref[:, :2] + noise, -1.2) + np.array([5.0, 2.0])
    assert least_squares_rmse_2d(est, ref) == pytest.approx(0.01 * np.sqrt(2.0), rel=0.1)


def _solution(t: np.ndarray, attitude: np.ndarray) -> Solution:
    n = t.size
    return Solution(
        t=t,
        position=np.zeros((n, 3)),
        velocity=np.zeros((n, 3)),
        attitude=attitude,
        sigma_position=np.ones((n, 3)),
    )


def test_heading_error_is_broads_and_never_bridges_a_reference_gap() -> None:
    rate = 100.0
    t_ref = np.arange(0.0, 10.0, 1.0 / rate)
    keep = (t_ref < 4.0) | (t_ref > 6.0)  # a 2 s optical gap
    yaw = 0.3 * t_ref
    att_ref = np.column_stack([0.2 * np.sin(t_ref), 0.1 * np.cos(t_ref), yaw])[keep]
    truth = TruthData(
        t=t_ref[keep],
        position=np.zeros((keep.sum(), 3)),
        velocity=np.zeros((keep.sum(), 3)),
        attitude=att_ref,
        cycle=np.ones(keep.sum(), dtype=np.int64),
    )
    t_sol = np.arange(0.05, 9.9, 0.1) + 0.003
    roll, pitch = 0.2 * np.sin(t_sol), 0.1 * np.cos(t_sol)
    # A pure heading offset of 2° (a rotation about the vertical, applied in n).
    c = dcm_from_euler(roll, pitch, 0.3 * t_sol)
    rz = dcm_from_euler(0.0, 0.0, np.radians(2.0))
    att_sol = euler_from_dcm(rz @ c)
    gap = (t_sol > 4.0) & (t_sol < 6.0)
    att_sol[gap, 2] += 1.0  # inside the gap: must not be scored
    rmse, n = heading_rmse_deg(_solution(t_sol, att_sol), truth, rate)
    assert rmse == pytest.approx(2.0, abs=1e-3)
    assert n == np.sum(~gap)


def test_isolated_time_sums_isolate_to_readmit_spans() -> None:
    events = [
        FaultEvent(10.0, "magnetometer", 30.0, 20.0, ISOLATE, "chi2"),
        FaultEvent(25.0, "magnetometer", 5.0, 20.0, READMIT, "consistent for hold"),
        FaultEvent(12.0, "position", 30.0, 20.0, ISOLATE, "chi2"),
        FaultEvent(40.0, "magnetometer", 30.0, 20.0, ISOLATE, "indicator"),
    ]

    class Result:
        faults = events

    assert isolated_seconds(Result(), "magnetometer", 100.0) == pytest.approx(15.0 + 60.0)  # type: ignore[arg-type]


def test_results_parts_are_updated_one_by_one_and_the_rest_kept(tmp_path: Path) -> None:
    path = tmp_path / "RESULTS.md"
    path.write_text("# Benchmark results\n\nother suite\n", encoding="utf-8")
    write_results({"drive": Section("drive v1", "one"), "broad": Section("broad v1", "b")}, path)
    write_results({"drive": Section("drive v2", "two")}, path)
    text = path.read_text(encoding="utf-8")
    assert "other suite" in text
    assert "### drive v2" in text and "### drive v1" not in text
    assert "### broad v1" in text  # a part not run keeps its last results
    assert text.count(BEGIN) == 1 and text.count(END) == 1
    assert text.index("drive v2") < text.index("broad v1")
