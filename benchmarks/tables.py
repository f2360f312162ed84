"""Monte Carlo tables: mean ± std over the runs of each row, the seed paper's figure beside it.

A :class:`TableSpec` lists its rows (a label and the ``group``/``method``/``solution`` that select
per-run rows) and its columns (a row field, a header, decimals). :func:`build_table` averages
every column over the selected runs — mean and population std (``ddof=0``) of the finite
values, ``n`` the number of runs — and attaches the paper's figure for (row label, field) when
the spec has one. :func:`to_markdown` prints ``mean ± std (paper)`` cells; :func:`to_csv`
writes one line per row with ``FIELD_mean``, ``FIELD_std``, ``FIELD_paper`` columns.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Column:
    """A table column: the row field it averages, its header, its decimals."""

    field: str
    header: str
    digits: int = 2
    group: str | None = None
    """Average the runs of this group instead of the row's (a pivot, e.g. one column per fault)."""
    agg: str = "mean"
    """How the runs combine: ``mean`` (mean ± std), ``median``, ``max``, ``min``, ``sum``,
    ``pooled_rms`` (``sqrt(Σ FIELD_sumsq / Σ FIELD_count)``) or ``per_hour``
    (``Σ FIELD / Σ duration_h`` over the runs where FIELD is finite)."""


@dataclass(frozen=True)
class RowSpec:
    """A table row: its label and the runs it averages (``solution`` forward or smoothed)."""

    label: str
    group: str
    method: str
    solution: str = "forward"


@dataclass(frozen=True)
class TableSpec:
    """A table of a suite."""

    name: str
    """File stem of its CSV and figure."""
    title: str
    rows: tuple[RowSpec, ...]
    columns: tuple[Column, ...]
    paper: dict[tuple[str, str], float] = field(default_factory=dict)
    """The seed paper's figure by (row label, column field; ``field@group`` for a pivot)."""
    headline: str | None = None
    """The column field of the suite's bar chart."""
    note: str = ""


@dataclass
class Cell:
    """Statistics of one column over the runs of one row (``mean`` holds the aggregate of a
    column whose ``agg`` is not ``mean``; ``std`` is then NaN)."""

    mean: float
    std: float
    n: int
    paper: float | None
    single: bool = False
    """Print the value alone (an aggregate other than the mean)."""


@dataclass
class Table:
    """A built table: its spec and one list of cells per row."""

    spec: TableSpec
    cells: list[list[Cell]]
    runs: list[int]


def _stats(values: Sequence[float]) -> tuple[float, float, int]:
    arr = np.asarray([v for v in values if v is not None and math.isfinite(v)], float)
    if arr.size == 0:
        return float("nan"), float("nan"), 0
    return float(arr.mean()), float(arr.std()), int(arr.size)


def _finite(values: Sequence[Any]) -> np.ndarray:
    return np.asarray(
        [v for v in values if v is not None and isinstance(v, int | float) and math.isfinite(v)],
        float,
    )


def _aggregate(column: Column, rows: Sequence[dict[str, Any]]) -> Cell:
    """A column's ``agg`` (not ``mean``) over the selected runs."""
    nan = float("nan")
    if column.agg == "pooled_rms":
        total = _finite([r.get(f"{column.field}_sumsq") for r in rows]).sum()
        count = _finite([r.get(f"{column.field}_count") for r in rows]).sum()
        value = math.sqrt(total / count) if count > 0 else nan
        return Cell(value, nan, int(count > 0), None, True)
    if column.agg == "per_hour":
        used = [r for r in rows if _finite([r.get(column.field)]).size]
        hours = _finite([r.get("duration_h") for r in used]).sum()
        events = _finite([r.get(column.field) for r in used]).sum()
        return Cell(events / hours if hours > 0 else nan, nan, len(used), None, True)
    arr = _finite([r.get(column.field) for r in rows])
    if arr.size == 0:
        return Cell(nan, nan, 0, None, True)
    funcs: dict[str, Callable[[Any], Any]] = {
        "median": np.median,
        "max": np.max,
        "min": np.min,
        "sum": np.sum,
    }
    if column.agg not in funcs:
        raise ValueError(f"column {column.field}: unknown agg {column.agg!r}")
    return Cell(float(funcs[column.agg](arr)), nan, int(arr.size), None, True)


