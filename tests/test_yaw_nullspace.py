"""The observability-constrained EKF keeps a turn about the vertical unobservable."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.config import parse_config
from fusion.engine import Engine
from fusion.error_model import observable_force
from fusion.kalman import KalmanFilter
from fusion.observability import ObservabilityTracker
from fusion.yaw_nullspace import constrain_rows, constrain_transition, turn_direction
from tests.test_engine import make_recording

G = 9.81


def _standstill(
    fluctuation_mg: float, constrained: bool, seconds: float = 300.0
) -> tuple[float, float, float, float]:
    """Covariance only, the engine's error model at rest, level, a zero-velocity update every
    0.1 s (σ 1 cm/s), the specific force in F gravity plus a white horizontal fluctuation;
    the nominal velocity a few mm/s and its position wandering by mm (what the zero velocity
    leaves). σ of the vertical gyro bias and of the yaw (with updates, then
    the prior propagated without any)."""
    engine = Engine(
        parse_config({"name": "z", "plugins": [{"type": "zupt"}]}),
        make_recording(1, 30.0, fixes=False),
    )
    layout, model = engine.layout, engine.model
    nav = engine.initial_state().to_array()
    rng = np.random.default_rng(7)
    kf = KalmanFilter(np.zeros(layout.dim), layout.initial_covariance())
    prior = ObservabilityTracker(layout)
    h = np.zeros((3, layout.dim))
    h[:, layout.slice("velocity")] = np.eye(3)
    r = 1e-4 * np.eye(3)
    position = np.zeros(3)
    before = turn_direction(layout, np.zeros(3), position)
    for _ in range(int(seconds / 0.1)):
        f = np.array([*(fluctuation_mg * 1e-3 * G * rng.standard_normal(2)), G])
        f = observable_force(f, np.eye(3), kf.P[:15, :15])
        phi, qd = model.discrete(nav, f, np.eye(3), 0.1)
        position += 0.001 * rng.standard_normal(3)  # the nominal's drift and the corrections
        after = turn_direction(layout, 0.003 * rng.standard_normal(3), position)
        rows = h
        if constrained:
            phi = constrain_transition(phi, before, after, layout)
            rows = constrain_rows(h, after, layout)
        before = after
        kf.predict(phi, qd)
        prior.predict(phi, qd)
        kf.update(np.zeros(3), rows, r)
    prior_variance = prior.report(kf.P).prior_variance
    bz, yaw = layout.slice("gyro_bias").start + 2, layout.slice("attitude").start + 2
    sd = np.sqrt(np.diag(kf.P))
    sd_prior = np.sqrt(prior_variance)
    return float(sd[bz]), float(sd[yaw]), float(sd_prior[bz]), float(sd_prior[yaw])


@pytest.mark.parametrize("fluctuation_mg", [0.0, 5.0, 50.0])
def test_a_standstill_observes_neither_the_heading_nor_the_vertical_gyro_bias(
    fluctuation_mg: float,
) -> None:
    """However the specific force fluctuates, σ(b_gz) and the yaw σ stay at what the prior
    alone gives (≥ 99 %); the unconstrained filter, on the same recursion, finds heading
    information in a fluctuating force (σ(b_gz) below half its prior at 50 mg)."""
    bz, yaw, bz_prior, yaw_prior = _standstill(fluctuation_mg, constrained=True)
    print(
        f"{fluctuation_mg} mg: σ(b_gz) {bz:.3g} of {bz_prior:.3g},"
        f" yaw σ {yaw:.3g} of {yaw_prior:.3g}"
    )
    assert bz >= 0.99 * bz_prior and yaw >= 0.99 * yaw_prior
    if fluctuation_mg == 50.0:
        bz_plain, *_ = _standstill(fluctuation_mg, constrained=False)
        assert bz_plain < 0.5 * bz_prior


def test_the_constraint_carries_and_hides_the_turn() -> None:
    """Φ* N_k = N_k+1 and H* N = 0, with only the heading column changed."""
    engine = Engine(
        parse_config({"name": "z", "plugins": [{"type": "zupt"}]}),
        make_recording(1, 30.0, fixes=False),
    )
    layout = engine.layout
    rng = np.random.default_rng(1)
    phi = np.eye(layout.dim) + 0.01 * rng.standard_normal((layout.dim, layout.dim))
    before = turn_direction(layout, rng.standard_normal(3), np.zeros(3))
    after = turn_direction(layout, rng.standard_normal(3), rng.standard_normal(3))
    constrained = constrain_transition(phi, before, after, layout)
    assert np.allclose(constrained @ before, after)
    heading = layout.slice("attitude").start + 2
    others = np.arange(layout.dim) != heading
    assert np.array_equal(constrained[:, others], phi[:, others])
    h = rng.standard_normal((3, layout.dim))
    assert np.allclose(constrain_rows(h, after, layout) @ after, 0.0)
