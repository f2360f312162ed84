"""Real-data validation (issue #8): ``python -m benchmarks real``.

Imports the real datasets (``$FUSION_DATASETS`` or ``../shared/datasets``) into a temporary
directory with :mod:`fusion.importers`, runs the configurations ``configs/real_*.yaml`` and
writes Markdown tables into ``benchmarks/RESULTS.md`` (between the ``real`` markers, one
sub-block per part, so other suites share the file and ``python -m benchmarks real drive``
updates only its part) and PNG figures into ``benchmarks/figures/``. Nothing is tuned per
trial or per file; every setting is in the three configuration files.

rtklib-drive (car, 100 Hz MEMS IMU, 4 Hz RTK)
    GNSS outages are simulated by withholding the RTK fixes inside windows of 10, 30 and 60 s
    (several per run: the first at 60 s, then one after every 30 s of fixes, all ending before
    the GNSS does); the recording is copied in memory with those fixes removed, the engine is
    unchanged. The drift of an outage is the horizontal distance between the antenna point of
    the solution (``p + C_b^n l``, linearly interpolated at the last withheld fix) and the RTK
    position there. Four variants (the 2 × 2 of motion constraint and ZUPT), the
    IMU-to-vehicle misalignment estimated by the motion constraint over the whole drive, and
    the dependence on the IMU sampling-lag handling (the importer's ``imu_lag_s``).

PyShoe (foot IMU, Vicon)
    The ZUPT plugin's detector (:func:`fusion.aiding.zupt.detect_stationary`) with the plugin's
    datasheet-derived thresholds and with the foot setting of ``configs/real_pyshoe.yaml``,
    scored per sample against the trial's optimal zero-velocity labels (those of its best
    detector): precision, recall, F1. The SINS + ZUPT trajectory is scored as PyShoe scores
    (``ins_tools/util.py``): both tracks translated to their start, the estimate rotated about
    the vertical so that its first point 0.8 m from the start lies on the Vicon bearing, then
    the mean over epochs of the per-epoch RMS over the two horizontal axes, ``√((δx² + δy²)/2)``
    (``compute_error``: the 2-D norm over √2) — the definition of ``best_error`` — and, for
    reference, the 2-D RMSE after a least-squares yaw-and-translation fit.

BROAD (hand-held board, magnetometer, optical reference)
    Heading error as BROAD defines it (``broad_utils.py``): ``q_err = q_est ⊗ q_ref⁻¹`` in the
    global frame, error ``2·atan(|q_err,z / q_err,w|)``, RMSE over the movement phase. The
    solution (10 Hz) is compared with the reference interpolated (slerp) between two
    *consecutive* optical samples only: solution epochs inside a gap of the optical reference
    are left out, never bridged. Three filters per trial: SINS + optical fixes (no
    magnetometer), the centralized CKF with the magnetometer, the federated AFKF with fault
    isolation (``filter.architecture: federated``).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from fusion.attitude import dcm_from_euler
from fusion.config import FusionConfig, load_config, parse_config
from fusion.engine import Engine, RunResult
from fusion.fault_detection import ISOLATE, READMIT
from fusion.importers import (
    datasets_root,
    import_broad,
    import_pyshoe,
    import_rtklib_drive,
    read_pyshoe_labels,
)
from fusion.importers.common import true_runs
from fusion.importers.rtklib_drive import DEFAULT_IMU_LAG_S
from fusion.recording import PositionData, Recording, TruthData, read_recording
from fusion.solution import Solution

FloatArray = NDArray[np.float64]

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
RESULTS = HERE / "RESULTS.md"
FIGURES = HERE / "figures"
BEGIN, END = "<!-- real:begin -->", "<!-- real:end -->"

OUTAGE_DURATIONS_S = (10.0, 30.0, 60.0)
FIRST_OUTAGE_S = 60.0
"""Start of the first outage (the car drives off at 39 s)."""
RECOVERY_S = 30.0
"""Fixes between two outages of a run."""
MEASURED_LAG_S = 0.110
"""The lag the importer's test measures by symmetric cross-correlation (tests/test_importers.py)."""
PYSHOE_ALIGN_M = 0.8


# --------------------------------------------------------------------------------------------
# Shared helpers
# --------------------------------------------------------------------------------------------


def config_variant(
    name: str,
    *,
    enable: Sequence[str] = (),
    disable: Sequence[str] = (),
    architecture: str | None = None,
) -> FusionConfig:
    """``configs/NAME.yaml`` with plugin blocks (by instance name) switched on or off."""
    data = load_config(REPO / "configs" / f"{name}.yaml").model_dump(mode="json")
    known = {b.get("name") or b["type"] for b in data["plugins"]}
    for block in data["plugins"]:
        instance = block.get("name") or block["type"]
        if instance in enable:
            block["enabled"] = True
        if instance in disable:
            block["enabled"] = False
    unknown = sorted((set(enable) | set(disable)) - known)
    if unknown:
        raise ValueError(f"configs/{name}.yaml has no plugin block(s) {unknown}")
    if architecture is not None:
        data["filter"]["architecture"] = architecture
    return parse_config(data, f"configs/{name}.yaml (variant)")


