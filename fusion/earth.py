"""WGS84 earth model: radii, normal gravity, earth rate, and geodetic / ECEF / ENU conversions.

Equations (NIMA TR8350.2, 3rd ed.):

* meridian and prime-vertical radii of curvature
  ``R_M = a (1 - e²) / (1 - e² sin²L)^{3/2}``, ``R_N = a / sqrt(1 - e² sin²L)``;
* normal gravity on the ellipsoid (Somigliana, eq. 4-1)
  ``γ_0 = γ_e (1 + k sin²L) / sqrt(1 - e² sin²L)``, and above it (eq. 4-3)
  ``γ(h) = γ_0 [1 - 2/a (1 + f + m - 2 f sin²L) h + 3 h² / a²]``;
* geodetic (L, λ, h) → ECEF, and ECEF → geodetic by Newton iteration on the latitude
  (converges to machine precision in a few steps for any terrestrial point);
* the ENU frame at an origin: ``C_e^n`` rows are the east, north and up unit vectors.

Every scalar function here is plain arithmetic on ``numpy`` so that it works element-wise on
arrays and also compiles unchanged under ``numba.njit`` (the strapdown kernels reuse them).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatOrArray = float | NDArray[np.float64]
"""A scalar, or an array evaluated element-wise."""

A = 6378137.0
"""Semi-major axis (m)."""
F = 1.0 / 298.257223563
"""Flattening."""
E2 = F * (2.0 - F)
"""First eccentricity squared."""
B = A * (1.0 - F)
"""Semi-minor axis (m)."""
OMEGA_IE = 7.292115e-5
"""Earth rotation rate (rad/s)."""
GM = 3.986004418e14
"""Earth's gravitational constant (m³/s²)."""
GAMMA_E = 9.7803253359
"""Normal gravity at the equator (m/s²)."""
GAMMA_K = 0.00193185265241
"""Somigliana constant k."""
GRAVITY_M = OMEGA_IE**2 * A**2 * B / GM
"""The ratio m = ω² a² b / GM of TR8350.2."""


def radii(lat: FloatOrArray) -> tuple[FloatOrArray, FloatOrArray]:
    """Return the meridian radius ``R_M`` and the prime-vertical radius ``R_N`` (m) at ``lat``."""
    s = np.sin(lat)
    w2 = 1.0 - E2 * s * s
    w = np.sqrt(w2)
    return A * (1.0 - E2) / (w2 * w), A / w


def normal_gravity(lat: FloatOrArray, height: FloatOrArray) -> FloatOrArray:
    """WGS84 normal gravity magnitude (m/s²) at geodetic latitude ``lat`` (rad), ``height`` (m)."""
    s2 = np.sin(lat) ** 2
    gamma0 = GAMMA_E * (1.0 + GAMMA_K * s2) / np.sqrt(1.0 - E2 * s2)
    return gamma0 * (
        1.0 - 2.0 / A * (1.0 + F + GRAVITY_M - 2.0 * F * s2) * height + 3.0 * height * height / A**2
    )


def normal_gravity_height_gradient(lat: float, height: float) -> float:
    """Derivative ``dγ/dh`` (1/s², negative) of :func:`normal_gravity`."""
    s2 = np.sin(lat) ** 2
    gamma0 = GAMMA_E * (1.0 + GAMMA_K * s2) / np.sqrt(1.0 - E2 * s2)
    return gamma0 * (-2.0 / A * (1.0 + F + GRAVITY_M - 2.0 * F * s2) + 6.0 * height / A**2)


def geodetic_to_ecef(lat: ArrayLike, lon: ArrayLike, height: ArrayLike) -> NDArray[np.float64]:
    """ECEF coordinates (..., 3) of geodetic points (radians, metres)."""
    lat, lon, height = np.asarray(lat), np.asarray(lon), np.asarray(height)
    _, rn = radii(lat)
    cl = np.cos(lat)
    return np.stack(
        [
            (rn + height) * cl * np.cos(lon),
            (rn + height) * cl * np.sin(lon),
            (rn * (1.0 - E2) + height) * np.sin(lat),
        ],
        axis=-1,
    )


