"""WGS84 strapdown mechanization in the local-level ENU frame (seed 003 §2, seed 000 §3.1).

The nominal navigation state is the attitude quaternion ``q_b^n`` (scalar first), the velocity
``v^n`` (East, North, Up, relative to the earth, resolved in the local-level frame at the current
point) and the geodetic position (L, λ, h). An IMU sample k holds the *mean* angular rate and
specific force over ``(t_{k-1}, t_k]`` (RECORDING_FORMAT.md), i.e. the increments
``Δθ_k = ω̄_k T_k`` and ``Δv_k = f̄_k T_k`` after the estimated biases are removed.

One update over an interval of length T whose predecessor had length T₁ (Savage's two-speed
algorithm reduced to one speed, as in PSINS and KF-GINS):

* two-sample coning and sculling, generalized to unequal intervals for a rate and specific force
  varying linearly across the two intervals (equal intervals give the familiar 1/12)::

      κ = T² / (6 T₁ (T₁ + T))
      φ_b   = Δθ_k + κ Δθ_{k-1} × Δθ_k
      Δv_sf = Δv_k + ½ Δθ_k × Δv_k + ⅙ Δθ_k × (Δθ_k × Δv_k) + κ (Δθ_{k-1} × Δv_k + Δv_{k-1} × Δθ_k)

  (the second-order rotation term, Savage's (1 − sin φ/φ)/φ² φ×(φ×Δv), matters: without it
  every rocking motion leaves a steady vertical error ⅙ T² g ⟨ω⊥²⟩ that the unstable vertical
  channel turns into metres within an hour);

* velocity, with the navigation-frame rotation ζ = ω_in^n T, the Coriolis and transport terms
  and normal gravity evaluated at mid-interval (extrapolated)::

      v_k = v_{k-1} + (I - ½ ζ×) C_b^n(k-1) Δv_sf + [g^n - (2 ω_ie^n + ω_en^n) × v^n]_mid T

* position by the trapezoidal rule on (L, λ, h) with the radii at mid-interval;
* attitude ``q_k = q(-ζ) ⊗ q_{k-1} ⊗ q(φ_b)``, renormalized.

The mechanization can stop at any time inside an IMU interval: the interval is split and each
part gets the increments of the sample's mean rates over its own length (the rates are taken as
constant inside one sample, which is all an interval mean says). Under 5–30 Hz vibration sampled
at 100 Hz the interval means cannot carry the within-sample coning and sculling; the two-sample
terms recover the part that is correlated between successive samples only.

The hot loop is compiled with numba: interpreted, the same step costs ≈ 38 µs per sample, compiled
≈ 1.5 µs, against the ≤ 10 µs budget (``python -m benchmarks strapdown``; README, "Why numba").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion import attitude, earth, kernels

# Layout of the packed navigation array used by the compiled kernels.
Q0, VEL, LAT, LON, HGT = 0, 4, 7, 8, 9
NAV_SIZE = 10
# History of the previous (sub-)interval: Δθ (3), Δv (3), length, and the last Δv^n (3).
HIST_SIZE = 10


@kernels.jit
def _step(
    nav: NDArray[np.float64],
    hist: NDArray[np.float64],
    dtheta: NDArray[np.float64],
    dv: NDArray[np.float64],
    dt: float,
    coning_sculling: bool,
) -> NDArray[np.float64]:
    """Advance ``nav`` in place over one (sub-)interval; return the specific-force Δv^n."""
    dtheta_prev = hist[0:3]
    dv_prev = hist[3:6]
    dt_prev = hist[6]
    if coning_sculling and dt_prev > 0.0:
        kappa = dt * dt / (6.0 * dt_prev * (dt_prev + dt))
        phi_b = dtheta + kappa * kernels.cross(dtheta_prev, dtheta)
        dv_scul = kappa * (kernels.cross(dtheta_prev, dv) + kernels.cross(dv_prev, dtheta))
    else:
        phi_b = dtheta.copy()
        dv_scul = np.zeros(3)
    dv_sf_b = (
        dv
        + 0.5 * kernels.cross(dtheta, dv)
        + kernels.cross(dtheta, kernels.cross(dtheta, dv)) / 6.0
        + dv_scul
    )

    # Mid-interval navigation quantities, extrapolated from the previous Δv^n.
    v_prev = nav[VEL : VEL + 3].copy()
    v_mid = v_prev + 0.5 * hist[7:10]
    lat_prev, lon_prev, h_prev = nav[LAT], nav[LON], nav[HGT]
    rm, _ = kernels.radii(lat_prev)
    h_mid = h_prev + 0.5 * v_mid[2] * dt
    lat_mid = lat_prev + 0.5 * v_mid[1] * dt / (rm + h_prev)
    rmh, rnh, w_ie, w_en = kernels.frame_rates(lat_mid, h_mid, v_mid)
    cl = math.cos(lat_mid)
    zeta = (w_ie + w_en) * dt

    c_b_n = kernels.dcm_from_quat(nav[Q0 : Q0 + 4])
    dv_sf_n = c_b_n @ dv_sf_b
    dv_sf_n = dv_sf_n - 0.5 * kernels.cross(zeta, dv_sf_n)
    g_n = np.array([0.0, 0.0, -kernels.normal_gravity(lat_mid, h_mid)])
    dv_n = dv_sf_n + (g_n - kernels.cross(2.0 * w_ie + w_en, v_mid)) * dt
    v_new = v_prev + dv_n

    v_avg = 0.5 * (v_prev + v_new)
    nav[HGT] = h_prev + v_avg[2] * dt
    nav[LAT] = lat_prev + v_avg[1] * dt / rmh
    nav[LON] = lon_prev + v_avg[0] * dt / (rnh * cl)
    nav[VEL : VEL + 3] = v_new

    q = kernels.quat_multiply(
        kernels.quat_from_rotvec(-zeta),
        kernels.quat_multiply(nav[Q0 : Q0 + 4], kernels.quat_from_rotvec(phi_b)),
    )
    nav[Q0 : Q0 + 4] = q / math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)

    hist[0:3] = dtheta
    hist[3:6] = dv
    hist[6] = dt
    hist[7:10] = dv_n
    return dv_sf_n


@kernels.jit
def _advance(
    nav: NDArray[np.float64],
    hist: NDArray[np.float64],
    imu_t: NDArray[np.float64],
    gyro: NDArray[np.float64],
    accel: NDArray[np.float64],
    k: int,
    t_now: float,
    t_target: float,
    gyro_bias: NDArray[np.float64],
    accel_bias: NDArray[np.float64],
    coning_sculling: bool,
    dv_sf_sum: NDArray[np.float64],
    travel: NDArray[np.float64],
) -> tuple[int, float]:
    """Consume IMU samples from index ``k`` (the sample covering ``t_now``) up to ``t_target``.

    Returns the new sample index and time. ``dv_sf_sum`` accumulates the specific-force
    velocity increments in n, from which the caller takes the mean f^n of a covariance step;
    ``travel`` accumulates the trapezoidal integral of the velocity ``∫ v^n dt`` (m).
    A sample end within 1 ns of ``t_target`` counts as reached, so that no sliver is left.
    """
    n = imu_t.shape[0]
    while k < n and t_now < t_target:
        t_end = imu_t[k]
        if t_end - t_target > 1e-9:
            t_end = t_target
        dt = t_end - t_now
        w = gyro[k] - gyro_bias
        f = accel[k] - accel_bias
        travel += 0.5 * dt * nav[VEL : VEL + 3]  # trapezoid: half the start velocity …
        dv_sf_sum += _step(nav, hist, w * dt, f * dt, dt, coning_sculling)
        travel += 0.5 * dt * nav[VEL : VEL + 3]  # … and half the end velocity
        t_now = t_end
        if t_end >= imu_t[k] - 1e-9:
            t_now = imu_t[k]
            k += 1
    return k, t_now


@dataclass
class NavState:
    """Nominal navigation state.

    Attributes
    ----------
    lat, lon, height
        Geodetic position (rad, rad, m).
    velocity
        ENU velocity (m/s) in the local-level frame.
    quaternion
        ``q_b^n``, scalar first.
    """

    lat: float
    lon: float
    height: float
    velocity: NDArray[np.float64]
    quaternion: NDArray[np.float64]

    @classmethod
    def from_enu(
        cls,
        frame: earth.LocalFrame,
        position_enu: ArrayLike,
        velocity_enu: ArrayLike,
        roll: float,
        pitch: float,
        yaw: float,
    ) -> NavState:
        """Build a state from ENU metres about ``frame``'s origin and Euler angles (rad)."""
        lat, lon, height = frame.to_geodetic(np.asarray(position_enu, dtype=float))
        c_b_n = attitude.dcm_from_euler(roll, pitch, yaw)
        return cls(
            float(lat),
            float(lon),
            float(height),
            np.array(velocity_enu, dtype=float),
            attitude.quat_from_dcm(c_b_n),
        )

    def to_array(self) -> NDArray[np.float64]:
        """The packed array of the compiled kernels."""
        nav = np.empty(NAV_SIZE)
        nav[Q0 : Q0 + 4] = self.quaternion
        nav[VEL : VEL + 3] = self.velocity
        nav[LAT], nav[LON], nav[HGT] = self.lat, self.lon, self.height
        return nav

    @classmethod
    def from_array(cls, nav: NDArray[np.float64]) -> NavState:
        """Inverse of :meth:`to_array` (copies)."""
        return cls(
            float(nav[LAT]),
            float(nav[LON]),
            float(nav[HGT]),
            nav[VEL : VEL + 3].copy(),
            nav[Q0 : Q0 + 4].copy(),
        )


