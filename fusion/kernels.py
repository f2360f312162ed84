"""numba-compiled forms of the scalar earth and attitude functions, for the compiled hot loops.

The functions of :mod:`fusion.earth` and :mod:`fusion.attitude` are written as plain arithmetic,
so they compile unchanged; this module compiles each once (cached on disk) for the strapdown and
error-model kernels, and adds the two 3-vector helpers those kernels need.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from fusion import attitude, earth

radii = numba.njit(cache=True)(earth.radii)
normal_gravity = numba.njit(cache=True)(earth.normal_gravity)
gravity_dlat = numba.njit(cache=True)(earth.normal_gravity_latitude_gradient)
gravity_dh = numba.njit(cache=True)(earth.normal_gravity_height_gradient)
quat_multiply = numba.njit(cache=True)(attitude.quat_multiply)
quat_from_rotvec = numba.njit(cache=True)(attitude.quat_from_rotvec)
dcm_from_quat = numba.njit(cache=True)(attitude.dcm_from_quat)


@numba.njit(cache=True)
def cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a × b`` of two 3-vectors."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


@numba.njit(cache=True)
def skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(v×)`` of a 3-vector."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@numba.njit(cache=True)
def frame_rates(
    lat: float, height: float, v: NDArray[np.float64]
) -> tuple[float, float, NDArray[np.float64], NDArray[np.float64]]:
    """``R_M+h``, ``R_N+h``, the earth rate ``ω_ie^n`` and the transport rate ``ω_en^n``.

    ``ω_ie^n = Ω [0, cos L, sin L]``, ``ω_en^n = [−v_N/(R_M+h), v_E/(R_N+h), v_E tan L/(R_N+h)]``.
    """
    rm, rn = radii(lat)
    rmh, rnh = float(rm + height), float(rn + height)
    sl, cl = np.sin(lat), np.cos(lat)
    w_ie = np.array([0.0, earth.OMEGA_IE * cl, earth.OMEGA_IE * sl])
    w_en = np.array([-v[1] / rmh, v[0] / rnh, v[0] * sl / cl / rnh])
    return rmh, rnh, w_ie, w_en