def ecef_to_geodetic(r_e: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """Geodetic latitude, longitude (rad) and height (m) of ECEF points ``r_e`` (..., 3)."""
    r = np.asarray(r_e, dtype=float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    lat = np.arctan2(z, p * (1.0 - E2))
    for _ in range(6):
        _, rn = radii(lat)
        height = p / np.cos(lat) - rn
        lat = np.arctan2(z, p * (1.0 - E2 * rn / (rn + height)))
    _, rn = radii(lat)
    height = p * np.cos(lat) + z * np.sin(lat) - A * A / rn
    return lat, lon, height


def ecef_to_enu_matrix(lat: float, lon: float) -> NDArray[np.float64]:
    """Rotation ``C_e^n`` from ECEF to the local East-North-Up frame at (lat, lon)."""
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


class LocalFrame:
    """ENU metres about a fixed geodetic origin, the positions of the recording contract.

    Parameters
    ----------
    lat_deg, lon_deg, height_m
        Geodetic origin (degrees, metres).
    """

    def __init__(self, lat_deg: float, lon_deg: float, height_m: float) -> None:
        self.lat0 = np.deg2rad(lat_deg)
        self.lon0 = np.deg2rad(lon_deg)
        self.height0 = float(height_m)
        self.r0_e = geodetic_to_ecef(self.lat0, self.lon0, self.height0)
        self.c_e_n = ecef_to_enu_matrix(self.lat0, self.lon0)
        self._point: (
            tuple[tuple[float, float, float], NDArray[np.float64], NDArray[np.float64]] | None
        ) = None

    def to_enu(self, lat: ArrayLike, lon: ArrayLike, height: ArrayLike) -> NDArray[np.float64]:
        """ENU metres (..., 3) of geodetic points (radians, metres).

        Element by element (no matrix product, whose kernels round a row differently with the
        array's size): a point's coordinates are the same bits alone or in any array, so that
        rows computed apart (a smoother's window, the whole forward track) compare exactly."""
        d = geodetic_to_ecef(lat, lon, height) - self.r0_e
        c = self.c_e_n
        return np.stack(
            [d[..., 0] * c[i, 0] + d[..., 1] * c[i, 1] + d[..., 2] * c[i, 2] for i in range(3)],
            axis=-1,
        )

    def point(
        self, lat: float, lon: float, height: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`to_enu` and :meth:`rotation_to_local` of one point, remembering the last one:
        the updates of one epoch (a round of UWB ranges, a stacked CPOEM point) all ask for the
        same nominal position. Copies, so that a caller may modify them."""
        key, memo = (lat, lon, height), self._point  # one read: safe beside other threads
        if memo is None or memo[0] != key:
            memo = self._point = (
                key,
                self.to_enu(lat, lon, height),
                ecef_to_enu_matrix(lat, lon) @ self.c_e_n.T,  # rotation_to_local, no loop
            )
        return memo[1].copy(), memo[2].copy()

    def to_geodetic(self, enu: ArrayLike) -> tuple[NDArray[np.float64], ...]:
        """Geodetic latitude, longitude (rad) and height (m) of ENU points (..., 3)."""
        return ecef_to_geodetic(np.asarray(enu, dtype=float) @ self.c_e_n + self.r0_e)

    def rotation_to_local(self, lat: ArrayLike, lon: ArrayLike) -> NDArray[np.float64]:
        """Rotation (..., 3, 3) from the origin's ENU axes to the local ENU axes at (lat, lon)."""
        lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
        local = np.stack(
            [ecef_to_enu_matrix(a, b) for a, b in zip(lat.ravel(), lon.ravel(), strict=True)]
        ).reshape(*lat.shape, 3, 3)
        return local @ self.c_e_n.T


def normal_gravity_latitude_gradient(lat: float, height: float) -> float:
    """Derivative ``dγ/dL`` (m/s² per rad) of :func:`normal_gravity`."""
    s = np.sin(lat)
    c = np.cos(lat)
    s2 = s * s
    w2 = 1.0 - E2 * s2
    gamma0 = GAMMA_E * (1.0 + GAMMA_K * s2) / np.sqrt(w2)
    dgamma0 = (
        GAMMA_E * 2.0 * s * c * (GAMMA_K / np.sqrt(w2) + (1.0 + GAMMA_K * s2) * 0.5 * E2 / w2**1.5)
    )
    factor = 1.0 - 2.0 / A * (1.0 + F + GRAVITY_M - 2.0 * F * s2) * height + 3.0 * height**2 / A**2
    dfactor = 8.0 * F * s * c * height / A
    return dgamma0 * factor + gamma0 * dfactor
