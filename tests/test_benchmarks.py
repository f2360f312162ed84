"""Benchmark machinery (issue 7): overrides, tables, fault scoring and planning, the dead
reckoning compensation convention, and identical results from local processes and Dask.

The campaigns themselves are not run here; the Monte Carlo cases are tiny (two seeds of a
100 s slice of seed003-brokenline-maginterf).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.container import BarContainer

from benchmarks.checkpoint import TaskStore, source_fingerprint
from benchmarks.faults import plan_fault
from benchmarks.figures import headline_figure
from benchmarks.report import SIMULATED_END, accuracy_csv, committed_section, write_suite
from benchmarks.runner import (
    Method,
    Task,
    TaskResult,
    collect,
    compensation_overrides,
    load_method_config,
    override_config,
    run_tasks,
    score_faults,
)
from benchmarks.suites import SUITES, Suite
from benchmarks.tables import Column, RowSpec, TableSpec, build_table, to_csv, to_markdown
from fusion.config import ConfigError, parse_config
from fusion.engine import Engine
from fusion.fault_detection import FaultEvent
from fusion.innovations import InnovationLog
from fusion.metrics import compute_metrics
from fusion.recording import read_recording
from fusion.sim.simulate import load_scenario, simulate, stream_rng
from fusion.sim.trajectory import Trajectory

TINY_OVERRIDES = ("duration_s=100",)


def _tiny_tasks() -> list[Task]:
    methods = (
        Method("sins_only", "sins_only"),
        Method("od gated", "sins_od_ckf", ("plugins.odometer.gate_probability=0.999",), trace=True),
        Method("missing", "no_such_config"),
    )
    return [
        Task(
            "tiny",
            "maginterf",
            "seed003-brokenline-maginterf",
            seed,
            methods,
            TINY_OVERRIDES,
            keep_traces=seed == 0,
        )
        for seed in (0, 1)
    ]


@pytest.fixture(scope="module")
def local_runs():
    return collect(run_tasks(_tiny_tasks(), jobs=2))


def test_override_config_selects_plugins_by_name_type_star_and_index():
    data = {
        "name": "x",
        "filter": {"covariance_step_s": 0.1},
        "plugins": [{"type": "odometer"}, {"type": "cpoem", "name": "points", "interval_m": 2}],
    }
    out = override_config(
        data,
        [
            "plugins.points.interval_m=6",
            "plugins.*.gate_probability=0.999",
            "plugins.0.mode=motion_constraint",
            "filter.federated.sharing=inverse_trace",
            "smoother.mode=whole",
        ],
    )
    assert out["plugins"][1]["interval_m"] == 6
    assert [p["gate_probability"] for p in out["plugins"]] == [0.999, 0.999]
    assert out["plugins"][0]["mode"] == "motion_constraint"
    assert out["filter"] == {"covariance_step_s": 0.1, "federated": {"sharing": "inverse_trace"}}
    assert out["smoother"] == {"mode": "whole"}
    assert data["plugins"][1]["interval_m"] == 2  # the input is not modified
    with pytest.raises(ConfigError, match="no plugin 'uwb'"):
        override_config(data, ["plugins.uwb.sigma_m=1"])


def test_missing_config_is_none_and_bad_override_names_the_key():
    assert load_method_config(Method("m", "no_such_config")) is None
    with pytest.raises(ConfigError, match="covariance_stp_s"):
        load_method_config(Method("m", "sins_only", ("filter.covariance_stp_s=0.1",)))


def test_table_mean_std_paper_and_pivot_columns():
    rows = [
        {"group": g, "method": "a", "solution": "forward", "seed": s, "x": v, "y": 10.0 * v}
        for g, values in (("g1", (1.0, 3.0)), ("g2", (5.0, float("nan"))))
        for s, v in enumerate(values)
    ]
    spec = TableSpec(
        name="t",
        title="T",
        rows=(RowSpec("A", "g1", "a"), RowSpec("B", "g1", "b")),
        columns=(Column("x", "x"), Column("y", "y", 1), Column("x", "x in g2", group="g2")),
        paper={("A", "x"): 2.5},
    )
    table = build_table(spec, rows)
    a = table.cells[0]
    assert (a[0].mean, a[0].std, a[0].n, a[0].paper) == (2.0, 1.0, 2, 2.5)
    assert (a[1].mean, a[1].std) == (20.0, 10.0)
    assert (a[2].mean, a[2].n) == (5.0, 1)  # NaN runs do not count
    assert table.runs == [2, 0]
    md = to_markdown(table)
    assert "| A | 2 | 2.00 ± 1.00 (2.50) | 20.0 ± 10.0 | 5.00 |" in md
    assert "| B | 0 | — | — | — |" in md
    csv_lines = to_csv(table).splitlines()
    assert csv_lines[0].startswith("label,group,method,solution,n,x_mean,x_std,x_paper")
    assert csv_lines[1].startswith("A,g1,a,forward,2,2.0,1.0,2.5")
    assert len(csv_lines) == 3


@pytest.mark.parametrize(
    ("agg", "legend", "error_bars"),
    [("mean", "ours, mean ± std", True), ("median", "ours, median over the runs", False)],
)
def test_headline_chart_names_its_aggregate(agg: str, legend: str, error_bars: bool) -> None:
    """The bar chart of a mean column shows ± std error bars and says so; a median column
    (the robustness table's) has no spread to show: bare bars, named by the aggregate."""
    rows = [
        {"group": "g", "method": "a", "solution": "forward", "seed": s, "x": v}
        for s, v in enumerate((1.0, 2.0, 6.0))
    ]
    spec = TableSpec(
        name="t",
        title="T",
        rows=(RowSpec("A", "g", "a"),),
        columns=(Column("x", "x", agg=agg),),
        headline="x",
    )
    fig = headline_figure(build_table(spec, rows))
    assert fig is not None
    ax = fig.axes[0]
    assert legend in [t.get_text() for t in ax.get_legend().get_texts()]
    (bars,) = [c for c in ax.containers if isinstance(c, BarContainer)]
    assert bars[0].get_height() == pytest.approx(3.0 if agg == "mean" else 2.0)
    assert (bars.errorbar is not None) == error_bars


def _event(t: float, local: str, action: str) -> FaultEvent:
    return FaultEvent(t, local, 30.0, 20.0, action, "window chi-square")


def _fake_result(architecture: str, plugins: list[dict], faults=(), innovations=None):
    config = parse_config(
        {"name": "fake", "filter": {"architecture": architecture}, "plugins": plugins}
    )
    return SimpleNamespace(config=config, faults=list(faults), innovations=innovations or {})


def test_fault_scoring_federated_delay_and_false_alarms():
    injected = [
        {"type": "magnetic_interference", "t_start": 70.0, "t_end": 90.0},
        {"type": "dropout", "sensor": "odometer", "t_start": 10.0, "t_end": 20.0},
    ]
    result = _fake_result(
        "federated",
        [{"type": "odometer"}, {"type": "magnetometer", "local": "heading"}],
        faults=[
            _event(50.0, "odometer", "isolate"),  # nothing injected on the odometer: false alarm
            _event(60.0, "odometer", "readmit"),
            _event(72.5, "heading", "isolate"),  # detection 2.5 s after onset
            _event(99.0, "heading", "readmit"),
        ],
    )
    fields = score_faults(injected, result)
    assert fields["faults_injected"] == 1.0  # a dropout is not an inconsistency to detect
    assert fields["detected_fraction"] == 1.0
    assert fields["detect_delay_s"] == pytest.approx(2.5)
    assert fields["false_alarms"] == 1.0
    assert fields["isolations"] == 2.0


def test_fault_scoring_counts_a_slip_taken_in_as_a_jump():
    injected = [{"type": "odometer_slip", "t_start": 100.0, "t_end": 160.0}]
    result = _fake_result(
        "federated",
        [{"type": "odometer", "slip_detection": True}, {"type": "magnetometer"}],
        faults=[
            _event(40.0, "odometer.slip", "jump"),  # no slip injected then: false alarm
            _event(100.3, "odometer.slip", "jump"),  # the onset, 0.3 s late
            _event(160.2, "odometer.slip", "jump"),  # the end
        ],
    )
    fields = score_faults(injected, result)
    assert fields["detected_fraction"] == 1.0
    assert fields["detect_delay_s"] == pytest.approx(0.3)
    assert fields["false_alarms"] == 1.0
    assert fields["isolations"] == 0.0


def test_fault_scoring_centralized_uses_gate_rejections():
    injected = [{"type": "odometer_slip", "t_start": 100.0, "t_end": 160.0}]
    log = InnovationLog()
    for t, accepted in ((90.0, False), (101.0, True), (104.0, False), (130.0, False)):
        log.append(t, SimpleNamespace(nis=1.0, dof=1, accepted=accepted), False)
    result = _fake_result("centralized", [{"type": "odometer"}], innovations={"odometer": log})
    fields = score_faults(injected, result)
    assert fields["detect_delay_s"] == pytest.approx(4.0)  # the rejection at 90 s precedes it
    assert math.isnan(fields["false_alarms"])
    no_gate_result = _fake_result("centralized", [{"type": "odometer"}])
    assert score_faults(injected, no_gate_result)["detected_fraction"] == 0.0


def test_planned_faults_keep_the_presets_own_and_fall_where_the_sensor_is_used():
    override = plan_fault("seed003-brokenline-maginterf", 0, "odometer_slip")
    sc = load_scenario("seed003-brokenline-maginterf", [override])
    kinds = [f.kind for f in sc.faults]
    assert kinds == ["magnetic_interference", "odometer_slip"]
    slip = sc.faults[1]
    traj = Trajectory(sc, stream_rng(0, "trajectory"))
    state = traj.evaluate(np.arange(slip.t_start, slip.t_end, 1.0))
    assert np.mean(state.moving) > 0.9
    nlos = load_scenario("longwall-200m", [plan_fault("longwall-200m", 3, "uwb_nlos")]).faults[0]
    traj = Trajectory(load_scenario("longwall-200m"), stream_rng(3, "trajectory"))
    sc = load_scenario("longwall-200m")
    anchors = np.array([traj.enu_from_face(*a) for a in sc.uwb.anchors.values()])
    pos = traj.evaluate(np.array([nlos.t_start, nlos.t_end])).position
    assert np.linalg.norm(pos[:, None] - anchors[None], axis=2).min(axis=1).max() < 40.0
    with pytest.raises(ValueError, match="unknown fault kind"):
        plan_fault("longwall-200m", 0, "gremlins")


@pytest.fixture(scope="module")
def carrier(tmp_path_factory):
    """One pass of seed 000's carrier, odometer yaw mounting 3°, scale error 5 %, no initial
    attitude error (it would turn the dead reckoning as much as the mounting)."""
    out = tmp_path_factory.mktemp("carrier")
    simulate(
        "seed000-carrier",
        out,
        seed=4,
        overrides=[
            "duration_s=230",
            "odometer.mounting_angles_deg=[0.0, 0.0, 3.0]",
            "odometer.scale_factor_error=0.05",
            "initial.perturb=false",
        ],
    )
    return read_recording(out)


def test_compensating_the_true_parameters_removes_the_dead_reckoning_drift(carrier):
    """The dead reckoning fed the true δα, δk_D and gyro bias through compensation_overrides
    (the odometer plugin's conventions) beats the uncompensated one and the sign-flipped one."""
    realized = carrier.meta.extra["imu_errors_realized"]["gyro_bias_deg_h"]
    truth = {
        "odometer.mounting_angles": np.deg2rad([0.0, 0.0, 3.0]),
        "odometer.scale_error": np.array([0.05]),
        "gyro_bias": np.deg2rad(realized) / 3600.0,
    }
    forward = parse_config({"name": "f", "plugins": [{"type": "odometer"}]})

    def as_result(sign: float) -> SimpleNamespace:
        est = {k: (sign * v if k.startswith("odometer.m") else v) for k, v in truth.items()}
        layout = SimpleNamespace(blocks=[SimpleNamespace(name=k) for k in est])
        return SimpleNamespace(
            config=forward, layout=layout, state_estimate=lambda b: (est[b], est[b] * 0)
        )

    base = load_method_config(Method("dr", "dr_traditional"))
    errors = {}
    for label, extra in (
        ("none", []),
        ("true", compensation_overrides(as_result(1.0))),
        ("flipped", compensation_overrides(as_result(-1.0))),
    ):
        config = load_method_config(Method("dr", "dr_traditional"), extra)
        assert config is not None and base is not None
        solution = Engine(config, carrier).run().solution
        errors[label] = compute_metrics(solution, carrier.truth)["horizontal_max"]
    assert errors["true"] < 0.3 * errors["none"]
    assert errors["true"] < 0.3 * errors["flipped"]


def test_local_runs_rows_notes_and_faults(local_runs):
    rows = local_runs.rows
    assert [(r["method"], r["seed"]) for r in rows] == [
        ("od gated", 0),
        ("od gated", 1),
        ("sins_only", 0),
        ("sins_only", 1),
    ]
    assert local_runs.notes == [
        "tiny/maginterf/missing: configs/no_such_config.yaml does not exist (yet); skipped"
    ]
    for r in rows:
        assert r["faults_injected"] == 0.0  # no magnetometer plugin reads the disturbed sensor
        assert r["horizontal_rms"] > 0 and np.isfinite(r["nees_rms"])
    od = [r for r in rows if r["method"] == "od gated"]
    free = [r for r in rows if r["method"] == "sins_only"]
    assert all(a["horizontal_max"] < b["horizontal_max"] for a, b in zip(od, free, strict=True))
    assert [t.method for t in local_runs.traces] == ["od gated"]


def test_dask_local_cluster_gives_identical_tables(local_runs):
    distributed = pytest.importorskip("distributed")
    assert distributed is not None
    dask_runs = collect(run_tasks(_tiny_tasks(), jobs=2, scheduler="local-dask"))
    assert accuracy_csv(dask_runs) == accuracy_csv(local_runs)
    assert dask_runs.notes == local_runs.notes


def test_unknown_scheduler_is_a_clear_error():
    from benchmarks.runner import BenchmarkError

    with pytest.raises(BenchmarkError, match="tcp://host:port"):
        run_tasks(_tiny_tasks()[:1], scheduler="http://nowhere")


def test_write_suite_outputs(local_runs, tmp_path: Path):
    spec = TableSpec(
        "tiny_table",
        "Tiny",
        (RowSpec("free", "maginterf", "sins_only"), RowSpec("OD", "maginterf", "od gated")),
        (Column("horizontal_max", "max (m)"), Column("e_max", "max E (m)")),
        headline="horizontal_max",
    )
    suite = Suite("tiny", "tiny suite", 2, lambda runs, ov: [], lambda: [spec])
    markdown = write_suite(suite, local_runs, tmp_path, 2, "python -m benchmarks tiny", "today")
    for name in ("runs.csv", "tiny_table.csv", "tiny_table.png", "results.md"):
        assert (tmp_path / name).stat().st_size > 0
    figures = sorted(p.name for p in (tmp_path / "figures").glob("*.png"))
    assert figures == [
        "maginterf_faults.png",
        "maginterf_od_gated_forward_errors.png",
        "maginterf_od_gated_plan.png",
    ]
    assert "| OD | 2 |" in markdown and "no_such_config" in markdown


def test_a_suite_without_output_keeps_its_committed_section():
    text = (
        "## Simulated\n\n### `seed002` — MC\n\nrow a\n\n![x](figures/x.png)\n\n"
        "### `seed003` — MAG\n\nrow b\n" + SIMULATED_END + "\n## Real\n"
    )
    assert (
        committed_section(text, "seed002") == "### `seed002` — MC\n\nrow a\n\n![x](figures/x.png)"
    )
    assert committed_section(text, "seed003") == "### `seed003` — MAG\n\nrow b"
    assert committed_section(text, "seed004") == ""


def test_every_suite_builds_its_tasks_and_tables():
    for suite in SUITES.values():
        tasks = suite.tasks(2, ())
        assert tasks and {t.seed for t in tasks} == {0, 1}
        keys = [(t.group, t.seed) for t in tasks]
        assert len(keys) == len(set(keys)), suite.name
        for spec in suite.tables():
            assert spec.rows and spec.columns


def test_speed_measurement_runs_in_a_child_process():
    task = Task(
        "speed",
        "tiny",
        "seed003-brokenline",
        0,
        (Method("m", "sins_only", measure_memory=True),),
        ("duration_s=70",),
    )
    (result,) = run_tasks([task])
    (row,) = result.rows
    assert row["duration_s"] == pytest.approx(70.0, abs=0.1)
    assert row["realtime_factor"] == pytest.approx(row["duration_s"] / row["wall_s"])
    assert 50.0 < row["peak_rss_mb"] < 2000.0


def test_missing_dask_is_a_clear_error(monkeypatch):
    from benchmarks.runner import BenchmarkError

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed → ImportError
    with pytest.raises(BenchmarkError, match=r"pip install 'shearer-fusion\[bench\]'"):
        run_tasks(_tiny_tasks()[:1], scheduler="local-dask")


def _stored_result(seed: int) -> TaskResult:
    return TaskResult(rows=[{"method": "m", "seed": seed, "horizontal_rms": 0.1 * seed}])


def test_a_stopped_run_resumes_from_its_stored_tasks(tmp_path: Path):
    """The tasks a run finished are kept; ``resume`` runs only the others and returns every
    result in the tasks' order; a fresh run starts empty."""
    tasks = _tiny_tasks()
    store = TaskStore(tmp_path / "tasks", resume=False, fingerprint="a")
    store.save(tasks[1], _stored_result(1))
    resumed = TaskStore(tmp_path / "tasks", resume=True, fingerprint="a")
    assert resumed.pending(tasks) == [tasks[0]]
    resumed.save(tasks[0], _stored_result(0))
    assert [r.rows[0]["seed"] for r in resumed.results(tasks)] == [0, 1]
    assert TaskStore(tmp_path / "tasks", resume=False, fingerprint="a").pending(tasks) == tasks


def test_resume_refuses_results_of_other_sources(tmp_path: Path):
    from benchmarks.runner import BenchmarkError

    TaskStore(tmp_path / "tasks", resume=False, fingerprint="a").save(
        _tiny_tasks()[0], _stored_result(0)
    )
    with pytest.raises(BenchmarkError, match=r"tasks.*other sources.*without --resume"):
        TaskStore(tmp_path / "tasks", resume=True, fingerprint="b")


def test_the_fingerprint_follows_the_sources(tmp_path: Path):
    for directory in ("fusion", "benchmarks", "configs"):
        (tmp_path / directory).mkdir()
    (tmp_path / "fusion" / "engine.py").write_text("x = 1\n")
    (tmp_path / "configs" / "full_ckf.yaml").write_text("name: full_ckf\n")
    before = source_fingerprint(tmp_path)
    (tmp_path / "configs" / "full_ckf.yaml").write_text("name: full_ckf  # changed\n")
    assert source_fingerprint(tmp_path) != before


def test_each_finished_task_is_handed_over(monkeypatch):
    import benchmarks.runner as runner

    monkeypatch.setattr(runner, "execute_task", lambda task: _stored_result(task.seed))
    handed: list[tuple[int, float]] = []
    run_tasks(
        _tiny_tasks(), jobs=1, on_result=lambda t, r: handed.append((t.seed, r.rows[0]["seed"]))
    )
    assert handed == [(0, 0), (1, 1)]
