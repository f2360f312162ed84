"""Tests of fusion.solution (solution.csv round trip) and fusion.metrics (hand-computable cases)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fusion.metrics import compute_metrics, interpolate_truth, write_metrics_json
from fusion.recording import RecordingError, TruthData
from fusion.solution import SOLUTION_COLUMNS, Solution, read_solution, write_solution


def make_solution(n: int = 50, seed: int = 3) -> Solution:
    rng = np.random.default_rng(seed)
    return Solution(
        t=0.1 * np.arange(n) + 1.0 / 3.0,
        position=rng.normal(0.0, 50.0, (n, 3)),
        velocity=rng.normal(0.0, 1.0, (n, 3)),
        attitude=rng.uniform(-np.pi, np.pi, (n, 3)),
        sigma_position=rng.uniform(0.01, 1.0, (n, 3)),
    )


def truth_at_rest(t: np.ndarray, cycle: np.ndarray | None = None) -> TruthData:
    n = t.size
    return TruthData(
        t=t,
        position=np.zeros((n, 3)),
        velocity=np.zeros((n, 3)),
        attitude=np.zeros((n, 3)),
        cycle=np.zeros(n, dtype=np.int64) if cycle is None else cycle,
    )


def solution_with_error(t: np.ndarray, err: np.ndarray, sigma: float = 1.0) -> Solution:
    n = t.size
    return Solution(
        t=t,
        position=np.broadcast_to(err, (n, 3)).copy(),
        velocity=np.zeros((n, 3)),
        attitude=np.zeros((n, 3)),
        sigma_position=np.full((n, 3), sigma),
    )


# ------------------------------------------------------------------------------------------
# solution.csv
# ------------------------------------------------------------------------------------------


def test_solution_round_trip_exact_and_deterministic(tmp_path: Path) -> None:
    sol = make_solution()
    write_solution(sol, tmp_path / "a.csv")
    write_solution(sol, tmp_path / "b.csv")
    data = (tmp_path / "a.csv").read_bytes()
    assert data == (tmp_path / "b.csv").read_bytes()
    assert data.decode().split("\n")[0] == ",".join(SOLUTION_COLUMNS)
    back = read_solution(tmp_path / "a.csv")
    for name in ("t", "position", "velocity", "attitude", "sigma_position"):
        np.testing.assert_array_equal(getattr(back, name), getattr(sol, name))
    assert back.position_covariance is None and len(back) == 50


def test_solution_gzip(tmp_path: Path) -> None:
    sol = make_solution(5)
    write_solution(sol, tmp_path / "smoothed.csv.gz")
    write_solution(sol, tmp_path / "again.csv.gz")
    assert (tmp_path / "smoothed.csv.gz").read_bytes() == (tmp_path / "again.csv.gz").read_bytes()
    np.testing.assert_array_equal(read_solution(tmp_path / "smoothed.csv.gz").t, sol.t)


def test_read_solution_reports_every_problem(tmp_path: Path) -> None:
    write_solution(make_solution(10), tmp_path / "solution.csv")
    lines = (tmp_path / "solution.csv").read_text().split("\n")
    cells = lines[3].split(",")
    cells[9] = "north"
    lines[3] = ",".join(cells)
    lines[6] = lines[2]  # repeats an earlier epoch
    (tmp_path / "solution.csv").write_text("\n".join(lines))
    with pytest.raises(RecordingError) as info:
        read_solution(tmp_path / "solution.csv")
    text = str(info.value)
    assert "solution.csv, line 4, column yaw: non-numeric value 'north'" in text
    assert "solution.csv, line 7: time must be strictly increasing" in text


def test_read_solution_header_and_missing(tmp_path: Path) -> None:
    (tmp_path / "solution.csv").write_text("t,e,n,u\n0,0,0,0\n")
    with pytest.raises(RecordingError, match="missing columns 've', 'vn'"):
        read_solution(tmp_path / "solution.csv")
    with pytest.raises(RecordingError, match="file is missing"):
        read_solution(tmp_path / "nope.csv")


def test_write_solution_refuses_nan(tmp_path: Path) -> None:
    sol = make_solution(4)
    sol.position[2, 1] = np.nan
    sol.position[2, 0] = np.inf
    sol.velocity[1, 2] = np.nan
    with pytest.raises(RecordingError) as err:
        write_solution(sol, tmp_path / "solution.csv")
    wheres = [p.where for p in err.value.problems]
    assert wheres == ["line 3, column vu", "line 4, column e", "line 4, column n"]


def test_solution_shapes_checked() -> None:
    with pytest.raises(ValueError, match="velocity"):
        Solution(
            t=[0.0, 1.0],
            position=np.zeros((2, 3)),
            velocity=np.zeros((3, 3)),
            attitude=np.zeros((2, 3)),
            sigma_position=np.zeros((2, 3)),
        )


# ------------------------------------------------------------------------------------------
# metrics
# ------------------------------------------------------------------------------------------


def test_constant_offset() -> None:
    t = np.arange(0.0, 10.0, 0.1)
    m = compute_metrics(solution_with_error(t, np.array([0.3, -0.4, 1.2])), truth_at_rest(t))
    e, n, u = (m["position"][a] for a in "enu")
    assert e["max_abs"] == pytest.approx(0.3) and e["rms"] == pytest.approx(0.3)
    assert n["mean"] == pytest.approx(-0.4) and n["mean_abs"] == pytest.approx(0.4)
    assert n["std"] == pytest.approx(0.0, abs=1e-12)
    assert u["rms"] == pytest.approx(1.2)
    assert m["horizontal_rms"] == pytest.approx(0.5) and m["horizontal_max"] == pytest.approx(0.5)
    assert m["rms_3d"] == pytest.approx(1.3) and m["max_3d"] == pytest.approx(1.3)
    assert m["sep"] == pytest.approx(1.3)
    assert m["sep_per_cycle"] == {}
    assert m["epochs"] == t.size and m["epochs_excluded"] == 0
    json.dumps(m, allow_nan=False)


def test_signed_mean_std_and_rms() -> None:
    t = np.arange(4.0)
    sol = solution_with_error(t, np.zeros(3))
    sol.position[:, 0] = [1.0, -1.0, 3.0, 1.0]  # mean 1, std sqrt(2), rms sqrt(3)
    m = compute_metrics(sol, truth_at_rest(t))["position"]["e"]
    assert m["mean"] == pytest.approx(1.0)
    assert m["std"] == pytest.approx(math.sqrt(2.0))
    assert m["rms"] == pytest.approx(math.sqrt(3.0))
    assert m["max_abs"] == pytest.approx(3.0) and m["mean_abs"] == pytest.approx(1.5)


def test_sep_per_cycle_split() -> None:
    t = np.arange(0.0, 30.0, 1.0)
    cycle = np.repeat([0, 1, 2], 10)
    sol = solution_with_error(t, np.zeros(3))
    sol.position[cycle == 1, 1] = 1.0
    sol.position[cycle == 2, 2] = 2.0
    sol.position[25, 2] = 50.0  # an outlier does not move the median
    m = compute_metrics(sol, truth_at_rest(t, cycle))
    assert m["sep_per_cycle"] == {1: pytest.approx(1.0), 2: pytest.approx(2.0)}


def test_cycle_of_epoch_is_last_truth_sample_before() -> None:
    truth = truth_at_rest(np.array([0.0, 1.0, 2.0, 3.0]), np.array([0, 1, 1, 2]))
    sol = solution_with_error(np.array([0.5, 0.99, 1.0, 2.5, 2.999, 3.0]), np.zeros(3))
    sol.position[:, 0] = [9.0, 9.0, 1.0, 1.0, 1.0, 4.0]
    m = compute_metrics(sol, truth)
    assert m["sep_per_cycle"] == {1: pytest.approx(1.0), 2: pytest.approx(4.0)}


def test_cycle_without_epochs_is_none() -> None:
    truth = truth_at_rest(np.arange(10.0), np.array([1] * 5 + [2] * 5))
    sol = solution_with_error(np.arange(0.0, 4.0), np.ones(3))
    assert compute_metrics(sol, truth)["sep_per_cycle"] == {1: pytest.approx(math.sqrt(3)), 2: None}


def test_epochs_outside_truth_excluded() -> None:
    truth = truth_at_rest(np.arange(1.0, 5.0))
    sol = solution_with_error(np.arange(0.0, 7.0), np.array([1.0, 0.0, 0.0]))
    sol.position[[0, 5, 6], 0] = 100.0  # outside the truth span: must not count
    m = compute_metrics(sol, truth)
    assert m["epochs"] == 4 and m["epochs_excluded"] == 3
    assert m["position"]["e"]["max_abs"] == pytest.approx(1.0)
    assert m["t_start"] == 1.0 and m["t_end"] == 4.0


def test_no_overlap_raises() -> None:
    with pytest.raises(ValueError, match="time span"):
        compute_metrics(
            solution_with_error(np.arange(3.0), np.zeros(3)), truth_at_rest(np.arange(5.0, 9.0))
        )


def test_truth_interpolated_linearly() -> None:
    tt = np.arange(0.0, 10.0)
    truth = TruthData(
        t=tt,
        position=np.column_stack([2.0 * tt, -tt, 0.5 * tt]),
        velocity=np.tile([2.0, -1.0, 0.5], (tt.size, 1)),
        attitude=np.zeros((tt.size, 3)),
        cycle=np.zeros(tt.size, dtype=np.int64),
    )
    ts = np.arange(0.25, 9.0, 0.5)
    sol = Solution(
        t=ts,
        position=np.column_stack([2.0 * ts, -ts, 0.5 * ts]),
        velocity=np.tile([2.0, -1.0, 0.5], (ts.size, 1)),
        attitude=np.zeros((ts.size, 3)),
        sigma_position=np.ones((ts.size, 3)),
    )
    m = compute_metrics(sol, truth)
    assert m["rms_3d"] == pytest.approx(0.0, abs=1e-12)
    assert m["velocity"]["n"]["rms"] == pytest.approx(0.0, abs=1e-12)


def test_yaw_wraps_and_unwraps() -> None:
    tt = np.arange(0.0, 4.0)
    yaw = np.deg2rad([178.0, -178.0, -174.0, -170.0])  # crosses ±180°: +4° per second
    truth = TruthData(
        t=tt,
        position=np.zeros((4, 3)),
        velocity=np.zeros((4, 3)),
        attitude=np.column_stack([np.zeros(4), np.zeros(4), yaw]),
        cycle=np.zeros(4, dtype=np.int64),
    )
    inside, _, _, att, _ = interpolate_truth(truth, np.array([0.5]))
    assert inside.all() and np.rad2deg(att[0, 2]) % 360 == pytest.approx(180.0)
    sol = solution_with_error(np.array([0.0, 2.0]), np.zeros(3))
    sol.attitude[:, 2] = np.deg2rad([179.0, -177.0])  # crosses ±180° too: 181° at t = 1 s
    sol.attitude[:, 0] = np.deg2rad([0.5, -0.5])
    m = compute_metrics(sol, truth)["attitude_deg"]  # errors +1°, -1°, -3° at t = 0, 1, 2 s
    assert m["yaw"]["max_abs"] == pytest.approx(3.0)
    assert m["yaw"]["mean"] == pytest.approx(-1.0)
    assert m["yaw"]["rms"] == pytest.approx(math.sqrt(11.0 / 3.0))
    assert m["roll"]["rms"] == pytest.approx(math.sqrt(1.0 / 6.0))


def test_scored_at_truth_epochs_so_a_sparse_truth_adds_no_chord_error() -> None:
    """A 1-Hz truth on a 5-m circle and an exact 100-Hz solution: no error at the truth epochs
    (truth interpolated onto the solution would add its chord's sagitta, up to 16 cm here), and
    RMS(err/σ) with the solution's σ taken at the same epochs."""
    omega = 0.5  # rad/s

    def circle(t: np.ndarray) -> np.ndarray:
        return np.column_stack([5.0 * np.cos(omega * t), 5.0 * np.sin(omega * t), 0 * t])

    tt = np.arange(0.0, 11.0)
    zeros = np.zeros((tt.size, 3))
    truth = TruthData(tt, circle(tt), zeros, zeros, np.zeros(tt.size, dtype=np.int64))
    ts = np.linspace(0.5, 10.0, 951)
    sol = solution_with_error(ts, np.zeros(3), 0.1)
    sol.position[:] = circle(ts)
    sol.position[:, 2] = 0.05 * ts  # the up error grows: 0.05 m at the 1-s truth epoch ...
    sol.sigma_position[:, 2] = 0.5 * ts  # ... with its σ growing alike: err/σ = 0.1 throughout
    m = compute_metrics(sol, truth)
    assert m["epochs"] == 10 and m["truth_epochs_excluded"] == 1 and m["epochs_excluded"] == 0
    assert m["t_start"] == 1.0 and m["t_end"] == 10.0
    assert m["horizontal_max"] == pytest.approx(0.0, abs=1e-5)
    assert m["nees"]["normalized_rms"]["u"] == pytest.approx(0.1)


def test_normalized_errors_from_sigma() -> None:
    t = np.arange(10.0)
    m = compute_metrics(solution_with_error(t, np.array([0.2, 0.0, -0.1]), 0.1), truth_at_rest(t))
    nees = m["nees"]
    assert nees["source"] == "sigma_position"
    assert nees["normalized_rms"] == {
        "e": pytest.approx(2.0),
        "n": pytest.approx(0.0),
        "u": pytest.approx(1.0),
    }
    assert "mean_3d" not in nees


def test_nees_from_covariance() -> None:
    t = np.arange(10.0)
    base = solution_with_error(t, np.array([1.0, 0.0, 0.0]), 5.0)
    cov = np.tile(np.diag([1.0, 4.0, 4.0]), (t.size, 1, 1))
    cov[5:] = np.diag([4.0, 4.0, 4.0])  # NEES 1 for the first half, 0.25 for the second
    sol = Solution(
        t=base.t,
        position=base.position,
        velocity=base.velocity,
        attitude=base.attitude,
        sigma_position=base.sigma_position,
        position_covariance=cov,
    )
    nees = compute_metrics(sol, truth_at_rest(t))["nees"]
    assert nees["source"] == "covariance"
    assert nees["mean_3d"] == pytest.approx(0.625)
    assert nees["normalized_rms"]["e"] == pytest.approx(math.sqrt(0.625))
    assert nees["fraction_within_95"] == pytest.approx(1.0)
    assert nees["chi2_95_bound"] == pytest.approx(7.8147, abs=1e-4)


def test_write_metrics_json(tmp_path: Path) -> None:
    t = np.arange(0.0, 20.0)
    cycle = np.repeat([1, 2], 10)
    metrics = {
        "solution.csv": compute_metrics(
            solution_with_error(t, np.ones(3)), truth_at_rest(t, cycle)
        ),
        "smoothed.csv": compute_metrics(
            solution_with_error(t, np.zeros(3)), truth_at_rest(t, cycle)
        ),
    }
    write_metrics_json(metrics, tmp_path / "metrics.json")
    text = (tmp_path / "metrics.json").read_text()
    data = json.loads(text)
    assert list(data) == ["smoothed.csv", "solution.csv"]
    assert data["solution.csv"]["sep_per_cycle"] == {
        "1": pytest.approx(math.sqrt(3)),
        "2": pytest.approx(math.sqrt(3)),
    }
    assert text == json.dumps(data, sort_keys=True, indent=2) + "\n"
