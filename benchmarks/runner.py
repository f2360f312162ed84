"""Monte Carlo engine of the benchmarks: simulate a recording, run every method on it, score.

A :class:`Task` is one simulated recording — a scenario preset, its ``key.sub=value``
overrides and a seed — and the :class:`Method` s run on it (a configuration from ``configs/``
with its own dotted overrides). :func:`execute_task` simulates into a temporary directory, runs
the :class:`~fusion.engine.Engine` for each method and returns flat rows, one per method and
solution (``forward``, and ``smoothed`` when the configuration smooths). Tasks run in parallel
local processes (:func:`run_tasks`, ``concurrent.futures`` with the ``spawn`` start method) or
on a Dask distributed cluster; each task is a pure function of its fields, so the rows — sorted
by :data:`ROW_KEY` — are identical either way. Only the fields in :data:`WALL_CLOCK_FIELDS`
depend on the machine; the accuracy tables never show them.

Scoring (per solution, errors ε = estimate − truth interpolated at the solution epochs):

* ``fusion.metrics.compute_metrics``: horizontal / 3-D RMS and max, SEP (median 3-D error)
  overall and per cutting cycle, per-axis max|ε|, mean|ε|, mean, std, RMS, and the consistency
  ``nees_rms = sqrt(mean_axes(RMS(ε_i/σ_i)²))`` (1 when σ is honest) and the mean 3-D NEES;
* per axis also min ε, max ε and the variance (seed 002 Table 2); on a face, the errors along
  and across the face (seed 004's x is across the face, its z is up);
* faults (the recording's ``meta.extra['faults']``) on a sensor that the method reads (a
  plugin of that type is enabled; dropouts and IMU gaps are not inconsistencies to detect) are
  counted in ``faults_injected``; such a fault is *detected* by the
  first isolation of a federated local holding that sensor's plugin, by the first jump taken
  in of one of that plugin's states (a slip, :mod:`fusion.jumps`, any architecture), or for a
  centralized filter by the first χ²-gate rejection of that plugin, within
  ``[t_start, t_end + DETECTION_GRACE_S]``; the delay is from ``t_start``. A *false alarm* is an
  isolation or a jump that no injected fault on that sensor explains (federated filters only; a
  gate rejection is not an alarm).
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchmarks.faults import plan_fault
from fusion.attitude import dcm_from_quat, euler_from_dcm, quat_from_rotvec, wrap_angle
from fusion.config import ConfigError, FusionConfig, find_config, load_config_data, parse_config
from fusion.engine import Engine, RunResult
from fusion.fault_detection import ISOLATE, READMIT
from fusion.jumps import JUMP
from fusion.metrics import compute_metrics, interpolate_truth
from fusion.recording import Recording, TruthData, read_recording
from fusion.sim.scenario import parse_override
from fusion.sim.simulate import simulate
from fusion.solution import Solution

WALL_CLOCK_FIELDS = ("wall_s", "realtime_factor", "peak_rss_mb", "read_s")
"""Row fields that depend on the machine and its load (never compared between runs)."""

ROW_KEY = ("suite", "group", "method", "solution", "seed")
"""Rows are sorted by these fields."""

DETECTION_GRACE_S = 5.0
"""A detection up to this long after a fault window closes still counts as a detection."""

FAULT_SENSOR = {
    "magnetic_interference": "magnetometer",
    "uwb_nlos": "uwb",
    "odometer_slip": "odometer",
}
"""Injected fault kinds that make a sensor inconsistent, and the plugin type that reads it."""

TRACE_POINTS = 3000
"""Most epochs kept in a trace for the figures."""


class BenchmarkError(RuntimeError):
    """A benchmark cannot run (bad option, missing optional dependency)."""


@dataclass(frozen=True)
class Method:
    """One estimator run on a task's recording.

    Parameters
    ----------
    label
        Row label (unique within the task).
    config
        Configuration name in ``configs/`` (or a path).
    overrides
        Dotted ``key.sub=value`` overrides of the configuration mapping; in the ``plugins``
        list a segment selects plugins by instance name or type, ``*`` all, a number one.
    compensate_from
        Label of an earlier method of the task whose final estimates (odometer mounting angles
        and scale error, gyro bias) go into ``filter.dead_reckoning`` (seed 000 Table 3,
        "traditional method with compensation").
    trace
        Keep a decimated trace of this method's solutions for the figures.
    measure_memory
        Run in a child process and record its peak resident memory (speed suite).
    """

    label: str
    config: str
    overrides: tuple[str, ...] = ()
    compensate_from: str | None = None
    trace: bool = False
    measure_memory: bool = False


@dataclass(frozen=True)
class Task:
    """One recording (scenario, overrides, seed) and the methods run on it.

    ``fault`` names a fault kind to inject on this seed's trajectory (see
    :func:`benchmarks.faults.plan_fault`), e.g. for the ablation suite.
    """

    suite: str
    group: str
    scenario: str
    seed: int
    methods: tuple[Method, ...]
    scenario_overrides: tuple[str, ...] = ()
    fault: str | None = None
    keep_traces: bool = False
    executor: str = "default"
    """``robustness``: :func:`benchmarks.robustness.execute` runs the task instead of
    :func:`execute_task`'s own loop."""


