"""Generic position fixes (``position.csv``): GNSS on a surface test, a total station, a survey.

Measurement (ENU metres): the fix antenna or prism sits at the lever arm ``l`` (body frame,
``position.lever_arm_b_m`` in meta.yaml). With ``C̃_b^n = (I − φ×) C_b^n`` and ``p̃ = p + δp``,
the SINS-predicted point is ``p̃ + C̃ l = p_fix,true + δp + (C l) × φ``, so ::

    z = R_local (p̃_origin-ENU + C̃ l − p_fix),    H = [0, (C̃ l)×, I, 0, …],    R = diag(σ²)

where ``R_local`` turns the origin's ENU axes into the local level axes of the error states
(a rotation of d/R_earth: 3e-5 rad at 200 m, 1e-3 rad at 6 km).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from fusion.attitude import skew
from fusion.error_model import ATTITUDE, POSITION
from fusion.plugin import Measurement, MeasurementContext, MissingStream, Plugin, PluginOptions
from fusion.recording import Recording


class PositionOptions(PluginOptions):
    """Options of the position-fix plugin."""

    sigma_scale: float = Field(1.0, gt=0, description="multiplies the σ given in position.csv")
    min_sigma_m: float = Field(0.0, ge=0, description="floor added in quadrature to each σ")


class PositionFixes(Plugin):
    """Position fixes with their σ, through a lever arm."""

    Options = PositionOptions

    def __init__(self, name: str, options: PositionOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        if recording.position is None or recording.meta.position is None:
            raise MissingStream(f"plugin {name!r} needs position.csv in the recording")
        self.data = recording.position
        self.lever_arm = np.array(recording.meta.position.lever_arm_b_m, dtype=float)
        sigma = self.data.sigma * options.sigma_scale
        self.variance = sigma**2 + options.min_sigma_m**2

    def epochs(self) -> NDArray[np.float64]:
        """The fix times."""
        return self.data.t

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement:
        """Residual of the predicted antenna position against fix ``index``."""
        arm_n = ctx.c_b_n @ self.lever_arm
        rot = ctx.rotation_to_local  # origin ENU → local ENU
        z = rot @ (ctx.position_enu - self.data.enu[index]) + arm_n
        h = np.zeros((3, ctx.layout.dim))
        h[:, ctx.layout.slice(ATTITUDE)] = skew(arm_n)
        h[:, ctx.layout.slice(POSITION)] = np.eye(3)
        return Measurement(z, h, np.diag(self.variance[index]))
