"""Benchmark suites: ``python -m benchmarks SUITE [--runs N] [--out DIR] [--jobs J]
[--scheduler tcp://host:port|local-dask] [--set key.sub=value ...] [--resume]``.

Suites (issue 7): ``seed000`` (SEP per cutting cycle, Δ, RTS, IMU grades), ``seed002`` (MC and
ZUPT), ``seed003`` (SINS/OD/MAG; CKF vs AFKF under magnetic interference), ``seed004`` (UWB),
``ablation`` (every configuration, nominal and with each injected fault), ``speed`` (real-time
factor and peak memory on the 8-hour shift, beside the naive covariance step), ``robustness``
(every configuration on 20 randomized worlds, failures counted), ``robustness-federated`` (its
federated filters and ``full_ckf`` alone, to rerun after a change of the fault detection),
``robustness-uwb`` (its filters with UWB ranges alone, to rerun after a change of the range
updates or the re-acquisition), ``robustness-zupt`` (``sins_zupt`` alone, after a change of the
ZUPT's re-acquisition at rest), ``robustness-harsh`` (the federated filters and their
centralized counterparts on worlds with a degraded IMU and injected faults) and
``robustness-smoke`` (its CI variant on short worlds); these five are not part of ``all``, and
RESULTS.md quotes all but the smoke one by hand. Each writes
Markdown and CSV tables and PNG figures into ``--out`` (default ``benchmarks/results/SUITE/``).
``all`` runs every suite (the real-data one too) and regenerates ``benchmarks/RESULTS.md``;
``results`` only assembles RESULTS.md from the suites' last outputs (each section keeps its
own command, date and machine). ``strapdown`` prints the mechanization cost per IMU sample.
``real`` hands its arguments to ``benchmarks.real.main``
(the real-dataset suite, issue 8) when that module exists.

Monte Carlo runs are seeded (0 … N−1) and execute in ``--jobs`` local processes (default: one
per core) or on a Dask cluster (``--scheduler``; needs ``pip install 'shearer-fusion[bench]'``);
the tables are identical either way. Each finished recording is kept in ``OUT/tasks/`` until
the suite's outputs are written, and ``--resume`` reruns an interrupted suite from there
(:mod:`benchmarks.checkpoint`; the full-length ``robustness`` suite takes hours).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from benchmarks.runner import describe_machine


def strapdown() -> None:
    """Cost of the mechanization per IMU sample."""
    from fusion.attitude import dcm_from_euler
    from fusion.earth import LocalFrame
    from fusion.strapdown import HIST_SIZE, NavState, Strapdown, _step, mechanize

    frame = LocalFrame(34.25, 108.95, -350.0)
    initial = NavState.from_enu(frame, [0, 0, 0], [0, 0.05, 0], 0.01, -0.02, 1.6)
    n = 360_001
    t = np.arange(n) / 100.0
    rng = np.random.default_rng(0)
    c = dcm_from_euler(0.01, -0.02, 1.6)
    gyro = 1e-3 * rng.standard_normal((n, 3))
    accel = (c.T @ [0, 0, 9.79])[None, :] + 1e-2 * rng.standard_normal((n, 3))
    mechanize(t[:10], gyro[:10], accel[:10], initial)  # compile / load the cache
    rows = []
    t0 = time.perf_counter()
    mechanize(t, gyro, accel, initial)
    rows.append(("mechanize(), whole record", (time.perf_counter() - t0) / (n - 1)))
    sins = Strapdown(t, gyro, accel, initial)
    t0 = time.perf_counter()
    for te in np.arange(0.1, t[-1] + 1e-9, 0.1):
        sins.advance_to(te)
        sins.take_velocity_increment()
    rows.append(("Strapdown.advance_to, 0.1 s steps", (time.perf_counter() - t0) / (n - 1)))
    nav, hist = initial.to_array(), np.zeros(HIST_SIZE)
    m = 20_000
    t0 = time.perf_counter()
    for k in range(1, m):
        _step.py_func(nav, hist, gyro[k] * 0.01, accel[k] * 0.01, 0.01, True)
    rows.append(("same step interpreted (no numba)", (time.perf_counter() - t0) / (m - 1)))
    print(f"machine: {describe_machine()}; one process, one core")
    print("| mechanization | µs per IMU sample | budget |")
    print("|---|---:|---:|")
    for name, sec in rows:
        print(f"| {name} | {sec * 1e6:.2f} | 10 |")


def _progress(done: int, total: int, task: object, seconds: float) -> None:
    from benchmarks.runner import Task

    assert isinstance(task, Task)
    print(
        f"[{done}/{total}] {task.suite} {task.group} seed {task.seed}: {seconds:.1f} s",
        file=sys.stderr,
        flush=True,
    )


def run_suites(names: list[str], args: argparse.Namespace, command: str) -> None:
    """Run suites and write each one's outputs; with ``all`` also benchmarks/RESULTS.md."""
    from benchmarks.checkpoint import TaskStore
    from benchmarks.report import write_suite
    from benchmarks.runner import collect, run_tasks
    from benchmarks.suites import SUITES

    root = _root(args)
    for name in names:
        suite = SUITES[name]
        runs = args.runs if args.runs is not None else suite.default_runs
        out = Path(args.out) if args.out and args.suite != "all" else root / name
        tasks = suite.tasks(runs, tuple(args.set))
        store = TaskStore(out / "tasks", args.resume)
        pending = store.pending(tasks)
        done = f", {len(tasks) - len(pending)} already done" if len(pending) < len(tasks) else ""
        print(f"{name}: {len(tasks)} recordings{done}, {runs} run(s) per row", file=sys.stderr)
        run_tasks(pending, args.jobs, args.scheduler, _progress, store.save)
        merged = collect(store.results(tasks))
        date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
        print(write_suite(suite, merged, out, runs, command, date))
        store.remove()


