"""Truth figure of a simulated (or any) recording with ``truth.csv``.

Four panels: the plan view with the cutting passes coloured by cycle (cycle 0 — static periods
and the end manoeuvres — in grey), the signed speed along body y (m/min: negative when the
shearer drives backwards), roll and pitch, and yaw, all against time.

For a longwall (``face.ends_enu_m`` in meta.yaml) the plan view is drawn in face coordinates:
distance along the first cutting line and offset to its right (the AFC advance direction), with
unequal axis scales so that the advance per cycle is visible; otherwise East/North at equal
scale. UWB anchors, when present, are marked.
"""

from __future__ import annotations

import gzip
import io
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from fusion.attitude import dcm_from_euler
from fusion.recording import Problem, RecordingError
from fusion.yaml_limits import YamlError, load_yaml


def _read_truth(root: Path) -> NDArray[np.float64]:
    plain, packed = root / "truth.csv", root / "truth.csv.gz"
    if plain.exists():
        text = plain.read_bytes()
    elif packed.exists():
        text = gzip.decompress(packed.read_bytes())
    elif not root.is_dir():
        found = "is not a directory" if root.exists() else "does not exist"
        raise RecordingError([Problem("", "", f"recording directory {str(root)!r} {found}")], root)
    else:
        problem = Problem("truth.csv", "", "required file is missing (the figure is of the truth)")
        raise RecordingError([problem], root)
    try:
        data = np.loadtxt(io.BytesIO(text), delimiter=",", skiprows=1, usecols=range(11), ndmin=2)
    except ValueError as exc:  # the reader's rules are not applied here: say what failed
        problem = Problem("truth.csv", "", f"cannot be read as 11 numeric columns ({exc})")
        raise RecordingError([problem], root) from None
    return np.asarray(data, dtype=float)


def plot_truth(
    recording_dir: str | Path, out_png: str | Path, *, max_points: int = 200_000
) -> Path:
    """Draw the truth figure of a recording directory into ``out_png``.

    Parameters
    ----------
    recording_dir
        Recording directory with ``truth.csv`` (or ``.csv.gz``) and ``meta.yaml``.
    out_png
        Output image path.
    max_points
        Decimate the truth to at most this many points.

    Returns
    -------
    Path
        ``out_png``.
    """
    root = Path(recording_dir)
    meta: dict[str, Any] = {}
    if (root / "meta.yaml").is_file():
        try:
            meta = load_yaml((root / "meta.yaml").read_bytes()).data or {}
        except YamlError as exc:
            line = f"line {exc.line}" if exc.line is not None else ""
            raise RecordingError([Problem("meta.yaml", line, exc.rule)], root) from None
    d = _read_truth(root)
    step = max(1, int(np.ceil(d.shape[0] / max_points)))
    d = d[::step]
    t, pos, vel, att, cyc = d[:, 0], d[:, 1:4], d[:, 4:7], d[:, 7:10], d[:, 10].astype(int)
    c_b_n = dcm_from_euler(att[:, 0], att[:, 1], att[:, 2])
    v_fwd = np.einsum("nij,ni->nj", c_b_n, vel)[:, 1] * 60.0

    fig, axes = plt.subplots(4, 1, figsize=(11, 13), gridspec_kw={"height_ratios": [3, 1, 1, 1]})
    ax = axes[0]
    face = meta.get("face") or {}
    ends = face.get("ends_enu_m")
    anchors = (meta.get("uwb") or {}).get("anchors") or {}
    if ends is not None:
        p0, p1 = np.asarray(ends[0], float), np.asarray(ends[1], float)
        u = (p1 - p0)[:2] / np.linalg.norm((p1 - p0)[:2])
        r = np.array([u[1], -u[0]])  # right of the face direction = advance direction

        def proj(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            q = np.atleast_2d(p)[:, :2] - p0[:2]
            return q @ u, q @ r

        x, y = proj(pos)
        ax.set_xlabel("along the first cutting line (m)")
        ax.set_ylabel("advance direction (m)")
    else:

        def proj(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            q = np.atleast_2d(p)
            return q[:, 0], q[:, 1]

        x, y = proj(pos)
        ax.set_xlabel("East (m)")
        ax.set_ylabel("North (m)")
        ax.set_aspect("equal", adjustable="datalim")
    ax.plot(x, y, color="0.75", lw=1.0, label="cycle 0 (static, end manoeuvres)")
    cmap = plt.get_cmap("viridis")
    cycles = sorted(int(c) for c in np.unique(cyc) if c > 0)
    for i, c in enumerate(cycles):
        sel = np.where(cyc == c, 1.0, np.nan)
        col = cmap(i / max(len(cycles) - 1, 1))
        ax.plot(x * sel, y * sel, color=col, lw=1.6, label=f"cycle {c}")
    ax.plot(x[:1], y[:1], "k*", ms=12, label="start")
    ax.plot(x[-1:], y[-1:], "ko", mfc="none", ms=9, label="end")
    if anchors:
        a = np.array(list(anchors.values()), dtype=float)
        ax_, ay_ = proj(a)
        ax.plot(ax_, ay_, "r^", ms=8, label="UWB anchors")
        for name, px, py in zip(anchors, ax_, ay_, strict=True):
            ax.annotate(str(name), (px, py), textcoords="offset points", xytext=(3, 3), fontsize=7)
    ax.legend(fontsize=7, ncol=4, loc="best")
    ax.grid(True, alpha=0.3)
    name = meta.get("name", root.name)
    ax.set_title(f"{name}: truth plan view")

    axes[1].plot(t, v_fwd, lw=0.8)
    axes[1].set_ylabel("speed along y\n(m/min)")
    axes[2].plot(t, np.rad2deg(att[:, 0]), lw=0.8, label="roll")
    axes[2].plot(t, np.rad2deg(att[:, 1]), lw=0.8, label="pitch")
    axes[2].set_ylabel("angle (deg)")
    axes[2].legend(fontsize=7)
    yaw = np.rad2deg(np.unwrap(att[:, 2]))
    axes[3].plot(t, yaw, lw=0.8, color="C2")
    axes[3].set_ylabel("yaw (deg)")
    axes[3].set_xlabel("time (s)")
    for a_ in axes[1:]:
        a_.grid(True, alpha=0.3)
        a_.set_xlim(t[0], t[-1])
    fig.tight_layout()
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
