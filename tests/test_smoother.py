"""RTS smoothing under closed-loop feedback against filterpy's smoother on the open-loop problem."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from fusion.kalman import KalmanFilter
from fusion.smoother import StepStore, rts


def _system() -> tuple[np.ndarray, ...]:
    dt = 0.1
    f = np.array([[1, dt, 0, 0], [0, 1, 0, dt], [0, 0, 1, dt], [0, 0, 0, 0.999]], dtype=float)
    q = np.diag([1e-4, 1e-3, 1e-4, 1e-6])
    h = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    r = np.diag([0.04, 0.09])
    return f, q, h, r


@pytest.mark.parametrize("budget_mb", [512.0, 0.0])
@pytest.mark.parametrize("fed_back", [(1, 1, 1, 1), (1, 1, 1, 0), (0, 0, 0, 0)])
def test_closed_loop_smoother_equals_open_loop_rts(
    fed_back: tuple[int, ...], budget_mb: float
) -> None:
    """Feed back some or all states after every update; the smoothed total state equals
    filterpy.rts_smoother on the equivalent open-loop problem (and spilling to disk changes
    nothing)."""
    f, q, h, r = _system()
    rng = np.random.default_rng(3)
    n_steps = 3000
    p0 = np.diag([1.0, 0.1, 1.0, 0.01])
    truth = rng.multivariate_normal(np.zeros(4), p0)
    zs = []
    for _ in range(n_steps):
        zs.append(h @ truth + rng.multivariate_normal(np.zeros(2), r))
        truth = f @ truth + rng.multivariate_normal(np.zeros(4), q)

    mask = np.array(fed_back, dtype=float)
    nominal = np.zeros(4)
    kf = KalmanFilter(np.zeros(4), p0)
    store = StepStore(4, memory_budget_mb=budget_mb)
    nominal_after = []
    for k, z in enumerate(zs):
        if k > 0:
            nominal = f @ nominal
            kf.predict(f, q)
        prior = (kf.x.copy(), kf.P.copy())
        kf.update(h @ nominal - z, h, r)  # error = nominal − truth
        posterior = (kf.x.copy(), kf.P.copy())
        u = kf.x * mask
        nominal = nominal - u
        kf.x = kf.x - u
        store.append(0.1 * k, f, prior, posterior, u, output=True)
        nominal_after.append(nominal.copy())
    assert store.spilled == (budget_mb == 0.0)
    d, p_s = rts(store)
    store.close()
    smoothed = np.array(nominal_after) - d

    ref = FilterpyKF(dim_x=4, dim_z=2)
    ref.x, ref.P, ref.F, ref.Q, ref.H, ref.R = np.zeros(4), p0.copy(), f, q, h, r
    xs, ps = [], []
    for k, z in enumerate(zs):
        if k > 0:
            ref.predict()
        ref.update(z)
        xs.append(ref.x.copy())
        ps.append(ref.P.copy())
    fs = np.repeat(f[None], n_steps, axis=0)
    qs = np.repeat(q[None], n_steps, axis=0)
    x_ref, p_ref, _, _ = ref.rts_smoother(np.array(xs), np.array(ps), fs, qs)
    np.testing.assert_allclose(smoothed, x_ref, atol=1e-8)
    np.testing.assert_allclose(p_s, p_ref, atol=1e-10)
