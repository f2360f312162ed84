"""The "traditional method" of seed 000 (§1, §4.3 Table 3): odometer dead reckoning, open loop.

The SINS runs free (no aiding) and only its attitude is used; the position is integrated from the
odometer speed along the travel axis of the odometer frame m:

    v^n_k = C_b^n(t_k) C_m^b [0, s_k / (1 + δk_D), 0]ᵀ,      p_k = p_{k−1} + v^n_k (t_k − t_{k−1})

with the nominal mounting ``C_b^m`` (roll, pitch, yaw of m relative to b) and scale error δk_D
from the options — zero for the plain traditional method, or the estimates of a forward filter
for the "estimated parameters compensated" row of Table 3 (optionally with the estimated gyro
bias removed from the IMU before the mechanization).

Nothing is estimated, so there is no filter covariance. The σ written with the solution is an
error envelope from the same first-order model: along track σ_k·d (d the distance travelled) and
the speed noise; across track and vertically the heading and pitch uncertainty integrated over
the path, σ_ψ(t)² = σ_ψ0² + σ_ε² t² + N_g² t (initial σ from meta.yaml, bias σ and angle random
walk from the IMU datasheet), all errors of one kind taken as fully correlated along the path.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.attitude import dcm_from_euler, dcm_from_quat
from fusion.config import DeadReckoningOptions
from fusion.earth import LocalFrame
from fusion.error_model import ImuNoise
from fusion.plugin import MissingStream
from fusion.recording import Recording
from fusion.solution import Solution
from fusion.strapdown import NavState, mechanize


def dead_reckon(
    recording: Recording,
    initial: NavState,
    frame: LocalFrame,
    imu: ImuNoise,
    options: DeadReckoningOptions,
) -> Solution:
    """Odometer dead reckoning with the free SINS attitude (see the module docstring)."""
    odo = recording.odometer
    if odo is None:
        raise MissingStream(
            f"recording {recording.path}: filter.architecture dead_reckoning needs odometer.csv"
        )
    data = recording.imu
    gyro = data.gyro - np.deg2rad(np.asarray(options.gyro_bias_deg_h)) / 3600.0
    free = mechanize(data.t, gyro, data.accel, initial, frame=frame)
    keep = (odo.t > data.t[0]) & (odo.t <= data.t[-1])
    t = np.concatenate([[data.t[0]], odo.t[keep]])
    speed = np.concatenate([[0.0], odo.speed[keep]]) / (1.0 + options.scale_error)
    rows = np.clip(np.searchsorted(data.t, t), 0, data.t.size - 1)
    c_b_n = np.array([dcm_from_quat(q) for q in free.quaternion[rows]])
    c_m_b = dcm_from_euler(*np.deg2rad(options.mounting_deg))
    v_n = c_b_n @ (c_m_b @ np.array([0.0, 1.0, 0.0])) * speed[:, None]
    dt = np.diff(t, prepend=t[0])
    position = free.position_enu[0] + np.cumsum(v_n * dt[:, None], axis=0)
    sigma = _envelope(t, v_n, dt, recording, imu, options)
    return Solution(
        t=t,
        position=position,
        velocity=v_n,
        attitude=free.attitude[rows],
        sigma_position=sigma,
        position_covariance=np.einsum("ni,ij->nij", sigma**2, np.eye(3)),
    )


def _envelope(
    t: NDArray[np.float64],
    v_n: NDArray[np.float64],
    dt: NDArray[np.float64],
    recording: Recording,
    imu: ImuNoise,
    options: DeadReckoningOptions,
) -> NDArray[np.float64]:
    """East, north, up 1-σ of the dead-reckoned position (first-order, see module docstring)."""
    sig0 = np.deg2rad(recording.meta.initial.sigma.attitude_deg)
    elapsed = t - t[0]
    heading = np.sqrt(sig0[2] ** 2 + (imu.gyro_bias * elapsed) ** 2 + imu.gyro_arw**2 * elapsed)
    pitch = np.sqrt(sig0[1] ** 2 + (imu.gyro_bias * elapsed) ** 2 + imu.gyro_arw**2 * elapsed)
    step = np.linalg.norm(v_n, axis=1) * dt
    along = np.hypot(
        options.scale_sigma * np.cumsum(step), options.speed_sigma_mps * np.sqrt(np.cumsum(dt**2))
    )
    across = np.cumsum(heading * step)
    vertical = np.cumsum(pitch * step)
    horizontal = np.hypot(along, across)
    sigma0 = np.asarray(recording.meta.initial.sigma.position_m)
    return np.sqrt(sigma0**2 + np.stack([horizontal, horizontal, vertical], axis=1) ** 2)
