"""Attitude representations in the recording convention.

The body frame b is x right, y forward, z up; the navigation frame n is East-North-Up. Roll γ,
pitch θ and yaw ψ define (RECORDING_FORMAT.md)

    C_b^n = R_z(-ψ) · R_x(θ) · R_y(γ),

with right-handed elementary rotations, so that ψ is the heading of the body y axis clockwise
from north, θ > 0 raises the nose and γ > 0 lowers the right side. Row 3 of C_b^n is
``[-cosθ sinγ, sinθ, cosθ cosγ]`` and column 2 is ``[sinψ cosθ, cosψ cosθ, sinθ]``, which gives
the inverse ``θ = asin(C[2,1])``, ``γ = atan2(-C[2,0], C[2,2])``, ``ψ = atan2(C[0,1], C[1,1])``.

Quaternions are scalar first, ``q = [w, x, y, z]``, and ``q_b^n`` rotates b-vectors into n.
The products ``quat_multiply`` / ``quat_from_rotvec`` / ``dcm_from_quat`` are written as plain
arithmetic so that the strapdown kernels compile them with ``numba`` as they are.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation


def skew(v: ArrayLike) -> NDArray[np.float64]:
    """Skew-symmetric matrix ``(v×)`` such that ``skew(v) @ u == cross(v, u)``."""
    x, y, z = np.asarray(v, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def dcm_from_euler(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> NDArray[np.float64]:
    """``C_b^n`` (..., 3, 3) from roll, pitch, yaw (radians)."""
    r, p, y = np.broadcast_arrays(
        np.asarray(roll, float), np.asarray(pitch, float), np.asarray(yaw, float)
    )
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    c = np.empty((*r.shape, 3, 3))
    # R_x(θ) R_y(γ) = [[cγ, 0, sγ], [sθ sγ, cθ, -sθ cγ], [-cθ sγ, sθ, cθ cγ]], then R_z(-ψ).
    m1 = np.stack([cr, np.zeros_like(cr), sr], axis=-1)
    m2 = np.stack([sp * sr, cp, -sp * cr], axis=-1)
    c[..., 0, :] = cy[..., None] * m1 + sy[..., None] * m2
    c[..., 1, :] = -sy[..., None] * m1 + cy[..., None] * m2
    c[..., 2, :] = np.stack([-cp * sr, sp, cp * cr], axis=-1)
    return c


def euler_from_dcm(c_b_n: ArrayLike) -> NDArray[np.float64]:
    """Roll, pitch, yaw (..., 3) in radians from ``C_b^n`` (..., 3, 3); yaw in [0, 2π)."""
    c = np.asarray(c_b_n, dtype=float)
    pitch = np.arcsin(np.clip(c[..., 2, 1], -1.0, 1.0))
    roll = np.arctan2(-c[..., 2, 0], c[..., 2, 2])
    yaw = np.mod(np.arctan2(c[..., 0, 1], c[..., 1, 1]), 2.0 * np.pi)
    return np.stack([roll, pitch, yaw], axis=-1)


def euler_jacobian(euler: ArrayLike) -> NDArray[np.float64]:
    """``∂(roll, pitch, yaw)/∂φ`` (..., 3, 3) at roll, pitch, yaw (..., 3) in radians, for the
    misalignment φ of the computed n-frame, ``C̃_b^n = (I − φ×) C_b^n``
    (:mod:`fusion.error_model`): the covariance of the Euler angles is ``J P_φ Jᵀ``. Singular
    at pitch ±90° (roll and yaw are then one angle); its pitch row, ``[-cos ψ, sin ψ, 0]``,
    is finite there."""
    e = np.asarray(euler, dtype=float)
    c = dcm_from_euler(e[..., 0], e[..., 1], e[..., 2])
    jacobian = np.empty((*e.shape[:-1], 3, 3))
    for k in range(3):
        dc = -skew(np.eye(3)[k]) @ c  # ∂C̃/∂φ_k
        jacobian[..., 0, k] = (c[..., 2, 0] * dc[..., 2, 2] - c[..., 2, 2] * dc[..., 2, 0]) / (
            c[..., 2, 0] ** 2 + c[..., 2, 2] ** 2
        )
        jacobian[..., 2, k] = (c[..., 1, 1] * dc[..., 0, 1] - c[..., 0, 1] * dc[..., 1, 1]) / (
            c[..., 0, 1] ** 2 + c[..., 1, 1] ** 2
        )
    # ∂θ/∂φ = ∂C[2,1]/∂φ / cos θ, where ∂C[2,1]/∂φ = cos θ · [-cos ψ, sin ψ, 0]
    jacobian[..., 1, 0] = -np.cos(e[..., 2])
    jacobian[..., 1, 1] = np.sin(e[..., 2])
    jacobian[..., 1, 2] = 0.0
    return jacobian


def misalignment_jacobian(euler: ArrayLike) -> NDArray[np.float64]:
    """``∂φ/∂(roll, pitch, yaw)`` (3, 3) at roll, pitch, yaw (3,) in radians: the misalignment φ
    that small Euler-angle errors give, ``C̃_b^n = (I − φ×) C_b^n``. Its columns are the axes
    the three elementary rotations of ``C_b^n = R_z(-ψ) · R_x(θ) · R_y(γ)`` turn about, in n,
    with the sign of φ: ``-R_z(-ψ) R_x(θ) e_y``, ``-R_z(-ψ) e_x`` and ``e_z``. It is the inverse
    of :func:`euler_jacobian` where that exists, and finite at pitch ±90°, where the roll's
    and the yaw's columns are the same axis."""
    _, pitch, yaw = np.asarray(euler, dtype=float)
    return np.stack(
        [
            -dcm_from_euler(0.0, pitch, yaw)[:, 1],
            -dcm_from_euler(0.0, 0.0, yaw)[:, 0],
            np.array([0.0, 0.0, 1.0]),
        ],
        axis=-1,
    )


