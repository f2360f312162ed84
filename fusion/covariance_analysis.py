"""The covariance the outputs report, when the filter's own cannot be believed: the actual error
covariance of the filter's estimate, analysed in the right-invariant error.

A Kalman filter's ``P`` is the error covariance of its estimate only if its model is right. With
no source that sees the heading (a motion constraint, zero velocities) the standard error state
of :mod:`fusion.error_model` is not: its rows and its ``fⁿ × φ`` are evaluated at a nominal
velocity and specific force that are themselves wrong, and through them the filter finds the
heading observable when nothing observes it. Its gains then correct the heading from noise and
its ``P`` claims the correction worked (``docs/design/2026-11-29-yaw-consistency.md``).

Whatever the gains ``K_k`` (however they were chosen), the error of the estimate evolves as

    e⁺ = (I − K H) e⁻ − K w,     e_{k+1} = Φ e_k + n_k

under the *true* model ``(Φ, H)``, and its covariance by the Joseph form with those gains
(Gelb, *Applied Optimal Estimation*, 1974, §7.2; Maybeck, *Stochastic Models, Estimation and
Control* vol. 1, §6.8):

    P_a⁺ = (I − K H) P_a⁻ (I − K H)ᵀ + K R Kᵀ,     P_a ← Φ P_a Φᵀ + Q_d.

This module runs that recursion with the filter's gains and, as the true model, the
linearization in the right-invariant error of the heading (:mod:`fusion.invariant_error`): there
a turn of the whole trajectory about the vertical is one fixed direction whatever the nominal
state, so a source that cannot see it has no heading column and ``Φ_ξ`` carries no specific
force into it. The filter's gain is over the standard error; over ``ξ`` it is ``T⁻¹ K``, and the
rows ``H T`` at the velocity the plugin linearized at. ``P_a`` is kept across a feedback, as the
invariant EKF keeps its covariance (the estimate it describes is the corrected one either way).

The estimate is the filter's: this changes no position, only the σ it is reported with. An
update analysed with the filter's own rows is the filter's own Joseph form; what differs is the
heading column the true model denies a source that cannot see a turn, the specific force the
transition leaves out of the heading, and the covariance kept across a feedback.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.invariant_error import AXES, InvariantCoordinates
from fusion.kalman import propagate_covariance


class CovarianceAnalysis:
    """``P_a`` over the right-invariant heading error ``ξ`` (module docstring), from a standard
    covariance ``p`` at ENU ``velocity`` and ``position`` (about the origin)."""

    def __init__(
        self,
        p: NDArray[np.float64],
        velocity: NDArray[np.float64],
        position: NDArray[np.float64],
    ) -> None:
        self.coordinates = InvariantCoordinates(AXES["heading"])
        self.P = self.coordinates.congruent(p, velocity, position, -1.0)
        self._identity = np.eye(p.shape[0])

    def predict(self, phi: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """Time update with ``Φ_ξ`` and ``Q_d,ξ`` (:meth:`InvariantCoordinates.transition`)."""
        self.P = propagate_covariance(self.P, phi, qd)

    def add(
        self,
        noise: NDArray[np.float64],
        velocity: NDArray[np.float64],
        position: NDArray[np.float64],
    ) -> None:
        """Add a covariance ``noise`` over the standard error (process noise a plugin releases
        at an instant). An inflation of the filter's covariance changes its gains, not its
        error, and is not added."""
        self.P = self.P + self.coordinates.congruent(noise, velocity, position, -1.0)

    def update(
        self,
        gain: NDArray[np.float64],
        h: NDArray[np.float64],
        r: NDArray[np.float64],
        rows_velocity: NDArray[np.float64],
        velocity: NDArray[np.float64],
        position: NDArray[np.float64],
    ) -> None:
        """The filter's update with ``gain`` over the standard error and rows ``h`` over the
        standard error (linearized at ``rows_velocity``), noise ``r``: the Joseph form over
        ``ξ`` with ``T⁻¹ K`` and ``H T``."""
        k = self.coordinates.apply(gain, velocity, position, -1.0)
        i_kh = self._identity - k @ self.coordinates.rows(h, rows_velocity, position)
        p = i_kh @ self.P @ i_kh.T + k @ r @ k.T
        self.P = 0.5 * (p + p.T)

    def standard(
        self, velocity: NDArray[np.float64], position: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """``T P_a Tᵀ``: the analysed covariance over the standard error."""
        return self.coordinates.congruent(self.P, velocity, position)

    def restart_block(
        self,
        indices: NDArray[np.intp],
        covariance: NDArray[np.float64],
        velocity: NDArray[np.float64],
        position: NDArray[np.float64],
    ) -> None:
        """Standard states ``indices`` restarted with ``covariance``, uncorrelated with the rest
        (a re-acquisition: their error is now the fix's)."""
        p = self.standard(velocity, position)
        p[indices, :] = 0.0
        p[:, indices] = 0.0
        p[np.ix_(indices, indices)] = covariance
        self.P = self.coordinates.congruent(p, velocity, position, -1.0)
