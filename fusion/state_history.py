"""The history of every estimated state and its 1-σ at the output epochs (``states.csv``).

Beside the trajectory, users of KF-GINS and pyins expect how each estimated state and its
uncertainty evolved: the biases converging, an odometer's scale factor, a magnetometer's hard
iron. At every output epoch the engine hands the filter's estimate and covariance over the whole
layout (the fused ones for the federated filter) to a :class:`StateRecorder`; the run's
:class:`StateHistory` (``RunResult.states``) joins them with the solution's nominal trajectory.

Columns of ``states.csv`` and of :meth:`StateHistory.to_pandas`, the unit in each name:

* ``t``: epoch (s, recording clock), the key shared with ``solution.csv``;
* ``lat_deg, lon_deg, h_m``: WGS84 latitude, longitude and ellipsoidal height, from the ENU
  position about the recording's origin (meta.yaml); ``e_m, n_m, u_m``; ``ve_m_s, vn_m_s, vu_m_s``;
  ``roll_deg, pitch_deg, yaw_deg``: the nominal state, ``solution.csv``'s in other units;
* one column per other estimated state, ``<block>_<label>_<unit>`` with the block's dots as
  underscores and the label left out of a one-state block (``gyro_bias_z_deg_h``,
  ``accel_bias_x_mg``, ``odometer_scale_error_ppm``, ``magnetometer_hard_iron_x_uT``); the IMU
  biases are the whole estimate, the part the SINS already compensates included;
* ``sigma_<column>``: its 1-σ, for the position (local ENU axes, ``solution.csv``'s σ), the
  velocity, the attitude (roll, pitch and yaw, from the misalignment's covariance) and every
  state of the previous item.

Memory: the history keeps per output epoch the σ of every state, the estimate of the states
that are not navigation errors and three attitude cross-covariances, in float32 (7 significant
digits, as many as a σ or a bias has; the nominal trajectory stays the solution's float64).
At output at every filter epoch that is 4·(2n − 6) bytes a row for n states: an 8-hour shift
at 200 Hz and 20 states holds 0.8 GB (1.6 GB in float64), less than the solution's own rows.
The file is formatted in blocks of :data:`WRITE_ROWS` rows. Measurements and the choices not
made (decimation, streaming): ``docs/design/2026-11-27-state-history.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from fusion.attitude import euler_jacobian
from fusion.earth import LocalFrame
from fusion.error_model import ATTITUDE, POSITION, STATE_UNITS, VELOCITY, StateBlock, StateLayout
from fusion.recording import csv_text_chunks
from fusion.rows import RowBuffer
from fusion.solution import Solution, require_pandas

if TYPE_CHECKING:
    import pandas as pd

NAVIGATION = (VELOCITY, ATTITUDE, POSITION)
"""Error-state blocks of the nominal trajectory: shown through it, their σ beside it."""
NOMINAL_COLUMNS = (
    "t",
    "lat_deg",
    "lon_deg",
    "h_m",
    "e_m",
    "n_m",
    "u_m",
    "ve_m_s",
    "vn_m_s",
    "vu_m_s",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
)
"""The first columns of ``states.csv``."""
WRITE_ROWS = 65536
"""Rows converted to user units and formatted at once when writing ``states.csv``."""
_DEG = STATE_UNITS["deg"]
_CROSS = ((0, 1), (0, 2), (1, 2))
"""The attitude covariances kept beside the σ: P_en, P_eu, P_nu."""


def column_name(block: str, label: str, size: int, unit: str) -> str:
    """``<block>_<label>_<unit>`` of one state (no label in a one-state block, no unit when
    the block declares none), e.g. ``gyro_bias_z_deg_h``."""
    parts = [block.replace(".", "_")] + ([label] if size > 1 else []) + ([unit] if unit else [])
    return "_".join(parts)


def _own_states(layout: StateLayout) -> list[tuple[int, StateBlock, str]]:
    """Index, block and label of every state that is not a navigation error (biases, plugin
    states): those with an estimate column."""
    return [
        (layout.slice(b.name).start + k, b, label)
        for b in layout.blocks
        if b.name not in NAVIGATION
        for k, label in enumerate(b.labels)
    ]


@dataclass(frozen=True, eq=False)
class StateHistory:
    """Every estimated state and its 1-σ at a run's output epochs (see the module).

    Attributes
    ----------
    solution
        The nominal trajectory at the same epochs (the run's forward solution).
    frame
        The recording's origin (geodetic columns).
    layout
        The run's states; :attr:`StateLayout.labels` names them (``"gyro_bias.z"``).
    sigma : ndarray, shape (N, layout.dim), float32
        1-σ of every state in its own unit (SI), layout order.
    estimate : ndarray, shape (N, len(estimated)), float32
        Estimates of the states :attr:`estimated` names, in their own unit (SI).
    attitude_covariance : ndarray, shape (N, 3), float32
        ``P_en, P_eu, P_nu`` of the attitude misalignment φ (rad²).
    """

    solution: Solution
    frame: LocalFrame
    layout: StateLayout
    sigma: NDArray[np.float32]
    estimate: NDArray[np.float32]
    attitude_covariance: NDArray[np.float32]

    def __post_init__(self) -> None:
        n = len(self.solution)
        shapes = {
            "sigma": (n, self.layout.dim),
            "estimate": (n, len(self.estimated)),
            "attitude_covariance": (n, 3),
        }
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {getattr(self, name).shape}")

    @property
    def t(self) -> NDArray[np.float64]:
        """Epochs (s, recording clock)."""
        return self.solution.t

    @property
    def estimated(self) -> tuple[str, ...]:
        """Labels of the states with an estimate column: every state but the navigation errors."""
        return tuple(f"{b.name}.{label}" for _, b, label in _own_states(self.layout))

    def __len__(self) -> int:
        """Number of epochs."""
        return len(self.solution)

    def sigma_of(self, label: str) -> NDArray[np.float32]:
        """1-σ over time of one state (its own unit), e.g. ``"gyro_bias.z"``."""
        return self.sigma[:, self._index(self.layout.labels, label)]

    def estimate_of(self, label: str) -> NDArray[np.float32]:
        """Estimate over time of one state that is not a navigation error (its own unit)."""
        return self.estimate[:, self._index(self.estimated, label)]

    @staticmethod
    def _index(labels: list[str] | tuple[str, ...], label: str) -> int:
        try:
            return list(labels).index(label)
        except ValueError:
            raise KeyError(f"no state {label!r}; the history has {list(labels)}") from None

    def column_names(self) -> list[str]:
        """Names of the columns of ``states.csv``, in order."""
        names = list(NOMINAL_COLUMNS)
        own = [
            column_name(b.name, label, b.size, b.unit) for _, b, label in _own_states(self.layout)
        ]
        names += own
        names += ["sigma_" + c for c in NOMINAL_COLUMNS[4:]]
        return names + ["sigma_" + c for c in own]

    def columns(self, rows: slice = slice(None)) -> dict[str, NDArray[np.floating]]:
        """The table of ``states.csv`` over ``rows`` (user units): name → column."""
        sol, layout = self.solution, self.layout
        position = sol.position[rows]
        lat, lon, height = self.frame.to_geodetic(position)
        sigma = self.sigma[rows]
        values = [sol.t[rows], np.rad2deg(lat), np.rad2deg(lon), height, *position.T]
        values += [*sol.velocity[rows].T, *np.rad2deg(sol.attitude[rows]).T]
        own = _own_states(layout)
        factors = np.array([STATE_UNITS[b.unit] for _, b, _ in own], dtype=np.float32)
        values += [*(self.estimate[rows] * factors).T]
        values += [*sigma[:, layout.slice(POSITION)].T, *sigma[:, layout.slice(VELOCITY)].T]
        values += [*self.euler_sigma(rows).T]
        values += [*(sigma[:, [i for i, _, _ in own]] * factors).T]
        return dict(zip(self.column_names(), values, strict=True))

    def euler_sigma(self, rows: slice = slice(None)) -> NDArray[np.float32]:
        """1-σ of roll, pitch, yaw (deg) from the misalignment's covariance: ``J P_φ Jᵀ``."""
        attitude = self.layout.slice(ATTITUDE)
        variance = np.square(self.sigma[rows, attitude].astype(np.float64))
        covariance = np.einsum("ni,ij->nij", variance, np.eye(3))
        for k, (i, j) in enumerate(_CROSS):
            covariance[:, i, j] = covariance[:, j, i] = self.attitude_covariance[rows, k]
        jacobian = euler_jacobian(self.solution.attitude[rows])
        euler = np.einsum("nij,njk,nik->ni", jacobian, covariance, jacobian)
        return (np.sqrt(euler) * _DEG).astype(np.float32)

    def to_pandas(self) -> pd.DataFrame:
        """The table of ``states.csv`` as a DataFrame (:meth:`column_names`).

        Raises
        ------
        ImportError
            Without pandas (``pip install 'shearer-fusion[pandas]'``).
        """
        pandas = require_pandas()
        return pandas.DataFrame(self.columns())


class StateRecorder:
    """The engine's hook: one row per output epoch, taken as a :class:`StateHistory` at the end.

    Parameters
    ----------
    layout
        The run's states.
    """

    def __init__(self, layout: StateLayout) -> None:
        self.layout = layout
        self._estimated = np.array([i for i, _, _ in _own_states(layout)], dtype=np.intp)
        a = layout.slice(ATTITUDE).start
        self._cross = (
            np.array([a + i for i, _ in _CROSS], dtype=np.intp),
            np.array([a + j for _, j in _CROSS], dtype=np.intp),
        )
        self._rows = RowBuffer((layout.dim + self._estimated.size + len(_CROSS),), "f")

    def record(self, estimate: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """Note one output epoch: the estimate (IMU biases whole, SINS part included) and the
        covariance over the layout."""
        row = np.concatenate(
            [
                np.sqrt(np.diagonal(covariance)),
                estimate[self._estimated],
                covariance[self._cross],
            ]
        )
        self._rows.append(row)

    def history(self, solution: Solution, frame: LocalFrame) -> StateHistory:
        """The rows recorded (one per epoch of ``solution``); the recorder is left empty."""
        rows = self._rows.take()
        dim, k = self.layout.dim, self._estimated.size
        return StateHistory(
            solution=solution,
            frame=frame,
            layout=self.layout,
            sigma=rows[:, :dim],
            estimate=rows[:, dim : dim + k],
            attitude_covariance=rows[:, dim + k :],
        )


def write_states(history: StateHistory, path: str | Path) -> None:
    """Write ``states.csv`` (see the module for its columns); the nominal columns exact
    (``repr``), the others to 7 significant digits."""
    names = history.column_names()
    kinds = "f" * len(NOMINAL_COLUMNS) + "g" * (len(names) - len(NOMINAL_COLUMNS))
    with open(path, "wb") as fh:
        for start in range(0, max(len(history), 1), WRITE_ROWS):
            block = history.columns(slice(start, start + WRITE_ROWS))
            chunks = iter(csv_text_chunks(names, list(block.values()), kinds))
            if start:
                next(chunks)  # the header, written with the first block
            fh.writelines(chunks)