def quat_multiply(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Hamilton product ``p ⊗ q`` of two scalar-first quaternions."""
    return np.array(
        [
            p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
            p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
            p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
            p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0],
        ]
    )


def quat_from_rotvec(rv: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternion of the rotation vector ``rv`` (series form near zero, exact elsewhere)."""
    a2 = rv[0] * rv[0] + rv[1] * rv[1] + rv[2] * rv[2]
    if a2 < 1e-8:
        # cos(a/2) and sin(a/2)/a to O(a⁶): below 1e-4 rad the truncation is < 1e-18.
        c = 1.0 - a2 / 8.0 + a2 * a2 / 384.0
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        a = np.sqrt(a2)
        c = np.cos(0.5 * a)
        s = np.sin(0.5 * a) / a
    return np.array([c, s * rv[0], s * rv[1], s * rv[2]])


def dcm_from_quat(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrix of a unit scalar-first quaternion."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_from_dcm(c: ArrayLike) -> NDArray[np.float64]:
    """Scalar-first unit quaternion (w ≥ 0) of a rotation matrix (Shepperd's method)."""
    m = np.asarray(c, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    cands = np.array([tr, m[0, 0], m[1, 1], m[2, 2]])
    i = int(np.argmax(cands))
    if i == 0:
        w = 0.5 * np.sqrt(1.0 + tr)
        q = [
            w,
            (m[2, 1] - m[1, 2]) / (4 * w),
            (m[0, 2] - m[2, 0]) / (4 * w),
            (m[1, 0] - m[0, 1]) / (4 * w),
        ]
    elif i == 1:
        x = 0.5 * np.sqrt(1.0 + 2 * m[0, 0] - tr)
        q = [
            (m[2, 1] - m[1, 2]) / (4 * x),
            x,
            (m[0, 1] + m[1, 0]) / (4 * x),
            (m[0, 2] + m[2, 0]) / (4 * x),
        ]
    elif i == 2:
        y = 0.5 * np.sqrt(1.0 + 2 * m[1, 1] - tr)
        q = [
            (m[0, 2] - m[2, 0]) / (4 * y),
            (m[0, 1] + m[1, 0]) / (4 * y),
            y,
            (m[1, 2] + m[2, 1]) / (4 * y),
        ]
    else:
        z = 0.5 * np.sqrt(1.0 + 2 * m[2, 2] - tr)
        q = [
            (m[1, 0] - m[0, 1]) / (4 * z),
            (m[0, 2] + m[2, 0]) / (4 * z),
            (m[1, 2] + m[2, 1]) / (4 * z),
            z,
        ]
    out = np.array(q)
    return out if out[0] >= 0 else -out


def wrap_angle(a: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles to [-π, π)."""
    return (np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def euler_from_quat(q: ArrayLike) -> NDArray[np.float64]:
    """Roll, pitch, yaw (N, 3) of scalar-first unit quaternions ``q_b^n`` (N, 4)."""
    return euler_from_dcm(Rotation.from_quat(np.asarray(q), scalar_first=True).as_matrix())
