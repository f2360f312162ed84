"""Figures of a run: plan view of the estimate against truth, and errors with their ±3σ envelope.

Each figure is written in the format its path's suffix names (``fusion run --format``: png, svg,
pdf)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from fusion.metrics import interpolate_solution
from fusion.observability import Observability
from fusion.recording import TruthData
from fusion.solution import Solution

MAX_POINTS = 10_000
"""Most epochs drawn per track in a figure against time."""

ATTITUDE_UP = "attitude.u"
"""The heading's error state: the attitude error about the local up axis."""


def plot_plan_view(solution: Solution, truth: TruthData | None, path: Path, title: str) -> Path:
    """East-north plan view of the estimated trajectory (and truth when known)."""
    fig = Figure(figsize=(9, 5))
    ax = fig.subplots()
    if truth is not None:
        ax.plot(truth.position[:, 0], truth.position[:, 1], "k-", lw=1.0, label="truth")
    ax.plot(solution.position[:, 0], solution.position[:, 1], "C0-", lw=0.8, label="estimate")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(title)
    ax.axis("equal")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def plot_errors(
    solution: Solution,
    truth: TruthData,
    path: Path,
    title: str,
    *,
    smoothed: Solution | None = None,
) -> Path:
    """Position error per axis against time with the filter's ±3σ envelope, at the truth epochs
    as ``metrics.json`` scores them (every k-th of them beyond :data:`MAX_POINTS`, which keeps an
    SVG or PDF of hours at 100 Hz small); the smoothed track's too when there is one."""
    tracks = [("forward", solution, "C0", "C1")]
    if smoothed is not None:
        tracks.append(("smoothed", smoothed, "C2", "C2"))
    stride = -(-truth.t.size // MAX_POINTS)
    fig = Figure(figsize=(10, 7))
    axes = fig.subplots(3, 1, sharex=True)
    for label, track, line, band in tracks:
        at = interpolate_solution(track, truth.t[::stride])
        err = at.position - truth.position[::stride][at.inside]
        for k, ax in enumerate(axes):
            sig = at.sigma_position[:, k]
            ax.fill_between(at.t, -3 * sig, 3 * sig, color=band, alpha=0.2, label=f"{label} ±3σ")
            ax.plot(at.t, err[:, k], color=line, lw=0.8, label=f"{label} error")
    for ax, name in zip(axes, ("east", "north", "up"), strict=True):
        ax.set_ylabel(f"{name} (m)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper left", fontsize="small", ncol=len(tracks))
    axes[0].set_title(title)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def plot_observability(report: Observability, path: Path, title: str) -> Path:
    """Share of the prior variance removed over time: the heading, then each bias block."""
    panels = [("heading", [ATTITUDE_UP])] + [
        (block, [lab for lab in report.labels if lab.startswith(f"{block}.")])
        for block in dict.fromkeys(lab.rpartition(".")[0] for lab in report.labels)
        if block.endswith("bias")
    ]
    fig = Figure(figsize=(10, 2.2 * len(panels) + 0.6))
    axes = np.atleast_1d(fig.subplots(len(panels), 1, sharex=True))
    for ax, (name, labels) in zip(axes, panels, strict=True):
        for label in labels:
            k = report.labels.index(label)
            ax.plot(report.t, 100.0 * report.removed_history[:, k], lw=0.9, label=label)
        ax.set_ylabel(f"{name}\nremoved (%)")
        ax.set_ylim(-3, 103)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize="small")
    axes[0].set_title(f"{title}: share of the prior variance the data removed")
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path
