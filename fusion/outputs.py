"""What ``fusion run`` writes: solution.csv, metrics.json (with truth), figures, run.json, and a
summary."""

from __future__ import annotations

import hashlib
import json
import sys
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from fusion import __version__
from fusion.engine import BOUND, RunResult
from fusion.error_model import STATE_UNITS
from fusion.fault_detection import ISOLATE, READMIT, FaultEvent
from fusion.jumps import JUMP
from fusion.lock import LOST_LOCK, REACQUIRE
from fusion.metrics import compute_metrics, write_metrics_json
from fusion.output_dir import FIGURE_FORMATS, RECORDING_FILES, RUN_JSON
from fusion.plugin import WIDEN
from fusion.recording import Recording
from fusion.solution import write_solution
from fusion.state_history import write_states


@dataclass(frozen=True)
class Invocation:
    """The command that asked for a result and when it started (``run.json``)."""

    command: list[str]
    started_utc: datetime
    started_clock: float
    """``time.perf_counter()`` at the start, for the wall time."""

    @classmethod
    def now(cls, command: Sequence[str]) -> Invocation:
        """An invocation starting now."""
        return cls(list(command), datetime.now(UTC), time.perf_counter())


def write_outputs(
    result: RunResult,
    recording: Recording,
    out_dir: str | Path,
    *,
    plots: bool = True,
    figure_format: str = "png",
    invocation: Invocation | None = None,
    recorded_as: Path | None = None,
) -> dict[str, Path]:
    """Write the run's files into ``out_dir``, ``run.json`` last, and return them by kind.

    Files are written in place: ``fusion run`` gives a staging directory here
    (:class:`fusion.output_dir.OutputTarget`). ``figure_format`` is ``png``, ``svg`` or ``pdf``.
    ``invocation`` defaults to this Python process's command line, started when the engine
    did. ``recorded_as`` is the recording's path for run.json when it is not ``recording.path``
    (a recording staged beside this result and moved with it).
    """
    if figure_format not in FIGURE_FORMATS:
        raise ValueError(f"figure format {figure_format!r}: not one of {', '.join(FIGURE_FORMATS)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"solution": out / "solution.csv"}
    write_solution(result.solution, files["solution"])
    if result.states is not None:
        files["states"] = out / "states.csv"
        write_states(result.states, files["states"])
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
        metrics["imu_noise_at_rest"] = result.rest_noise.to_dict()
        metrics["imu_bias_at_rest"] = result.rest_bias.to_dict()
        metrics["left_out"] = {"plugins": list(result.left_out)}
        if result.smoothed is not None:
            metrics["smoother"] = {
                "windows": result.smoother_windows,
                "windows_kept_forward": result.smoother_unresolved_windows,
                "kept_forward": result.smoother_kept_forward,
                "epochs_rejected": result.smoother_rejected,
            }
        if result.observability is not None:
            metrics["observability"] = result.observability.to_dict()
        write_metrics_json(metrics, files["metrics"])
    if plots:
        from fusion import plots as figures

        title = f"{result.config.name} on {result.recording_name}"
        ext = figure_format
        files["plan"] = figures.plot_plan_view(result.solution, truth, out / f"plan.{ext}", title)
        if truth is not None:
            files["errors"] = figures.plot_errors(
                result.solution, truth, out / f"errors.{ext}", title, smoothed=result.smoothed
            )
        if result.observability is not None and result.observability.t.size > 1:
            files["observability"] = figures.plot_observability(
                result.observability, out / f"observability.{ext}", title
            )
    files["run"] = write_run_json(
        out / RUN_JSON,
        result,
        recording.path,
        files.values(),
        invocation
        or Invocation(
            list(sys.argv),
            datetime.now(UTC) - timedelta(seconds=result.wall_time_s),
            time.perf_counter() - result.wall_time_s,
        ),
        recorded_as,
    )
    return files


def write_run_json(
    path: Path,
    result: RunResult,
    recording: Path | None,
    written: Iterable[Path],
    invocation: Invocation,
    recorded_as: Path | None = None,
) -> Path:
    """``run.json``: how a result was made and what it holds.

    Keys: ``fusion_version``; ``command`` (argument list); ``started_utc`` (ISO 8601);
    ``wall_time_s`` (from the start to this file) and ``engine_wall_time_s``; ``recording``:
    ``path`` (absolute: ``recorded_as`` when given, else ``recording``, the directory read; None
    for a recording built in memory), ``name``, ``files`` {name: sha256} of its recording files
    and ``sha256``, the digest of that listing as ``sha256sum`` prints it, sorted by name;
    ``files`` {name: {bytes, sha256}} of every other file of the result (``written``: paths in
    ``path``'s directory); ``config``, the configuration as used (every default filled in).
    """
    digests = {}
    if recording is not None:
        names = sorted(p.name for p in Path(recording).iterdir() if p.name in RECORDING_FILES)
        digests = {name: _sha256(Path(recording) / name) for name in names}
    listing = "".join(f"{digest}  {name}\n" for name, digest in digests.items())
    record = {
        "fusion_version": __version__,
        "command": invocation.command,
        "started_utc": invocation.started_utc.isoformat(timespec="milliseconds"),
        "wall_time_s": round(time.perf_counter() - invocation.started_clock, 3),
        "engine_wall_time_s": round(result.wall_time_s, 3),
        "recording": {
            "path": None if recording is None else str(Path(recorded_as or recording).resolve()),
            "name": result.recording_name,
            "files": digests,
            "sha256": hashlib.sha256(listing.encode()).hexdigest() if digests else None,
        },
        "files": {
            p.name: {"bytes": p.stat().st_size, "sha256": _sha256(p)}
            for p in sorted(written, key=lambda p: p.name)
        },
        "config": result.config.model_dump(mode="json"),
    }
    path.write_text(json.dumps(record, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return path


def _sha256(path: Path) -> str:
    with path.open("rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


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
    lines += [f"left out   {reason}" for reason in result.left_out]
    if result.rest_noise.taken:
        lines.append(f"IMU noise  {result.rest_noise.describe()}")
    if result.rest_bias.taken:
        lines.append(f"IMU bias   {result.rest_bias.describe()}")
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
        lines.append(f"faults     {_fault_counts(actions)} (faults.csv)")
    if result.smoothed is not None:
        kept = result.smoother_kept_forward
        parts = ", ".join(f"{name} in {result.smoother_windows - n}" for name, n in kept.items())
        lines.append(
            f"smoother   {result.smoother_windows} windows, smoothed: {parts} (elsewhere the"
            " expected gain was within its spread: forward kept)"
        )
    if result.smoother_rejected:
        lines.append(
            f"smoother   {result.smoother_rejected} output epochs kept their forward estimate"
            " (a smoothed correction their statistics did not allow)"
        )
    estimated = result.config.filter.architecture in ("centralized", "federated")
    for block in result.layout.blocks[3:] if estimated else ():
        est, sd = result.state_estimate(block.name)
        scale, unit = STATE_UNITS[block.unit], block.unit.replace("_", "/")
        lines.append(
            f"estimate   {block.name}: {np.array2string(est * scale, precision=4)} "
            f"± {np.array2string(sd * scale, precision=4)} {unit}".rstrip()
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


_ENGINE_ACTIONS = (
    (ISOLATE, "isolations"),
    (READMIT, "re-admissions"),
    (JUMP, "state jumps taken in"),
    (LOST_LOCK, "lost locks"),
    (REACQUIRE, "re-acquisitions"),
    (WIDEN, "widenings"),
    (BOUND, "estimates held at their bounds"),
)
"""The engine's ``faults.csv`` actions, each counted in the summary even when zero."""


def _fault_counts(actions: list[str]) -> str:
    """The summary's count of each ``faults.csv`` action: the engine's (:data:`_ENGINE_ACTIONS`),
    then any other that occurred (a ``disputed`` plugin, or one a plugin's own test wrote,
    :attr:`fusion.plugin.Measurement.fault`, e.g. ``exclude anchor``)."""
    counts = Counter(actions)
    engine = ", ".join(f"{counts.pop(action, 0)} {label}" for action, label in _ENGINE_ACTIONS)
    return engine + "".join(f", {n} × {action}" for action, n in sorted(counts.items()))