def interpolate_rows(t: FloatArray, t_rows: FloatArray, values: FloatArray) -> FloatArray:
    """Linear interpolation of each column of ``values`` (rows at ``t_rows``) at ``t``."""
    return np.column_stack([np.interp(t, t_rows, values[:, k]) for k in range(values.shape[1])])


def fmt(x: float | None, digits: int = 2) -> str:
    """A number for a table (``–`` for None/NaN)."""
    if x is None or not math.isfinite(x):
        return "–"
    return f"{x:.{digits}f}"


def table(header: Sequence[str], rows: Sequence[Sequence[str]], align: str = "") -> str:
    """A Markdown table; ``align`` has one ``l``/``r`` per column (default: first l, rest r)."""
    align = align or "l" + "r" * (len(header) - 1)
    sep = ["---" if a == "l" else "---:" for a in align]
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(sep) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


@dataclass
class Section:
    """One part of the results: Markdown text and the figures it refers to."""

    title: str
    text: str = ""
    figures: list[Path] = field(default_factory=list)


def run_engine(config: FusionConfig, recording: Recording) -> RunResult:
    """Run the engine (errors propagate to the caller, which reports them)."""
    return Engine(config, recording).run()


# --------------------------------------------------------------------------------------------
# rtklib-drive
# --------------------------------------------------------------------------------------------


def outage_windows(duration: float, t_first: float, t_last: float) -> list[tuple[float, float]]:
    """Windows ``(start, start + duration]`` every ``duration + RECOVERY_S`` from ``t_first``."""
    out = []
    start = t_first
    while start + duration <= t_last:
        out.append((start, start + duration))
        start += duration + RECOVERY_S
    return out


def withhold_fixes(recording: Recording, windows: Sequence[tuple[float, float]]) -> Recording:
    """A copy of the recording without the position fixes inside the windows."""
    pos = recording.position
    assert pos is not None
    keep = np.ones(pos.t.size, dtype=bool)
    for a, b in windows:
        keep &= ~((pos.t > a) & (pos.t <= b))
    return replace(
        recording, position=PositionData(t=pos.t[keep], enu=pos.enu[keep], sigma=pos.sigma[keep])
    )


def antenna_position(solution: Solution, lever_arm_b: FloatArray, t: FloatArray) -> FloatArray:
    """Solution point ``p + C_b^n l`` linearly interpolated at ``t``."""
    c = dcm_from_euler(*solution.attitude.T)
    points = solution.position + c @ lever_arm_b
    return interpolate_rows(t, solution.t, points)


def outage_drifts(
    result: RunResult, recording: Recording, windows: Sequence[tuple[float, float]]
) -> list[float]:
    """Horizontal error at the last withheld fix of each window (m)."""
    truth, pos = recording.truth, recording.position
    assert truth is not None and pos is not None and recording.meta.position is not None
    arm = np.array(recording.meta.position.lever_arm_b_m)
    ends = []
    for a, b in windows:
        inside = truth.t[(truth.t > a) & (truth.t <= b)]
        ends.append(inside[-1])
    t_end = np.array(ends)
    est = antenna_position(result.solution, arm, t_end)
    ref = interpolate_rows(t_end, truth.t, truth.position)
    return np.hypot(*(est[:, :2] - ref[:, :2]).T).tolist()


@dataclass
class DriveVariant:
    """A 2 × 2 cell: which of the motion constraint / ZUPT blocks are on."""

    label: str
    enable: tuple[str, ...]
    color: str


DRIVE_VARIANTS = (
    DriveVariant("SINS + fixes", (), "tab:red"),
    DriveVariant("+ motion constraint", ("motion_constraint",), "tab:blue"),
    DriveVariant("+ ZUPT", ("zupt",), "tab:orange"),
    DriveVariant("+ motion constraint + ZUPT", ("motion_constraint", "zupt"), "tab:green"),
)


