"""Write a suite's outputs (CSV, Markdown, PNG) and the repository's ``benchmarks/RESULTS.md``.

Layout of a suite's output directory (default ``benchmarks/results/SUITE/``, not committed):

* ``runs.csv`` — every per-run row (wall-clock fields included);
* ``TABLE.csv`` and ``TABLE.png`` — each table (mean, std, paper figure per column) and the bar
  chart of its headline column;
* ``results.md`` — the suite's tables in Markdown, the notes (skipped or failed methods) and
  links to the figures;
* ``figures/`` — per traced method (seed 0): plan view per cycle, error with ±3σ; per group with
  faults: the fault timeline.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Sequence
from pathlib import Path

from benchmarks.figures import plot_cycles, plot_error_envelope, plot_fault_timeline, plot_headline
from benchmarks.runner import WALL_CLOCK_FIELDS, TaskResult, Trace, describe_machine
from benchmarks.suites import Suite
from benchmarks.tables import build_table, rows_to_csv, to_csv, to_markdown

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_MD = BENCH_DIR / "RESULTS.md"
COMMITTED_FIGURES = BENCH_DIR / "figures"
FIGURES_LINE = "Figures: "


def slug(text: str) -> str:
    """A file-name-safe form of a label."""
    return re.sub(r"[^A-Za-z0-9.=-]+", "_", text.replace("Δ", "D")).strip("_")


def _trace_figures(traces: Sequence[Trace], figures: Path) -> list[Path]:
    by_method: dict[tuple[str, str], list[Trace]] = {}
    by_group: dict[str, list[Trace]] = {}
    for tr in traces:
        by_method.setdefault((tr.group, tr.method), []).append(tr)
        if tr.solution == "forward":
            by_group.setdefault(tr.group, []).append(tr)
    written = []
    for (group, method), items in sorted(by_method.items()):
        stem = slug(f"{group}_{method}")
        title = f"{method} — {group}, seed {items[0].seed}"
        written.append(plot_cycles(items, figures / f"{stem}_plan.png", title))
        for tr in items:
            name = f"{stem}_{tr.solution}_errors.png"
            written.append(plot_error_envelope(tr, figures / name, f"{title} ({tr.solution})"))
    for group, items in sorted(by_group.items()):
        if any(tr.injected or tr.events for tr in items):
            title = f"{group}, seed {items[0].seed}"
            written.append(plot_fault_timeline(items, figures / f"{slug(group)}_faults.png", title))
    return written


def write_suite(
    suite: Suite, merged: TaskResult, out: Path, runs: int, command: str, date: str
) -> str:
    """Tables, figures and the suite's Markdown report (with command, date, machine) in ``out``;
    returns the Markdown."""
    out.mkdir(parents=True, exist_ok=True)
    figures = out / "figures"
    figures.mkdir(exist_ok=True)
    (out / "runs.csv").write_text(rows_to_csv(merged.rows), encoding="utf-8")
    tables = [build_table(spec, merged.rows) for spec in suite.tables()]
    headline: list[Path] = []
    parts = [f"### `{suite.name}` — {suite.description}", ""]
    parts.append(
        f"{runs} run(s) per row (seeds 0…{runs - 1}). `{command}`, {date}, on {describe_machine()}."
    )
    parts.append("")
    if suite.preamble is not None:
        parts.append(suite.preamble())
    for table in tables:
        (out / f"{table.spec.name}.csv").write_text(to_csv(table), encoding="utf-8")
        parts.append(to_markdown(table))
        png = plot_headline(table, out / f"{table.spec.name}.png")
        if png is not None:
            headline.append(png)
    if merged.notes:
        parts.append("Not run:")
        parts.append("")
        parts.extend(f"- {note}" for note in merged.notes)
        parts.append("")
    trace_pngs = _trace_figures(merged.traces, figures)
    if headline or trace_pngs:
        parts.append(
            FIGURES_LINE
            + ", ".join(f"[{p.name}]({p.relative_to(out).as_posix()})" for p in headline)
            + (f"; {len(trace_pngs)} per-method figures in `figures/`" if trace_pngs else "")
        )
        parts.append("")
    markdown = "\n".join(parts)
    (out / "results.md").write_text(markdown, encoding="utf-8")
    return markdown


def accuracy_csv(merged: TaskResult) -> str:
    """The per-run rows without the wall-clock fields (what must not depend on the machine)."""
    return rows_to_csv(merged.rows, exclude=WALL_CLOCK_FIELDS)


SIMULATED_BEGIN, SIMULATED_END = "<!-- simulated:begin -->", "<!-- simulated:end -->"


def committed_section(results_md: str, suite: str) -> str:
    """Suite ``suite``'s section of a RESULTS.md text (its ``### `suite` —`` heading up to the
    next heading or the end of the simulated block), without trailing blank lines; "" if absent."""
    start = results_md.find(f"### `{suite}` ")
    if start < 0:
        return ""
    ends = [results_md.find(mark, start + 1) for mark in ("\n### ", "\n## ", SIMULATED_END)]
    end = min((e for e in ends if e >= 0), default=len(results_md))
    return results_md[start:end].rstrip()


def write_results_md(suites: Sequence[Suite], root: Path, command: str) -> Path:
    """The simulated suites' block of ``benchmarks/RESULTS.md``, from ``root/SUITE/results.md``.

    Each section keeps the command, date and machine that produced it; a suite without output
    under ``root`` keeps its section from the current RESULTS.md (so rerunning one suite in a
    fresh clone refreshes that suite only), or is listed as not run. Only the block between the
    ``simulated`` markers is replaced (the real-data suite keeps its own block in the same
    file). The headline bar charts are copied to ``benchmarks/figures/`` (committed) so that
    the image links work in the repository.
    """
    COMMITTED_FIGURES.mkdir(exist_ok=True)
    old = RESULTS_MD.read_text(encoding="utf-8") if RESULTS_MD.exists() else ""
    lines = [
        SIMULATED_BEGIN,
        "## Simulated Monte Carlo suites (`python -m benchmarks SUITE`)",
        "",
        f"Assembled by `{command}` from the suites' outputs; each section names the command,"
        " date and machine that produced it. `python -m benchmarks all` reruns every suite"
        " (and the real-data suite) and rewrites this file.",
        "",
        "Every table: mean ± std over the Monte Carlo runs (seeded simulations of the scenario"
        " presets, the same seeds for every method), the seed paper's figure in parentheses"
        " where one exists. Per-run rows and all figures: `benchmarks/results/SUITE/`.",
        "",
    ]
    for suite in suites:
        if not suite.in_results:
            continue
        md = root / suite.name / "results.md"
        if not md.exists():
            kept = committed_section(old, suite.name)
            heading = f"### `{suite.name}` — {suite.description}"
            lines += [kept] if kept else [heading, "", "Not run yet."]
            lines.append("")
            continue
        text = md.read_text(encoding="utf-8")
        lines.append(re.sub(rf"^{FIGURES_LINE}.*$", "", text, flags=re.MULTILINE).rstrip())
        lines.append("")
        for spec in suite.tables():
            png = root / suite.name / f"{spec.name}.png"
            if png.exists():
                target = COMMITTED_FIGURES / f"{spec.name}.png"
                shutil.copyfile(png, target)
                lines.append(f"![{spec.title}](figures/{target.name})")
        lines.append("")
    lines.append(SIMULATED_END)
    block = "\n".join(lines)
    pattern = re.compile(re.escape(SIMULATED_BEGIN) + r".*?" + re.escape(SIMULATED_END), re.DOTALL)
    if pattern.search(old):
        new = pattern.sub(lambda _: block, old)
    else:
        title, _, rest = old.partition("\n") if old.startswith("# ") else ("", "", old)
        new = (title or "# Benchmark results") + "\n\n" + block + "\n\n" + rest.lstrip()
    RESULTS_MD.write_text(new.rstrip() + "\n", encoding="utf-8")
    return RESULTS_MD
