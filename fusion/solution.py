"""Writer and reader of the engine's trajectory files ``solution.csv`` and ``smoothed.csv``.

Both files have the columns :data:`SOLUTION_COLUMNS` (``shared/RECORDING_FORMAT.md``, "Solutions
written by the engine"): time, ENU position (m) about the recording origin, ENU velocity (m/s),
roll / pitch / yaw (rad, the convention of the format) and the 1-sigma position uncertainty (m).
Floats are written with ``repr``, so a file reads back bit-identical; the writer is
deterministic.  A full position covariance, when the engine provides one, travels in memory only
(:attr:`Solution.position_covariance`, used for NEES in :mod:`fusion.metrics`).
:meth:`Solution.to_pandas` gives the file's table as a DataFrame (pandas is the optional extra
``shearer-fusion[pandas]``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from fusion.recording import (
    FloatArray,
    Problem,
    RecordingError,
    _check_time,
    _read_table,
    _Reporter,
    _write_csv,
)

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["SOLUTION_COLUMNS", "Solution", "read_solution", "require_pandas", "write_solution"]

SOLUTION_COLUMNS: tuple[str, ...] = (
    "t",
    "e",
    "n",
    "u",
    "ve",
    "vn",
    "vu",
    "roll",
    "pitch",
    "yaw",
    "se",
    "sn",
    "su",
)
"""Columns of ``solution.csv`` and ``smoothed.csv``, in order."""


def require_pandas() -> ModuleType:
    """The pandas module, or an ImportError saying how to install it (an optional extra)."""
    try:
        import pandas
    except ImportError as exc:
        raise ImportError(
            "to_pandas() needs pandas, an optional dependency: "
            "pip install 'shearer-fusion[pandas]' (or pip install pandas)"
        ) from exc
    return pandas


def _array(name: str, value: Any, shape: tuple[int, ...]) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


@dataclass(frozen=True, eq=False)
class Solution:
    """A trajectory estimate at the output epochs.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Epochs (s, recording clock), strictly increasing.
    position : ndarray, shape (N, 3)
        ENU position (m) about the recording origin.
    velocity : ndarray, shape (N, 3)
        ENU velocity (m/s).
    attitude : ndarray, shape (N, 3)
        Roll, pitch, yaw (rad).
    sigma_position : ndarray, shape (N, 3)
        1-sigma of the east, north, up position (m).
    position_covariance : ndarray, shape (N, 3, 3), optional
        Full ENU position covariance (m²); not written to the CSV file.
    """

    t: FloatArray
    position: FloatArray
    velocity: FloatArray
    attitude: FloatArray
    sigma_position: FloatArray
    position_covariance: FloatArray | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"t must be 1-D, got shape {t.shape}")
        n = t.shape[0]
        object.__setattr__(self, "t", t)
        for name in ("position", "velocity", "attitude", "sigma_position"):
            object.__setattr__(self, name, _array(name, getattr(self, name), (n, 3)))
        if self.position_covariance is not None:
            cov = _array("position_covariance", self.position_covariance, (n, 3, 3))
            object.__setattr__(self, "position_covariance", cov)

    def __len__(self) -> int:
        """Number of epochs."""
        return int(self.t.shape[0])

    def columns(self) -> list[FloatArray]:
        """The columns of the file, in :data:`SOLUTION_COLUMNS` order (views, no copy)."""
        return [
            self.t,
            *self.position.T,
            *self.velocity.T,
            *self.attitude.T,
            *self.sigma_position.T,
        ]

    def to_pandas(self) -> pd.DataFrame:
        """The table of ``solution.csv``: one row per epoch, the :data:`SOLUTION_COLUMNS`.

        Raises
        ------
        ImportError
            Without pandas (``pip install 'shearer-fusion[pandas]'``).
        """
        pandas = require_pandas()
        return pandas.DataFrame(dict(zip(SOLUTION_COLUMNS, self.columns(), strict=True)))


def write_solution(solution: Solution, path: str | Path) -> None:
    """Write a solution file (``solution.csv`` / ``smoothed.csv``).

    Parameters
    ----------
    solution : Solution
        The trajectory; ``position_covariance`` is not written.
    path : str or Path
        Output file; a name ending in ``.gz`` is written gzip-compressed (zero mtime).

    Raises
    ------
    ValueError
        When a value is NaN or infinite or time is not strictly increasing (such a file could not
        be read back).
    """
    s = solution
    columns = s.columns()
    rep = _Reporter(Path(path).name)
    lines = np.arange(2, len(s) + 2, dtype=np.int64)
    bad = [np.flatnonzero(~np.isfinite(c)) for c in columns]  # column by column: no table copy
    rows = np.concatenate(bad)
    cols = np.repeat(np.arange(len(columns)), [b.size for b in bad])
    order = np.lexsort((cols, rows))
    rows, cols = rows[order], cols[order]
    rep.add_many(
        "nonfinite",
        rows.size,
        lambda i: (
            f"line {lines[rows[i]]}, column {SOLUTION_COLUMNS[cols[i]]}",
            f"value at t={s.t[rows[i]]!r} is not a finite number",
        ),
        "a value is NaN or infinite",
    )
    _check_time(s.t, lines, rep)
    problems = rep.finish()
    if problems:
        raise RecordingError(problems, path)
    out = Path(path)
    compress = out.name.endswith(".gz")
    target = out.with_name(out.name.removesuffix(".gz")) if compress else out
    _write_csv(target, SOLUTION_COLUMNS, columns, "f" * len(SOLUTION_COLUMNS), compress=compress)


def read_solution(path: str | Path) -> Solution:
    """Read a solution file written by :func:`write_solution` (or any tool following the format).

    Parameters
    ----------
    path : str or Path
        ``solution.csv``, ``smoothed.csv`` or a ``.gz`` of them.

    Returns
    -------
    Solution
        Without ``position_covariance``.

    Raises
    ------
    RecordingError
        Listing every problem (missing file, wrong header, non-numeric / empty / non-finite
        cell, time not strictly increasing), each with its line and column.
    """
    file = Path(path)
    rep = _Reporter(file.name)
    if not file.is_file():
        raise RecordingError([Problem(file.name, "", "file is missing")], file)
    table = _read_table(file, file.name, SOLUTION_COLUMNS, rep)
    if table is not None:
        _check_time(table.values[:, 0], table.lines, rep)
    problems = rep.finish()
    if problems or table is None:
        raise RecordingError(problems, file)
    v = table.values
    return Solution(
        t=v[:, 0],
        position=v[:, 1:4],
        velocity=v[:, 4:7],
        attitude=v[:, 7:10],
        sigma_position=v[:, 10:13],
    )