def drive_section(work: Path) -> Section:
    """GNSS-outage drift of the car drive (issue #8 item 2)."""
    sec = Section("rtklib-drive: GNSS outages (car, ICM-45686 at 100 Hz, u-blox X20 RTK at 4 Hz)")
    src = datasets_root() / "rtklib-drive"
    if not src.exists():
        sec.text = f"Skipped: dataset folder {src} not found."
        return sec
    recordings: dict[float, Recording] = {}
    for lag in (DEFAULT_IMU_LAG_S, MEASURED_LAG_S, 0.0):
        out = work / f"drive_lag_{lag:.3f}"
        import_rtklib_drive(src, out, imu_lag_s=lag)
        recordings[lag] = read_recording(out)
    rec = recordings[DEFAULT_IMU_LAG_S]
    assert rec.truth is not None and rec.position is not None
    t_last = float(rec.position.t[-1]) - 1.0
    notes: list[str] = []

    drifts: dict[tuple[str, float], list[float]] = {}
    whitened: dict[tuple[str, float], float] = {}
    solutions: dict[tuple[str, float], Solution] = {}
    windows_of = {d: outage_windows(d, FIRST_OUTAGE_S, t_last) for d in OUTAGE_DURATIONS_S}
    zupt_run: RunResult | None = None
    for variant in DRIVE_VARIANTS:
        config = config_variant("real_drive", enable=variant.enable)
        for d, windows in windows_of.items():
            result = run_engine(config, withhold_fixes(rec, windows))
            drifts[variant.label, d] = outage_drifts(result, rec, windows)
            whitened[variant.label, d] = result.innovations["position"].whitened_rms()
            solutions[variant.label, d] = result.solution
            if variant.enable == ("zupt",) and d == 30.0:
                zupt_run = result

    header = ["outage", "windows"] + [v.label for v in DRIVE_VARIANTS]
    rows = []
    for d, windows in windows_of.items():
        row = [f"{d:.0f} s", str(len(windows))]
        for v in DRIVE_VARIANTS:
            got = drifts.get((v.label, d))
            row.append(f"{np.mean(got):.2f} / {np.max(got):.2f}" if got is not None else "n/a")
        rows.append(row)
    drift_table = table(header, rows)

    # Misalignment and consistency over the whole drive (no outage), motion constraint on.
    full = run_engine(config_variant("real_drive", enable=("motion_constraint",)), rec)
    mount, mount_sigma = full.state_estimate("motion_constraint.mounting_angles")
    mount_deg, mount_sigma_deg = np.degrees(mount), np.degrees(mount_sigma)
    author = rec.meta.extra["author_imu_misalignment_deg"]
    misalignment = table(
        ["IMU board relative to the car", "estimated (± 1σ)", "author's estimate (FRD rpy)"],
        [
            [
                "pitch (board nose-down < 0)",
                f"{-mount_deg[0]:.2f} ± {mount_sigma_deg[0]:.2f}°",
                f"{author['pitch']:.2f}°",
            ],
            [
                "yaw (board clockwise of the car > 0)",
                f"{mount_deg[2]:.2f} ± {mount_sigma_deg[2]:.2f}°",
                f"{author['yaw']:.2f}°",
            ],
            [
                "roll (not observable by the constraint)",
                f"{-mount_deg[1]:.2f} ± {mount_sigma_deg[1]:.2f}° (prior 10°)",
                f"{author['roll']:.2f}°",
            ],
        ],
        "lrr",
    )
    consistency = (
        f"Whole drive with fixes and the motion constraint: whitened innovation RMS "
        f"{full.innovations['position'].whitened_rms():.2f} (position fixes), "
        f"{full.innovations['motion_constraint'].whitened_rms():.2f} (motion constraint); "
        f"{full.realtime_factor:.0f}× real time."
    )

    # Sampling-lag handling: mean 30 s drift for each lag, with and without the constraint.
    lag_rows = []
    for lag, lag_rec in recordings.items():
        row = [f"{lag:.3f} s" + _lag_note(lag)]
        for variant in DRIVE_VARIANTS[:2]:
            config = config_variant("real_drive", enable=variant.enable)
            windows = windows_of[30.0]
            result = run_engine(config, withhold_fixes(lag_rec, windows))
            row.append(f"{np.mean(outage_drifts(result, lag_rec, windows)):.2f}")
            row.append(f"{result.innovations['position'].whitened_rms():.2f}")
        lag_rows.append(row)
    lag_table = table(
        [
            "IMU lag subtracted",
            "30 s drift, fixes (m)",
            "whitened RMS",
            "30 s drift, + constraint (m)",
            "whitened RMS",
        ],
        lag_rows,
    )

    zupt_stats = None
    if zupt_run is not None:
        zupt_stats = _drive_zupt_detector(rec, zupt_run, windows_of[30.0])
    figure = FIGURES / "real_drive_outages.png"
    _plot_drive(rec, solutions, windows_of[30.0], drifts, figure)
    sec.figures.append(figure)

    ok30 = ("+ motion constraint", 30.0) in drifts and np.mean(
        drifts["+ motion constraint", 30.0]
    ) < np.mean(drifts["SINS + fixes", 30.0])
    parts = [
        "Horizontal drift at the end of each outage, **mean / max over the windows (m)**; "
        f"outages every {RECOVERY_S:.0f} s of fixes from t = {FIRST_OUTAGE_S:.0f} s "
        f"(RTK standstills > 2 s: {_standstills(rec)}). Configuration "
        "`configs/real_drive.yaml`; IMU lag 0.120 s (importer default).",
        "",
        drift_table,
        "",
        "Acceptance (motion constraint reduces the mean 30 s drift): "
        + ("**met**" if ok30 else "**not met**")
        + f" — {np.mean(drifts['SINS + fixes', 30.0]):.2f} m without, "
        + (
            f"{np.mean(drifts['+ motion constraint', 30.0]):.2f} m with."
            if ("+ motion constraint", 30.0) in drifts
            else "n/a."
        ),
        "",
        "IMU-to-vehicle misalignment estimated by the motion constraint (its mounting-angle "
        "states, final value over the whole drive without outages) against the dataset "
        "author's estimate (`drive_config.py`, IMU relative to the forward-right-down body):",
        "",
        misalignment,
        "",
        consistency,
        "",
        "Dependence on the sampling-lag handling (30 s outages; the lag is subtracted from "
        "each IMU line's arrival time by the importer):",
        "",
        lag_table,
        "",
    ]
    if zupt_stats is not None:
        parts += [zupt_stats, ""]
    parts += [*notes, f"![drive]({figure.relative_to(HERE)})"]
    sec.text = "\n".join(parts)
    return sec


