"""An output directory replaced whole: never half-written, never mixed, never foreign files lost.

``fusion run``, ``demo``, ``simulate`` and ``import`` write into a staging directory beside their
target (``.NAME.staging-PID``: the same filesystem) and rename it into place only once every file
in it is complete. A process killed at any moment, SIGKILL included, therefore leaves the target
as it was (the complete earlier result, or nothing), never an earlier result's files beside new
ones and never a cut or empty file under a current name.

The target (:class:`OutputTarget`) may be absent, an empty directory, or a directory holding
other files (a log the caller redirected there, notes): fusion adds its files beside them and
never touches them, and it refuses (:class:`OutputRefused`) a directory where one of them bears
a name fusion would write. An earlier output of the same kind (:data:`RESULT`, a ``run.json``
and the files it lists; :data:`RECORDING`; :data:`DEMO`) is replaced only with ``force``, and
then whole: its files that the new output does not write go too, never left stale.

The swap: an absent or empty target is replaced by one ``rename(2)``, which is atomic. A previous
result is first renamed aside (``.NAME.replaced-PID``), the staging directory renamed into place,
then the previous result deleted: a kill between the two renames leaves no result at the target
(the earlier one stays aside, hidden), never a mix. SIGINT is held during the swap, so Ctrl-C lands
before it (nothing written) or after it (the new result in place). The hidden directories of a
killed process (whose PID is gone) are deleted by the next write to the same target.

Where the target holds other files, or a rename cannot do the swap (the target is a mount point,
or its parent another filesystem or not writable: a container's output volume), the staging
directory is made inside the target (``.fusion-staging-PID``, when the parent cannot be written)
and its files moved into place one by one, ``run.json`` last, after the earlier result's files
(its ``run.json`` first): a kill part-way then leaves a directory without ``run.json``, which is
no result.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from fusion.recording import STREAM_COLUMNS

__all__ = [
    "DEMO",
    "FIGURE_FORMATS",
    "RECORDING",
    "RECORDING_FILES",
    "RESULT",
    "RUN_JSON",
    "OutputKind",
    "OutputRefused",
    "OutputTarget",
    "OutputWriteError",
]

RUN_JSON = "run.json"
"""The file of a run's result that records how it was made and lists the files written."""

RECORDING_FILES = frozenset(
    ["meta.yaml"] + [f"{stem}.csv{gz}" for stem in STREAM_COLUMNS for gz in ("", ".gz")]
)
"""Every file name a recording directory written by fusion may hold."""

FIGURE_FORMATS = ("png", "svg", "pdf")
"""The formats a result's figures may be written in (``--format``)."""

DEMO_ENTRIES = ("recording", "result")
"""The two directories of ``fusion demo --out``: the simulated recording and the run's result."""

INSIDE_STAGING = re.compile(r"\.fusion-staging-(\d+)")
"""The name of a staging directory made inside the target (its parent could not be written)."""


class OutputRefused(ValueError):
    """The target exists and may not be replaced; the message names it and the rule."""


class OutputWriteError(OSError):
    """The result could not be written (disk full, no permission); nothing was replaced."""


@dataclass(frozen=True)
class OutputKind:
    """What fusion writes into one kind of target."""

    name: str
    earlier: Callable[[Path], frozenset[str]]
    """The entries of a directory that an earlier output of this kind holds."""
    writes: Callable[[str], bool]
    """Whether fusion may write an entry of this name into such a target."""


RESULT_FILES = frozenset(
    ["solution.csv", "smoothed.csv", "states.csv", "metrics.json", "faults.csv", RUN_JSON]
    + [f"{stem}.{ext}" for stem in ("plan", "errors", "observability") for ext in FIGURE_FORMATS]
)
"""Every file name a result of ``fusion run`` may hold (the figures in every format)."""


def _result_entries(path: Path) -> frozenset[str]:
    """``run.json`` and the files it lists, those present; nothing without a readable one."""
    try:
        listed = json.loads((path / RUN_JSON).read_text(encoding="utf-8"))["files"]
        names = {RUN_JSON, *(n for n in listed if isinstance(n, str))}
    except (OSError, ValueError, KeyError, TypeError):
        return frozenset()
    return frozenset(names & set(_entries(path)))


