"""Right-invariant error coordinates: the filter's covariance kept in the error of the invariant
EKF, the plugins' measurements and the SINS feedback in the error of :mod:`fusion.error_model`.

The error state of :mod:`fusion.error_model` (``δv``, ``φ``, ``δp``, biases) measures the velocity
and position errors in a fixed frame. Turn the whole estimated trajectory by α about the vertical
and that error moves along ``N = [δv = v̂ × e_U, φ = e_U, δp = p̂ × e_U]``, a direction that
changes with the nominal velocity; its dynamics carry the
nominal specific force, ``δv̇ = fⁿ × φ``, and whatever fluctuation that force shows (a tilt error
times gravity, cutting vibration) "observes" the heading at a standstill.

The right-invariant error of the extended pose (Barrau & Bonnabel, *The invariant extended Kalman
filter as a stable observer*, IEEE TAC 62(4), 2017, §V; with IMU biases as in Hartley et al.,
*Contact-aided invariant extended Kalman filtering for robot state estimation*, IJRR 39(4), 2020)
is, to first order and in this module's sign convention (``C̃ = (I − φ×) C``),

    ξ_φ = φ,   ξ_v = δv − v × φ,   ξ_p = δp − p × φ,   biases unchanged,

that is ``δx = T ξ`` with ``T`` the identity but for the blocks ``v×`` (velocity ← attitude) and
``p×`` (position ← attitude); ``p`` is the ENU position about the recording's origin and ``v``,
``p`` the true velocity and position (in practice their best estimate). A turn of the
trajectory is then ``ξ = (e_U, 0, 0, …)`` at every instant, and its dynamics no longer hold the
specific force:

    ξ̇_φ = φ̇,   ξ̇_v = −g × ξ_φ + C∇ + v × Cε + …,   ξ̇_p = ξ_v + p × Cε + …

(``F_ξ = T⁻¹ (F T − Ṫ)``, ``F`` and ``Ṫ`` at the same specific force, whose ``fⁿ`` then cancels
exactly from the columns ``T`` carries). Since ``g`` is vertical, the heading enters no velocity
derivative, and a source that cannot see a turn (a zero velocity, a body-frame velocity
evaluated at the same velocity as ``T``) has no heading column: what is unobservable stays so
without constraining anything. (The observability-constrained EKF of Huang, Mourikis &
Roumeliotis, IJRR 2010, projects the same direction out of Φ and H instead; it was this
project's first treatment, with the same figures: docs/design/2026-11-29-ablation-regressions.md.)

``T`` may carry the heading alone (:data:`AXES` ``heading``: the turn about the vertical, the one
symmetry gravity leaves; the tilt keeps the standard error and its ``fⁿ × φ``) or the whole attitude
(``full``). ``heading`` is on in the odometer-only configurations and in ``sins_uwb``; measured
effects, and why it is not the default elsewhere: ``docs/design/2026-11-29-invariant-error.md``.

The plugins keep their measurement rows in the error of :mod:`fusion.error_model`; the engine
multiplies them by ``T`` at the velocity the plugin linearized at
(:attr:`fusion.plugin.Measurement.velocity_at`: zero for a zero-velocity update, the column
velocity for a motion constraint) and feeds back ``T ξ̂`` at the nominal state. The covariance
read by plugins and written to the outputs is ``T P_ξ Tᵀ``. Differences from the invariant EKF
proper: the feedback is first order (the SINS is corrected, not retracted on the group), and the
IMU biases' columns use the nominal state (the "imperfect" InEKF of Hartley et al.). And ``T``
follows the corrected nominal velocity while ``P_ξ`` is kept across a feedback: with a motion
constraint alone on a straight face the speed along the track then rings
(docs/design/2026-11-29-invariant-error.md).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion import earth, kernels
from fusion.attitude import skew
from fusion.error_model import ATTITUDE, POSITION, VELOCITY, ErrorModel, discretize
from fusion.strapdown import HGT, LAT, VEL

_V = slice(0, 3)
_PHI = slice(3, 6)
_P = slice(6, 9)
AXES = {"heading": (2,), "full": (0, 1, 2)}
"""Attitude components whose turn the coordinates carry: the heading alone (a turn about the
local vertical, the symmetry gravity leaves) or all three (the invariant EKF proper)."""


class InvariantCoordinates:
    """``δx = T ξ`` over the attitude components ``axes`` (:data:`AXES`): ``T = I + A`` with
    ``A`` the blocks ``v×`` and ``p×`` restricted to those columns (``A² = 0``, so
    ``T⁻¹ = I − A``)."""

    def __init__(self, axes: tuple[int, ...]) -> None:
        self.columns = np.array([_PHI.start + a for a in axes], dtype=np.intp)
        self._axes = list(axes)

    def _blocks(
        self, velocity: NDArray[np.float64], position: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return skew(velocity)[:, self._axes], skew(position)[:, self._axes]

    def transform(
        self, dim: int, velocity: NDArray[np.float64], position: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """``T`` (dim × dim) at ENU ``velocity`` (m/s) and ``position`` about the origin (m)."""
        return self.apply(np.eye(dim), velocity, position)

    def inverse_transform(
        self, dim: int, velocity: NDArray[np.float64], position: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """``T⁻¹ = I − A``."""
        return self.apply(np.eye(dim), velocity, position, -1.0)

    def rows(
        self, h: NDArray[np.float64], velocity: NDArray[np.float64], position: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """``H T``: measurement rows over the standard error expressed over ``ξ``."""
        v_block, p_block = self._blocks(velocity, position)
        rows = h.copy()
        rows[:, self.columns] += h[:, _V] @ v_block + h[:, _P] @ p_block
        return rows

    def apply(
        self,
        x: NDArray[np.float64],
        velocity: NDArray[np.float64],
        position: NDArray[np.float64],
        sign: float = 1.0,
    ) -> NDArray[np.float64]:
        """``T x`` (``sign`` 1) or ``T⁻¹ x`` (−1) for a vector or the columns of a matrix
        (the rows of ``A`` are velocity and position, its columns the carried attitude)."""
        return self._apply(x, *self._blocks(velocity, position), sign)

    def _apply(
        self,
        x: NDArray[np.float64],
        v_block: NDArray[np.float64],
        p_block: NDArray[np.float64],
        sign: float,
    ) -> NDArray[np.float64]:
        y = x.copy()
        carried = x[self.columns]
        y[_V] += sign * (v_block @ carried)
        y[_P] += sign * (p_block @ carried)
        return y

    def congruent(
        self,
        p: NDArray[np.float64],
        velocity: NDArray[np.float64],
        position: NDArray[np.float64],
        sign: float = 1.0,
    ) -> NDArray[np.float64]:
        """``T P Tᵀ`` (``sign`` 1) or ``T⁻¹ P T⁻ᵀ`` (−1)."""
        return self._congruent(p, *self._blocks(velocity, position), sign)

    def _congruent(
        self,
        p: NDArray[np.float64],
        v_block: NDArray[np.float64],
        p_block: NDArray[np.float64],
        sign: float,
    ) -> NDArray[np.float64]:
        once = self._apply(p, v_block, p_block, sign)
        return self._apply(once.T, v_block, p_block, sign).T

    def to_standard(
        self,
        x: NDArray[np.float64],
        p: NDArray[np.float64],
        velocity: NDArray[np.float64],
        position: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(T x, T P Tᵀ)``."""
        blocks = self._blocks(velocity, position)
        return self._apply(x, *blocks, 1.0), self._congruent(p, *blocks, 1.0)

    def transition(
        self,
        model: ErrorModel,
        nav: NDArray[np.float64],
        f_n: NDArray[np.float64],
        c_b_n: NDArray[np.float64],
        position: NDArray[np.float64],
        dt: float,
        heading_coupling: float = 1.0,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Φ_ξ and Q_d,ξ over ``dt`` at the nominal state: ``F_ξ = T⁻¹ (F T − Ṫ)`` with ``F``
        at the specific force ``f_n`` (and ``heading_coupling``,
        :func:`fusion.error_model.heading_coupling`) and ``Ṫ`` at
        ``v̇ = fⁿ + g − (2ω_ie + ω_en) × v``, the same force, which therefore cancels from the
        columns ``T`` carries."""
        layout = model.layout
        assert (layout.slice(VELOCITY), layout.slice(ATTITUDE), layout.slice(POSITION)) == (
            _V,
            _PHI,
            _P,
        )
        f, q = model.continuous(nav, f_n, c_b_n, heading_coupling)
        v = nav[VEL : VEL + 3]
        lat, h = float(nav[LAT]), float(nav[HGT])
        _, _, w_ie, w_en = kernels.frame_rates(lat, h, v)
        gravity = np.array([0.0, 0.0, -float(earth.normal_gravity(lat, h))])
        acceleration = f_n + gravity - np.cross(2.0 * w_ie + w_en, v)
        f_t = self.rows(f, v, position)  # F T
        f_t[_V, self.columns] -= skew(acceleration)[:, self._axes]  # − Ṫ
        f_t[_P, self.columns] -= skew(v)[:, self._axes]
        f_xi = self.apply(f_t, v, position, -1.0)
        q_xi = self.congruent(q, v, position, -1.0)
        return discretize(f_xi, q_xi, dt, model.discretization)