def _standstills(rec: Recording) -> str:
    """The RTK standstills (< 0.1 m/s) longer than 2 s, as text."""
    truth = rec.truth
    assert truth is not None
    speed = np.hypot(truth.velocity[:, 0], truth.velocity[:, 1])
    spans = [(truth.t[a], truth.t[b - 1]) for a, b in true_runs(speed < 0.1)]
    return ", ".join(f"{a:.0f}–{b:.0f} s" for a, b in spans if b - a > 2.0)


def _lag_note(lag: float) -> str:
    if lag == DEFAULT_IMU_LAG_S:
        return " (importer default, README)"
    if lag == MEASURED_LAG_S:
        return " (measured by the importer test)"
    if lag == 0.0:
        return " (none: arrival time)"
    return ""


def _drive_zupt_detector(
    rec: Recording, result: RunResult, windows: Sequence[tuple[float, float]]
) -> str:
    """How the ZUPT detector labels the car's standstills, and which ZUPTs the gate let in."""
    from fusion.aiding.zupt import StationaryThresholds, detect_stationary

    config = config_variant("real_drive", enable=("zupt",))
    block = next(b for b in config.plugins if b.instance_name == "zupt")
    opts = block.options
    thresholds = StationaryThresholds(
        opts["accel_min_mps2"], opts["accel_max_mps2"], math.radians(opts["gyro_max_dps"])
    )
    labels = detect_stationary(
        rec.imu.t, rec.imu.gyro, rec.imu.accel, thresholds, opts["window_s"], opts["causal"]
    )
    truth = rec.truth
    assert truth is not None

    def speed_at(t: FloatArray) -> FloatArray:
        return np.interp(t, truth.t, np.hypot(truth.velocity[:, 0], truth.velocity[:, 1]))

    speed = speed_at(rec.imu.t)
    precision, recall, f1 = scores(labels, speed < 0.1)
    log = result.innovations["zupt"]
    t = np.array(log.t)
    accepted = np.array(log.accepted, dtype=bool)
    in_outage = np.zeros(t.size, dtype=bool)
    for a, b in windows:
        in_outage |= (t > a) & (t <= b)
    v = speed_at(t)
    parked, moving = in_outage & (v < 0.1), in_outage & (v > 0.5)
    fast = v[accepted & moving]
    return (
        f"ZUPT detector on the car (thresholds of `configs/real_drive.yaml`) against the RTK "
        f"standstills (< 0.1 m/s): precision {precision:.2f}, recall {recall:.2f}, F1 {f1:.2f}; "
        f"it labels samples at up to {speed[labels].max():.1f} m/s stationary (steady driving "
        "looks like a standstill to a norm detector at this vibration level). Inside the 30 s "
        f"outages the χ² gate accepted {int(np.sum(accepted & parked))} of "
        f"{int(np.sum(parked))} ZUPT epochs at a true standstill and "
        f"{int(np.sum(accepted & moving))} of {int(np.sum(moving))} while the car moved "
        + (f"(up to {fast.max():.1f} m/s)" if fast.size else "")
        + ": after some seconds without fixes the SINS velocity error is larger than its "
        "covariance admits, so the right ZUPTs fail the gate and a few wrong ones pass — "
        "which is why ZUPT does not help here."
    )


def _plot_drive(
    rec: Recording,
    solutions: dict[tuple[str, float], Solution],
    windows: Sequence[tuple[float, float]],
    drifts: dict[tuple[str, float], list[float]],
    path: Path,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    truth = rec.truth
    assert truth is not None
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 6))
    ax.plot(truth.position[:, 0], truth.position[:, 1], color="0.6", lw=2, label="RTK")
    for variant in DRIVE_VARIANTS[:2]:
        label, color = variant.label, variant.color
        sol = solutions.get((label, 30.0))
        if sol is None:
            continue
        for a, b in windows:
            sel = (sol.t > a) & (sol.t <= b)
            ax.plot(sol.position[sel, 0], sol.position[sel, 1], color=color, lw=1)
        ax.plot([], [], color=color, label=f"{label}, during 30 s outages")
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("30 s outages: solution during each outage")
    width = 0.8 / len(DRIVE_VARIANTS)
    for i, v in enumerate(DRIVE_VARIANTS):
        means = [np.mean(drifts.get((v.label, d), [np.nan])) for d in OUTAGE_DURATIONS_S]
        x = np.arange(len(OUTAGE_DURATIONS_S)) + (i - 1.5) * width
        bx.bar(x, means, width, label=v.label, color=v.color)
    bx.set_xticks(np.arange(len(OUTAGE_DURATIONS_S)), [f"{d:.0f} s" for d in OUTAGE_DURATIONS_S])
    bx.set_yscale("log")
    bx.set_ylabel("mean horizontal drift at outage end (m)")
    bx.legend(fontsize=8)
    bx.set_title("drift by outage length")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------------------------