def build_table(spec: TableSpec, rows: Sequence[dict[str, Any]]) -> Table:
    """Average the per-run rows into the table's cells (``n``: runs of the row's own group)."""

    def runs_of(group: str, r: RowSpec) -> list[dict[str, Any]]:
        return [
            row
            for row in rows
            if row["group"] == group and row["method"] == r.method and row["solution"] == r.solution
        ]

    cells: list[list[Cell]] = []
    runs: list[int] = []
    for r in spec.rows:
        runs.append(len(runs_of(r.group, r)))
        line = []
        for c in spec.columns:
            chosen = runs_of(c.group or r.group, r)
            if c.agg != "mean":
                line.append(_aggregate(c, chosen))
                continue
            mean, std, n = _stats([row.get(c.field, float("nan")) for row in chosen])
            key = c.field if c.group is None else f"{c.field}@{c.group}"
            line.append(Cell(mean, std, n, spec.paper.get((r.label, key))))
        cells.append(line)
    return Table(spec, cells, runs)


def _number(x: float, digits: int) -> str:
    if not math.isfinite(x):
        return "—"
    if abs(x) >= 10 ** (6 - digits) and digits > 0:
        return f"{x:.3g}"
    return f"{x:.{digits}f}"


def format_cell(cell: Cell, digits: int) -> str:
    """``mean ± std`` (just ``mean`` for a single run), then ``(paper)`` when known."""
    if cell.n == 0:
        text = "—"
    elif cell.n == 1 or cell.single:
        text = _number(cell.mean, digits)
    else:
        text = f"{_number(cell.mean, digits)} ± {_number(cell.std, digits)}"
    if cell.paper is not None:
        text += f" ({_number(cell.paper, digits)})"
    return text


def to_markdown(table: Table) -> str:
    """The table in Markdown with its title, run counts and note."""
    spec = table.spec
    has_paper = bool(spec.paper)
    lines = [f"#### {spec.title}", ""]
    lines.append("| | n | " + " | ".join(c.header for c in spec.columns) + " |")
    lines.append("|---|---:|" + "---:|" * len(spec.columns))
    for r, n, cells in zip(spec.rows, table.runs, table.cells, strict=True):
        body = " | ".join(
            format_cell(cell, c.digits) for cell, c in zip(cells, spec.columns, strict=True)
        )
        lines.append(f"| {r.label} | {n} | {body} |")
    lines.append("")
    notes = []
    if has_paper:
        notes.append("mean ± std over the runs; (the seed paper's figure)")
    elif any(c.agg == "mean" for c in spec.columns):
        notes.append("mean ± std over the runs")
    if spec.note:
        notes.append(spec.note)
    lines.append("*" + ". ".join(notes) + ".*")
    return "\n".join(lines) + "\n"


def to_csv(table: Table) -> str:
    """One line per row: label, group, method, solution, n, then mean/std/paper per column."""
    spec = table.spec
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    header = ["label", "group", "method", "solution", "n"]
    for c in spec.columns:
        header += [f"{c.field}_mean", f"{c.field}_std", f"{c.field}_paper"]
    writer.writerow(header)
    for r, n, cells in zip(spec.rows, table.runs, table.cells, strict=True):
        line: list[Any] = [r.label, r.group, r.method, r.solution, n]
        for cell in cells:
            line += [
                repr(cell.mean),
                repr(cell.std),
                "" if cell.paper is None else repr(cell.paper),
            ]
        writer.writerow(line)
    return buf.getvalue()


def rows_to_csv(rows: Sequence[dict[str, Any]], exclude: Sequence[str] = ()) -> str:
    """Per-run rows as CSV (columns: the union of the rows' fields, in first-seen order)."""
    fields: list[str] = []
    for row in rows:
        fields.extend(k for k in row if k not in fields and k not in exclude)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n", extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: repr(v) if isinstance(v, float) else v for k, v in row.items()})
    return buf.getvalue()
