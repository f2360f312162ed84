"""The Kalman core against filterpy, and its numerical robustness."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from fusion.kalman import CorrelatedNoise, KalmanFilter, chi2_threshold


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


@pytest.mark.parametrize("n_updates", [100_000, pytest.param(300_000, marks=pytest.mark.slow)])
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


def _schmidt_reference(
    cov: np.ndarray, n: int, h: np.ndarray, b_full: np.ndarray, r_v: np.ndarray
) -> np.ndarray:
    """The update of the joint covariance of (ε, e) for ``z = H x + B e + v`` when only x is
    estimated (a Schmidt, or consider, filter): gain rows of e zero, Joseph form."""
    h_joint = np.hstack([h, b_full])
    s = h_joint @ cov @ h_joint.T + r_v
    gain = np.zeros((cov.shape[0], h.shape[0]))
    gain[:n] = (cov @ h_joint.T)[:n] @ np.linalg.inv(s)
    i_kh = np.eye(cov.shape[0]) - gain @ h_joint
    return i_kh @ cov @ i_kh.T + gain @ r_v @ gain.T


def test_stored_error_update_is_the_joint_gaussian_one() -> None:
    """Two stored errors (3 variables each) taken from the filter at different times, ordinary
    updates in between, then updates whose noise carries one of them: P, the cross-covariances
    C and the stored covariance D equal those of a filter over the joint state (ε, e) that
    does not estimate e, and so do the gain's corrections of x."""
    phi, q, h, r, p0, x0 = _problem(3)
    n, m = x0.size, h.shape[0]
    rng = np.random.default_rng(4)
    kf = KalmanFilter(x0, p0, stored_errors=6)
    joint = np.zeros((n + 6, n + 6))
    joint[:n, :n] = p0
    x_ref = x0.copy()
    groups = (np.arange(3), np.arange(3, 6))
    store_at = {3: 0, 9: 1}
    carried_at = {14: 0, 17: 1, 20: 0}
    for step in range(22):
        kf.predict(phi, q)
        phi_joint = np.eye(n + 6)
        phi_joint[:n, :n] = phi
        joint = phi_joint @ joint @ phi_joint.T
        joint[:n, :n] += q
        x_ref = phi @ x_ref
        z = rng.standard_normal(m)
        if step in carried_at:
            cols = groups[carried_at[step]]
            b = rng.standard_normal((m, 3))
            b_full = np.zeros((m, 6))
            b_full[:, cols] = b
            r_total = r + b @ kf.stored_covariance[np.ix_(cols, cols)] @ b.T
            kf.update(z, h, r_total, correlated=CorrelatedNoise(cols, b))
            h_joint = np.hstack([h, b_full])
            s = h_joint @ joint @ h_joint.T + r
            x_ref = x_ref + (joint @ h_joint.T)[:n] @ np.linalg.solve(s, z - h @ x_ref)
            joint = _schmidt_reference(joint, n, h, b_full, r)
        else:
            kf.update(z, h, r)
            joint = _schmidt_reference(joint, n, h, np.zeros((m, 6)), r)
            x_ref = x_ref + kf.P @ h.T @ np.linalg.solve(r, z - h @ x_ref)
        if step in store_at:
            cols = groups[store_at[step]]
            h_store = rng.standard_normal((3, n))
            kf.store_error(cols, h_store)
            transform = np.eye(n + 6)
            transform[n + cols] = 0.0
            transform[np.ix_(n + cols, np.arange(n))] = h_store
            joint = transform @ joint @ transform.T
        np.testing.assert_allclose(kf.P, joint[:n, :n], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(kf.cross, joint[:n, n:], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(kf.stored_covariance, joint[n:, n:], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(kf.x, x_ref, rtol=1e-9, atol=1e-12)


def test_innovations_against_a_stored_estimate_are_consistent() -> None:
    """A random walk observed for 10 steps; its estimate at step 10 is stored and at step 20,
    after 10 unobserved steps, the walk is measured relative to it. With the stored error's
    correlation tracked, the NIS of that measurement averages 1 over 2000 runs and the
    posterior variance is the spread of the errors; taking the stored error for independent
    noise (its variance added to R) misses both (measured: NIS 0.97 and error variance 1.01×
    the posterior's tracked, 0.38 and 1.62× untracked)."""
    runs, q, r_direct, r_relative = 2000, 0.01, 1.0, 1e-4
    rng = np.random.default_rng(8)
    nis: dict[bool, list[float]] = {True: [], False: []}
    errors: dict[bool, list[float]] = {True: [], False: []}
    variances: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(runs):
        walk = np.cumsum(rng.normal(0.0, np.sqrt(q), 21))
        noise = rng.normal(0.0, np.sqrt(r_direct), 11)
        relative_noise = rng.normal(0.0, np.sqrt(r_relative))
        for tracked in (True, False):
            kf = KalmanFilter(np.zeros(1), np.array([[q]]), stored_errors=1)
            for k in range(21):
                if k:
                    kf.predict(np.eye(1), np.array([[q]]))
                if k <= 10:
                    kf.update(np.array([walk[k] + noise[k]]), np.eye(1), np.array([[r_direct]]))
                if k == 10:
                    stored = kf.x[0]
                    kf.store_error(np.array([0]), -np.eye(1))  # ŝ − x = −(x − x̂)
            # z = x_20 − x_10 + v, i.e. z + ŝ = x_20 + (ŝ − x_10) + v
            z = walk[20] - walk[10] + relative_noise + stored
            r = r_relative + kf.stored_covariance[0, 0]
            correlated = CorrelatedNoise(np.array([0]), np.eye(1)) if tracked else None
            res = kf.update(np.array([z]), np.eye(1), np.array([[r]]), correlated=correlated)
            nis[tracked].append(res.nis)
            errors[tracked].append(walk[20] - kf.x[0])
            variances[tracked].append(kf.P[0, 0])
    assert 0.9 < np.mean(nis[True]) < 1.1
    assert abs(np.var(errors[True]) / np.mean(variances[True]) - 1.0) < 0.1
    assert np.mean(nis[False]) < 0.5
    assert abs(np.var(errors[False]) / np.mean(variances[False]) - 1.0) > 0.1


def test_consider_states_are_left_alone_and_the_rest_updated_as_by_kalman() -> None:
    """Schmidt–Kalman: the considered states keep their estimate and variance; the others get
    the estimate and covariance of the full Kalman update (their gain does not depend on
    whether the considered states are corrected), and P stays symmetric positive definite."""
    for seed in range(5):
        _, _, h, r, p0, x0 = _problem(seed)
        z = np.random.default_rng(seed + 10).standard_normal(h.shape[0])
        full, schmidt = KalmanFilter(x0, p0), KalmanFilter(x0, p0)
        full.update(z, h, r)
        schmidt.update(z, h, r, consider=(2, 4))
        kept = [0, 1, 3, 5]
        np.testing.assert_allclose(schmidt.x[[2, 4]], x0[[2, 4]], atol=0)
        np.testing.assert_allclose(schmidt.P[np.ix_([2, 4], [2, 4])], p0[np.ix_([2, 4], [2, 4])])
        np.testing.assert_allclose(schmidt.x[kept], full.x[kept], atol=1e-12)
        np.testing.assert_allclose(
            schmidt.P[np.ix_(kept, kept)], full.P[np.ix_(kept, kept)], atol=1e-10
        )
        assert np.all(np.linalg.eigvalsh(schmidt.P) > 0)
