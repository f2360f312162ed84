"""Give the allocator's freed heap memory back to the operating system.

glibc's malloc serves requests below a threshold from its heap, and the threshold rises (up to
32 MB) each time a larger block is freed. Reading an 8-hour recording allocates and frees many
arrays of a few to 30 MB (parse blocks, line numbers, time differences, masks); they end up in
the heap, and the holes they leave between live arrays are not returned: the process stayed
about 140 MB above what it held. ``malloc_trim(0)`` releases every free heap page. Elsewhere
(other C libraries, other systems) this is a no-op.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys
from collections.abc import Callable


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim: Callable[[int], int] = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc (musl has no malloc_trim)
        return None
    return trim


def release_freed_memory() -> None:
    """Return the free pages of the C heap to the operating system (glibc only)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)