def _recording_entries(path: Path) -> frozenset[str]:
    """The recording files, when a ``meta.yaml`` says the directory holds a recording."""
    if not (path / "meta.yaml").is_file():
        return frozenset()
    return frozenset(RECORDING_FILES & set(_entries(path)))


def _demo_entries(path: Path) -> frozenset[str]:
    """``recording/`` and ``result/`` when each holds nothing but an earlier one of its kind."""
    found = set()
    for name, kind in zip(DEMO_ENTRIES, (RECORDING, RESULT), strict=True):
        entry = path / name
        if entry.is_dir() and not entry.is_symlink():
            inside = set(_entries(entry))
            if inside and inside == kind.earlier(entry):
                found.add(name)
    return frozenset(found)


RESULT = OutputKind("result", _result_entries, RESULT_FILES.__contains__)
"""The result of ``fusion run``, recognised by its ``run.json``."""
RECORDING = OutputKind("recording", _recording_entries, RECORDING_FILES.__contains__)
"""A recording written by ``fusion simulate`` or ``fusion import``."""
DEMO = OutputKind("demo", _demo_entries, frozenset(DEMO_ENTRIES).__contains__)
"""The output of ``fusion demo``: ``recording/`` and ``result/``."""


class OutputTarget:
    """A directory about to be written whole (see the module docstring).

    Creating one checks the target at once, before any work is done, so a refused target costs
    nothing; :meth:`staging` checks it again just before the swap.

    Raises
    ------
    OutputRefused
        ``path`` is not a directory (nor can become one), holds a file fusion did not write
        under a name it writes, or holds an earlier output and ``force`` is not given.
    """

    def __init__(self, path: str | Path, *, force: bool, kind: OutputKind) -> None:
        self.shown = str(path)
        self.path = Path(path).resolve()
        self.force = force
        self.kind = kind
        self.earlier: frozenset[str] = frozenset()
        self.others: frozenset[str] = frozenset()
        self.had_result = self._check()

    def _check(self) -> bool:
        """Whether the target holds an earlier result; raise when it may not be replaced."""
        if not self.path.exists():
            ancestor = next(a for a in self.path.parents if a.exists())
            if not ancestor.is_dir():
                raise OutputRefused(
                    f"{self.shown}: cannot be created, {ancestor} is not a directory"
                )
            return False
        if not self.path.is_dir():
            raise OutputRefused(f"{self.shown}: exists and is not a directory")
        entries = set(_entries(self.path))
        self.earlier = self.kind.earlier(self.path)
        self.others = frozenset(entries - self.earlier)
        clash = sorted(name for name in self.others if self.kind.writes(name))
        if clash:
            raise OutputRefused(
                f"{self.shown}: holds {clash[0]!r}, which fusion did not write and would"
                " overwrite; move it or choose another directory"
            )
        if self.earlier and not self.force:
            raise OutputRefused(
                f"{self.shown}: holds an earlier {self.kind.name}; give --force to replace it"
            )
        return bool(self.earlier)

    def kept(self) -> str:
        """What the target holds when nothing new was written."""
        if self.had_result:
            return f"{self.shown} still holds the earlier result"
        return f"{self.shown} unchanged (no earlier result)"

    def final(self, staged: Path, staging: Path) -> Path:
        """Where a file written at ``staged`` inside ``staging`` is once swapped in."""
        return Path(self.shown) / staged.relative_to(staging)

    @contextmanager
    def staging(self) -> Iterator[Path]:
        """A new empty directory beside the target to write into; swapped in on a normal exit.

        Any exception deletes it and leaves the target as it was. Ctrl-C becomes a
        ``KeyboardInterrupt`` whose message says what was kept; an ``OSError`` becomes an
        :class:`OutputWriteError` saying the same.
        """
        self._delete_leftovers()
        try:
            staging = self._new_staging()
        except OSError as exc:
            raise self._write_error(exc) from None
        try:
            yield staging
            self._check()  # unchanged since the start? (a foreign file may have appeared)
            clash = sorted(self.others & {entry.name for entry in staging.iterdir()})
            if clash:
                raise OutputRefused(f"{self.shown}: holds {clash[0]!r}, which fusion did not write")
        except KeyboardInterrupt:
            shutil.rmtree(staging, ignore_errors=True)
            raise KeyboardInterrupt(f"nothing written; {self.kept()}") from None
        except OSError as exc:
            shutil.rmtree(staging, ignore_errors=True)
            raise self._write_error(exc) from None
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        try:
            self._swap(staging)
        except OSError as exc:
            shutil.rmtree(staging, ignore_errors=True)
            raise self._write_error(exc) from None
        except KeyboardInterrupt:  # held during the swap, delivered once it is done
            raise KeyboardInterrupt(f"{self.shown} holds the new result") from None

    def _write_error(self, exc: OSError) -> OutputWriteError:
        where = f" ({exc.filename})" if exc.filename else ""
        return OutputWriteError(
            f"{self.shown}: cannot write the result: {exc.strerror or exc}{where};"
            f" nothing written, {self.kept()}"
        )

    def _new_staging(self) -> Path:
        """An empty staging directory beside the target, or inside an existing target whose
        parent cannot be written."""
        beside = self.path.parent / f".{self.path.name}.staging-{os.getpid()}"
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            beside.mkdir()
            return beside
        except OSError:
            if not self.path.is_dir():
                raise
        inside = self.path / f".fusion-staging-{os.getpid()}"
        inside.mkdir()
        return inside

    def _swap(self, staging: Path) -> None:
        """Put ``staging`` in place with SIGINT held: by rename, or file by file where a rename
        cannot (see the module docstring); the target is restored when a rename fails."""
        held = hasattr(signal, "pthread_sigmask")
        if held:
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            if staging.parent == self.path or self.others:
                self._move_into(staging)
            else:
                try:
                    self._rename_into(staging)
                except OSError as exc:
                    if exc.errno not in (errno.EXDEV, errno.EBUSY) or not self.path.is_dir():
                        raise
                    self._move_into(staging)
        finally:
            if held:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})

    def _rename_into(self, staging: Path) -> None:
        """Replace the target by ``staging`` with renames (the earlier result set aside first)."""
        if not self.path.exists() or not _entries(self.path):
            os.rename(staging, self.path)  # replaces an empty directory atomically
            return
        aside = self.path.parent / f".{self.path.name}.replaced-{os.getpid()}"
        os.rename(self.path, aside)
        try:
            os.rename(staging, self.path)
        except OSError:
            os.rename(aside, self.path)
            raise
        shutil.rmtree(aside, ignore_errors=True)

    def _move_into(self, staging: Path) -> None:
        """Delete the earlier output's entries (``run.json`` first), then move the staged ones
        into the target (``run.json`` last) and remove ``staging``; other files stay."""
        earlier = [self.path / name for name in self.earlier]
        for entry in sorted(earlier, key=lambda e: e.name != RUN_JSON):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
        for entry in sorted(staging.iterdir(), key=lambda e: e.name == RUN_JSON):
            shutil.move(entry, self.path / entry.name)
        staging.rmdir()

    def _delete_leftovers(self) -> None:
        """Delete the hidden directories of earlier writes to this target whose process is gone."""
        beside = re.compile(rf"\.{re.escape(self.path.name)}\.(?:staging|replaced)-(\d+)")
        for folder, pattern in ((self.path.parent, beside), (self.path, INSIDE_STAGING)):
            if not folder.is_dir():
                continue
            for entry in folder.iterdir():
                match = pattern.fullmatch(entry.name)
                if match and entry.is_dir() and not _alive(int(match.group(1))):
                    shutil.rmtree(entry, ignore_errors=True)


def _entries(path: Path) -> list[str]:
    """The names in directory ``path`` except the staging directories fusion makes inside it."""
    return [name for name in os.listdir(path) if not INSIDE_STAGING.fullmatch(name)]


def _alive(pid: int) -> bool:
    """Whether another live process has this PID (this process's own leftovers are stale)."""
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
