"""Zero angular rate update (ZARU) at a standstill, shared by the ``zupt`` and ``odometer``
plugins.

A machine that stands does not turn, so the mean gyro output ω̄ over an interval of N samples at
rate f_s, minus the bias the SINS removes (``ctx.gyro_bias`` = b̂, with the error state
ε = b − b̂), is the earth rate seen in the body frame. With ``C̃_n^b = C_n^b (I + φ×)``::

    z = ω̄ − b̂ − C̃_n^b ω_ieⁿ = ε + C̃_n^b (ω_ieⁿ×) φ + n,
    R = diag(max(N_g² f_s, s²) / N + σ_floor²)

(N_g the datasheet angle random walk, s² the samples' own variance per axis pooled over the
last intervals at rest, σ_floor the standstill vibration). s²/N is the standard error of the
mean when the gyro is noisier than its datasheet (a harsh world's IMU 2–5× its figures, a
conveyor shaking the machine): with the datasheet's alone the ZARU rows came out 5–13σ at rest
and the odometer update that carries them was rejected whole, until the SINS coasted.

The ZARU makes every gyro bias observable at rest — the vertical one included, which no velocity
update reaches — so a static start learns a large turn-on bias (an MTi-G-700's 720 °/h) before
the heading has run away with it: the static gyro calibration every MEMS alignment begins with.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from numpy.typing import NDArray

from fusion.attitude import skew
from fusion.earth import OMEGA_IE
from fusion.error_model import ATTITUDE, GYRO_BIAS
from fusion.plugin import Measurement, MeasurementContext
from fusion.recording import Recording

SCATTER_INTERVALS = 20
"""ZARU intervals whose gyro scatter is pooled (2 s of a standstill at 10 Hz)."""


class ZeroAngularRate:
    """The ZARU rows over an interval of the recording's IMU samples.

    Parameters
    ----------
    recording
        Supplies the IMU samples and ``meta.yaml`` ``imu.spec.gyro_arw_deg_rth`` (the noise).
    floor_dps
        Standstill vibration added to the averaged ARW, 1σ in deg/s.
    owner
        Plugin name for the error raised when the datasheet ARW is missing.
    """

    def __init__(self, recording: Recording, floor_dps: float, owner: str) -> None:
        spec = recording.meta.imu.spec
        if spec is None or spec.gyro_arw_deg_rth is None:
            raise ValueError(
                f"plugin {owner!r}: zero_angular_rate needs meta.yaml imu.spec.gyro_arw_deg_rth"
                " (its noise)"
            )
        self.imu = recording.imu
        self.arw = math.radians(spec.gyro_arw_deg_rth) / 60.0
        self.rate = 1.0 / float(np.median(np.diff(self.imu.t)))
        self.floor = math.radians(floor_dps)
        self._scatter: deque[tuple[NDArray[np.float64], int]] = deque(maxlen=SCATTER_INTERVALS)

    def start_run(self) -> None:
        """Forget a run's gyro scatter at rest."""
        self._scatter.clear()

    def measure(self, t_start: float, t_end: float, ctx: MeasurementContext) -> Measurement:
        """The ZARU from the IMU samples in ``(t_start, t_end]`` (module docstring); from the
        last sample at or before ``t_end`` when the interval holds none (an epoch grid as fine
        as the IMU's)."""
        stop = int(np.searchsorted(self.imu.t, t_end, side="right"))
        start = min(int(np.searchsorted(self.imu.t, t_start, side="right")), stop - 1)
        samples = slice(max(start, 0), stop)
        count = max(samples.stop - samples.start, 1)
        c_n_b = ctx.c_b_n.T
        w_ie = OMEGA_IE * np.array([0.0, np.cos(ctx.lat), np.sin(ctx.lat)])
        gyro = self.imu.gyro[samples]
        mean = gyro.mean(axis=0)
        z = mean - ctx.gyro_bias - c_n_b @ w_ie
        h = np.zeros((3, ctx.layout.dim))
        h[:, ctx.layout.slice(GYRO_BIAS)] = np.eye(3)
        h[:, ctx.layout.slice(ATTITUDE)] = c_n_b @ skew(w_ie)
        variance = np.maximum(self.arw**2 * self.rate, self._spread(gyro, mean)) / count
        return Measurement(z, h, np.diag(variance + self.floor**2))

    def _spread(self, gyro: NDArray[np.float64], mean: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per-axis variance of the gyro samples at rest (``gyro``, their ``mean``), pooled
        over the last :data:`SCATTER_INTERVALS` intervals (a 10-sample interval's own estimate
        alone, taken at its max with the datasheet's, would raise R by a quarter on average)."""
        if gyro.shape[0] > 1:
            self._scatter.append((np.sum((gyro - mean) ** 2, axis=0), gyro.shape[0] - 1))
        if not self._scatter:
            return np.zeros(3)
        dof = sum(d for _, d in self._scatter)
        return np.sum([ss for ss, _ in self._scatter], axis=0) / dof
