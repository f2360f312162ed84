"""What is at a user's input path, before anything opens it.

A directory, a named pipe, a socket, a device, a dangling symbolic link or a symbolic-link loop
named like an input file is not a file to read: opening a named pipe blocks until a writer
comes, and the others were reported as "missing" or not at all. :func:`regular_file_problem`
tells them apart without opening anything.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

__all__ = ["regular_file_problem"]

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def regular_file_problem(path: Path) -> str | None:
    """Why ``path`` cannot be read as a regular file, or None when it can (a symbolic link to a
    regular file can). The caller has checked that the entry exists (:func:`os.path.lexists`).

    Returns
    -------
    str or None
        ``"not a regular file: a directory"`` (a named pipe, a socket, a device, a dangling
        symbolic link to ..., a symbolic-link loop), or None.
    """
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        try:
            target = os.readlink(path)
        except OSError:
            return "not a regular file: it vanished while being read"
        return f"not a regular file: a dangling symbolic link to {target!r}"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "not a regular file: a symbolic-link loop"
        return f"cannot be read: {exc.strerror}"
    if stat.S_ISREG(mode):
        return None
    kind = next((name for test, name in _KINDS if test(mode)), "not a file")
    return f"not a regular file: {kind}"