@dataclass
class Trace:
    """A decimated solution with its truth, for the figures."""

    group: str
    method: str
    solution: str
    seed: int
    t: NDArray[np.float64]
    position: NDArray[np.float64]
    truth: NDArray[np.float64]
    sigma: NDArray[np.float64]
    cycle: NDArray[np.int64]
    face_along: NDArray[np.float64] | None
    injected: list[dict[str, Any]]
    events: list[tuple[float, str, str]]
    """(t, local, action) of the federated master's isolations and re-admissions."""
    rejections: dict[str, NDArray[np.float64]]
    """Times of χ²-gate rejections per plugin."""


@dataclass
class TaskResult:
    """Rows, traces and notes (skipped or failed methods) of one task."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    traces: list[Trace] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def describe_machine() -> str:
    """CPU model, logical cores, OS and Python/NumPy versions of this machine."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (
        f"{cpu}, {os.cpu_count()} logical cores, {platform.system()} {platform.release()},"
        f" Python {platform.python_version()}, NumPy {np.__version__}"
    )


# ----------------------------------------------------------------------------- configuration
def override_config(data: dict[str, Any], overrides: Iterable[str]) -> dict[str, Any]:
    """Apply dotted overrides to a configuration mapping (returns a new mapping).

    Parameters
    ----------
    data
        The raw configuration mapping (YAML contents).
    overrides
        ``key.sub=value`` (value parsed as YAML); inside the ``plugins`` list a segment is a
        plugin instance name or type, ``*`` (every plugin) or an index.

    Raises
    ------
    ConfigError
        When a segment selects no plugin or walks into a value that is not a mapping.
    """
    import copy

    out = copy.deepcopy(data)
    for text in overrides:
        path, value = parse_override(text)
        nodes: list[Any] = [out]
        for i, part in enumerate(path[:-1]):
            nxt: list[Any] = []
            for node in nodes:
                if isinstance(node, list):
                    nxt.extend(_select_plugins(node, part, text))
                elif isinstance(node, dict):
                    child = node.get(part)
                    if child is None:
                        child = node[part] = {}
                    nxt.append(child)
                else:
                    where = ".".join(path[: i + 1])
                    raise ConfigError(f"config override {text!r}: {where!r} is not a mapping")
            nodes = nxt
        for node in nodes:
            targets = _select_plugins(node, path[-1], text) if isinstance(node, list) else [node]
            for target in targets:
                if not isinstance(target, dict):
                    raise ConfigError(f"config override {text!r}: cannot set {'.'.join(path)!r}")
                target[path[-1]] = value
    return out


def _select_plugins(plugins: list[Any], part: str, text: str) -> list[Any]:
    if part == "*":
        chosen = list(plugins)
    elif part.isdigit():
        chosen = [plugins[int(part)]] if int(part) < len(plugins) else []
    else:
        chosen = [
            p for p in plugins if isinstance(p, dict) and part in (p.get("name"), p.get("type"))
        ]
    if not chosen:
        raise ConfigError(f"config override {text!r}: no plugin {part!r} in the configuration")
    return chosen


