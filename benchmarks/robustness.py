"""The robustness suites: every shipped configuration on randomized worlds.

``python -m benchmarks robustness [--runs N]`` simulates the worlds ``longwall-random`` seeds
0 … N−1 (default 20; :mod:`fusion.sim.worlds`, the same worlds for every configuration) and
runs each configuration of ``configs/`` except the real datasets' ``real_*`` ones on each (the
dead-reckoning and standalone ones included: :data:`ROBUSTNESS_CONFIGS`). Every
(world, configuration) runs in a child process (``python -m benchmarks.robustness CONFIG
RECORDING``) with a CPU-time limit, so that an exception, a crash, a non-zero exit, a run
that does not reach :data:`TIMEOUT_RTF` times real time or a non-finite output counts as one
*failed run* and the suite goes on. ``robustness-smoke`` is the CI variant: 20 short worlds
(``longwall-random-short`` at :data:`SMOKE_DURATION_S`) and :data:`SMOKE_CONFIGS`, run
in-process (exceptions and non-finite outputs are caught per run the same way).

Per run and solution (forward; smoothed where the configuration smooths) the row holds:

* ``horizontal_rms``, ``horizontal_max`` — horizontal error (m) against truth.csv;
* ``nz_e_sumsq``, ``nz_n_sumsq``, ``nz_count`` — Σ(ε/σ)² east / north and the epoch count, so
  that the table pools RMS(ε/σ) over the worlds (``sqrt(Σ / n)``); ``nz_yaw_sumsq`` and
  ``nz_yaw_count`` the same for the yaw against the σ of the run's state history (forward
  only; issue 29 asks the yaw's σ to keep its promise too);
* ``isolations`` — isolation rows in the run's fault list (federated filters; NaN otherwise
  and on worlds with injected faults, so that the table's per-hour figure counts false
  isolations only), ``duration_h`` the recording's length;
* ``near_anchor_max`` — the worst horizontal error at epochs where the UWB tag (truth position
  plus the lever arm) is within :data:`NEAR_ANCHOR_M` of an anchor, after the first pass
  reached the far face end (NaN if it never did);
* ``smoothed_worse`` (on the forward row) — 1 when the smoothed horizontal RMS exceeds the
  forward one;
* ``failed`` (1 or 0) and ``failure`` (the reason).

The ``full_afkf / full_ckf`` rows hold the per-world ratio of the two forward horizontal RMS.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.runner import Method, Task, TaskResult, load_method_config
from benchmarks.tables import Column, RowSpec, TableSpec
from fusion.attitude import dcm_from_euler, wrap_angle
from fusion.config import FusionConfig, load_config
from fusion.engine import Engine, RunResult
from fusion.fault_detection import ISOLATE
from fusion.metrics import interpolate_truth
from fusion.recording import Recording, read_recording
from fusion.sim.simulate import simulate
from fusion.sim.worlds import ranges_markdown
from fusion.solution import Solution

REPO = Path(__file__).resolve().parents[1]
NEAR_ANCHOR_M = 12.0
"""Tag-to-anchor distance (m) of the near-anchor error."""
TIMEOUT_RTF = 4.0
"""A child run that uses more CPU time than the recording's duration divided by this (plus
:data:`TIMEOUT_BASE_S`) is stopped and fails (the configurations run at 15–1000× real time on
these worlds). CPU time, so that a loaded machine does not fail runs; a wall-clock limit of
:data:`WALL_FACTOR` times that catches a child that hangs without computing."""
TIMEOUT_BASE_S = 120.0
WALL_FACTOR = 6.0
RATIO = ("full_afkf", "full_ckf")
RATIO_METHOD = f"{RATIO[0]} / {RATIO[1]}"


def robustness_configs() -> list[str]:
    """Every configuration of ``configs/`` but the real datasets' ``real_*``."""
    from benchmarks.suites import config_names

    return config_names()


SMOKE_CONFIGS = ("full_afkf_rts", "sins_od_cpoem_rts")
"""The CI smoke suite's subset: every plugin in the federated filter with online RTS, and the
centralized odometer + CPOEM + RTS filter (the two code paths a world can break)."""
SMOKE_DURATION_S = 150.0
"""Length of the smoke suite's worlds (s): 20 worlds, both configurations, < 3 min on 2 cores."""


