"""Test support for plugins: a measurement context whose SINS state carries a chosen error.

A plugin's H is tested against numerical differentiation of its full nonlinear measurement
function through a perturbed SINS state. :func:`perturbed_context` builds the context the engine
would hand the plugin when the nominal SINS state is the truth plus the error ``dx``:
``ṽ = v + δv``, ``C̃_b^n = (I − φ×) C_b^n`` (exactly, through the rotation vector −φ) and
``p̃ = p + δp`` (local metres, converted through the recording frame). Plugin states in ``dx``
are not applied here — they are parameters of the truth, which each test perturbs itself.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from fusion.attitude import dcm_from_quat, quat_from_rotvec
from fusion.earth import LocalFrame
from fusion.error_model import ImuNoise, StateBlock, StateLayout, common_blocks
from fusion.plugin import MeasurementContext

FRAME = LocalFrame(34.0, 117.0, 40.0)


def layout_with(blocks: tuple[StateBlock, ...]) -> StateLayout:
    """The common 15 states followed by ``blocks``."""
    imu = ImuNoise(1e-4, 1e-3, 1e-5, 1e-3)
    return StateLayout(common_blocks(imu, [1.0] * 3, [0.01] * 3, [1.0] * 3)).extended(blocks)


def perturbed_context(
    layout: StateLayout,
    dx: NDArray[np.float64],
    *,
    t: float = 0.5,
    position_enu: NDArray[np.float64] | None = None,
    velocity: NDArray[np.float64] | None = None,
    c_b_n: NDArray[np.float64] | None = None,
    x: NDArray[np.float64] | None = None,
    covariance: NDArray[np.float64] | None = None,
    frame: LocalFrame = FRAME,
) -> MeasurementContext:
    """Context of a SINS whose state is the truth plus the common-state error ``dx[:9]``.

    The position error is in the local level axes at the true point; at the short distances of
    these tests they coincide with the frame's ENU axes to better than 1e-4 rad.
    """
    p = np.zeros(3) if position_enu is None else np.asarray(position_enu, dtype=float)
    v = np.zeros(3) if velocity is None else np.asarray(velocity, dtype=float)
    c = np.eye(3) if c_b_n is None else np.asarray(c_b_n, dtype=float)
    lat, lon, height = frame.to_geodetic(p + dx[6:9])
    return MeasurementContext(
        t=t,
        lat=float(lat),
        lon=float(lon),
        height=float(height),
        velocity=v + dx[0:3],
        c_b_n=dcm_from_quat(quat_from_rotvec(-dx[3:6])) @ c,
        layout=layout,
        x=np.zeros(layout.dim) if x is None else x,
        covariance=layout.initial_covariance() if covariance is None else covariance,
        frame=frame,
    )


def numerical_jacobian(
    residual: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    dim: int,
    steps: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Central-difference Jacobian of ``residual(dx)`` at zero, column j with step ``steps[j]``
    (a zero step leaves the column zero)."""
    columns = []
    for j in range(dim):
        dx = np.zeros(dim)
        if steps[j] == 0.0:
            columns.append(np.zeros_like(residual(dx)))
            continue
        dx[j] = steps[j]
        zp = residual(dx)
        dx[j] = -steps[j]
        zm = residual(dx)
        columns.append((zp - zm) / (2 * steps[j]))
    return np.stack(columns, axis=-1)
