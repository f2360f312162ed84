"""The README's worked plugin example: height fixes with a datum offset state it owns."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.error_model import POSITION, StateBlock
from fusion.plugin import Measurement, MeasurementContext, Plugin, PluginOptions


class HeightOptions(PluginOptions):
    sigma_m: float = 0.05
    offset_sigma_m: float = 0.1


class HeightFix(Plugin):
    """Heights from position.csv against the SINS height, with an unknown datum offset."""

    Options = HeightOptions
    options: HeightOptions

    def state_blocks(self) -> tuple[StateBlock, ...]:  # optional: states this plugin owns
        return (StateBlock(f"{self.name}.datum_offset", ("u",), (self.options.offset_sigma_m,)),)

    def epochs(self) -> NDArray[np.float64]:  # when to call measure()
        assert self.recording.position is not None, "needs position.csv"
        return self.recording.position.t

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        assert self.recording.position is not None
        # fix = true height + datum offset b; z = SINS height − fix = δp_up − b. The filter
        # subtracts H x itself, so z is formed from the nominal state only.
        z = np.array([ctx.position_enu[2] - self.recording.position.enu[index, 2]])
        h = np.zeros((1, ctx.layout.dim))
        h[0, ctx.layout.slice(POSITION).start + 2] = 1.0  # δp_up
        h[0, ctx.layout.slice(f"{self.name}.datum_offset")] = -1.0  # b
        return Measurement(z, h, np.array([[self.options.sigma_m**2]]))