def _smooths(config: str) -> bool:
    cfg = load_config(REPO / "configs" / f"{config}.yaml")
    return cfg.smoother.mode != "off"


# ----------------------------------------------------------------------------- tasks, tables
def robustness_tasks(
    runs: int,
    overrides: tuple[str, ...],
    configs: Sequence[str] | None = None,
    family: str = "longwall-random",
) -> list[Task]:
    """The worlds ``family`` 0 … runs−1, each configuration (default: every one) in a child
    process."""
    methods = tuple(Method(c, c) for c in (configs or robustness_configs()))
    return [
        Task(
            suite="robustness",
            group="worlds",
            scenario=family,
            seed=seed,
            methods=methods,
            scenario_overrides=overrides,
            executor="robustness",
        )
        for seed in range(runs)
    ]


def smoke_tasks(runs: int, overrides: tuple[str, ...]) -> list[Task]:
    """The short worlds 0 … runs−1 (:data:`SMOKE_DURATION_S` long), :data:`SMOKE_CONFIGS`
    in-process."""
    methods = tuple(Method(c, c) for c in SMOKE_CONFIGS)
    return [
        Task(
            suite="robustness-smoke",
            group="worlds",
            scenario="longwall-random-short",
            seed=seed,
            methods=methods,
            scenario_overrides=(f"duration_s={SMOKE_DURATION_S!r}", *overrides),
            executor="robustness",
        )
        for seed in range(runs)
    ]


ACCURACY_COLUMNS = (
    Column("failed", "failed runs", 0, agg="sum"),
    Column("horizontal_rms", "h. RMS median (m)", 2, agg="median"),
    Column("horizontal_rms", "h. RMS worst (m)", 2, agg="max"),
)
"""Failed runs and the horizontal RMS over the worlds (rows of :func:`run_one`)."""

SIGMA_COLUMNS = (
    Column("nz_e", "RMS(ε/σ) E", 2, agg="pooled_rms"),
    Column("nz_n", "RMS(ε/σ) N", 2, agg="pooled_rms"),
    Column("nz_yaw", "RMS(ε/σ) yaw", 2, agg="pooled_rms"),
)
"""RMS(ε/σ) east, north and yaw, pooled over every epoch of every world."""


def _table(configs: Sequence[str], title: str) -> list[TableSpec]:
    rows: list[RowSpec] = []
    for c in configs:
        rows.append(RowSpec(c, "worlds", c))
        if _smooths(c):
            rows.append(RowSpec(f"{c} smoothed", "worlds", c, "smoothed"))
    main = TableSpec(
        name="robustness",
        title=title,
        rows=tuple(rows),
        columns=(
            *ACCURACY_COLUMNS,
            Column("horizontal_max", "h. max median (m)", 2, agg="median"),
            Column("horizontal_max", "h. max worst (m)", 2, agg="max"),
            *SIGMA_COLUMNS,
            Column("isolations", "false isolations / h", 2, agg="per_hour"),
            Column("smoothed_worse", "smoothed > forward (worlds)", 0, agg="sum"),
            Column("near_anchor_max", "worst h. error near anchors (m)", 2, agg="max"),
        ),
        headline="horizontal_rms",
        note="n = worlds run; median and worst over the worlds that did not fail; RMS(ε/σ)"
        " pooled over every epoch of every world (yaw: forward, against the σ of the state"
        " history; — where the configuration estimates no attitude); false isolations:"
        " isolation rows of the federated filters per hour of recording on worlds without"
        " injected faults (— for centralized filters); smoothed > forward: worlds whose"
        " smoothed horizontal RMS exceeds the forward one; near anchors: epochs with the UWB"
        f" tag within {NEAR_ANCHOR_M:g} m of an anchor after the first pass reached the far"
        " face end"
        " (sins_uwb is the configuration it is meant for)",
    )
    ratio = TableSpec(
        name="robustness_ratio",
        title=f"Federated against centralized: {RATIO[0]} / {RATIO[1]} forward horizontal RMS",
        rows=(RowSpec(RATIO_METHOD, "worlds", RATIO_METHOD),),
        columns=(
            Column("ratio", "median ratio", 2, agg="median"),
            Column("ratio", "worst ratio", 2, agg="max"),
            Column("ratio", "best ratio", 2, agg="min"),
        ),
        note="per world, over the worlds where both ran",
    )
    return [main, ratio] if all(c in configs for c in RATIO) else [main]


