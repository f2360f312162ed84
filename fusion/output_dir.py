"""An output directory replaced whole: never half-written, never mixed, never foreign files lost.

``fusion run``, ``demo``, ``simulate`` and ``import`` write into a staging directory beside their
target (``.NAME.staging-PID``: the same filesystem) and rename it into place only once every file
in it is complete. A process killed at any moment, SIGKILL included, therefore leaves the target
as it was (the complete earlier result, or nothing), never an earlier result's files beside new
ones and never a cut or empty file under a current name.

The target (:class:`OutputTarget`) is written when it is absent or an empty directory. Anything
else is refused (:class:`OutputRefused`) unless ``force``; ``force`` replaces only what fusion
wrote, each kind recognised by its own test (:func:`foreign_to_result`,
:func:`foreign_to_recording`, :func:`foreign_to_demo`), and a directory holding one file fusion
did not write is refused even then.

The swap: an absent or empty target is replaced by one ``rename(2)``, which is atomic. A previous
result is first renamed aside (``.NAME.replaced-PID``), the staging directory renamed into place,
then the previous result deleted: a kill between the two renames leaves no result at the target
(the earlier one stays aside, hidden), never a mix. SIGINT is held during the swap, so Ctrl-C lands
before it (nothing written) or after it (the new result in place). The hidden directories of a
killed process (whose PID is gone) are deleted by the next write to the same target.

Where a rename cannot do the swap (the target is a mount point, or its parent another filesystem
or not writable: a container's output volume), the staging directory is made inside the target
(``.fusion-staging-PID``, when the parent cannot be written) and its files moved into place one by
one, ``run.json`` last, after the earlier result's files (its ``run.json`` first): a kill part-way
then leaves a directory without ``run.json``, which is no result.
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
from pathlib import Path

from fusion.recording import STREAM_COLUMNS

__all__ = [
    "FIGURE_FORMATS",
    "RECORDING_FILES",
    "RUN_JSON",
    "OutputRefused",
    "OutputTarget",
    "OutputWriteError",
    "foreign_to_demo",
    "foreign_to_recording",
    "foreign_to_result",
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

Recogniser = Callable[[Path], "str | None"]
"""Why a directory is not one fusion wrote (naming an entry), or None when it is."""


class OutputRefused(ValueError):
    """The target exists and may not be replaced; the message names it and the rule."""


class OutputWriteError(OSError):
    """The result could not be written (disk full, no permission); nothing was replaced."""


def foreign_to_result(path: Path) -> str | None:
    """None when ``path`` is a result of ``fusion run``: a ``run.json`` that lists every other
    file in the directory; else why not."""
    try:
        listed = json.loads((path / RUN_JSON).read_text(encoding="utf-8"))["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return f"it holds no readable {RUN_JSON}, so it is not a fusion result"
    return _foreign(path, set(listed) | {RUN_JSON}, "its run.json does not list")


def foreign_to_recording(path: Path) -> str | None:
    """None when ``path`` holds a ``meta.yaml`` and nothing but recording files; else why not."""
    if not (path / "meta.yaml").is_file():
        return "it holds no meta.yaml, so it is not a recording"
    return _foreign(path, RECORDING_FILES, "a recording has no such file")


def foreign_to_demo(path: Path) -> str | None:
    """None when ``path`` is the output of ``fusion demo`` (``recording/`` and ``result/``, each
    recognised as such); else why not."""
    reason = _foreign(path, set(DEMO_ENTRIES), "fusion demo writes only recording/ and result/")
    for name, test in zip(DEMO_ENTRIES, (foreign_to_recording, foreign_to_result), strict=True):
        if reason is None and (path / name).exists():
            inner = test(path / name) if (path / name).is_dir() else "it is not a directory"
            reason = None if inner is None else f"{name}/: {inner}"
    return reason


def _foreign(path: Path, allowed: set[str] | frozenset[str], rule: str) -> str | None:
    extra = sorted(set(_entries(path)) - allowed)
    return f"it holds {extra[0]!r}, which fusion did not write ({rule})" if extra else None


class OutputTarget:
    """A directory about to be written whole (see the module docstring).

    Creating one checks the target at once, before any work is done, so a refused target costs
    nothing; :meth:`staging` checks it again just before the swap.

    Raises
    ------
    OutputRefused
        ``path`` is not a directory, or is a non-empty one and ``force`` is not given, or
        ``force`` is given and ``foreign`` finds something fusion did not write.
    """

    def __init__(self, path: str | Path, *, force: bool, foreign: Recogniser) -> None:
        self.shown = str(path)
        self.path = Path(path).resolve()
        self.force = force
        self.foreign = foreign
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
        if not _entries(self.path):
            return False
        if not self.force:
            raise OutputRefused(
                f"{self.shown}: directory is not empty; give --force to replace what fusion"
                " wrote there"
            )
        reason = self.foreign(self.path)
        if reason is not None:
            raise OutputRefused(
                f"{self.shown}: not replaced although --force was given: {reason};"
                " --force replaces only what fusion wrote"
            )
        return True

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
            if staging.parent == self.path:
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
        """Delete the earlier result's entries (``run.json`` first), then move the staged ones
        into the target (``run.json`` last) and remove ``staging``."""
        earlier = [self.path / name for name in _entries(self.path) if name != staging.name]
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
