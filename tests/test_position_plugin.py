"""Position fixes: H against numerical differentiation through a perturbed SINS state."""

from __future__ import annotations

import numpy as np

from fusion.attitude import dcm_from_euler
from fusion.recording import PositionData, Recording
from plugins.position import PositionFixes, PositionOptions
from tests.plugin_support import (
    FRAME,
    layout_with,
    numerical_jacobian,
    perturbed_context,
    recording_meta,
    still_imu,
)


def _recording(fix_enu: np.ndarray, lever_arm: tuple[float, float, float]) -> Recording:
    return Recording(
        path=None,
        meta=recording_meta(position={"lever_arm_b_m": list(lever_arm)}),
        imu=still_imu(),
        position=PositionData(
            t=np.array([0.5]), enu=fix_enu[None, :], sigma=np.array([[0.01, 0.02, 0.03]])
        ),
    )


def test_h_matches_numerical_differentiation() -> None:
    """The fix of the true antenna point gives z = 0 at the truth and z(δx) ≈ H δx around it."""
    lever_arm = (0.4, -1.2, 0.8)
    c_b_n = dcm_from_euler(0.05, -0.03, 2.1)
    p_true = np.array([35.0, -12.0, 3.0])
    # The attitude is relative to the local level axes at the point, the fix is in the origin's.
    rot = FRAME.rotation_to_local(*FRAME.to_geodetic(p_true)[:2])
    antenna = p_true + rot.T @ c_b_n @ np.array(lever_arm)
    plugin = PositionFixes("position", PositionOptions(), _recording(antenna, lever_arm))
    layout = layout_with(plugin.state_blocks())

    def residual(dx: np.ndarray) -> np.ndarray:
        ctx = perturbed_context(layout, dx, position_enu=p_true, c_b_n=c_b_n)
        return plugin.measure(0, ctx).z

    np.testing.assert_allclose(residual(np.zeros(layout.dim)), 0.0, atol=1e-8)
    steps = np.array([1e-3] * 3 + [1e-5] * 3 + [1e-2] * 3 + [0.0] * 6)
    numeric = numerical_jacobian(residual, layout.dim, steps)
    h = plugin.measure(
        0, perturbed_context(layout, np.zeros(layout.dim), position_enu=p_true, c_b_n=c_b_n)
    ).H
    # δp is applied along the origin's ENU axes, which differ from the local axes at 38 m by
    # 6e-6 rad: the only mismatch allowed.
    np.testing.assert_allclose(h, numeric, atol=1e-5)