def load_method_config(method: Method, extra: Sequence[str] = ()) -> FusionConfig | None:
    """The method's configuration with its overrides, or None when the file does not exist."""
    path = find_config(method.config)
    if not path.exists():
        return None
    data = load_config_data(path)
    return parse_config(override_config(data, [*method.overrides, *extra]), str(path))


def compensation_overrides(result: RunResult) -> list[str]:
    """``filter.dead_reckoning`` overrides from a forward filter's final estimates.

    The odometer plugin's mounting error δα is a rotation vector in body axes with the true
    mounting ``C_b^m = exp(−δα×)`` relative to its nominal (here the identity), so the dead
    reckoning's ``C_m^b = exp(δα×)`` expressed as (roll, pitch, yaw); δα about the travel axis
    (y) is unobservable and left at zero, as seed 000 compensates only [δk_D, δα_x, δα_z].
    The gyro bias is the filter's total estimate (SINS compensation plus residual state).
    """
    odometer = [p for p in result.config.plugins if p.enabled and p.type == "odometer"]
    if not odometer:
        raise ConfigError("compensate_from: the forward filter has no odometer plugin")
    name = odometer[0].instance_name
    alpha = result.state_estimate(f"{name}.mounting_angles")[0].copy()
    alpha[1] = 0.0
    euler = euler_from_dcm(dcm_from_quat(quat_from_rotvec(alpha)))
    mounting = np.rad2deg(wrap_angle(euler))
    gyro = np.rad2deg(result.state_estimate("gyro_bias")[0]) * 3600.0
    overrides = [
        f"filter.dead_reckoning.mounting_deg=[{', '.join(repr(float(x)) for x in mounting)}]",
        f"filter.dead_reckoning.gyro_bias_deg_h=[{', '.join(repr(float(x)) for x in gyro)}]",
    ]
    if f"{name}.scale_error" in [b.name for b in result.layout.blocks]:
        scale = float(result.state_estimate(f"{name}.scale_error")[0][0])
        overrides.append(f"filter.dead_reckoning.scale_error={scale!r}")
    return overrides


# ----------------------------------------------------------------------------- scoring
def _face_axes(recording: Recording) -> NDArray[np.float64] | None:
    """Horizontal unit vector along the face (from the surveyed face ends), if any."""
    face = recording.meta.face
    if face is None or face.ends_enu_m is None or len(face.ends_enu_m) < 2:
        return None
    d = np.asarray(face.ends_enu_m[1][:2], float) - np.asarray(face.ends_enu_m[0][:2], float)
    norm = float(np.hypot(*d))
    return d / norm if norm > 0 else None


def _axis_fields(prefix: str, err: NDArray[np.float64]) -> dict[str, float]:
    a = np.abs(err)
    return {
        f"{prefix}_max": float(a.max()),
        f"{prefix}_mean": float(a.mean()),
        f"{prefix}_absstd": float(a.std()),
        f"{prefix}_std": float(err.std()),
        f"{prefix}_rms": float(np.sqrt(np.mean(err**2))),
        f"{prefix}_min_signed": float(err.min()),
        f"{prefix}_max_signed": float(err.max()),
        f"{prefix}_var": float(err.var()),
    }


def _nan(x: Any) -> float:
    return float("nan") if x is None else float(x)


def score_solution(
    solution: Solution, truth: TruthData, along: NDArray[np.float64] | None, cycles: int
) -> dict[str, float]:
    """Accuracy and consistency fields of one solution (see the module docstring)."""
    m = compute_metrics(solution, truth)
    inside, pos, _, _, _ = interpolate_truth(truth, solution.t)
    err = solution.position[inside] - pos
    row: dict[str, float] = {
        "horizontal_mean": float(np.mean(np.hypot(err[:, 0], err[:, 1]))),
        "horizontal_rms": _nan(m["horizontal_rms"]),
        "horizontal_max": _nan(m["horizontal_max"]),
        "rms_3d": _nan(m["rms_3d"]),
        "max_3d": _nan(m["max_3d"]),
        "sep": _nan(m["sep"]),
    }
    for c in range(1, cycles + 1):
        row[f"sep_c{c}"] = _nan(m["sep_per_cycle"].get(c))
    for k, axis in enumerate("enu"):
        row.update(_axis_fields(axis, err[:, k]))
    if along is not None:
        across = np.array([along[1], -along[0]])
        row.update(_axis_fields("along", err[:, :2] @ along))
        row.update(_axis_fields("across", err[:, :2] @ across))
    ratios = [_nan(v) for v in m["nees"]["normalized_rms"].values()]
    row["nees_rms"] = float(np.sqrt(np.mean(np.square(ratios))))
    row["nees_mean_3d"] = _nan(m["nees"].get("mean_3d"))
    return row


