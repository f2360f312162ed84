"""The Kalman core against filterpy, and its numerical robustness."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from fusion.kalman import KalmanFilter, chi2_threshold


def _problem(seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    n, m = 6, 3
    dt = 0.1
    phi = np.eye(n) + dt * np.diag(np.ones(n - 1), 1) + 0.01 * rng.standard_normal((n, n))
    a = rng.standard_normal((n, n))
    q = 1e-3 * a @ a.T
    h = rng.standard_normal((m, n))
    b = rng.standard_normal((m, m))
    r = 0.1 * b @ b.T + 0.01 * np.eye(m)
    c = rng.standard_normal((n, n))
    p0 = c @ c.T + np.eye(n)
    return phi, q, h, r, p0, rng.standard_normal(n)


def test_predict_and_update_match_filterpy() -> None:
    phi, q, h, r, p0, x0 = _problem(1)
    ours = KalmanFilter(x0, p0)
    ref = FilterpyKF(dim_x=len(x0), dim_z=h.shape[0])
    ref.x, ref.P, ref.F, ref.Q, ref.H, ref.R = x0.copy(), p0.copy(), phi, q, h, r
    rng = np.random.default_rng(2)
    for _ in range(200):
        ours.predict(phi, q)
        ref.predict()
        z = rng.standard_normal(h.shape[0])
        res = ours.update(z, h, r)
        ref.update(z)
        np.testing.assert_allclose(ours.x, ref.x, rtol=0, atol=1e-10)
        np.testing.assert_allclose(ours.P, ref.P, rtol=0, atol=1e-10)
        np.testing.assert_allclose(res.innovation, ref.y, atol=1e-10)
        np.testing.assert_allclose(
            res.nis, float(ref.y @ np.linalg.solve(ref.S, ref.y)), rtol=1e-10
        )


def test_whitened_innovations_have_unit_covariance_on_a_consistent_problem() -> None:
    rng = np.random.default_rng(5)
    phi = np.array([[1.0, 0.1], [0.0, 1.0]])
    q = np.diag([1e-4, 1e-3])
    h = np.array([[1.0, 0.0]])
    r = np.array([[0.04]])
    kf = KalmanFilter(np.zeros(2), np.eye(2))
    truth = rng.multivariate_normal(np.zeros(2), np.eye(2))
    whitened = []
    for _ in range(5000):
        truth = phi @ truth + rng.multivariate_normal(np.zeros(2), q)
        kf.predict(phi, q)
        z = h @ truth + rng.normal(0, 0.2, 1)
        whitened.append(kf.update(z, h, r).whitened[0])
    rms = np.sqrt(np.mean(np.square(whitened[100:])))
    assert 0.95 < rms < 1.05


def test_gate_rejects_an_outlier_and_leaves_the_state_alone() -> None:
    kf = KalmanFilter(np.zeros(2), np.eye(2))
    h = np.array([[1.0, 0.0]])
    res = kf.update(np.array([50.0]), h, np.array([[1.0]]), gate_probability=0.999)
    assert not res.accepted
    assert res.threshold == pytest.approx(chi2_threshold(1, 0.999))
    np.testing.assert_array_equal(kf.x, 0.0)
    np.testing.assert_array_equal(kf.P, np.eye(2))
    assert kf.update(np.array([0.5]), h, np.array([[1.0]]), gate_probability=0.999).accepted


@pytest.mark.parametrize("n_updates", [100_000, pytest.param(1_000_000, marks=pytest.mark.slow)])
def test_covariance_stays_symmetric_positive_definite(n_updates: int) -> None:
    """Ill-conditioned: states spanning 12 orders of magnitude, precise measurements."""
    scales = np.array([1e-6, 1e-3, 1.0, 1e3, 1e6])
    phi = np.eye(5) + np.diag([1e-3] * 4, 1)
    q = np.diag((1e-4 * scales) ** 2)
    h = np.zeros((2, 5))
    h[0, 0] = 1.0 / scales[0]
    h[1, 4] = 1.0 / scales[4]
    r = np.diag([1e-8, 1e-8])
    kf = KalmanFilter(np.zeros(5), np.diag(scales**2))
    z = np.zeros(2)
    min_eig = np.inf
    for k in range(n_updates):
        if k % 10 == 0:
            kf.predict(phi, q)
        kf.update(z, h, r)
        if k % 10_000 == 0:
            np.testing.assert_array_equal(kf.P, kf.P.T)
            d = np.sqrt(np.diag(kf.P))
            min_eig = min(min_eig, np.linalg.eigvalsh(kf.P / np.outer(d, d)).min())
    np.testing.assert_array_equal(kf.P, kf.P.T)
    assert np.all(np.diag(kf.P) > 0)
    d = np.sqrt(np.diag(kf.P))
    assert np.linalg.eigvalsh(kf.P / np.outer(d, d)).min() > 0
    assert min_eig > 0


def test_restart_moves_only_the_restarted_state() -> None:
    kf = KalmanFilter(
        np.array([0.3, -0.2, 0.19]), np.array([[1.0, 0.5, 0.2], [0.5, 2.0, 0.1], [0.2, 0.1, 0.3]])
    )
    kf.signatures = np.ones((3, 2))
    kf.restart(2, 0.0, 1e-8)
    np.testing.assert_array_equal(kf.x, [0.3, -0.2, 0.0])
    np.testing.assert_array_equal(kf.P[2], [0.0, 0.0, 1e-8])
    np.testing.assert_array_equal(kf.P[:2, :2], [[1.0, 0.5], [0.5, 2.0]])
    np.testing.assert_array_equal(kf.signatures[2], [0.0, 0.0])
