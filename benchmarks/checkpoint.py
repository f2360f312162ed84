"""Finished tasks of a suite run kept on disk, so that an interrupted run resumes (``--resume``).

The full-length ``robustness`` suite runs fifteen configurations on twenty worlds of 30–100
minutes: hours of two cores. A run stopped half-way (a session, a reboot, a killed job) kept
nothing. Now each task's :class:`~benchmarks.runner.TaskResult` is written to
``OUT/tasks/<key>.pkl`` as soon as it finishes, ``key`` the SHA-256 of the task's ``repr`` (its
scenario, overrides, seed and methods), and ``OUT/tasks/source.json`` holds the fingerprint of
the sources that produced them: the SHA-256 over the ``fusion`` and ``benchmarks`` packages'
Python files and every file under ``configs/`` (:func:`source_fingerprint`).

A run without ``--resume`` starts from an empty store. With ``--resume`` the stored results of
this run's tasks are taken as they stand and only the others run; a store written by other
sources is refused (:class:`~benchmarks.runner.BenchmarkError` naming the directory), so that
results of two versions of the code never meet in one table. The store is removed once the
suite's outputs are written.

The pickles are the run's own files, read back only from the output directory the user named.
"""

from __future__ import annotations

import hashlib
import json
import pickle
import shutil
from collections.abc import Sequence
from pathlib import Path

from benchmarks.report import BENCH_DIR
from benchmarks.runner import BenchmarkError, Task, TaskResult

REPO = BENCH_DIR.parent
FINGERPRINTED = (("fusion", "*.py"), ("benchmarks", "*.py"), ("configs", "*"))
"""(directory under the repository, glob) of the files whose content the results depend on."""
MANIFEST = "source.json"


def source_fingerprint(root: Path = REPO) -> str:
    """SHA-256 over the relative paths and contents of the files in :data:`FINGERPRINTED`."""
    digest = hashlib.sha256()
    for directory, pattern in FINGERPRINTED:
        for path in sorted((root / directory).rglob(pattern)):
            if path.is_file() and "__pycache__" not in path.parts:
                digest.update(path.relative_to(root).as_posix().encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()


def task_key(task: Task) -> str:
    """File stem of a task's stored result: the SHA-256 of its ``repr``."""
    return hashlib.sha256(repr(task).encode()).hexdigest()[:32]


class TaskStore:
    """The finished tasks of one suite run under ``directory``.

    Parameters
    ----------
    directory
        ``OUT/tasks`` of the suite's output directory.
    resume
        Keep what a run of the same sources stored there (else start empty).
    fingerprint
        The sources' fingerprint (default: :func:`source_fingerprint` of this checkout).
    """

    def __init__(self, directory: Path, resume: bool, fingerprint: str | None = None) -> None:
        self.directory = directory
        self.fingerprint = source_fingerprint() if fingerprint is None else fingerprint
        manifest = directory / MANIFEST
        if resume and manifest.exists():
            stored = json.loads(manifest.read_text(encoding="utf-8")).get("fingerprint")
            if stored != self.fingerprint:
                raise BenchmarkError(
                    f"--resume: the results in {directory} were computed by other sources"
                    " (fusion/, benchmarks/ or configs/ changed since); rerun without --resume"
                )
        else:
            shutil.rmtree(directory, ignore_errors=True)
        directory.mkdir(parents=True, exist_ok=True)
        manifest.write_text(json.dumps({"fingerprint": self.fingerprint}), encoding="utf-8")

    def _path(self, task: Task) -> Path:
        return self.directory / f"{task_key(task)}.pkl"

    def pending(self, tasks: Sequence[Task]) -> list[Task]:
        """The tasks without a stored result, in their order."""
        return [t for t in tasks if not self._path(t).exists()]

    def save(self, task: Task, result: TaskResult) -> None:
        """Store one finished task (written to a temporary name, then renamed: a run killed
        while writing leaves no half file)."""
        path = self._path(task)
        partial = path.with_suffix(".partial")
        partial.write_bytes(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
        partial.replace(path)

    def results(self, tasks: Sequence[Task]) -> list[TaskResult]:
        """The stored results of ``tasks``, in their order (every one must be stored)."""
        return [pickle.loads(self._path(t).read_bytes()) for t in tasks]

    def remove(self) -> None:
        """Delete the store (the suite's outputs are written)."""
        shutil.rmtree(self.directory, ignore_errors=True)