def score_faults(
    injected: Sequence[dict[str, Any]],
    result: RunResult,
) -> dict[str, float]:
    """Detection fields (see the module docstring); NaN where they do not apply."""
    blocks = [b for b in result.config.plugins if b.enabled]
    federated = result.config.filter.architecture == "federated"
    local_types: dict[str, set[str]] = {}
    for b in blocks:
        local_types.setdefault(b.local_name, set()).add(b.type)
    plugin_type = {b.instance_name: b.type for b in blocks}
    for e in result.faults:
        if e.action == JUMP:  # a jump's local is its state, named after the plugin instance
            local_types.setdefault(e.local, {plugin_type[e.local.split(".")[0]]})
    alarms = [e for e in result.faults if e.action in (ISOLATE, JUMP)]
    isolations = [e for e in alarms if e.action == ISOLATE]
    used = {b.type for b in blocks}
    detectable = [f for f in injected if FAULT_SENSOR.get(f.get("type", "")) in used]
    rejections = {
        b.instance_name: result.innovations[b.instance_name].rejection_times()
        for b in blocks
        if not federated and b.instance_name in result.innovations
    }
    delays: list[float] = []
    explained: set[int] = set()
    for f in detectable:
        sensor = FAULT_SENSOR[f["type"]]
        t0, t1 = float(f["t_start"]), float(f["t_end"]) + DETECTION_GRACE_S
        times: list[float] = []
        for i, e in enumerate(alarms):
            if sensor in local_types.get(e.local, set()) and t0 <= e.t <= t1:
                explained.add(i)
                times.append(e.t)
        for b in blocks:
            t = rejections.get(b.instance_name)
            if b.type == sensor and t is not None:
                times.extend(t[(t >= t0) & (t <= t1)][:1].tolist())
        if times:
            delays.append(min(times) - t0)
    return {
        "faults_injected": float(len(detectable)),
        "detected_fraction": len(delays) / len(detectable) if detectable else float("nan"),
        "detect_delay_s": float(np.mean(delays)) if delays else float("nan"),
        "false_alarms": float(len(alarms) - len(explained)) if federated else float("nan"),
        "isolations": float(len(isolations)) if federated else float("nan"),
    }


def _trace(
    task: Task,
    label: str,
    kind: str,
    solution: Solution,
    recording: Recording,
    result: RunResult,
) -> Trace:
    truth = recording.truth
    assert truth is not None
    inside, pos, _, _, cycle = interpolate_truth(truth, solution.t)
    stride = max(1, math.ceil(int(inside.sum()) / TRACE_POINTS))
    rows = np.flatnonzero(inside)[::stride]
    events = [(e.t, e.local, e.action) for e in result.faults if e.action in (ISOLATE, READMIT)]
    rejections = {name: log.rejection_times() for name, log in result.innovations.items()}
    return Trace(
        group=task.group,
        method=label,
        solution=kind,
        seed=task.seed,
        t=solution.t[rows],
        position=solution.position[rows],
        truth=pos[::stride],
        sigma=solution.sigma_position[rows],
        cycle=cycle[::stride],
        face_along=_face_axes(recording),
        injected=list(recording.meta.extra.get("faults", [])),
        events=events,
        rejections=rejections,
    )


