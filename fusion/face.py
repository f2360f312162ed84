"""The surveyed face line: along-face and across-face coordinates of a longwall.

meta.yaml's ``face.ends_enu_m`` gives the two surveyed face-end points A and B of the first
cycle (origin ENU). The face line is their horizontal direction: unit vector ``a`` from A to
B, horizontal normal ``n = (a_N, −a_E, 0)`` and length ``L = ‖(B − A)_h‖``. A point p has the
along-face coordinate ``s = a · (p − A)`` (m from end A). The shearer works between the ends
(``0 ≤ s ≤ L``) while the face advances across it cycle by cycle, so the across-face
coordinate grows without a bound the meta data give, and the along-face one stays. The face's
height at ``s`` is the straight line between the ends' heights, ``A_U + (B_U − A_U) s / L``
(``s`` held within the ends): the floor between them follows the seam, which rolls about that
line by what the meta data do not give.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.recording import FaceMeta


@dataclass(frozen=True)
class FaceLine:
    """The face line from end A to end B (see the module docstring)."""

    end_a: NDArray[np.float64]
    along: NDArray[np.float64]
    normal: NDArray[np.float64]
    length: float
    rise: float
    """Height of end B above end A (m)."""

    @classmethod
    def from_ends(cls, ends_enu: NDArray[np.float64]) -> FaceLine:
        """The line through the two surveyed ends (2 × 3, origin ENU); its length may be 0
        only if the caller checks it."""
        ends = np.asarray(ends_enu, dtype=float)
        step = ends[1] - ends[0]
        length = float(np.hypot(step[0], step[1]))
        scale = 1.0 / length if length > 0 else 0.0
        along = np.array([step[0], step[1], 0.0]) * scale
        normal = np.array([step[1], -step[0], 0.0]) * scale
        return cls(ends[0].copy(), along, normal, length, float(step[2]))

    @classmethod
    def from_meta(cls, face: FaceMeta | None) -> FaceLine | None:
        """The face line of meta.yaml's ``face`` section, or None without surveyed ends."""
        if face is None or face.ends_enu_m is None:
            return None
        line = cls.from_ends(np.array(face.ends_enu_m, dtype=float))
        return line if line.length > 0 else None

    @property
    def azimuth(self) -> float:
        """Azimuth α of the line from end A to end B (rad, clockwise from north)."""
        return float(np.arctan2(self.along[0], self.along[1]))

    def along_face(self, position_enu: NDArray[np.float64]) -> float:
        """Along-face coordinate s of an origin-ENU position (m from end A)."""
        return float(self.along @ (position_enu - self.end_a))

    def height(self, position_enu: NDArray[np.float64]) -> float:
        """The face line's height (origin ENU up, m) at the along-face coordinate of a
        position, that coordinate held within the ends."""
        if self.length <= 0.0:
            return float(self.end_a[2])
        s = min(max(self.along_face(position_enu), 0.0), self.length)
        return float(self.end_a[2]) + self.rise * s / self.length

    def reaches(self, position_enu: NDArray[np.float64], margin_m: float) -> bool:
        """Whether a position lies along the face within ``margin_m`` beyond either end."""
        s = self.along_face(position_enu)
        return -margin_m <= s <= self.length + margin_m
