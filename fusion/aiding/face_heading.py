"""The shearer's heading along its face: a longwall shearer rides the AFC, so its body y axis
(forward, along the face: docs/recording-format.md) points along the surveyed face line.

Why. Nothing else a shearer carries needs to measure its heading: UWB ranges and a motion
constraint see it only through the track between the face ends, a magnetometer is often
absent or disturbed underground, and a SINS heading left to itself drifts by the vertical gyro
bias. On random worlds at their own length, ``sins_uwb`` ran 23° off the face's heading after
an hour, then 50–120° after a lost lock, and followed the mirror image of a row of anchors at a
σ of centimetres (docs/design/2026-11-27-face-heading.md). The face line alone bounds the
heading to a few degrees, without any sensor.

The reference. With the face line of meta.yaml's ``face.ends_enu_m`` (:mod:`fusion.face`) of
azimuth α (clockwise from north, end A to end B), the shearer faces α or α + 180°: the one
nearer meta.yaml's initial yaw ψ₀ (a shearer never turns round on its face; it drives
backwards). The reference is ψ_f, and it is not used at all when ψ₀ is more than
``max_initial_offset_deg`` away from both (the recording starts off the face: a roadway).

The offset. The machine's heading differs from ψ_f by where it is on the AFC: the snake behind
the shearer at a face end (the advance over the bend length: 1 m over 15–35 m, 2–4°) and the
line's waviness (2π × amplitude / wavelength: 0.15 m over 15 m is 3.6°), which change along
the face within metres; and by what every place shares: the IMU's mounting on the machine, the
AFC's mean line against the surveyed ends. The shared part is a random constant o of σ
``sigma_offset_deg``; the local part is white noise of σ ``sigma_local_deg`` per update, and
an update is made only after the SINS has travelled ``spacing_m`` (horizontally) since the last
one, so that the local parts are independent. A standing machine measures nothing: its heading
off the face is the same at every instant, and updates in time would have made it known to
fractions of a degree (a GM offset with τ = 300 s swung the vertical gyro bias by ±300 °/h on
random world 0, learning the waviness as a turn rate). With ``C̃_b^n = (I − φ×) C_b^n`` the body's
y axis is ``ỹ = y + (y×) φ``; its heading h(y) = atan2(y_E, y_N) has the gradient
``[y_N, −y_E, 0] / |y_h|²``, so ::

    z = wrap(h(ỹ) − ψ_f),       H = [0, [−y_U y_E, −y_U y_N, |y_h|²] / |y_h|², 0, …, 1 (o)],
    R = σ_local²

(columns δv, φ, δp, …; a level machine has H_φ = [0, 0, 1], the magnetometer's tilt-free row).
The face therefore never tells the heading to better than σ_o, however long the machine rides
it. The plugin looks every ``1 / check_rate_hz`` seconds.

Without a ``face`` section, or with its ends absent, the plugin has no epochs and no states (a
warning says so): a shipped configuration may list it for any recording.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from fusion.attitude import wrap_angle
from fusion.error_model import ATTITUDE, StateBlock
from fusion.face import FaceLine
from fusion.plugin import Measurement, MeasurementContext, Plugin, PluginOptions
from fusion.recording import Recording

_log = logging.getLogger(__name__)


class FaceHeadingOptions(PluginOptions):
    """Options of the face-heading plugin (see the module docstring)."""

    check_rate_hz: float = Field(1.0, gt=0, description="how often the travel is looked at")
    spacing_m: float = Field(
        5.0,
        gt=0,
        description="horizontal travel between two updates: over which the AFC's local"
        " direction (snake, waviness) is taken to be independent",
    )
    sigma_offset_deg: float = Field(
        2.0,
        gt=0,
        description="1σ of the heading off the face line that every place shares (IMU mounting"
        " on the machine, the AFC's mean line against the surveyed ends)",
    )
    sigma_local_deg: float = Field(
        3.0, gt=0, description="1σ of the local part (AFC snake at a face end, waviness)"
    )
    max_initial_offset_deg: float = Field(
        30.0,
        gt=0,
        lt=90,
        description="meta.yaml's initial yaw farther than this from the face line (either"
        " way): the recording does not start on the face, and the plugin is not used",
    )


class FaceHeading(Plugin):
    """The heading of the body y axis against the surveyed face line (module docstring)."""

    Options = FaceHeadingOptions
    options: FaceHeadingOptions

    def __init__(self, name: str, options: FaceHeadingOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        self.offset_block = f"{name}.offset"
        self.reference = self._reference(recording, options)
        if self.reference is None:
            self._epochs = np.zeros(0)
        else:
            t = recording.imu.t
            step = 1.0 / options.check_rate_hz
            self._epochs = np.arange(t[0] + step, t[-1], step)
        self.start_run()

    def start_run(self) -> None:
        """Forget where the last update was made (a new run over the recording)."""
        self._last_travel: NDArray[np.float64] | None = None

    def _reference(self, recording: Recording, options: FaceHeadingOptions) -> float | None:
        """ψ_f (rad), or None (no face ends, or a start off the face; logged)."""
        line = FaceLine.from_meta(recording.meta.face)
        if line is None:
            _log.warning(
                "plugin %r: meta.yaml has no face.ends_enu_m, or its two ends coincide, so no"
                " face heading",
                self.name,
            )
            return None
        azimuth = line.azimuth
        yaw = math.radians(recording.meta.initial.attitude_deg.yaw)
        nearest = min((azimuth, azimuth + math.pi), key=lambda a: abs(float(wrap_angle(yaw - a))))
        if abs(float(wrap_angle(yaw - nearest))) > math.radians(options.max_initial_offset_deg):
            _log.warning(
                "plugin %r: the initial yaw %.1f° is more than %g° off the face line (%.1f°):"
                " the recording does not start on the face, so no face heading",
                self.name,
                math.degrees(yaw),
                options.max_initial_offset_deg,
                math.degrees(azimuth) % 360.0,
            )
            return None
        return nearest

    def state_blocks(self) -> tuple[StateBlock, ...]:
        """The shared heading offset o, a random constant (none without a reference)."""
        if self.reference is None:
            return ()
        sigma = math.radians(self.options.sigma_offset_deg)
        return (StateBlock(self.offset_block, ("o",), (sigma,), unit="deg"),)

    def epochs(self) -> NDArray[np.float64]:
        """Every ``1 / check_rate_hz`` over the IMU span (none without a reference)."""
        return self._epochs

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        """The heading of the body's y axis against ψ_f (module docstring)."""
        if self.reference is None:
            return None
        if self._last_travel is None:
            self._last_travel = ctx.travel.copy()
        moved = ctx.travel[:2] - self._last_travel[:2]
        if math.hypot(moved[0], moved[1]) < self.options.spacing_m:
            return None
        self._last_travel = ctx.travel.copy()
        y = ctx.c_b_n[:, 1]
        horizontal2 = float(y[0] ** 2 + y[1] ** 2)
        if horizontal2 < 0.25:  # the y axis more than 60° off level: no heading to speak of
            return None
        z = np.array([float(wrap_angle(math.atan2(y[0], y[1]) - self.reference))])
        h = np.zeros((1, ctx.layout.dim))
        h[0, ctx.layout.slice(ATTITUDE)] = [-y[2] * y[0], -y[2] * y[1], horizontal2]
        h[0, ctx.layout.slice(ATTITUDE)] /= horizontal2
        h[0, ctx.layout.slice(self.offset_block)] = 1.0
        r = math.radians(self.options.sigma_local_deg) ** 2
        return Measurement(z, h, np.array([[r]]))