# ----------------------------------------------------------------------------- one task
def _measure_in_child(config: FusionConfig, recording_dir: Path, work: Path) -> dict[str, float]:
    """Run one configuration in a fresh child process (:mod:`benchmarks.measure`); its wall
    time, real-time factor and peak resident memory."""
    cfg_path = work / "measured_config.yaml"
    cfg_path.write_text(config.to_yaml(), encoding="utf-8")
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks.measure", str(cfg_path), str(recording_dir)],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
        check=False,
    )
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-3:]
        raise RuntimeError(f"measurement child failed ({proc.returncode}): {' | '.join(tail)}")
    return {k: float(v) for k, v in json.loads(proc.stdout.strip().splitlines()[-1]).items()}


def execute_task(task: Task) -> TaskResult:
    """Simulate the task's recording, run its methods, score them (a pure function of the task).

    Parameters
    ----------
    task
        The recording and methods.

    Returns
    -------
    TaskResult
        One row per method and solution; notes for methods whose configuration does not exist
        or whose run failed (the failure message is kept, the campaign goes on).
    """
    if task.executor == "robustness":
        from benchmarks.robustness import execute

        return execute(task)
    base = {"suite": task.suite, "group": task.group, "scenario": task.scenario, "seed": task.seed}
    out = TaskResult()
    overrides = list(task.scenario_overrides)
    if task.fault is not None:
        try:
            overrides.append(plan_fault(task.scenario, task.seed, task.fault, overrides))
        except ValueError as exc:
            out.notes.append(f"{task.suite}/{task.group}, seed {task.seed}: {exc}")
            return out
    with tempfile.TemporaryDirectory(prefix="bench-") as tmp:
        work = Path(tmp)
        simulate(task.scenario, work / "rec", seed=task.seed, overrides=overrides)
        recording = read_recording(work / "rec", bridge_imu_gaps=True)
        truth = recording.truth
        if truth is None:
            raise BenchmarkError(f"scenario {task.scenario} wrote no truth.csv")
        cycles = int(truth.cycle.max())
        along = _face_axes(recording)
        injected = list(recording.meta.extra.get("faults", []))
        needed = {m.compensate_from for m in task.methods}
        results: dict[str, RunResult] = {}  # only those a later method compensates from
        for method in task.methods:
            where = f"{task.suite}/{task.group}/{method.label}"
            try:
                extra: list[str] = []
                if method.compensate_from is not None:
                    source = results.get(method.compensate_from)
                    if source is None:
                        out.notes.append(f"{where}: needs {method.compensate_from}, not run")
                        continue
                    extra = compensation_overrides(source)
                config = load_method_config(method, extra)
                if config is None:
                    out.notes.append(
                        f"{where}: configs/{method.config}.yaml does not exist (yet); skipped"
                    )
                    continue
                if method.measure_memory:
                    figures = _measure_in_child(config, work / "rec", work)
                    out.rows.append(
                        {**base, "method": method.label, "solution": "forward", **figures}
                    )
                    continue
                result = Engine(config, recording).run()
            except Exception as exc:  # a broken configuration must not stop the campaign
                out.notes.append(f"{where}: {type(exc).__name__}: {str(exc).splitlines()[0]}")
                continue
            if method.label in needed:
                results[method.label] = result
            solutions = [("forward", result.solution)]
            if result.smoothed is not None:
                solutions.append(("smoothed", result.smoothed))
            fault_fields = score_faults(injected, result)
            for kind, solution in solutions:
                row: dict[str, Any] = {**base, "method": method.label, "solution": kind}
                row.update(score_solution(solution, truth, along, cycles))
                row.update(fault_fields)
                row["wall_s"] = result.wall_time_s
                row["realtime_factor"] = result.realtime_factor
                out.rows.append(row)
                if task.keep_traces and method.trace:
                    out.traces.append(_trace(task, method.label, kind, solution, recording, result))
    return out


# ----------------------------------------------------------------------------- many tasks
ProgressCallback = Callable[[int, int, Task, float], None]


def _timed(task: Task) -> tuple[TaskResult, float]:
    start = time.perf_counter()
    return execute_task(task), time.perf_counter() - start


