"""Innovation log: every update a plugin made, kept compactly and spilled to disk.

One record per update: time (float64), normalized innovation squared NIS = νᵀS⁻¹ν (float32),
degrees of freedom m (uint8), and the accepted and suspect flags (uint8): 15 bytes. The
whitened innovation w = L⁻¹ν (S = LLᵀ, :mod:`fusion.kalman`) has ‖w‖² = NIS, so the
whitened-innovation RMS over the accepted updates,

    RMS(w) = sqrt( Σ_accepted NIS_k / Σ_accepted m_k ),

needs no per-component storage; it is ≈ 1 when the filter is consistent.

An 8-hour shift logs about 4.6 million UWB ranges (≈ 70 MB of records). The log keeps the
running totals that the run summary needs (updates, rejections, Σ NIS and Σ m of the accepted)
in memory, holds the newest records in a buffer of :data:`CHUNK_RECORDS`, and appends each full
buffer to an anonymous temporary file (deleted when the log is garbage-collected or the
process ends). The record arrays are read back only when asked for (:meth:`InnovationLog.records`
and the column properties).
"""

from __future__ import annotations

import tempfile
from typing import IO

import numpy as np
from numpy.typing import NDArray

from fusion.kalman import UpdateResult

RECORD = np.dtype(
    [("t", "<f8"), ("nis", "<f4"), ("dof", "u1"), ("accepted", "u1"), ("suspect", "u1")]
)
"""One update, packed (15 bytes)."""
CHUNK_RECORDS = 1 << 16
"""Records held in memory before they are appended to the spill file (about 1 MB)."""


class InnovationLog:
    """Per-plugin record of every measurement epoch that produced a measurement."""

    def __init__(self) -> None:
        self._chunk = np.empty(CHUNK_RECORDS, RECORD)
        self._filled = 0
        self._spill: IO[bytes] | None = None
        self.count = 0
        """Updates logged."""
        self.rejected = 0
        """Updates the gate rejected."""
        self._accepted_nis = 0.0
        self._accepted_dof = 0

    def append(self, t: float, result: UpdateResult, suspect: bool) -> None:
        """Log one update."""
        self.record(t, result.nis, result.dof, result.accepted, suspect)

    def record(self, t: float, nis: float, dof: int, accepted: bool, suspect: bool) -> None:
        """Log one update from its figures (a solver that is not a Kalman update)."""
        self._chunk[self._filled] = (t, nis, dof, accepted, suspect)
        self._filled += 1
        self.count += 1
        if accepted:
            self._accepted_nis += nis
            self._accepted_dof += dof
        else:
            self.rejected += 1
        if self._filled == CHUNK_RECORDS:
            self._flush()

    def _flush(self) -> None:
        if self._spill is None:
            self._spill = tempfile.TemporaryFile(prefix="fusion-innovations-")
        self._spill.write(self._chunk[: self._filled].tobytes())
        self._filled = 0

    def whitened_rms(self) -> float:
        """RMS of all accepted whitened innovation components (≈ 1 when consistent)."""
        if self._accepted_dof == 0:
            return float("nan")
        return float(np.sqrt(self._accepted_nis / self._accepted_dof))

    def records(self) -> NDArray[np.void]:
        """Every update in time order as a structured array of :data:`RECORD`."""
        held = self._chunk[: self._filled]
        if self._spill is None:
            return held.copy()
        self._spill.seek(0)
        spilled = np.frombuffer(self._spill.read(), dtype=RECORD)
        return np.concatenate([spilled, held])

    def rejection_times(self) -> NDArray[np.float64]:
        """Times (s) of the updates the gate rejected, from one read of the records."""
        records = self.records()
        times: NDArray[np.float64] = records["t"][records["accepted"] == 0]
        return times

    def __len__(self) -> int:
        return self.count

    @property
    def t(self) -> NDArray[np.float64]:
        """Update times (s)."""
        return self.records()["t"]

    @property
    def nis(self) -> NDArray[np.float64]:
        """Normalized innovation squared of each update."""
        return self.records()["nis"].astype(np.float64)

    @property
    def dof(self) -> NDArray[np.int64]:
        """Measurement dimension of each update."""
        return self.records()["dof"].astype(np.int64)

    @property
    def accepted(self) -> NDArray[np.bool_]:
        """Whether the gate let each update through."""
        return self.records()["accepted"].astype(bool)

    @property
    def suspect(self) -> NDArray[np.bool_]:
        """Whether the plugin flagged each update (its own fault indicator)."""
        return self.records()["suspect"].astype(bool)