def robustness_tables() -> list[TableSpec]:
    """The configurations' table and the federated/centralized ratio."""
    return _table(robustness_configs(), "Every configuration on random worlds (longwall-random)")


@dataclass(frozen=True)
class Subset:
    """Some of the ``robustness`` table's configurations on its worlds, to rerun after a change
    that can move only their rows (RESULTS.md quotes such a run by hand)."""

    configs: tuple[str, ...]
    title: str
    description: str

    def tasks(self, runs: int, overrides: tuple[str, ...]) -> list[Task]:
        """:func:`robustness_tasks` for these configurations."""
        return robustness_tasks(runs, overrides, self.configs)

    def tables(self) -> list[TableSpec]:
        """:func:`robustness_tables` for these configurations."""
        return _table(self.configs, self.title)


SUBSETS = {
    "robustness-federated": Subset(
        ("full_afkf", "full_afkf_rts", "full_ckf", "sins_od_mag_afkf"),
        "Federated filters on random worlds (longwall-random)",
        "the federated filters and full_ckf on the robustness worlds",
    ),
    "robustness-uwb": Subset(
        ("full_afkf", "full_afkf_rts", "full_ckf", "sins_uwb"),
        "Filters with UWB ranges on random worlds (longwall-random)",
        "the filters with UWB ranges on the robustness worlds",
    ),
    "robustness-zupt": Subset(
        ("sins_zupt",),
        "SINS + ZUPT on random worlds (longwall-random)",
        "SINS + ZUPT on the robustness worlds",
    ),
}
"""The subsets by suite name. ``robustness-federated``: the federated filters (the ones that
isolate) and the centralized filter they are compared with, after a change of the fault
detection; ``robustness-uwb``: the filters with tightly coupled UWB ranges, after a change of
the range updates or their re-acquisition; ``robustness-zupt``: the ZUPT's re-acquisition at
rest (``max_speed_mps``), after a change of it."""


HARSH_CONFIGS = ("full_afkf", "full_afkf_rts", "full_ckf", "sins_od_mag_afkf", "sins_od_mag_ckf")
"""``robustness-harsh``: the federated filters and their centralized counterparts on worlds with a
degraded IMU (worse than its datasheet) and injected faults, where isolation decisions matter."""


def harsh_tasks(runs: int, overrides: tuple[str, ...]) -> list[Task]:
    """:func:`robustness_tasks` for :data:`HARSH_CONFIGS` on ``longwall-random-harsh``."""
    return robustness_tasks(runs, overrides, HARSH_CONFIGS, "longwall-random-harsh")


def harsh_tables() -> list[TableSpec]:
    """:func:`robustness_tables` for :data:`HARSH_CONFIGS`."""
    return _table(HARSH_CONFIGS, "Federated and centralized filters on harsh random worlds")


def smoke_tables() -> list[TableSpec]:
    """The smoke suite's tables."""
    return _table(SMOKE_CONFIGS, "Smoke: short random worlds (longwall-random-short)")


def ranges_preamble() -> str:
    """The ranges the worlds are drawn from (from :class:`fusion.sim.worlds.WorldRanges`)."""
    return (
        "Worlds drawn by `fusion.sim.worlds.draw_world(seed)` (seeds 0…N−1, the same for every"
        " configuration; `fusion simulate longwall-random OUT --seed N` writes one). A pair is"
        " drawn uniformly unless it says log-uniform; a magnitude gets a random sign; a"
        " sub-range is the world's own range (each run draws inside it); a range is used as it"
        " stands; choices are equally likely. Configurations: "
        + ", ".join(f"`{c}`" for c in robustness_configs())
        + ".\n\n<details><summary>World ranges (WorldRanges defaults)</summary>\n\n"
        + ranges_markdown()
        + "\n</details>\n"
    )


# ----------------------------------------------------------------------------- scoring
def _first_far_end(recording: Recording) -> float | None:
    """Time at which the first pass reaches the far face end (None if never)."""
    truth, face = recording.truth, recording.meta.face
    if truth is None or face is None or face.ends_enu_m is None or len(face.ends_enu_m) < 2:
        return None
    a = np.asarray(face.ends_enu_m[0][:2], float)
    d = np.asarray(face.ends_enu_m[1][:2], float) - a
    length = float(np.hypot(*d))
    along = (truth.position[:, :2] - a) @ (d / length)
    hit = np.flatnonzero(along >= length - 1.0)
    return float(truth.t[hit[0]]) if hit.size else None


