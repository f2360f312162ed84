"""Bridging IMU logging gaps: the rates assumed over a gap and the uncertainty they leave.

An IMU sample ``k`` stands for the mean angular rate and specific force over ``(t_{k-1}, t_k]``
(RECORDING_FORMAT.md). After a logging gap that is no longer true: the sample closing the gap
measured only its own sample period, and integrating it over the whole gap turns one instant of
vibration into a velocity error. On a shearer (≈ 0.35 m/s² of conveyor vibration per sample)
a 1-s gap left 0.4–0.5 m/s of velocity error, far outside the covariance, and the federated
filter's fault detection blamed every aiding sensor in turn.

A bridged gap ``(t_a, t_b]`` of length ``T`` is therefore given

* the rates of the window ``W = max(T, 1 s)`` before the gap, averaged: the motion the gap
  hides is assumed to continue at the level it had, while the vibration averages out; the
  closing sample's value is replaced by that mean (it is the mean over the gap that the
  contract asks for);
* an uncertainty per axis ``σ = √2 · std(block means)``, the spread of the window's means over
  blocks of ``W/10``: what remains of the motion after averaging at that scale, once for the
  window's mean and once for the gap's own. The error is one constant offset ``δ = [δω, δf]``
  over the whole gap (the same assumed value is held throughout), so it enters the error state
  like a bias held for ``T`` (error_model: ``φ̇ = … − C_b^n ε``, ``δv̇ = … + C_b^n ∇``)::

      δx(t_b) = G δ,   G = (I T + F T²/2 + F² T³/6) B,   Q_gap = G diag(σ²) Gᵀ

  with ``B`` the bias columns of ``F`` without the bias rows. The engine adds
  ``Q_gap`` once, at the first covariance step that reaches into the gap — early rather than
  late, so measurements inside the gap are not judged against a covariance that does not know
  the gap yet.

No gap is bridged unless the recording was read with ``bridge_imu_gaps=True``; the reader
reports and logs each one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.recording import ImuData

MIN_WINDOW_S = 1.0
"""Shortest window of samples before a gap whose mean bridges it (s)."""
BLOCKS = 10
"""Blocks per window for the spread of the motion left after averaging."""


@dataclass(frozen=True)
class GapBridge:
    """One bridged gap ``(t_start, t_end]`` and the per-axis σ of the rates assumed over it.

    Attributes
    ----------
    t_start, t_end : float
        Last sample before and first sample after the gap (s).
    sigma_gyro : ndarray, shape (3,)
        σ of the assumed mean angular rate (rad/s).
    sigma_accel : ndarray, shape (3,)
        σ of the assumed mean specific force (m/s²).
    """

    t_start: float
    t_end: float
    sigma_gyro: NDArray[np.float64]
    sigma_accel: NDArray[np.float64]

    @property
    def length_s(self) -> float:
        """Length of the gap (s)."""
        return self.t_end - self.t_start

    def noise(
        self, f: NDArray[np.float64], gyro_bias: slice, accel_bias: slice
    ) -> NDArray[np.float64]:
        """``Q_gap`` (n×n) for the error dynamics ``F`` at the gap (module docstring).

        Parameters
        ----------
        f
            Continuous error dynamics at the start of the gap.
        gyro_bias, accel_bias
            Where the two bias blocks sit in the state.
        """
        n = f.shape[0]
        b = np.hstack([f[:, gyro_bias], f[:, accel_bias]])
        b[gyro_bias] = 0.0  # δ is not a change of the bias states themselves
        b[accel_bias] = 0.0
        t = self.length_s
        ft = f * t
        g = (np.eye(n) * t + ft * t / 2.0 + ft @ ft * t / 6.0) @ b
        sigma2 = np.concatenate([self.sigma_gyro, self.sigma_accel]) ** 2
        q = (g * sigma2) @ g.T
        return 0.5 * (q + q.T)


def bridge_imu_gaps(
    imu: ImuData, gaps: list[tuple[float, float]]
) -> tuple[ImuData, list[GapBridge]]:
    """The IMU with each gap's closing sample replaced by the window mean, and the bridges.

    Parameters
    ----------
    imu
        The samples as read.
    gaps
        ``(t_before, t_after)`` of each gap (``Recording.imu_gaps``).

    Returns
    -------
    ImuData
        A copy (the input itself when there are no gaps).
    list of GapBridge
        One per gap, in time order.
    """
    if not gaps:
        return imu, []
    gyro, accel = imu.gyro.copy(), imu.accel.copy()
    bridges = []
    for t_before, t_after in sorted(gaps):
        closing = int(np.searchsorted(imu.t, t_after))
        window = max(t_after - t_before, MIN_WINDOW_S)
        first = int(np.searchsorted(imu.t, t_before - window, side="right"))
        rows = slice(first, closing)  # the samples of the window, up to t_before
        gyro[closing] = imu.gyro[rows].mean(axis=0)
        accel[closing] = imu.accel[rows].mean(axis=0)
        bridges.append(
            GapBridge(
                t_before,
                t_after,
                _spread_of_means(imu.gyro[rows]),
                _spread_of_means(imu.accel[rows]),
            )
        )
    return ImuData(t=imu.t, gyro=gyro, accel=accel), bridges


def _spread_of_means(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """``√2 · std`` of the means of ``BLOCKS`` equal blocks (per axis; whole samples).

    Fewer than ``BLOCKS`` samples (a gap right after the start) give blocks of one sample, the
    most conservative spread; a single sample gives zero, as nothing is known of the motion.
    """
    per_block = max(samples.shape[0] // BLOCKS, 1)
    blocks = samples.shape[0] // per_block
    means = samples[: blocks * per_block].reshape(blocks, per_block, 3).mean(axis=1)
    spread = means.std(axis=0, ddof=1) if blocks > 1 else np.zeros(3)
    return np.asarray(np.sqrt(2.0) * spread, dtype=float)