class Strapdown:
    """The SINS: nominal state driven by a recording's IMU samples, with bias compensation.

    Parameters
    ----------
    imu_t, gyro, accel
        IMU time stamps (s), mean angular rates (rad/s) and specific forces (m/s²), (N,) and
        (N, 3). Sample k covers ``(imu_t[k-1], imu_t[k]]``.
    initial
        Navigation state at ``imu_t[0]``.
    coning_sculling
        Apply the two-sample coning and sculling corrections.
    """

    def __init__(
        self,
        imu_t: NDArray[np.float64],
        gyro: NDArray[np.float64],
        accel: NDArray[np.float64],
        initial: NavState,
        *,
        coning_sculling: bool = True,
    ) -> None:
        self.imu_t = np.ascontiguousarray(imu_t, dtype=float)
        self.gyro = np.ascontiguousarray(gyro, dtype=float)
        self.accel = np.ascontiguousarray(accel, dtype=float)
        self.nav = initial.to_array()
        self.gyro_bias = np.zeros(3)
        self.accel_bias = np.zeros(3)
        self.coning_sculling = coning_sculling
        self.k = 1
        self.t = float(self.imu_t[0])
        self.hist = np.zeros(HIST_SIZE)
        if len(self.imu_t) > 1:
            # Sample 0 is the interval before the start: it seeds the coning/sculling history.
            dt0 = float(self.imu_t[1] - self.imu_t[0])
            self.hist[0:3] = self.gyro[0] * dt0
            self.hist[3:6] = self.accel[0] * dt0
            self.hist[6] = dt0
        self._dv_sf_sum = np.zeros(3)
        self.travel = np.zeros(3)

    @property
    def t_end(self) -> float:
        """Time of the last IMU sample."""
        return float(self.imu_t[-1])

    def advance_to(self, t_target: float) -> None:
        """Propagate the nominal state to ``t_target`` (≤ the last IMU time)."""
        self.k, self.t = _advance(
            self.nav,
            self.hist,
            self.imu_t,
            self.gyro,
            self.accel,
            self.k,
            self.t,
            float(t_target),
            self.gyro_bias,
            self.accel_bias,
            self.coning_sculling,
            self._dv_sf_sum,
            self.travel,
        )

    def take_velocity_increment(self) -> NDArray[np.float64]:
        """Specific-force Δv^n summed since the last call (and reset)."""
        out = self._dv_sf_sum.copy()
        self._dv_sf_sum[:] = 0.0
        return out

    @property
    def state(self) -> NavState:
        """A copy of the current nominal state."""
        return NavState.from_array(self.nav)

    @property
    def c_b_n(self) -> NDArray[np.float64]:
        """Current ``C_b^n``."""
        return attitude.dcm_from_quat(self.nav[Q0 : Q0 + 4])

    def correct(
        self,
        velocity_error: NDArray[np.float64],
        attitude_error: NDArray[np.float64],
        position_error_enu: NDArray[np.float64],
        gyro_bias_error: NDArray[np.float64],
        accel_bias_error: NDArray[np.float64],
    ) -> None:
        """Closed-loop feedback of estimated errors (conventions of :mod:`fusion.error_model`).

        ``v ← v − δv``; ``C_b^n ← R(φ) C̃_b^n`` (since ``C̃ = (I − φ×) C``); position minus the
        ENU-metre error converted to (L, λ, h); biases ``b ← b + ε`` and ``b ← b + ∇``.
        """
        remove_errors(self.nav, velocity_error, attitude_error, position_error_enu)
        self.gyro_bias += gyro_bias_error
        self.accel_bias += accel_bias_error


