"""Rows of a fixed shape accumulated compactly (8 bytes per number, or 4 in float32).

An 8-hour run produces about 300 000 output epochs; kept as a Python list of small numpy
arrays each row costs ~100 bytes of object header beside its data, and the final
``np.array(list)`` briefly holds both. :class:`RowBuffer` appends the numbers to one
:class:`array.array` instead and views it as an ``(n, *shape)`` array at the end.
"""

from __future__ import annotations

from array import array
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray


class RowBuffer:
    """Growable ``(n, *shape)`` float64 (or float32) array.

    Parameters
    ----------
    shape
        Shape of one row (``()`` for scalars).
    typecode
        ``"d"`` float64, ``"f"`` float32 (an :class:`array.array` type code).
    """

    def __init__(self, shape: tuple[int, ...] = (), typecode: str = "d") -> None:
        self.shape = shape
        self._size = int(np.prod(shape, dtype=int))
        self._data = array(typecode)

    def append(self, row: ArrayLike) -> None:
        """Append one row (anything of ``shape``)."""
        values = np.asarray(row, dtype=np.float64)
        if values.shape != self.shape:
            raise ValueError(f"row of shape {values.shape}, expected {self.shape}")
        self._data.extend(values.ravel())

    def extend(self, rows: ArrayLike) -> None:
        """Append rows (anything of shape ``(n, *shape)``)."""
        values = np.asarray(rows, dtype=np.float64)
        if values.shape[1:] != self.shape:
            raise ValueError(f"rows of shape {values.shape}, expected (n, *{self.shape})")
        self._data.frombytes(np.ascontiguousarray(values, dtype=self._data.typecode).tobytes())

    def __len__(self) -> int:
        return len(self._data) // max(self._size, 1)

    def take(self) -> NDArray[Any]:
        """All rows as an ``(n, *shape)`` array without a copy (it shares the buffer's memory);
        the buffer is left empty."""
        data = self._data
        self._data = array(data.typecode)
        return np.frombuffer(data, dtype=data.typecode).reshape(-1, *self.shape)
