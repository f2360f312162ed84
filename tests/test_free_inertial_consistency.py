"""Monte Carlo: the error model's covariance against the mechanization's actual free drift.

100 seeded runs of 10 min free inertial navigation at rest with a MEMS-grade IMU (constant
biases drawn from their σ, white noise from ARW/VRW, initial errors drawn from their σ). The
errors of the mechanized states against truth, divided by the σ the error model predicts,
must have RMS in [0.7, 1.3] for position, velocity and attitude.
"""

import numpy as np

from fusion import earth
from fusion.attitude import dcm_from_euler, dcm_from_quat, quat_from_rotvec, quat_multiply
from fusion.earth import LocalFrame
from fusion.error_model import ErrorModel, ImuNoise, StateLayout, common_blocks, navigation_error
from fusion.strapdown import HGT, LAT, LON, Q0, VEL, NavState, mechanize
from tests.plugin_support import group_rms

RATE = 100.0
DURATION = 600.0
STEP = 0.1
IMU = ImuNoise.from_datasheet(
    gyro_arw_deg_rth=0.2, accel_vrw_mg_rthz=0.1, gyro_bias_deg_h=10.0, accel_bias_mg=2.0
)
SIGMA_V = np.array([0.01, 0.01, 0.01])
SIGMA_ATT = np.deg2rad([0.3, 0.3, 1.0])
SIGMA_P = np.array([0.05, 0.05, 0.05])


def _predicted_sigma(truth: NavState, c_b_n: np.ndarray, f_n: np.ndarray) -> np.ndarray:
    layout = StateLayout(common_blocks(IMU, SIGMA_V, SIGMA_ATT, SIGMA_P))
    phi, qd = ErrorModel(layout, IMU).discrete(truth.to_array(), f_n, c_b_n, STEP)
    p = layout.initial_covariance()
    sig = [np.sqrt(np.diag(p))[:9]]
    for _ in range(round(DURATION / STEP)):
        p = phi @ p @ phi.T + qd
        sig.append(np.sqrt(np.diag(p))[:9])
    return np.array(sig)


def test_monte_carlo_errors_match_predicted_sigma() -> None:
    frame = LocalFrame(34.25, 108.95, -350.0)
    roll, pitch, yaw = np.deg2rad([0.5, -1.2, 92.0])
    truth = NavState.from_enu(frame, [0, 0, 0], [0, 0, 0], roll, pitch, yaw)
    c_b_n = dcm_from_euler(roll, pitch, yaw)
    g = earth.normal_gravity(truth.lat, truth.height)
    w_ie = earth.OMEGA_IE * np.array([0.0, np.cos(truth.lat), np.sin(truth.lat)])
    f_n = np.array([0.0, 0.0, g])
    n = round(DURATION * RATE) + 1
    t = np.arange(n) / RATE
    gyro_true = c_b_n.T @ w_ie
    accel_true = c_b_n.T @ f_n
    sigma = _predicted_sigma(truth, c_b_n, f_n)
    check_steps = np.arange(100, sigma.shape[0], 100)  # every 10 s from 10 s on
    truth_nav = truth.to_array()
    rng = np.random.default_rng(20261121)
    ratios = []
    for _ in range(100):
        bias_g = IMU.gyro_bias * rng.standard_normal(3)
        bias_a = IMU.accel_bias * rng.standard_normal(3)
        gyro = gyro_true + bias_g + IMU.gyro_arw * np.sqrt(RATE) * rng.standard_normal((n, 3))
        accel = accel_true + bias_a + IMU.accel_vrw * np.sqrt(RATE) * rng.standard_normal((n, 3))
        init = truth.to_array()
        init[VEL : VEL + 3] += SIGMA_V * rng.standard_normal(3)
        init[Q0 : Q0 + 4] = quat_multiply(
            quat_from_rotvec(-SIGMA_ATT * rng.standard_normal(3)), init[Q0 : Q0 + 4]
        )
        dp = SIGMA_P * rng.standard_normal(3)
        rm, rn = earth.radii(init[LAT])
        init[LAT] += dp[1] / (rm + init[HGT])
        init[LON] += dp[0] / ((rn + init[HGT]) * np.cos(init[LAT]))
        init[HGT] += dp[2]
        res = mechanize(t, gyro, accel, NavState.from_array(init), frame=frame)
        for k in check_steps:
            i = k * round(STEP * RATE)
            nav = np.concatenate(
                [res.quaternion[i], res.velocity[i], [res.lat[i], res.lon[i], res.height[i]]]
            )
            ratios.append(navigation_error(nav, truth_nav) / sigma[k])
    r = np.array(ratios)
    rms = group_rms(r)
    per_axis = np.sqrt(np.mean(r**2, axis=0))
    print("RMS(err/σ):", rms, "per state:", np.round(per_axis, 2))
    assert np.allclose(dcm_from_quat(truth.quaternion), c_b_n)
    for group, value in rms.items():
        assert 0.7 <= value <= 1.3, (group, value)
