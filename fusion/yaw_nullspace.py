"""Observability-constrained EKF: a turn of the whole trajectory about the vertical stays
unobservable to the sources that cannot see it.

Turn the true trajectory by an angle α about the local vertical: the body-frame IMU readings do
not change (up to the Earth's rate, far below a MEMS gyro's bias), nor does a zero velocity, a
zero angular rate, a body-frame speed or a motion constraint. To such sources the heading is
unobservable, and an EKF whose Jacobians are evaluated at its own fluctuating estimates finds
information there anyway: ``f̂ⁿ × φ`` couples the heading to the velocity through whatever
horizontal force the nominal state shows (a tilt error times gravity, vibration), and a zero
velocity update then "observes" the heading and the vertical gyro bias at a standstill
(docs/design/2026-11-27-observability.md: σ of the vertical gyro bias from 20 to 1 °/h in
10 minutes at rest with 50 mg of fluctuation).

In the error state of :mod:`fusion.error_model` (``δv``, ``φ``, ``δp``, biases; ``δv̇ = fⁿ × φ``,
``δṗ = δv``) that turn is the direction

    N = [δv = v̂ × e_U,  φ = e_U,  δp = (p̂ − c) × e_U,  0 …]

(``e_U`` the local up axis, ``c`` a point on the axis of the turn: the frame's origin here).
Following the observability-constrained EKF (Huang, Mourikis & Roumeliotis, *Observability-based
rules for designing consistent EKF SLAM estimators*, IJRR 2010; Hesch et al., *Consistency
analysis and improvement of vision-aided inertial navigation*, IEEE T-RO 2014), ``N`` is taken at
the propagated (prior) estimates, and each transition is changed so that it carries ``N_k`` at
one covariance step onto ``N_k+1`` at the next, however the feedback moved the estimate between:

    Φ* = Φ + (N_k+1 − Φ N_k) e_ψᵀ        ⇒ Φ* N_k = N_k+1

(``e_ψ`` selects the heading column; ``N_k`` has 1 there, so only that column changes), and the
measurement rows of a source that cannot see a turn are changed so that they do not see it:

    H* = H − (H N) e_ψᵀ                   ⇒ H* N = 0.

The rest of Φ and H is left as it was; a source that sees the heading (a magnetometer, UWB
anchors, position fixes, CPOEM's stored face line) keeps its rows, and brings the heading
information it really has. The Earth's rate, which would let a navigation-grade gyro find north
at rest, is dropped along with the rest of the heading's spurious coupling: this is an option for
MEMS-grade IMUs (``filter.observability_constrained``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.error_model import ATTITUDE, POSITION, VELOCITY, StateLayout

HEADING = 2
"""Index of the up component within the attitude block (``φ_U``)."""


def turn_direction(
    layout: StateLayout, velocity_enu: NDArray[np.float64], position_enu: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``N`` over ``layout``: the error of a unit turn about the vertical through the ENU
    origin, at ENU velocity ``velocity_enu`` and position ``position_enu`` (m)."""
    n = np.zeros(layout.dim)
    n[layout.slice(ATTITUDE).start + HEADING] = 1.0
    n[layout.slice(VELOCITY)] = (velocity_enu[1], -velocity_enu[0], 0.0)  # v × e_U
    n[layout.slice(POSITION)] = (position_enu[1], -position_enu[0], 0.0)  # p × e_U
    return n


def constrain_transition(
    phi: NDArray[np.float64],
    before: NDArray[np.float64],
    after: NDArray[np.float64],
    layout: StateLayout,
) -> NDArray[np.float64]:
    """``Φ*`` with ``Φ* before = after`` (only the heading column changes)."""
    constrained = phi.copy()
    constrained[:, layout.slice(ATTITUDE).start + HEADING] += after - phi @ before
    return constrained


def constrain_rows(
    h: NDArray[np.float64], direction: NDArray[np.float64], layout: StateLayout
) -> NDArray[np.float64]:
    """``H*`` with ``H* direction = 0`` (only the heading column changes)."""
    constrained = h.copy()
    constrained[:, layout.slice(ATTITUDE).start + HEADING] -= h @ direction
    return constrained