# PyShoe
# --------------------------------------------------------------------------------------------


def scores(predicted: NDArray[np.bool_], actual: NDArray[np.bool_]) -> tuple[float, float, float]:
    """Precision, recall and F1 of boolean labels."""
    tp = float(np.sum(predicted & actual))
    precision = tp / max(float(np.sum(predicted)), 1.0)
    recall = tp / max(float(np.sum(actual)), 1.0)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return precision, recall, f1


def pyshoe_align(estimate: FloatArray, reference: FloatArray) -> tuple[FloatArray, FloatArray]:
    """PyShoe's ``align_plots``: horizontal tracks from their start, the estimate rotated.

    Both tracks start at the origin; the estimate is rotated about the vertical so that its
    first sample at least 0.8 m from the start (sample 300 when none) points like the
    reference's sample of the same index.
    """
    e = estimate[:, :2] - estimate[0, :2]
    r = reference[:, :2] - reference[0, :2]
    far = np.flatnonzero(np.hypot(e[:, 0], e[:, 1]) >= PYSHOE_ALIGN_M)
    k = int(far[0]) if far.size else min(300, len(e) - 1)
    angle = math.atan2(r[k, 1], r[k, 0]) - math.atan2(e[k, 1], e[k, 0])
    c, s = math.cos(angle), math.sin(angle)
    return e @ np.array([[c, -s], [s, c]]).T, r


def pyshoe_armse(estimate: FloatArray, reference: FloatArray) -> float:
    """PyShoe's 2-D ARMSE after :func:`pyshoe_align`: the mean over epochs of
    ``√((δx² + δy²)/2)``, the RMS over the two axes (``ins_tools/util.py`` ``compute_error``),
    not the error norm, which is √2 larger. A textbook 9-state ZUPT filter with PyShoe's noise
    and the trials' own labels reproduces every trial's ``best_error`` within 9 % by this
    definition (docs/design/2026-11-29-pyshoe-metric.md)."""
    aligned, r = pyshoe_align(estimate, reference)
    return float(np.mean(np.sqrt(np.mean((aligned - r) ** 2, axis=1))))


def least_squares_rmse_2d(estimate: FloatArray, reference: FloatArray) -> float:
    """2-D RMSE after the least-squares rotation about the vertical and translation."""
    e = estimate[:, :2] - estimate[:, :2].mean(axis=0)
    r = reference[:, :2] - reference[:, :2].mean(axis=0)
    angle = math.atan2(float(np.sum(e[:, 0] * r[:, 1] - e[:, 1] * r[:, 0])), float(np.sum(e * r)))
    c, s = math.cos(angle), math.sin(angle)
    rotated = e @ np.array([[c, -s], [s, c]]).T
    return float(np.sqrt(np.mean(np.sum((rotated - r) ** 2, axis=1))))


