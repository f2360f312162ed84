"""Helpers shared by the dataset importers: reports, dataset location, levelling, truth rows.

Equations
---------
* Levelling (RECORDING_FORMAT.md attitude convention): at rest the specific force is
  ``f^b = C_n^b [0, 0, g]``, the third row of ``C_b^n`` times g, i.e.
  ``f^b / |f^b| = [−cos θ sin γ, sin θ, cos θ cos γ]``, so ``θ = asin(f_y / |f|)`` and
  ``γ = atan2(−f_x, f_z)``.
* Course attitude of a land vehicle from its velocity: ``ψ = atan2(v_E, v_N)`` (clockwise from
  north, the format's yaw), flight-path angle ``θ = atan2(v_U, hypot(v_E, v_N))``, ``γ = 0``.
  It describes the direction of travel, not the body's attitude (no attitude reference).
* Velocity of a sampled position reference by central differences over ``±k`` samples,
  ``v_i = (p_{i+k} − p_{i−k}) / (t_{i+k} − t_{i−k})`` (one-sided at the ends of each run of
  valid samples), computed only inside runs so that no difference spans a gap.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.io
from numpy.typing import ArrayLike, NDArray

from fusion.recording import Recording, RecordingError, RecordingMeta, validate_recording
from fusion.validation import error_lines

FloatArray = NDArray[np.float64]

DATASETS_ENV = "FUSION_DATASETS"
"""Environment variable naming the folder that holds the real datasets."""


class DatasetError(ValueError):
    """A dataset file is missing, unreadable or lacks a variable; the message names it."""


@dataclass
class ImportReport:
    """What an importer wrote and every explicit choice it made about the data.

    Attributes
    ----------
    kind : str
        Importer name (``rtklib-drive``, ``broad``, ``pyshoe``).
    source : Path
        Dataset folder or file read.
    out : Path
        Recording directory written.
    notes : list of str
        One sentence per quirk handled (axis mapping, time base, gaps, dropped samples). The
        same sentences are written to ``meta.yaml`` under ``extra.import_notes``.
    """

    kind: str
    source: Path
    out: Path
    notes: list[str] = field(default_factory=list)

    def __str__(self) -> str:
        """Human-readable summary (one note per line)."""
        lines = [f"{self.kind}: {self.source} -> {self.out}"]
        lines += [f"  - {note}" for note in self.notes]
        return "\n".join(lines)


def datasets_root() -> Path:
    """The real-dataset folder: ``$FUSION_DATASETS`` or ``<repo>/../shared/datasets``."""
    env = os.environ.get(DATASETS_ENV)
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2].parent / "shared" / "datasets"


def load_mat(path: str | Path, variables: tuple[str, ...]) -> dict[str, Any]:
    """Read a MATLAB v5 file and check that it holds ``variables``.

    Raises
    ------
    DatasetError
        Naming the file and the missing variables (or the read error).
    """
    path = Path(path)
    try:
        data = scipy.io.loadmat(path)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read as a MATLAB .mat file ({exc})") from None
    missing = [v for v in variables if v not in data]
    if missing:
        raise DatasetError(f"{path}: missing variable(s) {', '.join(missing)}")
    return data


def read_csv_columns(path: str | Path, columns: tuple[str, ...]) -> dict[str, FloatArray]:
    """Read the named columns of a numeric CSV file with one header line.

    Raises
    ------
    DatasetError
        Naming the file and the missing columns, or the unreadable content.
    """
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as fh:
            header = fh.readline().strip().split(",")
            values = np.loadtxt(fh, delimiter=",", ndmin=2)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read as a numeric CSV file ({exc})") from None
    missing = [c for c in columns if c not in header]
    if missing:
        raise DatasetError(
            f"{path}: missing column(s) {', '.join(missing)} (header: {','.join(header)})"
        )
    if values.shape[1] != len(header):
        raise DatasetError(f"{path}: {values.shape[1]} values per row, {len(header)} in header")
    return {c: values[:, header.index(c)] for c in columns}


def leveling_angles(specific_force_b: ArrayLike) -> tuple[float, float]:
    """Roll and pitch (rad) of a body at rest from its mean specific force in b."""
    f = np.asarray(specific_force_b, dtype=float)
    norm = float(np.linalg.norm(f))
    return float(np.arctan2(-f[0], f[2])), float(np.arcsin(np.clip(f[1] / norm, -1.0, 1.0)))


def true_runs(mask: ArrayLike) -> list[tuple[int, int]]:
    """Half-open index ranges ``[start, stop)`` of the runs of True in a boolean array."""
    m = np.asarray(mask, dtype=bool).astype(np.int8)
    edges = np.diff(np.concatenate(([0], m, [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def course_attitude(velocity_enu: ArrayLike, min_speed_mps: float) -> FloatArray:
    """Roll 0, flight-path pitch and course yaw (N, 3, rad) from ENU velocities.

    Samples slower than ``min_speed_mps`` (course undefined) take the value of the nearest
    faster sample before them, or after them at the start.
    """
    v = np.asarray(velocity_enu, dtype=float)
    horizontal = np.hypot(v[:, 0], v[:, 1])
    moving = horizontal >= min_speed_mps
    if not moving.any():
        raise DatasetError(f"the reference never moves faster than {min_speed_mps} m/s")
    idx = np.where(moving, np.arange(len(v)), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = np.flatnonzero(moving)[0]
    yaw = np.mod(np.arctan2(v[idx, 0], v[idx, 1]), 2.0 * np.pi)
    pitch = np.arctan2(v[idx, 2], horizontal[idx])
    return np.column_stack([np.zeros(len(v)), pitch, yaw])


def central_difference_velocity(
    t: ArrayLike, position: ArrayLike, half_window: int, valid: ArrayLike | None = None
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Velocity of a position track by central differences inside runs of valid samples.

    Parameters
    ----------
    t : array, shape (N,)
        Sample times (s).
    position : array, shape (N, 3)
        Positions (m).
    half_window : int
        ``k``: the difference spans samples ``i − k .. i + k`` (clipped to the run).
    valid : bool array, shape (N,), optional
        Samples that exist (default: all finite rows).

    Returns
    -------
    velocity : ndarray, shape (N, 3)
        NaN where no velocity can be formed (invalid samples, runs of one sample).
    has_velocity : ndarray of bool, shape (N,)
    """
    t = np.asarray(t, dtype=float)
    p = np.asarray(position, dtype=float)
    ok = np.isfinite(p).all(axis=1) if valid is None else np.asarray(valid, dtype=bool)
    v = np.full(p.shape, np.nan)
    for start, stop in true_runs(ok):
        if stop - start < 2:
            continue
        i = np.arange(start, stop)
        lo = np.maximum(i - half_window, start)
        hi = np.minimum(i + half_window, stop - 1)
        v[start:stop] = (p[hi] - p[lo]) / (t[hi] - t[lo])[:, None]
    return v, np.isfinite(v).all(axis=1)


def make_meta(data: dict[str, Any], source: str) -> RecordingMeta:
    """Validate a meta.yaml mapping built by an importer (an importer bug if it fails)."""
    from pydantic import ValidationError

    try:
        return RecordingMeta.model_validate(data)
    except ValidationError as exc:
        raise DatasetError("\n".join(error_lines(source, RecordingMeta, exc))) from None


def write_validated(recording: Recording, report: ImportReport) -> ImportReport:
    """Write the recording, then read it back through the format validator.

    Raises
    ------
    RecordingError
        When the written directory breaks the format (never expected; reported, not hidden).
    """
    from fusion.recording import write_recording

    write_recording(recording, report.out)
    problems = validate_recording(report.out)
    if problems:
        raise RecordingError(problems, report.out)
    return report