def run_tasks(
    tasks: Sequence[Task],
    jobs: int = 1,
    scheduler: str | None = None,
    progress: ProgressCallback | None = None,
    on_result: Callable[[Task, TaskResult], None] | None = None,
) -> list[TaskResult]:
    """Execute tasks locally (``jobs`` processes) or on Dask; results in the order of ``tasks``.

    Parameters
    ----------
    tasks
        The tasks.
    jobs
        Local worker processes (1: run in this process); with ``scheduler="local-dask"`` the
        number of Dask workers.
    scheduler
        ``None`` (local processes), ``"local-dask"`` (a ``distributed.LocalCluster`` started here)
        or the address of a running scheduler (``tcp://host:port``).
    progress
        Called after each task with (done, total, task, seconds).
    on_result
        Called with each task and its result as it finishes (e.g. to store it:
        :class:`benchmarks.checkpoint.TaskStore`).
    """
    if jobs < 1:
        raise BenchmarkError(f"--jobs must be at least 1, got {jobs}")
    # one BLAS thread per worker, as Dask's nannies set it: identical arithmetic everywhere
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    if scheduler is not None:
        return _run_dask(tasks, jobs, scheduler, progress, on_result)
    results: list[TaskResult | None] = [None] * len(tasks)

    def finished(done: int, i: int, result: TaskResult, seconds: float) -> None:
        results[i] = result
        if on_result is not None:
            on_result(tasks[i], result)
        if progress is not None:
            progress(done, len(tasks), tasks[i], seconds)

    if jobs == 1:
        for i, task in enumerate(tasks):
            finished(i + 1, i, *_timed(task))
        return [r for r in results if r is not None]
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
        futures = {pool.submit(_timed, task): i for i, task in enumerate(tasks)}
        for done, future in enumerate(as_completed(futures), start=1):
            finished(done, futures[future], *future.result())
    return [r for r in results if r is not None]


def _run_dask(
    tasks: Sequence[Task],
    jobs: int,
    scheduler: str,
    progress: ProgressCallback | None,
    on_result: Callable[[Task, TaskResult], None] | None,
) -> list[TaskResult]:
    local = scheduler == "local-dask"
    if not local and not scheduler.startswith(("tcp://", "tls://", "ucx://", "inproc://")):
        raise BenchmarkError(
            f"--scheduler {scheduler!r}: expected tcp://host:port (a running Dask scheduler)"
            " or local-dask"
        )
    try:
        from distributed import Client, LocalCluster
        from distributed import as_completed as dask_completed
    except ImportError:
        raise BenchmarkError(
            "--scheduler needs dask.distributed, which is not installed: "
            "pip install 'shearer-fusion[bench]' (or pip install 'dask[distributed]')"
        ) from None
    cluster = None
    if local:
        cluster = LocalCluster(
            n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None
        )
        client = Client(cluster)
    else:
        client = Client(scheduler)
        _upload_package(client)
    try:
        futures = client.map(_timed, list(tasks), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        results: list[TaskResult | None] = [None] * len(tasks)
        for done, future in enumerate(dask_completed(futures), start=1):
            i = index[future.key]
            result, seconds = future.result()
            results[i] = result
            if on_result is not None:
                on_result(tasks[i], result)
            if progress is not None:
                progress(done, len(tasks), tasks[i], seconds)
        return [r for r in results if r is not None]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _upload_package(client: Any) -> None:
    """Send the ``benchmarks`` package to a remote cluster's workers (``fusion`` must be
    installed there, e.g. ``pip install shearer-fusion[bench]``)."""
    import zipfile

    root = Path(__file__).resolve().parent
    with tempfile.TemporaryDirectory() as tmp:
        archive = Path(tmp) / "benchmarks.zip"
        with zipfile.ZipFile(archive, "w") as zf:
            for path in sorted(root.glob("*.py")):
                zf.write(path, f"benchmarks/{path.name}")
        client.upload_file(str(archive))


def collect(results: Iterable[TaskResult]) -> TaskResult:
    """All rows (sorted by :data:`ROW_KEY`), traces and de-duplicated notes of many tasks."""
    merged = TaskResult()
    for r in results:
        merged.rows.extend(r.rows)
        merged.traces.extend(r.traces)
        merged.notes.extend(n for n in r.notes if n not in merged.notes)
    merged.rows.sort(key=lambda row: tuple(row[k] for k in ROW_KEY))
    return merged
