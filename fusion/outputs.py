"""What ``fusion run`` writes: solution.csv, metrics.json (with truth), figures, and a summary."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from fusion.engine import RunResult
from fusion.fault_detection import ISOLATE, READMIT, FaultEvent
from fusion.jumps import JUMP
from fusion.metrics import compute_metrics, write_metrics_json
from fusion.recording import Recording
from fusion.solution import write_solution


def write_outputs(
    result: RunResult, recording: Recording, out_dir: str | Path, *, plots: bool = True
) -> dict[str, Path]:
    """Write the run's files into ``out_dir`` and return them by kind."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"solution": out / "solution.csv"}
    write_solution(result.solution, files["solution"])
    if result.config.filter.architecture == "federated" or result.faults:
        files["faults"] = out / "faults.csv"
        write_faults(result.faults, files["faults"])
    solutions = {"solution.csv": result.solution}
    if result.smoothed is not None:
        files["smoothed"] = out / "smoothed.csv"
        write_solution(result.smoothed, files["smoothed"])
        solutions["smoothed.csv"] = result.smoothed
    truth = recording.truth
    if truth is not None:
        files["metrics"] = out / "metrics.json"
        metrics: dict[str, dict[str, Any]] = {
            name: compute_metrics(sol, truth) for name, sol in solutions.items()
        }
        metrics["screening"] = result.screening.to_dict()
        if result.observability is not None:
            metrics["observability"] = result.observability.to_dict()
        write_metrics_json(metrics, files["metrics"])
    if plots:
        from fusion import plots as figures

        title = f"{result.config.name} on {result.recording_name}"
        files["plan"] = figures.plot_plan_view(result.solution, truth, out / "plan.png", title)
        if truth is not None:
            files["errors"] = figures.plot_errors(result.solution, truth, out / "errors.png", title)
        if result.observability is not None and result.observability.t.size > 1:
            files["observability"] = figures.plot_observability(
                result.observability, out / "observability.png", title
            )
    return files


def write_faults(events: list[FaultEvent], path: Path) -> None:
    """``faults.csv``: one row per isolation or re-admission of a local filter, and per state
    jump taken in (:mod:`fusion.jumps`)."""
    rows = ["time_s,local,statistic,threshold,action,reason"]
    rows += [
        f"{e.t:.3f},{e.local},{e.statistic:.6g},{e.threshold:.6g},{e.action},{e.reason}"
        for e in events
    ]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


def summary(result: RunResult, recording: Recording) -> str:
    """A one-screen text summary of a run."""
    sol = result.solution
    lines = [
        f"config     {result.config.name}",
        f"recording  {result.recording_name}  ({result.duration_s:.1f} s, {len(sol.t)} epochs)",
        f"speed      {result.wall_time_s:.2f} s wall, {result.realtime_factor:.0f}x real time",
        f"final σ    e/n/u {np.array2string(sol.sigma_position[-1], precision=3)} m",
    ]
    lines += [
        f"screened   {entry.describe()}" for entry in result.screening.streams if entry.rejected
    ]
    for name, log in result.innovations.items():
        lines.append(
            f"plugin     {name}: {log.count} updates, {log.rejected} rejected, "
            f"whitened-innovation RMS {log.whitened_rms():.2f}"
        )
    actions = [e.action for e in result.faults]
    if result.config.filter.architecture == "federated" or actions:
        lines.append(
            f"faults     {actions.count(ISOLATE)} isolations, {actions.count(READMIT)} "
            f"re-admissions, {actions.count(JUMP)} state jumps taken in (faults.csv)"
        )
    if result.smoother_rejected:
        lines.append(
            f"smoother   {result.smoother_rejected} output epochs kept their forward estimate"
            " (a smoothed correction their statistics did not allow)"
        )
    estimated = result.config.filter.architecture in ("centralized", "federated")
    for block in result.layout.blocks[3:] if estimated else ():
        est, sd = result.state_estimate(block.name)
        lines.append(
            f"estimate   {block.name}: {np.array2string(est, precision=6)} "
            f"± {np.array2string(sd, precision=6)}"
        )
    if result.observability is not None:
        lines.append("observed   share of each state's prior variance the data removed:")
        lines += [f"           {line}" for line in result.observability.describe()]
    if recording.truth is not None:
        named = [("accuracy", sol)] + ([("smoothed", result.smoothed)] if result.smoothed else [])
        for label, solution in named:
            m = compute_metrics(solution, recording.truth)
            lines.append(
                f"{label:10s} horizontal RMS {m['horizontal_rms']:.3f} m, 3-D RMS"
                f" {m['rms_3d']:.3f} m, max horizontal {m['horizontal_max']:.3f} m"
            )
    return "\n".join(lines)


class OutputError(ValueError):
    """An output path that cannot be used (an existing file where a directory is to be
    written, a directory that cannot be created); the message names the path."""


def check_out_dir(path: str | Path) -> None:
    """Refuse, before any work, an output directory that cannot be made: ``path`` is an
    existing non-directory, or its nearest existing ancestor is not a writable directory.

    Raises
    ------
    OutputError
        Naming the path and the reason.
    """
    out = Path(path)
    if out.is_dir():
        return
    if out.exists():
        raise OutputError(f"{out}: exists and is not a directory; give a directory to write to")
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{out}: cannot be created, {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{out}: cannot be created, {parent} is not writable")