def score(solution: Solution, recording: Recording, after: float | None) -> dict[str, float]:
    """Accuracy, consistency and near-anchor figures of one solution (module docstring)."""
    truth = recording.truth
    assert truth is not None
    inside, pos, _, att, _ = interpolate_truth(truth, solution.t)
    est = solution.position[inside]
    sig = solution.sigma_position[inside]
    if not (np.isfinite(est).all() and np.isfinite(sig).all()) or est.shape[0] == 0:
        raise FloatingPointError("non-finite (or empty) solution")
    err = est - pos
    h = np.hypot(err[:, 0], err[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        z = err[:, :2] / sig[:, :2]
    z = np.where(np.isfinite(z), z, np.nan)
    row = {
        "horizontal_rms": float(np.sqrt(np.mean(h**2))),
        "horizontal_max": float(h.max()),
        "nz_e_sumsq": float(np.nansum(z[:, 0] ** 2)),
        "nz_n_sumsq": float(np.nansum(z[:, 1] ** 2)),
        "nz_e_count": float(np.isfinite(z[:, 0]).sum()),
        "nz_n_count": float(np.isfinite(z[:, 1]).sum()),
        "near_anchor_max": float("nan"),
    }
    uwb = recording.meta.uwb
    if uwb is not None and after is not None:
        c = dcm_from_euler(att[:, 0], att[:, 1], att[:, 2])
        tag = pos + c @ np.asarray(uwb.tag_lever_arm_b_m, float)
        anchors = np.asarray(list(uwb.anchors.values()), float)
        near = np.linalg.norm(tag[:, None, :] - anchors[None], axis=2).min(axis=1)
        sel = (near <= NEAR_ANCHOR_M) & (solution.t[inside] >= after)
        if sel.any():
            row["near_anchor_max"] = float(h[sel].max())
    return row


def yaw_consistency(result: RunResult, recording: Recording) -> dict[str, float]:
    """Σ(ε/σ)² and the epoch count of the forward yaw error (wrapped to ±180°) against the
    yaw σ of the run's state history; empty when the run keeps none."""
    if result.states is None:
        return {}
    truth = recording.truth
    assert truth is not None
    solution = result.solution
    inside, _, _, att, _ = interpolate_truth(truth, solution.t)
    error = wrap_angle(solution.attitude[inside, 2] - att[:, 2])
    sigma = np.radians(result.states.euler_sigma()[inside, 2].astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = error / sigma
    z = z[np.isfinite(z)]
    return {"nz_yaw_sumsq": float(np.sum(z**2)), "nz_yaw_count": float(z.size)}


def run_one(config: FusionConfig, recording: Recording) -> list[dict[str, Any]]:
    """Run one configuration on one recording: a row per solution (without the task fields).

    Raises whatever the engine raises, and FloatingPointError on a non-finite solution.
    """
    result = Engine(config, recording).run()
    after = _first_far_end(recording)
    federated = config.filter.architecture == "federated"
    injected = recording.meta.extra.get("faults", [])
    isolations = sum(1 for e in result.faults if e.action == ISOLATE)
    truth = recording.truth
    assert truth is not None
    common = {
        "isolations": float(isolations) if federated and not injected else float("nan"),
        "faults_injected": float(len(injected)),
        "duration_h": float(truth.t[-1] - truth.t[0]) / 3600.0,
        "wall_s": result.wall_time_s,
        "realtime_factor": result.realtime_factor,
    }
    rows: list[dict[str, Any]] = [
        {
            "solution": "forward",
            **score(result.solution, recording, after),
            **yaw_consistency(result, recording),
            **common,
        }
    ]
    if result.smoothed is not None:
        rows.append({"solution": "smoothed", **score(result.smoothed, recording, after), **common})
        worse = rows[1]["horizontal_rms"] > rows[0]["horizontal_rms"]
        rows[0]["smoothed_worse"] = 1.0 if worse else 0.0
    for r in rows:
        r["failed"] = 0.0
    return rows


def _run_child(config: FusionConfig, rec: Path, work: Path, duration_s: float) -> Any:
    """:func:`run_one` in a child process with a time limit; its rows, or raises."""
    cfg_path = work / "config.yaml"
    cfg_path.write_text(config.to_yaml(), encoding="utf-8")
    path = os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path}
    limit = int(TIMEOUT_BASE_S + duration_s / TIMEOUT_RTF)

    def cpu_limit() -> None:  # in the child: SIGXCPU after `limit` s of CPU time
        resource.setrlimit(resource.RLIMIT_CPU, (limit, limit + 10))

    try:
        proc = subprocess.run(
            [sys.executable, "-m", "benchmarks.robustness", str(cfg_path), str(rec)],
            capture_output=True,
            text=True,
            cwd=REPO,
            env=env,
            timeout=WALL_FACTOR * limit,
            check=False,
            preexec_fn=cpu_limit,
        )
    except subprocess.TimeoutExpired:
        raise TimeoutError(f"no result after {WALL_FACTOR * limit:.0f} s wall time") from None
    if proc.returncode == -signal.SIGXCPU:
        raise TimeoutError(f"CPU time limit of {limit} s exceeded")
    if proc.returncode != 0:
        tail = " | ".join(proc.stderr.strip().splitlines()[-2:])
        raise RuntimeError(f"exit {proc.returncode}: {tail}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _failed(base: dict[str, Any], method: str, reason: str) -> dict[str, Any]:
    return {**base, "method": method, "solution": "forward", "failed": 1.0, "failure": reason}


def execute(task: Task) -> TaskResult:
    """Simulate the task's world and run every method on it, each failure caught and counted."""
    base = {"suite": task.suite, "group": task.group, "scenario": task.scenario, "seed": task.seed}
    out = TaskResult()
    isolate = task.suite == "robustness"
    with tempfile.TemporaryDirectory(prefix="robust-") as tmp:
        work = Path(tmp)
        try:
            simulate(task.scenario, work / "rec", seed=task.seed, overrides=task.scenario_overrides)
            recording = read_recording(work / "rec", bridge_imu_gaps=True)
        except Exception as exc:  # a world the simulator or reader cannot handle: every run fails
            reason = f"simulation: {type(exc).__name__}: {str(exc).splitlines()[0]}"
            out.rows.extend(_failed(base, m.label, reason) for m in task.methods)
            out.notes.append(f"{task.suite} seed {task.seed}: {reason}")
            return out
        duration = float(recording.imu.t[-1] - recording.imu.t[0])
        forward: dict[str, float] = {}
        for method in task.methods:
            try:
                config = load_method_config(method)
                if config is None:
                    raise FileNotFoundError(f"configs/{method.config}.yaml")
                if isolate:
                    rows = _run_child(config, work / "rec", work, duration)
                else:
                    rows = run_one(config, recording)
            except Exception as exc:  # counted as a failed run; the suite goes on
                reason = f"{type(exc).__name__}: {(str(exc).splitlines() or [''])[0]}"[:300]
                out.rows.append(_failed(base, method.label, reason))
                out.notes.append(f"{task.suite} seed {task.seed} {method.label}: {reason}")
                continue
            for r in rows:
                out.rows.append({**base, "method": method.label, **r})
            forward[method.label] = float(rows[0]["horizontal_rms"])
        if all(m in forward for m in RATIO) and forward[RATIO[1]] > 0:
            ratio = forward[RATIO[0]] / forward[RATIO[1]]
            out.rows.append({**base, "method": RATIO_METHOD, "solution": "forward", "ratio": ratio})
    return out


# ----------------------------------------------------------------------------- child process
def main(argv: list[str]) -> int:
    """``python -m benchmarks.robustness CONFIG.yaml RECORDING``: print :func:`run_one`'s rows
    as JSON on the last stdout line."""
    if len(argv) != 2:
        print("usage: python -m benchmarks.robustness CONFIG.yaml RECORDING_DIR", file=sys.stderr)
        return 2
    config = load_config(argv[0])
    recording = read_recording(argv[1], bridge_imu_gaps=True)
    start = time.perf_counter()
    rows = run_one(config, recording)
    for r in rows:
        r["child_s"] = time.perf_counter() - start
    print(json.dumps(rows, allow_nan=True))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