def _root(args: argparse.Namespace) -> Path:
    """Directory holding one output directory per suite."""
    from benchmarks.report import BENCH_DIR

    if args.out and args.suite in ("all", "results"):
        return Path(args.out)
    return BENCH_DIR / "results"


def _assemble(args: argparse.Namespace, command: str) -> None:
    from benchmarks.report import write_results_md
    from benchmarks.suites import SUITES

    path = write_results_md(list(SUITES.values()), _root(args), command)
    print(f"wrote {path}", file=sys.stderr)


def _real_available() -> bool:
    return (Path(__file__).parent / "real.py").exists()


def _real(argv: list[str]) -> int:
    import importlib

    try:
        real = importlib.import_module("benchmarks.real")
    except ImportError as exc:
        if exc.name != "benchmarks.real":
            raise
        print(
            "suite 'real' is not available: benchmarks/real.py (issue 8) does not exist yet",
            file=sys.stderr,
        )
        return 2
    return int(real.main(argv) or 0)


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and run the suite(s)."""
    from benchmarks.suites import SUITES

    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["real"]:
        return _real(argv[1:])
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    choices = [*sorted(SUITES), "all", "results", "strapdown", "real"]
    parser.add_argument(
        "suite",
        choices=choices,
        help="suite to run; all: every suite, then RESULTS.md; results: only assemble"
        " RESULTS.md from the suites' last outputs; real: issue 8's suite",
    )
    parser.add_argument(
        "--runs", type=int, help="Monte Carlo runs (seeds 0…N−1); default per suite"
    )
    parser.add_argument(
        "--out",
        help="output directory (default benchmarks/results/SUITE; for all/results the parent"
        " of the suites' directories, default benchmarks/results)",
    )
    parser.add_argument(
        "--jobs", type=int, default=None, help="local worker processes (default: cores)"
    )
    parser.add_argument(
        "--scheduler",
        default=os.environ.get("FUSION_BENCH_SCHEDULER") or None,
        help="tcp://host:port of a running Dask scheduler, or local-dask (a local cluster);"
        " default: $FUSION_BENCH_SCHEDULER, else local processes",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="keep the tasks an interrupted run of the same command and sources finished in"
        " --out (benchmarks/checkpoint.py) and run only the rest",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="scenario override for every recording, e.g. --set duration_s=900 (smoke runs)",
    )
    args = parser.parse_args(argv)
    if args.suite == "strapdown":
        strapdown()
        return 0
    if args.runs is not None and args.runs < 1:
        parser.error("--runs must be at least 1")
    if args.jobs is None:
        args.jobs = os.cpu_count() or 1
    command = "python -m benchmarks " + " ".join(shlex.quote(a) for a in argv)
    from benchmarks.runner import BenchmarkError

    try:
        if args.suite != "results":
            every = [name for name, suite in SUITES.items() if suite.in_results]
            run_suites(every if args.suite == "all" else [args.suite], args, command)
        if args.suite in ("all", "results"):
            _assemble(args, command)
        if args.suite == "all" and _real_available():
            return _real([])
    except BenchmarkError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