def pyshoe_section(work: Path) -> Section:
    """ZUPT detector and SINS + ZUPT against Vicon (issue #8 item 4)."""
    sec = Section("PyShoe VICON: ZUPT detector and SINS + ZUPT (foot, 3DM-GX3-25 at 200 Hz)")
    folder = datasets_root() / "pyshoe-vicon"
    if not folder.exists():
        sec.text = f"Skipped: dataset folder {folder} not found."
        return sec
    from fusion.aiding.zupt import StationaryThresholds, default_thresholds, detect_stationary
    from fusion.earth import normal_gravity

    config = load_config(REPO / "configs" / "real_pyshoe.yaml")
    opts = config.plugins[0].options
    foot = StationaryThresholds(
        opts["accel_min_mps2"], opts["accel_max_mps2"], math.radians(opts["gyro_max_dps"])
    )
    rows = []
    f1_default, f1_foot, ratio = [], [], []
    figure = FIGURES / "real_pyshoe_tracks.png"
    tracks = []
    failures = []
    for src in sorted(folder.glob("*.mat")):
        out = work / f"pyshoe_{src.stem}"
        import_pyshoe(src, out)
        rec = read_recording(out)
        labels = read_pyshoe_labels(src)
        truth = rec.truth
        assert truth is not None
        gravity = float(
            normal_gravity(math.radians(rec.meta.origin.lat_deg), rec.meta.origin.height_m)
        )
        assert rec.meta.imu.spec is not None
        datasheet = default_thresholds(rec.meta.imu.spec, rec.meta.imu.rate_hz, gravity)
        det = {
            name: detect_stationary(
                rec.imu.t, rec.imu.gyro, rec.imu.accel, th, opts["window_s"], opts["causal"]
            )
            for name, th in (("datasheet", datasheet), ("foot", foot))
        }
        f_d = scores(det["datasheet"], labels.zero_velocity)[2]
        p_f, r_f, f_f = scores(det["foot"], labels.zero_velocity)
        f1_default.append(f_d)
        f1_foot.append(f_f)
        try:
            result = run_engine(config, rec)
            est = interpolate_rows(truth.t, result.solution.t, result.solution.position)
            armse = pyshoe_armse(est, truth.position)
            ls = least_squares_rmse_2d(est, truth.position)
            wh = result.innovations["zupt"].whitened_rms()
            tracks.append((src.stem, est, truth.position))
        except Exception as exc:  # a failed run is a result to report, not a crash
            armse = ls = wh = float("nan")
            traceback.print_exc()
            failures.append(f"- {src.stem}: run failed ({type(exc).__name__}: {exc})")
        ratio.append(armse / labels.best_error)
        rows.append(
            [
                src.stem,
                f"{f_d:.2f}",
                f"{p_f:.2f} / {r_f:.2f} / {f_f:.2f}",
                labels.best_detector,
                fmt(armse, 3),
                f"{labels.best_error:.3f}",
                fmt(ls, 3),
                fmt(wh),
            ]
        )
    _plot_pyshoe(tracks, figure)
    sec.figures.append(figure)
    sec.text = "\n".join(
        [
            "Detector: `fusion.aiding.zupt.detect_stationary` (offline, 25 ms median window) "
            "against the trial's optimal zero-velocity labels (`zv_<best_detector>_opt`), per IMU "
            "sample. *Datasheet* = the plugin's default thresholds from the 3DM-GX3-25 figures "
            "in meta.yaml; *foot* = the one setting of `configs/real_pyshoe.yaml` for all "
            "trials. Position: SINS + ZUPT (foot thresholds) vs Vicon; *ARMSE* is PyShoe's "
            "metric (start-point alignment, bearing at 0.8 m, mean 2-D error), the one "
            "`best_error` uses; *LS* is the 2-D RMSE after a least-squares yaw + translation.",
            "",
            table(
                [
                    "trial",
                    "F1 datasheet",
                    "P / R / F1 foot",
                    "best detector",
                    "ARMSE (m)",
                    "best_error (m)",
                    "LS RMSE (m)",
                    "ZUPT whitened RMS",
                ],
                rows,
            ),
            "",
            f"Median F1: datasheet thresholds {np.median(f1_default):.2f}, foot setting "
            f"{np.median(f1_foot):.2f}. ARMSE / best_error: median "
            f"{np.nanmedian(ratio):.1f}×, range {np.nanmin(ratio):.1f}–{np.nanmax(ratio):.1f}×.",
            *failures,
            "",
            f"![pyshoe]({figure.relative_to(HERE)})",
        ]
    )
    return sec


