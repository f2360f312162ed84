"""Benchmark figures (matplotlib ``Figure`` objects, no GUI backend).

* :func:`plot_cycles` — plan view of estimate(s) and truth, one panel per cutting cycle; on a
  face in face coordinates (along, across — the across axis exaggerated), otherwise east/north;
* :func:`plot_error_envelope` — error per axis against time with ±3σ (``fusion.plots``);
* :func:`plot_fault_timeline` — injected fault windows against each method's isolations
  (federated) and χ²-gate rejections (centralized), with the horizontal error below;
* :func:`plot_headline` — bar chart of a table's headline column (mean ± std, or the column's
  own aggregate), the seed paper's figure as a star.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from benchmarks.runner import Trace
from benchmarks.tables import Table
from fusion.plots import plot_errors
from fusion.recording import TruthData
from fusion.solution import Solution

FAULT_COLOR = "#d62728"


def _plan(trace: Trace, xyz: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    if trace.face_along is None:
        return xyz[:, 0], xyz[:, 1]
    a = trace.face_along
    return xyz[:, :2] @ a, xyz[:, :2] @ np.array([a[1], -a[0]])


def plot_cycles(traces: Sequence[Trace], path: Path, title: str) -> Path:
    """Estimates of one method (forward, smoothed) against truth, one panel per cycle."""
    ref = traces[0]
    cycles = [int(c) for c in np.unique(ref.cycle) if c >= 1] or [int(ref.cycle.max())]
    fig = Figure(figsize=(10, 2.2 + 2.0 * len(cycles)))
    axes = fig.subplots(len(cycles), 1, squeeze=False)[:, 0]
    face = ref.face_along is not None
    for ax, c in zip(axes, cycles, strict=True):
        sel = ref.cycle == c
        ax.plot(*_plan(ref, ref.truth[sel]), "k-", lw=1.2, label="truth")
        for k, tr in enumerate(traces):
            s = tr.cycle == c
            ax.plot(*_plan(tr, tr.position[s]), f"C{k}-", lw=0.8, label=tr.solution)
        ax.set_ylabel(f"cycle {c}\n" + ("across (m)" if face else "north (m)"))
        ax.grid(True, alpha=0.3)
        if not face:
            ax.set_aspect("equal", adjustable="datalim")
    axes[0].legend(loc="best", fontsize=8)
    axes[0].set_title(title)
    axes[-1].set_xlabel("along the face (m)" if face else "east (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return path


def plot_error_envelope(trace: Trace, path: Path, title: str) -> Path:
    """Position error per axis with the ±3σ envelope (the ``fusion run`` figure)."""
    zeros = np.zeros_like(trace.position)
    solution = Solution(trace.t, trace.position, zeros, zeros, trace.sigma)
    truth = TruthData(trace.t, trace.truth, zeros, zeros, trace.cycle)
    return plot_errors(solution, truth, path, title)


def _isolated_spans(trace: Trace, t_end: float) -> dict[str, list[tuple[float, float]]]:
    spans: dict[str, list[tuple[float, float]]] = {}
    open_at: dict[str, float] = {}
    for t, local, action in trace.events:
        if action == "isolate":
            open_at[local] = t
        elif local in open_at:
            spans.setdefault(local, []).append((open_at.pop(local), t))
    for local, t in open_at.items():
        spans.setdefault(local, []).append((t, t_end))
    return spans


def plot_fault_timeline(traces: Sequence[Trace], path: Path, title: str) -> Path:
    """Injected faults against what each method detected, horizontal error below."""
    fig = Figure(figsize=(11, 3.0 + 0.45 * len(traces)))
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[1.0 + 0.3 * len(traces), 2.0])
    t_end = max(float(tr.t[-1]) for tr in traces)
    for f in traces[0].injected:
        for ax in (top, bottom):
            ax.axvspan(f["t_start"], f["t_end"], color=FAULT_COLOR, alpha=0.12)
    labels = []
    for i, tr in enumerate(traces):
        for local, spans in _isolated_spans(tr, t_end).items():
            for a, b in spans:
                top.plot([a, b], [i, i], "-", color="C1", lw=6, solid_capstyle="butt")
                top.text(a, i + 0.25, local, fontsize=7, color="C1")
        rejected = np.concatenate(list(tr.rejections.values()) or [np.empty(0)])
        top.plot(rejected, np.full(rejected.size, i), "|", color="C0", ms=9)
        err = np.hypot(*(tr.position[:, :2] - tr.truth[:, :2]).T)
        bottom.plot(tr.t, err, lw=0.9, label=tr.method)
        labels.append(tr.method)
    top.set_yticks(range(len(traces)), labels, fontsize=8)
    top.set_ylim(-0.7, len(traces) - 0.3)
    kinds = ", ".join(sorted({f["type"] for f in traces[0].injected})) or "none"
    top.set_title(
        f"{title}\ninjected ({kinds}): red band; isolated local: orange bar; gate rejection: blue |"
    )
    bottom.set_ylabel("horizontal error (m)")
    bottom.set_xlabel("time (s)")
    bottom.grid(True, alpha=0.3)
    bottom.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return path


def plot_headline(table: Table, path: Path) -> Path | None:
    """Bar chart of the table's headline column in ``path`` (None when it has none or no
    data)."""
    fig = headline_figure(table)
    if fig is None:
        return None
    fig.savefig(path, dpi=100)
    return path


def headline_figure(table: Table) -> Figure | None:
    """The figure of :func:`plot_headline`: one bar per row, with ± std error bars and a
    "mean ± std" legend for a mean column, bare bars named by the aggregate otherwise (a
    median has no spread to show)."""
    spec = table.spec
    if spec.headline is None:
        return None
    columns = [c for c in spec.columns if c.field == spec.headline]
    if not columns:
        return None
    col = spec.columns.index(columns[0])
    cells = [line[col] for line in table.cells]
    if not any(c.n for c in cells):
        return None
    labels = [r.label for r in spec.rows]
    means = [c.mean if c.n else math.nan for c in cells]
    agg = columns[0].agg  # another aggregate than the mean has no spread (build_table)
    errors = [c.std if c.n > 1 else 0.0 for c in cells] if agg == "mean" else None
    label = "ours, mean ± std" if agg == "mean" else f"ours, {agg} over the runs"
    fig = Figure(figsize=(max(6.0, 0.55 * len(labels) + 2.0), 4.8))
    ax = fig.subplots()
    x = np.arange(len(labels))
    ax.bar(x, means, yerr=errors, color="C0", alpha=0.8, capsize=3, label=label)
    paper = [(i, c.paper) for i, c in enumerate(cells) if c.paper is not None]
    if paper:
        ax.plot([i for i, _ in paper], [v for _, v in paper], "k*", ms=11, label="seed paper")
    values = [v for v in [*means, *(v for _, v in paper)] if math.isfinite(v) and v > 0]
    if values and max(values) > 100.0 * min(values):
        ax.set_yscale("log")  # e.g. free SINS next to aided filters
    ax.set_xticks(x, labels, rotation=35, ha="right", fontsize=8)
    ax.set_ylabel(columns[0].header)
    ax.set_title(spec.title, fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