def remove_errors(
    nav: NDArray[np.float64],
    velocity_error: NDArray[np.float64],
    attitude_error: NDArray[np.float64],
    position_error_enu: NDArray[np.float64],
) -> None:
    """Remove estimated errors from a packed navigation state in place (see ``correct``)."""
    nav[VEL : VEL + 3] -= velocity_error
    q = attitude.quat_multiply(attitude.quat_from_rotvec(attitude_error), nav[Q0 : Q0 + 4])
    nav[Q0 : Q0 + 4] = q / np.linalg.norm(q)
    rm, rn = earth.radii(nav[LAT])
    h = nav[HGT]
    nav[LAT] -= position_error_enu[1] / (rm + h)
    nav[LON] -= position_error_enu[0] / ((rn + h) * math.cos(nav[LAT]))
    nav[HGT] -= position_error_enu[2]


@dataclass(frozen=True)
class MechanizationResult:
    """States at every IMU time stamp (row 0 = initial state)."""

    t: NDArray[np.float64]
    lat: NDArray[np.float64]
    lon: NDArray[np.float64]
    height: NDArray[np.float64]
    position_enu: NDArray[np.float64]
    velocity: NDArray[np.float64]
    quaternion: NDArray[np.float64]
    attitude: NDArray[np.float64]


