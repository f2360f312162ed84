"""Exact, independent IMU truth for testing the strapdown mechanization.

This module deliberately shares **nothing** with the navigation code in ``fusion``: the WGS84
constants, normal gravity, radii of curvature, geodetic ⇄ ECEF conversions and the attitude
matrices are all re-implemented here, so that a mistake in ``fusion.earth`` or
``fusion.attitude`` cannot cancel out between the truth and the navigator.

Method
------
A trajectory is a set of closed-form functions of time: the position ``p(t)`` in ENU metres
about a fixed geodetic origin, and the roll / pitch / yaw angles ``(γ, θ, ψ)(t)`` of the
recording convention ``C_b^n = R_z(-ψ) R_x(θ) R_y(γ)`` relative to the *local* level ENU frame
at the current point. Every quantity is carried as a :class:`Jet` ``(value, d/dt, d²/dt²)`` —
forward-mode automatic differentiation, exact to rounding — so that

* ``r_e(t) = r0_e + C_n0^e p(t)`` gives the exact ECEF velocity ``v_e = ṙ_e`` and acceleration
  ``a_e = r̈_e``;
* the geodetic point ``(L, λ, h)`` of ``r_e`` is found by Newton iteration; the Jacobian of
  geodetic → ECEF has orthogonal columns ``[(R_M+h) n_e, (R_N+h) cosL e_e, u_e]`` so each Newton
  step is exact, and two Newton steps in Jet arithmetic on a converged value give exact first
  and second derivatives (Newton on truncated power series doubles the number of correct
  Taylor coefficients);
* ``C_b^e(t) = C_n^e(L, λ) C_b^n(γ, θ, ψ)`` in Jets gives ``Ω_eb^b = C_e^b Ċ_b^e`` exactly.

Kinematics (ECEF): ``f_e = a_e + 2 Ω_ie × v_e + γ(L, h) u_e`` (normal gravity
``g_e = -γ u_e`` along the ellipsoid normal), ``f^b = C_e^b f_e`` and
``ω_ib^b = C_e^b ω_ie^e + ω_eb^b``. The IMU output is the mean of these over each interval
``(t_{k-1}, t_k]`` by Gauss–Legendre quadrature, exactly like the recording contract's
``imu.csv``; the quadrature error for the band-limited signals used here (≤ 30 Hz at 100 Hz
sampling) is far below double-precision rounding.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

# --------------------------------------------------------------------------------------------
# WGS84 (NIMA TR8350.2), own copy
# --------------------------------------------------------------------------------------------
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_B = WGS84_A * (1.0 - WGS84_F)
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
WGS84_OMEGA = 7.292115e-5
WGS84_GM = 3.986004418e14
WGS84_GAMMA_E = 9.7803253359
WGS84_K = 0.00193185265241
WGS84_M = WGS84_OMEGA**2 * WGS84_A**2 * WGS84_B / WGS84_GM

Array = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# Forward-mode second-order "Jet" arithmetic
# --------------------------------------------------------------------------------------------
class Jet:
    """A value with its exact first and second time derivatives (element-wise over arrays)."""

    __slots__ = ("d", "dd", "v")

    def __init__(self, v, d=0.0, dd=0.0) -> None:
        self.v = v
        self.d = d
        self.dd = dd

    def __add__(self, o):
        if isinstance(o, Jet):
            return Jet(self.v + o.v, self.d + o.d, self.dd + o.dd)
        return Jet(self.v + o, self.d, self.dd)

    __radd__ = __add__

    def __neg__(self):
        return Jet(-self.v, -self.d, -self.dd)

    def __sub__(self, o):
        if isinstance(o, Jet):
            return Jet(self.v - o.v, self.d - o.d, self.dd - o.dd)
        return Jet(self.v - o, self.d, self.dd)

    def __rsub__(self, o):
        return Jet(o - self.v, -self.d, -self.dd)

    def __mul__(self, o):
        if isinstance(o, Jet):
            return Jet(
                self.v * o.v,
                self.d * o.v + self.v * o.d,
                self.dd * o.v + 2.0 * self.d * o.d + self.v * o.dd,
            )
        return Jet(self.v * o, self.d * o, self.dd * o)

    __rmul__ = __mul__

    def __truediv__(self, o):
        if isinstance(o, Jet):
            q = self.v / o.v
            qd = (self.d - q * o.d) / o.v
            qdd = (self.dd - 2.0 * qd * o.d - q * o.dd) / o.v
            return Jet(q, qd, qdd)
        return Jet(self.v / o, self.d / o, self.dd / o)

    def __rtruediv__(self, o):
        return Jet(o, 0.0, 0.0) / self


def jsin(x):
    if not isinstance(x, Jet):
        return np.sin(x)
    s, c = np.sin(x.v), np.cos(x.v)
    return Jet(s, c * x.d, c * x.dd - s * x.d * x.d)


def jcos(x):
    if not isinstance(x, Jet):
        return np.cos(x)
    s, c = np.sin(x.v), np.cos(x.v)
    return Jet(c, -s * x.d, -s * x.dd - c * x.d * x.d)


def jsqrt(x):
    if not isinstance(x, Jet):
        return np.sqrt(x)
    s = np.sqrt(x.v)
    sd = x.d / (2.0 * s)
    return Jet(s, sd, (x.dd - 2.0 * sd * sd) / (2.0 * s))


def harmonic(t: Array, amp: float, freq_hz: float, phase: float = 0.0) -> Jet:
    """``amp · sin(2π f t + phase)`` as a Jet of the plain time array ``t``."""
    w = 2.0 * np.pi * freq_hz
    arg = w * t + phase
    s, c = np.sin(arg), np.cos(arg)
    return Jet(amp * s, amp * w * c, -amp * w * w * s)


def polynomial(t: Array, coeffs: Sequence[float]) -> Jet:
    """``Σ c_i t^i`` as a Jet of the plain time array ``t``."""
    v = np.zeros_like(t)
    d = np.zeros_like(t)
    dd = np.zeros_like(t)
    for i, c in enumerate(coeffs):
        v = v + c * t**i
        if i >= 1:
            d = d + i * c * t ** (i - 1)
        if i >= 2:
            dd = dd + i * (i - 1) * c * t ** (i - 2)
    return Jet(v, d, dd)


def _val(x):
    return x.v if isinstance(x, Jet) else x


def _matmul(a, b):
    """3×3 (nested lists of Jets / floats) matrix product."""
    return [
        [a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3)]
        for i in range(3)
    ]


def _stack_vec(vec, attr: str, n: int) -> Array:
    out = np.empty((n, 3))
    for i in range(3):
        x = vec[i]
        out[:, i] = getattr(x, attr) if isinstance(x, Jet) else (x if attr == "v" else 0.0)
    return out


def _stack_mat(mat, attr: str, n: int) -> Array:
    out = np.empty((n, 3, 3))
    for i in range(3):
        for j in range(3):
            x = mat[i][j]
            if isinstance(x, Jet):
                out[:, i, j] = getattr(x, attr)
            else:
                out[:, i, j] = x if attr == "v" else 0.0
    return out


# --------------------------------------------------------------------------------------------
# Own earth model (works on floats, arrays and Jets)
# --------------------------------------------------------------------------------------------
def radii_of_curvature(lat):
    """Meridian ``R_M`` and prime-vertical ``R_N`` radii (m)."""
    s = jsin(lat)
    w2 = 1.0 - WGS84_E2 * s * s
    w = jsqrt(w2)
    return WGS84_A * (1.0 - WGS84_E2) / (w2 * w), WGS84_A / w


def normal_gravity(lat, h):
    """WGS84 normal gravity magnitude γ(L, h) (Somigliana + second-order height correction)."""
    s = jsin(lat)
    s2 = s * s
    g0 = WGS84_GAMMA_E * (1.0 + WGS84_K * s2) / jsqrt(1.0 - WGS84_E2 * s2)
    return g0 * (
        1.0
        - 2.0 / WGS84_A * (1.0 + WGS84_F + WGS84_M - 2.0 * WGS84_F * s2) * h
        + 3.0 * h * h / WGS84_A**2
    )


def enu_axes_ecef(lat, lon):
    """East, north, up unit vectors in ECEF (each a 3-list) at geodetic (lat, lon)."""
    sl, cl, so, co = jsin(lat), jcos(lat), jsin(lon), jcos(lon)
    east = [-so, co, 0.0]
    north = [-sl * co, -sl * so, cl]
    up = [cl * co, cl * so, sl]
    return east, north, up


def geodetic_to_ecef(lat, lon, h):
    """ECEF position (3-list) of a geodetic point."""
    _, rn = radii_of_curvature(lat)
    sl, cl, so, co = jsin(lat), jcos(lat), jsin(lon), jcos(lon)
    return [(rn + h) * cl * co, (rn + h) * cl * so, (rn * (1.0 - WGS84_E2) + h) * sl]


def _newton_step(r, lat, lon, h):
    g = geodetic_to_ecef(lat, lon, h)
    rm, rn = radii_of_curvature(lat)
    east, north, up = enu_axes_ecef(lat, lon)
    dr = [r[i] - g[i] for i in range(3)]

    def dot(u):
        return u[0] * dr[0] + u[1] * dr[1] + u[2] * dr[2]

    return (
        lat + dot(north) / (rm + h),
        lon + dot(east) / ((rn + h) * jcos(lat)),
        h + dot(up),
    )


def ecef_to_geodetic(r, guess=None, float_iterations: int = 6, jet_iterations: int = 2):
    """Geodetic (lat, lon, h) of an ECEF point by Newton iteration.

    ``r`` is a 3-list of arrays or Jets. The value is converged with plain floats first, then
    ``jet_iterations`` Newton steps in Jet arithmetic make the derivatives exact.
    """
    rv = [_val(x) for x in r]
    if guess is None:
        p = np.hypot(rv[0], rv[1])
        lat = np.arctan2(rv[2], p * (1.0 - WGS84_E2))
        lon = np.arctan2(rv[1], rv[0])
        h = np.zeros_like(p)
    else:
        lat, lon, h = (np.broadcast_to(np.asarray(g, float), np.shape(rv[0])) for g in guess)
    for _ in range(float_iterations):
        lat, lon, h = _newton_step(rv, lat, lon, h)
    if any(isinstance(x, Jet) for x in r):
        lat, lon, h = Jet(lat), Jet(lon), Jet(h)
        for _ in range(jet_iterations):
            lat, lon, h = _newton_step(r, lat, lon, h)
    return lat, lon, h


def c_n_e(lat, lon):
    """``C_n^e`` (3×3 nested list): columns are east, north, up in ECEF."""
    east, north, up = enu_axes_ecef(lat, lon)
    return [[east[i], north[i], up[i]] for i in range(3)]


def c_b_n_from_euler(roll, pitch, yaw):
    """``C_b^n = R_z(-ψ) R_x(θ) R_y(γ)`` built from elementary rotations (own implementation)."""
    cr, sr = jcos(roll), jsin(roll)
    cp, sp = jcos(pitch), jsin(pitch)
    cy, sy = jcos(yaw), jsin(yaw)
    rz = [[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]]  # R_z(-ψ)
    rx = [[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]]
    ry = [[cr, 0.0, sr], [0.0, 1.0, 0.0], [-sr, 0.0, cr]]
    return _matmul(_matmul(rz, rx), ry)


def euler_from_c_b_n(c: Array) -> Array:
    """Roll, pitch, yaw (..., 3) from ``C_b^n`` (..., 3, 3); yaw in [0, 2π)."""
    pitch = np.arcsin(np.clip(c[..., 2, 1], -1.0, 1.0))
    roll = np.arctan2(-c[..., 2, 0], c[..., 2, 2])
    yaw = np.mod(np.arctan2(c[..., 0, 1], c[..., 1, 1]), 2.0 * np.pi)
    return np.stack([roll, pitch, yaw], axis=-1)


def rotvec_from_dcm(c: Array) -> Array:
    """Rotation vector (..., 3) of rotation matrices (..., 3, 3), accurate for small angles."""
    ax = np.stack(
        [c[..., 2, 1] - c[..., 1, 2], c[..., 0, 2] - c[..., 2, 0], c[..., 1, 0] - c[..., 0, 1]],
        axis=-1,
    )
    s = 0.5 * np.linalg.norm(ax, axis=-1)
    cosang = 0.5 * (np.trace(c, axis1=-2, axis2=-1) - 1.0)
    ang = np.arctan2(s, cosang)
    scale = np.where(s > 1e-12, ang / np.where(s > 1e-12, s, 1.0), 1.0 + s * s / 6.0)
    return 0.5 * ax * scale[..., None]


# --------------------------------------------------------------------------------------------
# Trajectories
# --------------------------------------------------------------------------------------------
Terms = Sequence[tuple[float, float, float]]  # (amplitude, frequency Hz, phase rad)


def _signal(t: Array, poly: Sequence[float], terms: Terms) -> Jet:
    out = polynomial(t, poly)
    for amp, f, ph in terms:
        out = out + harmonic(t, amp, f, ph)
    return out


@dataclass
class Trajectory:
    """Closed-form trajectory: ENU position about ``origin`` and local-level Euler angles.

    ``position(t)`` returns a 3-list of Jets (E, N, U metres about the origin), ``euler(t)`` a
    3-list (roll, pitch, yaw radians), both for a plain time array ``t``.
    """

    origin_deg: tuple[float, float, float]
    position: Callable[[Array], list[Jet]]
    euler: Callable[[Array], list[Jet]]
    name: str = ""


@dataclass
class ShearerMotion:
    """Parameters of the slow shearer-like test trajectory (plus optional vibration).

    The shearer cuts along a face heading ``face_yaw_deg``: the along-face distance is
    ``s(t) = travel_m sin(2π t / travel_period_s) + ...`` (speed up to ~0.15 m/s, stopping and
    reversing at the face ends), the face bends gently (path heading changes of a few degrees),
    climbs with a slope of a few degrees, and every axis carries 0.2–2 Hz oscillations of a few
    millimetres. Attitude: pitch and roll of a few degrees with slow variation plus 0.2–2 Hz
    oscillations of 0.05–0.1°, yaw within a few degrees of the face heading.

    Vibration (off by default): *coning* — roll and pitch oscillations of ``coning_amp_deg`` at
    ``coning_hz``, 90° out of phase; *sculling* — a pitch (about body x) oscillation of
    ``sculling_amp_deg`` at ``sculling_hz`` in phase with a linear acceleration of amplitude
    ``sculling_accel`` along the face (≈ body y).
    """

    origin_deg: tuple[float, float, float] = (34.25, 108.95, -350.0)
    face_yaw_deg: float = 92.0
    travel_m: float = 72.0
    travel_period_s: float = 3400.0
    coning_amp_deg: float = 0.0
    coning_hz: float = 15.0
    sculling_amp_deg: float = 0.0
    sculling_hz: float = 22.0
    sculling_accel: float = 0.0

    def along(self, t: Array) -> Jet:
        return harmonic(t, self.travel_m, 1.0 / self.travel_period_s, 0.0) + harmonic(
            t, 0.5, 1.0 / 170.0, 0.7
        )

    def position(self, t: Array) -> list[Jet]:
        s = self.along(t)
        # lateral offset (advance direction) bending the face: path heading changes of ~4°
        w = 0.0005 * s * s + harmonic(t, 0.15, 1.0 / 1300.0, 0.2)
        up = 0.05 * s + 0.0004 * s * s + harmonic(t, 0.3, 1.0 / 900.0, 1.0)
        w = w + harmonic(t, 0.003, 0.7, 0.3) + harmonic(t, 0.0015, 1.6, 2.5)
        s = s + harmonic(t, 0.002, 1.9, 1.1) + harmonic(t, 0.003, 0.35, 0.4)
        up = up + harmonic(t, 0.004, 0.25, 0.0) + harmonic(t, 0.0015, 1.3, 2.0)
        if self.sculling_accel:
            wv = 2.0 * np.pi * self.sculling_hz
            s = s + harmonic(t, -self.sculling_accel / wv**2, self.sculling_hz, 0.0)
        a = np.deg2rad(self.face_yaw_deg)
        sa, ca = np.sin(a), np.cos(a)
        # face direction (sin a, cos a), advance (x right) direction (cos a, -sin a)
        return [s * sa + w * ca, s * ca - w * sa, up]

    def euler(self, t: Array) -> list[Jet]:
        roll = _signal(
            t,
            [-0.035],
            [(0.015, 1.0 / 1100.0, 1.57), (0.0015, 0.35, 0.0), (0.0007, 1.7, 2.2)],
        )
        pitch = _signal(
            t,
            [0.05],
            [(0.02, 1.0 / 800.0, 1.0), (0.0012, 1.3, 0.4), (0.0009, 0.2, 1.9)],
        )
        yaw = _signal(
            t,
            [np.deg2rad(self.face_yaw_deg)],
            [(0.06, 1.0 / 1700.0, 0.5), (0.0008, 0.9, 0.0), (0.0005, 2.0, 1.2)],
        )
        if self.coning_amp_deg:
            ac = np.deg2rad(self.coning_amp_deg)
            roll = roll + harmonic(t, ac, self.coning_hz, 0.0)
            pitch = pitch + harmonic(t, ac, self.coning_hz, np.pi / 2)
        if self.sculling_amp_deg:
            pitch = pitch + harmonic(t, np.deg2rad(self.sculling_amp_deg), self.sculling_hz, 0.0)
        return [roll, pitch, yaw]

    def trajectory(self) -> Trajectory:
        return Trajectory(self.origin_deg, self.position, self.euler, "shearer")


def static_trajectory(
    origin_deg=(34.25, 108.95, -350.0), position=(0.0, 0.0, 0.0), euler=(0.0, 0.0, 0.0)
) -> Trajectory:
    """Constant position and attitude."""

    def pos(t):
        return [polynomial(t, [c]) for c in position]

    def eul(t):
        return [polynomial(t, [c]) for c in euler]

    return Trajectory(tuple(origin_deg), pos, eul, "static")


# --------------------------------------------------------------------------------------------
# Pointwise kinematics and IMU synthesis
# --------------------------------------------------------------------------------------------
@dataclass
class _Origin:
    lat: float
    lon: float
    h: float
    r0: Array
    c_n0_e: Array  # 3x3 float

    @classmethod
    def from_deg(cls, origin_deg) -> _Origin:
        lat, lon, h = np.deg2rad(origin_deg[0]), np.deg2rad(origin_deg[1]), float(origin_deg[2])
        r0 = np.array([float(x) for x in geodetic_to_ecef(lat, lon, h)])
        c = np.array([[float(x) for x in row] for row in c_n_e(lat, lon)])
        return cls(lat, lon, h, r0, c)


def pointwise(traj: Trajectory, t: Array) -> dict[str, Array]:
    """Exact kinematics at the instants ``t`` (1-D array).

    Returns ``enu`` (origin ENU position), ``vel`` (local ENU velocity), ``euler``, ``lat``,
    ``lon``, ``h``, ``r_e``, ``v_e``, ``a_e``, ``f_e``, ``c_b_e``, ``w_eb_b``, ``f_b``, ``w_ib_b``.
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    o = _Origin.from_deg(traj.origin_deg)
    p = traj.position(t)
    r = [
        o.r0[i] + o.c_n0_e[i, 0] * p[0] + o.c_n0_e[i, 1] * p[1] + o.c_n0_e[i, 2] * p[2]
        for i in range(3)
    ]
    lat, lon, h = ecef_to_geodetic(r, guess=(o.lat, o.lon, o.h))
    cne = c_n_e(lat, lon)
    eul = traj.euler(t)
    cbn = c_b_n_from_euler(*eul)
    cbe = _matmul(cne, cbn)

    r_e = _stack_vec(r, "v", n)
    v_e = _stack_vec(r, "d", n)
    a_e = _stack_vec(r, "dd", n)
    cbe_v = _stack_mat(cbe, "v", n)
    cbe_d = _stack_mat(cbe, "d", n)
    cne_v = _stack_mat(cne, "v", n)
    omega = np.einsum("nji,njk->nik", cbe_v, cbe_d)  # C_e^b Ċ_b^e = (ω_eb^b ×)
    w_eb_b = 0.5 * np.stack(
        [
            omega[:, 2, 1] - omega[:, 1, 2],
            omega[:, 0, 2] - omega[:, 2, 0],
            omega[:, 1, 0] - omega[:, 0, 1],
        ],
        axis=-1,
    )
    w_ie_e = np.array([0.0, 0.0, WGS84_OMEGA])
    gam = normal_gravity(lat.v, h.v)
    f_e = a_e + 2.0 * np.cross(w_ie_e, v_e) + gam[:, None] * cne_v[:, :, 2]
    f_b = np.einsum("nji,nj->ni", cbe_v, f_e)
    w_ib_b = np.einsum("nji,j->ni", cbe_v, w_ie_e) + w_eb_b
    vel = np.einsum("nji,nj->ni", cne_v, v_e)  # C_e^n v_e
    return {
        "t": t,
        "enu": _stack_vec(p, "v", n),
        "vel": vel,
        "euler": np.stack([_val(x) for x in eul], axis=-1) * np.ones((n, 1)),
        "lat": lat.v,
        "lon": lon.v,
        "h": h.v,
        "r_e": r_e,
        "v_e": v_e,
        "a_e": a_e,
        "f_e": f_e,
        "c_b_e": cbe_v,
        "c_n_e": cne_v,
        "w_eb_b": w_eb_b,
        "f_b": f_b,
        "w_ib_b": w_ib_b,
    }


