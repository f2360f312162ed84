"""Bridged IMU gaps (fusion/imu_gaps.py): the assumed rates, the noise they add, and a federated
run through a 1-s gap while the shearer cuts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from fusion.config import load_config, parse_config
from fusion.engine import Engine
from fusion.imu_gaps import GapBridge, bridge_imu_gaps
from fusion.recording import ImuData, RecordingError, read_recording
from fusion.sim.simulate import simulate
from tests.fault_support import MID_FACE, max_horizontal

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_closing_sample_becomes_the_window_mean() -> None:
    rng = np.random.default_rng(3)
    t = np.concatenate([np.arange(0.0, 2.0, 0.01), [3.0], np.arange(3.01, 4.0, 0.01)])
    gyro = 0.01 * rng.standard_normal((t.size, 3))
    accel = np.array([0.1, -0.2, 9.8]) + 0.3 * rng.standard_normal((t.size, 3))
    imu = ImuData(t=t, gyro=gyro, accel=accel)
    bridged, (gap,) = bridge_imu_gaps(imu, [(1.99, 3.0)])
    closing = int(np.searchsorted(t, 3.0))
    window = (t > 1.99 - 1.01 + 1e-9) & (t <= 1.99)  # the 1.01-s gap's length before it
    np.testing.assert_allclose(bridged.accel[closing], accel[window].mean(axis=0))
    np.testing.assert_allclose(bridged.gyro[closing], gyro[window].mean(axis=0))
    untouched = np.arange(t.size) != closing
    np.testing.assert_array_equal(bridged.accel[untouched], accel[untouched])
    # White vibration: block means of 10 samples spread by σ/√10, times √2.
    np.testing.assert_allclose(gap.sigma_accel, 0.3 * np.sqrt(2 / 10), rtol=0.5)
    assert gap.length_s == pytest.approx(1.01)


def test_gap_noise_is_a_bias_held_over_the_gap() -> None:
    """Q_gap against the exact response of the error dynamics to a constant rate offset."""
    rng = np.random.default_rng(5)
    n = 15  # velocity, attitude, position, gyro bias, accel bias
    f = 1e-4 * rng.standard_normal((n, n))
    f[0:3, 3:6] += np.array([[0, -9.8, 0], [9.8, 0, 0], [0, 0, 0]])  # δv̇ = f^n × φ
    f[6:9, 0:3] += np.eye(3)  # δṗ = δv
    f[9:, :] = -np.eye(n)[9:] / 100.0  # Gauss–Markov biases
    c_b_n = scipy.linalg.expm(np.cross(np.eye(3), [0.1, -0.2, 1.3]))
    f[3:6, 9:12] = -c_b_n  # φ̇ = −C_b^n ε
    f[0:3, 12:15] = c_b_n  # δv̇ = C_b^n ∇
    sigma = np.array([1e-3, 2e-3, 3e-3, 0.02, 0.03, 0.04])
    gap = GapBridge(10.0, 11.0, sigma[:3], sigma[3:])
    q = gap.noise(f, slice(9, 12), slice(12, 15))
    # Exact: x(T) = ∫ e^{F(T−s)} B δ ds, from the augmented exponential [[F, B], [0, 0]].
    b = np.zeros((n, 6))
    b[0:9, 0:3], b[0:9, 3:6] = f[0:9, 9:12], f[0:9, 12:15]
    aug = np.zeros((n + 6, n + 6))
    aug[:n, :n], aug[:n, n:] = f, b
    g = scipy.linalg.expm(aug * gap.length_s)[:n, n:]
    exact = g @ np.diag(sigma**2) @ g.T
    np.testing.assert_allclose(q, exact, atol=1e-3 * np.abs(exact).max())
    assert np.all(q[9:, :] == 0.0)  # the biases themselves are not disturbed


@pytest.fixture(scope="module")
def gap_pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("gap")
    short = [*MID_FACE, "duration_s=160", "uwb.rate_hz=10"]  # each anchor at 10 Hz
    gap = "faults=[{kind: imu_gap, t_start: 120, t_end: 121}]"
    simulate("longwall-200m", root / "clean", seed=4, overrides=short)
    simulate("longwall-200m", root / "gap", seed=4, overrides=[*short, gap])
    return root / "clean", root / "gap"


def test_unbridged_gap_is_refused(gap_pair: tuple[Path, Path]) -> None:
    with pytest.raises(RecordingError, match=r"gap of 1\.0"):
        read_recording(gap_pair[1])


def test_federated_filter_runs_through_a_gap(gap_pair: tuple[Path, Path]) -> None:
    """A 1-s logging gap under conveyor vibration (0.35 m/s² per sample). Integrating the
    closing sample over the gap left 0.4 m/s of velocity error the covariance did not know,
    and full_afkf isolated the UWB, kinematic and magnetic locals one after another and
    diverged (ablation, longwall-200m seed 1: 1.2e5 m RMS). Bridged, no local is isolated and
    the error stays at its gap-free level."""
    clean_path, gap_path = gap_pair
    data = load_config(CONFIGS / "full_afkf.yaml").model_dump()
    data["bridge_imu_gaps"] = True
    config = parse_config(data)
    clean, gapped = read_recording(clean_path), read_recording(gap_path, bridge_imu_gaps=True)
    assert len(gapped.imu_gaps) == 1
    result = Engine(config, gapped).run()
    assert [(e.local, e.action) for e in result.faults if e.action != "jump"] == []
    nominal = max_horizontal(Engine(config, clean).run(), clean)
    worst = max_horizontal(result, gapped)
    print(f"max horizontal: {worst:.3f} m through the gap, {nominal:.3f} m without")
    assert worst <= 1.3 * nominal
