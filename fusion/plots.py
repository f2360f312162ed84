"""Figures of a run: plan view of the estimate against truth, and errors with their ±3σ envelope."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from fusion.observability import Observability
from fusion.recording import TruthData
from fusion.solution import Solution

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


def plot_errors(solution: Solution, truth: TruthData, path: Path, title: str) -> Path:
    """Position error per axis against time with the filter's ±3σ envelope."""
    inside = (solution.t >= truth.t[0]) & (solution.t <= truth.t[-1])
    t = solution.t[inside]
    fig = Figure(figsize=(10, 7))
    axes = fig.subplots(3, 1, sharex=True)
    for k, (ax, name) in enumerate(zip(axes, ("east", "north", "up"), strict=True)):
        ref = np.interp(t, truth.t, truth.position[:, k])
        err = solution.position[inside, k] - ref
        sig = solution.sigma_position[inside, k]
        ax.fill_between(t, -3 * sig, 3 * sig, color="C1", alpha=0.25, label="±3σ")
        ax.plot(t, err, "C0-", lw=0.8, label="error")
        ax.set_ylabel(f"{name} (m)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper left")
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
