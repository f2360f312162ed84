"""numba-compiled forms of the scalar earth and attitude functions, for the compiled hot loops,
and :func:`jit`, the one way the package compiles a kernel.

The functions of :mod:`fusion.earth` and :mod:`fusion.attitude` are written as plain arithmetic,
so they compile unchanged; this module compiles each once (cached on disk where numba can write,
see :func:`jit`) for the strapdown and error-model kernels, and adds the two 3-vector helpers
those kernels need.
"""

from __future__ import annotations

import functools
import inspect
import logging
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numba
import numpy as np
from numba.core.dispatcher import Dispatcher
from numpy.typing import NDArray

from fusion import attitude, earth

_log = logging.getLogger(__name__)

_Function = TypeVar("_Function", bound=Callable[..., object])


def jit(function: _Function) -> Dispatcher[_Function]:
    """``numba.njit(cache=True)(function)``, or without the on-disk cache where numba has
    nowhere to write it.

    numba caches a compiled kernel in ``NUMBA_CACHE_DIR`` when it is set, else in the
    ``__pycache__`` beside its source, else in the user's cache directory; with none of them
    writable (a read-only site-packages and no writable HOME) ``cache=True`` raises "no locator
    available" at import. The kernel is then compiled in every process instead (the same
    results, 30–60 s more on its first call), and one warning per source directory says so:
    all of fusion's kernels live in one, so a process warns once.
    """
    try:
        return numba.njit(cache=True)(function)
    except RuntimeError as exc:
        if "no locator available" not in str(exc):
            raise
    _warn_no_cache(Path(inspect.getfile(function)).parent)
    return numba.njit(function)


@functools.cache
def _warn_no_cache(source_dir: Path) -> None:
    _log.warning(
        "numba cannot cache the compiled kernels of %s (no writable NUMBA_CACHE_DIR, __pycache__"
        " or user cache directory): each process compiles them again (30-60 s on first use);"
        " set NUMBA_CACHE_DIR to a writable directory to keep them",
        source_dir,
    )


radii = jit(earth.radii)
normal_gravity = jit(earth.normal_gravity)
gravity_dlat = jit(earth.normal_gravity_latitude_gradient)
gravity_dh = jit(earth.normal_gravity_height_gradient)
quat_multiply = jit(attitude.quat_multiply)
quat_from_rotvec = jit(attitude.quat_from_rotvec)
dcm_from_quat = jit(attitude.dcm_from_quat)


@jit
def cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a × b`` of two 3-vectors."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


@jit
def skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(v×)`` of a 3-vector."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@jit
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