@dataclass
class Synthetic:
    """IMU samples and truth on the grid ``t``.

    ``gyro[k]`` / ``accel[k]`` are the means of ω_ib^b and f^b over ``(t[k] - dt, t[k]]`` —
    sample 0 is a genuine interval mean over the interval *before* ``t[0]``. The truth is at
    ``t[k]``: ``position_enu`` about the origin, ``velocity`` in the local ENU frame,
    ``attitude`` (roll, pitch, yaw; yaw in [0, 2π)), ``lat``/``lon`` (rad), ``height`` (m).
    """

    t: Array
    gyro: Array
    accel: Array
    position_enu: Array
    velocity: Array
    attitude: Array
    lat: Array
    lon: Array
    height: Array
    origin_deg: tuple[float, float, float]


def synthesize(
    traj: Trajectory,
    duration_s: float,
    rate_hz: float = 100.0,
    t0: float = 0.0,
    nodes: int = 6,
    chunk: int = 20000,
) -> Synthetic:
    """IMU interval means and truth for ``traj`` over ``[t0, t0 + duration_s]``."""
    dt = 1.0 / rate_hz
    n = round(duration_s * rate_hz) + 1
    t: Array = t0 + dt * np.arange(n, dtype=np.float64)
    x, w = np.polynomial.legendre.leggauss(nodes)
    offs = 0.5 * dt * (x - 1.0)  # node offsets in (t_k - dt, t_k)
    gyro = np.empty((n, 3))
    accel = np.empty((n, 3))
    for a in range(0, n, chunk):
        tk = t[a : a + chunk]
        tn = (tk[:, None] + offs[None, :]).ravel()
        pw = pointwise(traj, tn)
        m = tk.size
        gyro[a : a + m] = 0.5 * np.einsum("kqi,q->ki", pw["w_ib_b"].reshape(m, nodes, 3), w)
        accel[a : a + m] = 0.5 * np.einsum("kqi,q->ki", pw["f_b"].reshape(m, nodes, 3), w)
    truth: dict[str, list[Array]] = {k: [] for k in ("enu", "vel", "euler", "lat", "lon", "h")}
    for a in range(0, n, chunk * nodes):
        pw = pointwise(traj, t[a : a + chunk * nodes])
        for k in truth:
            truth[k].append(pw[k])
    cat = {k: np.concatenate(v) for k, v in truth.items()}
    att = cat["euler"].copy()
    att[:, 2] = np.mod(att[:, 2], 2.0 * np.pi)
    return Synthetic(
        t=t,
        gyro=gyro,
        accel=accel,
        position_enu=cat["enu"],
        velocity=cat["vel"],
        attitude=att,
        lat=cat["lat"],
        lon=cat["lon"],
        height=cat["h"],
        origin_deg=traj.origin_deg,
    )
