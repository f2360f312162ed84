"""Magnetometer yaw (seed 003 §3.2, eqs. 18–26; adaptive noise §4.2, eq. 32).

**Tilt-compensated heading** (eqs. 18–19 in the recording convention
``C_b^n = R_z(−ψ) R_x(θ) R_y(γ)``, ψ clockwise from north). The measured body field ``B̃^b`` is
levelled with the SINS roll γ̃ and pitch θ̃, ``B^h = R_x(θ̃) R_y(γ̃) B̃^b``; the earth field
``B^n = F [cos I sin D, cos I cos D, −sin I]`` (D declination, east > 0; I inclination,
down > 0) levelled by the true attitude is ``R_z(ψ) B^n``, whose horizontal part is
``F cos I [−sin(ψ − D), cos(ψ − D)]``, hence

    ψ_mag = atan2(−B^h_x, B^h_y) + D,       z = wrap(ψ̃_SINS − ψ_mag)     (eqs. 19, 23).

**Full first-order model** (replaces eq. 26). Since ``R_x(θ̃) R_y(γ̃) = R_z(ψ̃) C̃_b^n``, the
levelled field is ``B^h = R_z(ψ̃) u`` with ``u = C̃_b^n B̃^b`` (the measured field rotated into n
by the whole SINS attitude), and a rotation by ``R_z(ψ̃)`` lowers the heading of a vector by ψ̃,
so ψ̃ cancels exactly:

    z = h(u) − D,     h(u) = atan2(u_E, u_N)   (the heading of u).

With ``C̃_b^n = (I − φ×) C_b^n`` and ``B̃^b = C_n^b B^n + v``, ``u = B^n + (B^n×) φ + C̃ v``;
``∂h/∂u = [u_N, −u_E, 0] / |u_h|²`` (``|u_h|² = u_E² + u_N²``) and ``u = B^n`` give

    H_φ = [B_N, −B_E, 0] (B^n×) / |B_h|² = [−B_E B_U, −B_N B_U, |B_h|²] / |B_h|²
        = [tan I sin D, tan I cos D, 1].

The seed's ``H = [0, 0, 1]`` (eq. 26) keeps only the last term. The tilt terms do not vanish:
a tilt error about magnetic east turns part of the vertical field (larger than the horizontal
one for I > 45°) into the horizontal plane; at I = 54° a 0.1° tilt error moves ψ_mag by 0.14°.
They are modelled here. H is evaluated at the *expected* field (meta.yaml's D and I; without
``inclination_deg``, the mean measured dip of the earlier samples), not at the measured ``u``:
an H built from the noisy sample is correlated with the noise of the same sample's z, so
``E[K ν] ≠ 0`` and every update pushes the state the same way — on seed003-brokenline that
walked the tilt along its unobservable tilt/accelerometer-bias direction at 0.003°/s. The white
field noise (σ_B per axis, rotated isotropically; its horizontal component across the field
moves the heading) gives ``R_0 = σ_B² / (F cos I)²`` (F: meta.yaml's ``field_uT``, else the
measured norm). Optionally (``declination_sigma_deg``
> 0) the plugin owns the error of the declination in meta.yaml, ``δD = D_meta − D_true``, a
random constant with ``H_δD = −1`` (seed 003 ignores it; an unmodelled declination error biases
the heading).

**Adaptive R** (eq. 32), over the last N innovations ``e = z − H x̂`` (``x̂`` the filter's
current estimate) of this plugin, the current one excluded:

* ``window`` — the seed's ``R* = mean(e²)``; it estimates the innovation variance
  ``H P Hᵀ + R``, so it over-states R by the mean ``H P Hᵀ``;
* ``sage_husa`` (default) — ``R* = mean(e² − H P⁻ Hᵀ)`` with ``P⁻`` the covariance before
  each of those updates, an unbiased estimate of R;

in both cases ``R = max(R*, R_0)``: the floor is the sensor-noise value ``R_0``, so R stays
positive and an adaptive filter never trusts the magnetometer more than its
datasheet allows; it only inflates R when the innovations say so (interference, soft iron).
Until N innovations exist, ``R = R_0``. ``off`` uses ``R_0`` throughout.

**Disturbance indicator.** The field norm ``|B̃^b|`` (attitude-free) and the dip angle
``d = atan2(−u_U, |u_h|)`` (depends on the SINS tilt only) against the expected earth field of
meta.yaml (``magnetometer.field_uT``, ``inclination_deg``)::

    q = (|B̃| − F)² / σ_F² + (d − I)² / σ_d²,    suspect if q > χ²_k(p)   (k = terms available)

    σ_F² = σ_B² + σ_F,model²,    σ_d² = σ_B²/F² + σ_I,model² + g P_φ gᵀ,   g = [u_N, −u_E, 0]/|u_h|

(the noise along and across the field; the uncertainty of the earth-field model; ``g`` is the
dip's sensitivity to the SINS tilt error φ, so the tilt covariance widens the dip test). With
the defaults — σ_B = 0.1 µT (MTi-30, the simulator's ``noise_sigma_uT``), model σ 0.15 µT and
0.2° (WMM-class accuracy), p = 0.9999 (χ²₂ = 18.4) — the norm test alone trips at 0.8 µT
(1.5 % of a 53 µT field) and the dip test at ≈ 0.9° with a 0.1° tilt σ. The
simulator's interference (``magnetic_interference``, an additive body-frame field) changes
both; a rotation of the field about the vertical changes neither, so a disturbance fading out
(the simulator's ramps) passes under the threshold while it still turns the heading by degrees:
the flag is held ``indicator_hold_s`` (1 s) after the test last tripped. A suspect epoch is
still returned with ``suspect=True`` (the federated master isolates the local filter; the
centralized filter logs it) unless ``skip_suspect`` is set; skipped epochs do not enter the
adaptive window.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from fusion.attitude import dcm_from_euler, euler_from_dcm, wrap_angle
from fusion.error_model import ATTITUDE, StateBlock
from fusion.kalman import chi2_threshold
from fusion.plugin import Measurement, MeasurementContext, Plugin, PluginOptions
from fusion.recording import Recording


class MagnetometerOptions(PluginOptions):
    """Options of the magnetometer-yaw plugin."""

    sigma_field_uT: float = Field(
        0.1,
        gt=0,
        description="white field noise per axis per sample (µT); seed 003 Table 1, MTi-30: "
        "200 µG/√Hz over 25 Hz = 0.1 µT",
    )
    declination_sigma_deg: float = Field(
        0.0, ge=0, description="> 0: estimate the error of meta.yaml's declination (prior σ)"
    )
    adaptive_noise: Literal["sage_husa", "window", "off"] = Field(
        "sage_husa", description="innovation-window R (eq. 32): Sage–Husa, the seed's, or none"
    )
    adaptive_window: int = Field(50, ge=2, description="N innovations of the adaptive R")
    disturbance_indicator: bool = Field(
        True, description="test field norm and dip against meta.yaml's expected earth field"
    )
    field_model_sigma_uT: float = Field(
        0.15, ge=0, description="uncertainty of meta.yaml's field_uT (WMM-class model: ~0.15)"
    )
    inclination_model_sigma_deg: float = Field(
        0.2, ge=0, description="uncertainty of meta.yaml's inclination_deg (WMM-class: ~0.2)"
    )
    indicator_probability: float = Field(
        0.9999, gt=0, lt=1, description="χ² quantile of the indicator test"
    )
    indicator_hold_s: float = Field(
        1.0, ge=0, description="keep flagging this long after the test last tripped (s)"
    )
    skip_suspect: bool = Field(
        False, description="do not apply suspect epochs (default: apply them, flagged)"
    )


class Magnetometer(Plugin):
    """Tilt-compensated magnetic heading against the SINS yaw, with a disturbance indicator."""

    Options = MagnetometerOptions
    options: MagnetometerOptions

    def __init__(self, name: str, options: MagnetometerOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        if recording.magnetometer is None or recording.meta.magnetometer is None:
            raise ValueError(
                f"plugin {name!r} needs magnetometer.csv and the magnetometer section of"
                " meta.yaml in the recording"
            )
        self.data = recording.magnetometer
        meta = recording.meta.magnetometer
        self.declination = math.radians(meta.declination_deg)
        self.field_norm = meta.field_uT
        self.inclination = (
            None if meta.inclination_deg is None else math.radians(meta.inclination_deg)
        )
        if options.disturbance_indicator and self.field_norm is None and self.inclination is None:
            raise ValueError(
                f"plugin {name!r}: disturbance_indicator needs the expected earth field in"
                " meta.yaml (magnetometer.field_uT and/or magnetometer.inclination_deg);"
                " give it or set disturbance_indicator: false"
            )
        dof = (self.field_norm is not None) + (self.inclination is not None)
        self.indicator_threshold = chi2_threshold(dof, options.indicator_probability)
        # Adaptive R: (e², H P⁻ Hᵀ) of the last N epochs of this pass.
        self._window: deque[tuple[float, float]] = deque(maxlen=options.adaptive_window)
        self._last_index = -1
        self._dip_sum, self._dip_count = 0.0, 0
        self._suspect_until = -math.inf

    def state_blocks(self) -> tuple[StateBlock, ...]:
        """The declination error δD when ``declination_sigma_deg`` > 0 (a random constant)."""
        if self.options.declination_sigma_deg == 0.0:
            return ()
        sigma = math.radians(self.options.declination_sigma_deg)
        return (StateBlock(f"{self.name}.declination_error", ("d",), (sigma,)),)

    def epochs(self) -> NDArray[np.float64]:
        """The magnetometer sample times."""
        return self.data.t

    def magnetic_heading(self, index: int, c_b_n: NDArray[np.float64]) -> float:
        """Tilt-compensated heading ψ_mag (rad, eqs. 18–19) of sample ``index``, levelled with
        the roll and pitch of ``c_b_n``."""
        roll, pitch, _ = euler_from_dcm(c_b_n)
        levelled = dcm_from_euler(roll, pitch, 0.0) @ self.data.field[index]
        return math.atan2(-levelled[0], levelled[1]) + self.declination

    def indicator_statistic(
        self, field_b: NDArray[np.float64], u: NDArray[np.float64], p_attitude: NDArray[np.float64]
    ) -> float:
        """χ² statistic ``q`` of the field norm and dip against the expected earth field.

        Parameters
        ----------
        field_b
            Measured body field (µT).
        u
            The same field rotated into n by the SINS attitude (µT).
        p_attitude
            Covariance of φ (rad²).
        """
        opts = self.options
        sigma_b2 = opts.sigma_field_uT**2
        q = 0.0
        if self.field_norm is not None:
            var_norm = sigma_b2 + opts.field_model_sigma_uT**2
            q += (float(np.linalg.norm(field_b)) - self.field_norm) ** 2 / var_norm
        if self.inclination is not None:
            horizontal = math.hypot(u[0], u[1])
            dip = math.atan2(-u[2], horizontal)
            g = np.array([u[1], -u[0], 0.0]) / horizontal
            norm = self.field_norm if self.field_norm is not None else float(np.linalg.norm(u))
            var_dip = (
                sigma_b2 / norm**2
                + math.radians(opts.inclination_model_sigma_deg) ** 2
                + float(g @ p_attitude @ g)
            )
            q += (dip - self.inclination) ** 2 / var_dip
        return q

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        """Heading residual ``ψ̃ − ψ_mag`` with its full H, adaptive R and indicator flag."""
        if index <= self._last_index:  # a new pass over the recording
            self._window.clear()
            self._dip_sum, self._dip_count = 0.0, 0
            self._suspect_until = -math.inf
        self._last_index = index
        opts = self.options
        field_b = self.data.field[index]
        u = ctx.c_b_n @ field_b
        att = ctx.layout.slice(ATTITUDE)
        if opts.disturbance_indicator and (
            self.indicator_statistic(field_b, u, ctx.covariance[att, att])
            > self.indicator_threshold
        ):
            self._suspect_until = ctx.t + opts.indicator_hold_s
        suspect = ctx.t <= self._suspect_until
        dip = self._linearization_dip(u, suspect)
        if suspect and opts.skip_suspect:
            return None
        yaw = euler_from_dcm(ctx.c_b_n)[2]
        z = np.array([wrap_angle(yaw - self.magnetic_heading(index, ctx.c_b_n))])
        h = np.zeros((1, ctx.layout.dim))
        tan_dip = math.tan(dip)
        h[0, att] = [tan_dip * math.sin(self.declination), tan_dip * math.cos(self.declination), 1]
        if opts.declination_sigma_deg > 0.0:
            h[0, ctx.layout.slice(f"{self.name}.declination_error")] = -1.0
        norm = self.field_norm if self.field_norm is not None else float(np.linalg.norm(field_b))
        floor = (opts.sigma_field_uT / (norm * math.cos(dip))) ** 2
        r = self._adaptive_variance(floor)
        innovation = float(z[0] - h[0] @ ctx.x)
        self._window.append((innovation**2, float(h[0] @ ctx.covariance @ h[0])))
        return Measurement(z, h, np.array([[r]]), suspect=suspect)

    def _linearization_dip(self, u: NDArray[np.float64], suspect: bool) -> float:
        """The dip of the expected field: meta.yaml's inclination, or else the mean measured dip
        of the earlier unsuspected samples of this pass (this sample's before there is one)."""
        if self.inclination is not None:
            return self.inclination
        measured = math.atan2(-u[2], math.hypot(u[0], u[1]))
        dip = self._dip_sum / self._dip_count if self._dip_count else measured
        if not suspect:
            self._dip_sum += measured
            self._dip_count += 1
        return dip

    def _adaptive_variance(self, floor: float) -> float:
        """R from the innovation window (eq. 32, see the module docstring), at least ``floor``."""
        mode = self.options.adaptive_noise
        if mode == "off" or len(self._window) < self.options.adaptive_window:
            return floor
        squares, predicted = np.array(self._window).T
        estimate = float(np.mean(squares if mode == "window" else squares - predicted))
        return max(estimate, floor)