@kernels.jit
def _mechanize_all(
    nav: NDArray[np.float64],
    hist: NDArray[np.float64],
    imu_t: NDArray[np.float64],
    gyro: NDArray[np.float64],
    accel: NDArray[np.float64],
    coning_sculling: bool,
) -> NDArray[np.float64]:
    n = imu_t.shape[0]
    out = np.empty((n, NAV_SIZE))
    out[0] = nav
    for k in range(1, n):
        dt = imu_t[k] - imu_t[k - 1]
        _step(nav, hist, gyro[k] * dt, accel[k] * dt, dt, coning_sculling)
        out[k] = nav
    return out


def mechanize(
    t: ArrayLike,
    gyro: ArrayLike,
    accel: ArrayLike,
    initial: NavState,
    *,
    coning_sculling: bool = True,
    frame: earth.LocalFrame | None = None,
) -> MechanizationResult:
    """Free-inertial navigation over a whole IMU record.

    Parameters
    ----------
    t, gyro, accel
        IMU samples as in :class:`Strapdown`; sample 0 only seeds the coning history.
    initial
        State at ``t[0]``.
    coning_sculling
        Apply the two-sample corrections.
    frame
        ENU frame for ``position_enu``; default: one with its origin at the initial point.
    """
    sins = Strapdown(
        np.asarray(t), np.asarray(gyro), np.asarray(accel), initial, coning_sculling=coning_sculling
    )
    out = _mechanize_all(sins.nav, sins.hist, sins.imu_t, sins.gyro, sins.accel, coning_sculling)
    if frame is None:
        frame = earth.LocalFrame(np.rad2deg(initial.lat), np.rad2deg(initial.lon), initial.height)
    lat, lon, height = out[:, LAT], out[:, LON], out[:, HGT]
    quats = out[:, Q0 : Q0 + 4]
    return MechanizationResult(
        t=sins.imu_t.copy(),
        lat=lat,
        lon=lon,
        height=height,
        position_enu=frame.to_enu(lat, lon, height),
        velocity=out[:, VEL : VEL + 3],
        quaternion=quats,
        attitude=attitude.euler_from_quat(quats),
    )