def _plot_pyshoe(tracks: list[tuple[str, FloatArray, FloatArray]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(tracks)
    cols = 5
    rows = max(1, math.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.2 * rows), squeeze=False)
    for ax, (name, est, ref) in zip(axes.ravel(), tracks, strict=False):
        e, r = pyshoe_align(est, ref)
        ax.plot(r[:, 0], r[:, 1], color="0.5", lw=1.5, label="Vicon")
        ax.plot(e[:, 0], e[:, 1], color="tab:blue", lw=0.8, label="SINS + ZUPT")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(name, fontsize=8)
        ax.tick_params(labelsize=6)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --------------------------------------------------------------------------------------------
# BROAD
# --------------------------------------------------------------------------------------------


def heading_rmse_deg(solution: Solution, truth: TruthData, rate_hz: float) -> tuple[float, int]:
    """BROAD heading error RMSE (deg) over the movement phase, never across optical gaps."""
    k = np.searchsorted(truth.t, solution.t, side="right") - 1
    ok = (k >= 0) & (k < truth.t.size - 1)
    k = np.clip(k, 0, truth.t.size - 2)
    ok &= truth.t[k + 1] - truth.t[k] < 1.5 / rate_hz
    ok &= (truth.cycle[k] == 1) & (truth.cycle[k + 1] == 1)
    k = k[ok]
    before = Rotation.from_matrix(dcm_from_euler(*truth.attitude[k].T))
    after = Rotation.from_matrix(dcm_from_euler(*truth.attitude[k + 1].T))
    fraction = (solution.t[ok] - truth.t[k]) / (truth.t[k + 1] - truth.t[k])
    step = (before.inv() * after).as_rotvec()
    reference = before * Rotation.from_rotvec(step * fraction[:, None])
    estimate = Rotation.from_matrix(dcm_from_euler(*solution.attitude[ok].T))
    q = (estimate * reference.inv()).as_quat(scalar_first=True)
    error = 2.0 * np.arctan(np.abs(q[:, 3] / q[:, 0]))
    return float(np.degrees(np.sqrt(np.mean(error**2)))), int(k.size)


def isolated_seconds(result: RunResult, local: str, t_end: float) -> float:
    """Time the federated master kept ``local`` isolated."""
    total, since = 0.0, None
    for event in result.faults:
        if event.local != local:
            continue
        if event.action == ISOLATE and since is None:
            since = event.t
        elif event.action == READMIT and since is not None:
            total += event.t - since
            since = None
    if since is not None:
        total += t_end - since
    return total


BROAD_FILTERS: tuple[tuple[str, Callable[[], FusionConfig]], ...] = (
    ("no magnetometer", lambda: config_variant("real_broad", disable=("magnetometer",))),
    ("CKF + magnetometer", lambda: config_variant("real_broad")),
    ("AFKF + magnetometer", lambda: config_variant("real_broad", architecture="federated")),
)


def broad_section(work: Path) -> Section:
    """Yaw error against the optical reference (issue #8 item 3)."""
    sec = Section("BROAD: heading error against the optical reference (aktos-t, 285.7 Hz)")
    folder = datasets_root() / "broad"
    if not folder.exists():
        sec.text = f"Skipped: dataset folder {folder} not found."
        return sec
    trials = json.loads((folder / "trials.json").read_text())["trials"]
    rows = []
    rmse: dict[tuple[str, str], float] = {}
    group_of: dict[str, str] = {}
    failures: list[str] = []
    for src in sorted(folder.glob("*.mat")):
        groups = trials.get(src.stem, {}).get("groups", [])
        group = "undisturbed" if "undisturbed" in groups else "disturbed"
        group_of[src.stem] = group
        out = work / f"broad_{src.stem}"
        import_broad(src, out)
        rec = read_recording(out)
        assert rec.truth is not None
        row = [src.stem, group]
        suspect, isolated = "–", "–"
        for label, make in BROAD_FILTERS:
            try:
                result = run_engine(make(), rec)
            except Exception as exc:  # reported in the table, not hidden
                failures.append(f"{src.stem}, {label}: {type(exc).__name__}: {exc}")
                row.append("failed")
                continue
            value, _ = heading_rmse_deg(result.solution, rec.truth, rec.meta.imu.rate_hz)
            rmse[src.stem, label] = value
            row.append(f"{value:.2f}")
            if label.startswith("AFKF"):
                seconds = isolated_seconds(result, "magnetometer", float(rec.imu.t[-1]))
                isolated = f"{seconds:.0f} s"
            if label.startswith("CKF"):
                share = float(np.mean(result.innovations["magnetometer"].suspect))
                suspect = f"{100 * share:.0f} %"
        rows.append([*row, suspect, isolated, str(len(rec.meta.extra["truth_gaps"]))])

    def mean_of(label: str, group: str) -> float:
        """Group mean; NaN unless every trial of the group ran (no mean over survivors)."""
        values = [rmse.get((trial, label), math.nan) for trial, g in group_of.items() if g == group]
        return float(np.mean(values)) if values else math.nan

    def verdict(ok: bool, *values: float) -> str:
        if not all(math.isfinite(v) for v in values):
            return "**not evaluated** (a run of the group failed)"
        return "**met**" if ok else "**not met**"

    summary = [
        [g] + [fmt(mean_of(label, g)) for label, _ in BROAD_FILTERS]
        for g in ("undisturbed", "disturbed")
    ]
    afkf_u = mean_of("AFKF + magnetometer", "undisturbed")
    afkf_d = mean_of("AFKF + magnetometer", "disturbed")
    ckf_u = mean_of("CKF + magnetometer", "undisturbed")
    ckf_d = mean_of("CKF + magnetometer", "disturbed")
    checks = [
        (
            "disturbed: AFKF yaw RMSE lower than the CKF's",
            verdict(afkf_d < ckf_d, afkf_d, ckf_d),
            f"{fmt(afkf_d)}° vs {fmt(ckf_d)}°",
        ),
        (
            "disturbed AFKF ≤ 1.5 × its undisturbed RMSE",
            verdict(afkf_d <= 1.5 * afkf_u, afkf_d, afkf_u),
            f"{fmt(afkf_d)}° vs 1.5 × {fmt(afkf_u)}° = {fmt(1.5 * afkf_u)}°",
        ),
        (
            "undisturbed: AFKF within 10 % of the CKF (read one-sided: at most 10 % worse)",
            verdict(afkf_u <= 1.1 * ckf_u, afkf_u, ckf_u),
            f"{fmt(afkf_u)}° vs {fmt(ckf_u)}° ({fmt(100 * (afkf_u / ckf_u - 1), 1)} %)",
        ),
    ]
    figure = FIGURES / "real_broad_heading.png"
    _plot_broad(rmse, list(group_of), figure)
    sec.figures.append(figure)
    sec.text = "\n".join(
        [
            "Heading RMSE (deg) over BROAD's movement phase, per trial; solution epochs "
            "inside an optical gap are excluded. Configuration `configs/real_broad.yaml` "
            "(optical position fixes at 10 Hz, σ 5 mm; magnetometer at 28.6 Hz). *suspect* = "
            "share of the CKF's magnetometer epochs its disturbance indicator flags; "
            "*isolated* = time the AFKF kept the magnetometer's local filter out of the fusion; "
            "*gaps* = optical-reference gaps listed by the importer.",
            "",
            table(
                ["trial", "group"]
                + [label for label, _ in BROAD_FILTERS]
                + ["suspect (CKF)", "isolated (AFKF)", "gaps"],
                rows,
                "ll" + "r" * (len(BROAD_FILTERS) + 3),
            ),
            "",
            "Mean heading RMSE (deg) by group (– when a run of the group failed):",
            "",
            table(["group"] + [label for label, _ in BROAD_FILTERS], summary),
            "",
            "Acceptance:",
            "",
            *[f"- {name}: {result} ({detail})" for name, result, detail in checks],
            *([""] + [f"- run failed: {f}" for f in failures] if failures else []),
            "",
            f"![broad]({figure.relative_to(HERE)})",
        ]
    )
    return sec


def _plot_broad(rmse: dict[tuple[str, str], float], trials: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 4.5))
    width = 0.8 / len(BROAD_FILTERS)
    x = np.arange(len(trials))
    for i, (label, _) in enumerate(BROAD_FILTERS):
        values = [rmse.get((t, label), np.nan) for t in trials]
        ax.bar(x + (i - 1) * width, values, width, label=label)
    ax.set_xticks(
        x,
        [t[:2] + " " + t[3:].replace("_", " ")[:22] for t in trials],
        rotation=35,
        ha="right",
        fontsize=7,
    )
    ax.set_ylabel("heading RMSE, movement phase (deg)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------------------------

PARTS: dict[str, Callable[[Path], Section]] = {
    "drive": drive_section,
    "pyshoe": pyshoe_section,
    "broad": broad_section,
}


def _part_markers(name: str) -> tuple[str, str]:
    return f"<!-- real:part {name} -->", f"<!-- real:part-end {name} -->"


def write_results(sections: dict[str, Section], path: Path = RESULTS) -> None:
    """Update the ``real`` block of RESULTS.md (created when missing) with ``sections``.

    Each part sits between its own markers, so running some parts keeps the others' last
    results; the rest of the file (other suites) is left as it is.
    """
    old = path.read_text(encoding="utf-8") if path.exists() else "# Benchmark results\n"
    body = [
        BEGIN,
        "## Real data (`python -m benchmarks real`)",
        "",
        "Datasets imported by `fusion.importers` from `$FUSION_DATASETS` or "
        "`../shared/datasets`. Nothing is tuned per trial or per file: every setting is in "
        "`configs/real_drive.yaml`, `configs/real_pyshoe.yaml`, `configs/real_broad.yaml`.",
        "",
    ]
    for name in PARTS:
        begin, end = _part_markers(name)
        if name in sections:
            sec = sections[name]
            stamp = f"Generated {time.strftime('%Y-%m-%d %H:%M')} from `{datasets_root()}`."
            body += [begin, f"### {sec.title}", "", stamp, "", sec.text.strip(), end, ""]
        else:
            kept = re.search(re.escape(begin) + r".*?" + re.escape(end), old, re.DOTALL)
            if kept:
                body += [kept.group(0), ""]
    body.append(END)
    block = "\n".join(body)
    pattern = re.compile(re.escape(BEGIN) + r".*?" + re.escape(END), re.DOTALL)
    new = (
        pattern.sub(lambda _: block, old) if pattern.search(old) else old.rstrip() + "\n\n" + block
    )
    path.write_text(new.rstrip() + "\n", encoding="utf-8")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the real-data suite (all parts, or the ones named) and write RESULTS.md."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks real")
    parser.add_argument("parts", nargs="*", help=f"some of {', '.join(PARTS)} (default: all)")
    args = parser.parse_args(argv)
    unknown = [p for p in args.parts if p not in PARTS]
    if unknown:
        parser.error(f"unknown part(s) {unknown}; choose from {', '.join(PARTS)}")
    names = args.parts or list(PARTS)
    sections = {}
    with tempfile.TemporaryDirectory(prefix="fusion-real-") as tmp:
        for name in names:
            t0 = time.perf_counter()
            sections[name] = PARTS[name](Path(tmp))
            print(f"{name}: {time.perf_counter() - t0:.0f} s")
    write_results(sections)
    for sec in sections.values():
        print(f"\n### {sec.title}\n\n{sec.text}")
    print(f"\nwrote {RESULTS}")
    return 0
