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
They are modelled here. H is evaluated at the *expected* field, not at the measured ``u``:
an H built from the noisy sample is correlated with the noise of the same sample's z, so
``E[K ν] ≠ 0`` and every update pushes the state the same way — on seed003-brokenline that
walked the tilt along its unobservable tilt/accelerometer-bias direction at 0.003°/s. The
expected field is fixed for the run (a first-estimates Jacobian, Huang, Mourikis & Roumeliotis
2008): meta.yaml's D, F and I, or the first sample's F and I where meta.yaml states none; not
the site field learned below. At rest the magnetometer measures one sum, the heading plus the
heading its hard iron and δD make; an H that follows a learned F and I changes while the state
stays put, and the filter reads the change as information that tells the heading from its
biases, which no sample carried (docs/design/2026-12-04-magnetometer-linearization.md). A
meta.yaml field a few per cent off only rescales the hard-iron states' µT. The white field
noise (σ_B per axis, rotated isotropically; its horizontal component across the field moves
the heading) gives ``R_0 = σ_B² / (F cos I)²`` (F, I: the learned site field; R may follow
what is learned, H may not).

**Heading biases.** A calibrated magnetometer still carries a residual hard iron ``h`` (a body
field of 1–2 µT: up to 4° of heading against a 30 µT horizontal field) and meta.yaml's
declination its model error (~0.5° globally, more near anomalies underground); seed 003
ignores both, and a filter that does believes a biased heading to a fraction of a degree. The
plugin owns them as random constants (prior σ ``hard_iron_sigma_uT``, ``declination_sigma_deg``;
0 drops a block): ``δD = D_meta − D_true`` with ``H_δD = −1``, and the hard iron itself with
``u = C̃ (B̃ − v) + C̃ h``, so ``∂z/∂h = gᵀ C̃_b^n``, ``g = [cos D, −sin D, 0] / (F cos I)`` (the
heading's gradient at the expected field). A shearer that keeps its heading cannot separate
the two from each other or from its heading (their sum stays at its prior); a vehicle that
turns observes the hard iron from the heading-dependent error it makes. Soft iron (±2 %) adds
a second-harmonic error of ~1° that the hard-iron states absorb while the attitude is steady.

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
``d = atan2(−u_U, |u_h|)`` (depends on the SINS tilt only) against the *site* field, learned
from the data: each is a scalar Kalman filter (:class:`LearnedValue`) started at meta.yaml's
``field_uT`` / ``inclination_deg`` with the prior σ ``field_model_sigma_uT`` /
``inclination_model_sigma_deg`` (none in meta.yaml: the first sample), drifting by its
tolerance over ``reference_drift_s``, and taught by every sample that passes the test::

    q = (|B̃| − F̂)² / (P_F + r_F) + (d − Î)² / (P_I + r_I),     suspect if q > χ²_2(p)

    r_F = σ_B² + τ_F²,    r_I = σ_B²/F² + τ_I² + g P_φ gᵀ,   g = [u_N, −u_E, 0]/|u_h|

(P the learned values' variances; τ the benign spread ``field_tolerance_uT``,
``inclination_tolerance_deg`` that residual hard and soft iron make as the attitude changes;
``g`` is the dip's sensitivity to the SINS tilt error φ, so the tilt covariance widens the dip
test). A field a few per cent off meta.yaml's is thus the site's field, learned within seconds,
not a disturbance that never ends: only a *change* of the field trips the test — with the
defaults (σ_B 0.1 µT, τ 0.5 µT and 0.5°, p = 0.9999, χ²₂ = 18.4) ≈ 2.2 µT of norm or ≈ 2.3°
of dip; a board carried through all attitudes (BROAD) sees more benign spread than a machine
that keeps its heading, and sets a larger τ.
A rotation of the field about the vertical changes neither, so a disturbance fading out (the
simulator's ramps) passes under the threshold while it still turns the heading by degrees:
the flag is held ``indicator_hold_s`` (1 s) after the test last tripped. A suspect epoch is
*down-weighted*: the least disturbance field ``d = √(ΔF² + (F̂ ΔI)²)`` that explains the
deviation turns the heading by up to ``d / (F cos I)``, and its component across the
horizontal field, which neither test sees, can be as large again: ``(2 d / (F cos I))²`` is
added to R (the
centralized filter then barely moves; the federated master isolates the local only when the
flags persist, :mod:`fusion.fault_detection`). With ``skip_suspect`` suspect epochs are not
applied at all. Suspect epochs teach neither the site field nor the adaptive R.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from fusion.attitude import dcm_from_euler, euler_from_dcm, wrap_angle
from fusion.error_model import ATTITUDE, StateBlock
from fusion.kalman import chi2_threshold
from fusion.plugin import Measurement, MeasurementContext, MissingStream, Plugin, PluginOptions
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
        1.0,
        ge=0,
        description="> 0: estimate the error of meta.yaml's declination (prior σ; a global model"
        " is good to ~0.5°, local anomalies underground add as much)",
    )
    hard_iron_sigma_uT: float = Field(
        1.0,
        ge=0,
        description="> 0: estimate the residual hard iron per body axis (prior σ, µT; a"
        " calibration leaves 1–2 µT in some direction, ≈ 1 µT per axis)",
    )
    adaptive_noise: Literal["sage_husa", "window", "off"] = Field(
        "sage_husa", description="innovation-window R (eq. 32): Sage–Husa, the seed's, or none"
    )
    adaptive_window: int = Field(50, ge=2, description="N innovations of the adaptive R")
    disturbance_indicator: bool = Field(
        True, description="test field norm and dip against the site's earth field"
    )
    field_model_sigma_uT: float = Field(
        2.5,
        ge=0,
        description="prior σ of meta.yaml's field_uT as the site's field (µT; a global model is"
        " good to ~0.15 µT, the field at a machine underground differs by a few per cent)",
    )
    inclination_model_sigma_deg: float = Field(
        2.0, ge=0, description="prior σ of meta.yaml's inclination_deg as the site's dip"
    )
    field_tolerance_uT: float = Field(
        0.5,
        ge=0,
        description="benign spread of the field norm about the site's (µT): residual hard and"
        " soft iron change it with the attitude",
    )
    inclination_tolerance_deg: float = Field(
        0.5, ge=0, description="benign spread of the dip about the site's (deg)"
    )
    reference_drift_s: float = Field(
        60.0,
        gt=0,
        description="the learned site field may drift by its tolerance over this time (s)",
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


@dataclass
class LearnedValue:
    """A slowly drifting scalar learned from measurements (a scalar Kalman filter).

    ``value`` starts at the prior (``variance`` its variance; infinite: taken from the first
    measurement) and drifts as a random walk of ``drift`` variance per second; each learned
    measurement ``y`` of variance ``r`` updates it. :meth:`distance` is the squared
    Mahalanobis distance of a measurement from it (prior variance plus ``r``).
    """

    value: float
    variance: float
    drift: float
    t_last: float | None = None

    def predict(self, t: float) -> None:
        """Let the value drift up to time ``t``."""
        if self.t_last is not None:
            self.variance += self.drift * max(t - self.t_last, 0.0)
        self.t_last = t

    def distance(self, y: float, r: float) -> float:
        """``(y − value)² / (variance + r)`` (0 before any value is known)."""
        if not math.isfinite(self.variance):
            return 0.0
        return (y - self.value) ** 2 / (self.variance + r)

    def learn(self, y: float, r: float) -> None:
        """Update with measurement ``y`` of variance ``r``."""
        if not math.isfinite(self.variance):
            self.value, self.variance = y, r
            return
        gain = self.variance / (self.variance + r)
        self.value += gain * (y - self.value)
        self.variance *= 1.0 - gain


class Magnetometer(Plugin):
    """Tilt-compensated magnetic heading against the SINS yaw, with a disturbance indicator."""

    Options = MagnetometerOptions
    options: MagnetometerOptions

    def __init__(self, name: str, options: MagnetometerOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        if recording.magnetometer is None or recording.meta.magnetometer is None:
            raise MissingStream(
                f"plugin {name!r} needs magnetometer.csv and the magnetometer section of"
                " meta.yaml in the recording"
            )
        self.data = recording.magnetometer
        self.meta = recording.meta.magnetometer
        self.declination = math.radians(self.meta.declination_deg)
        self.indicator_threshold = chi2_threshold(2, options.indicator_probability)
        self.declination_block = f"{name}.declination_error"
        self.hard_iron_block = f"{name}.hard_iron"
        self.start_run()

    def start_run(self) -> None:
        """Forget what a run over the recording learned (adaptive R, site field, flags)."""
        opts, meta = self.options, self.meta
        self._window: deque[tuple[float, float]] = deque(maxlen=opts.adaptive_window)
        self._suspect_until = -math.inf
        self._disturbance_uT = 0.0
        self._linearization: tuple[float, float] | None = None
        tolerance_dip = math.radians(opts.inclination_tolerance_deg)
        self.site_norm = LearnedValue(
            meta.field_uT if meta.field_uT is not None else 0.0,
            opts.field_model_sigma_uT**2 if meta.field_uT is not None else math.inf,
            opts.field_tolerance_uT**2 / opts.reference_drift_s,
        )
        self.site_dip = LearnedValue(
            math.radians(meta.inclination_deg) if meta.inclination_deg is not None else 0.0,
            math.radians(opts.inclination_model_sigma_deg) ** 2
            if meta.inclination_deg is not None
            else math.inf,
            tolerance_dip**2 / opts.reference_drift_s,
        )

    def state_blocks(self) -> tuple[StateBlock, ...]:
        """The declination error δD (``declination_sigma_deg`` > 0) and the residual hard iron
        h (``hard_iron_sigma_uT`` > 0), random constants."""
        blocks = []
        if self.options.declination_sigma_deg > 0.0:
            sigma = math.radians(self.options.declination_sigma_deg)
            blocks.append(StateBlock(self.declination_block, ("d",), (sigma,), unit="deg"))
        if self.options.hard_iron_sigma_uT > 0.0:
            sigma = self.options.hard_iron_sigma_uT
            blocks.append(
                StateBlock(self.hard_iron_block, ("x", "y", "z"), (sigma,) * 3, unit="uT")
            )
        return tuple(blocks)

    def epochs(self) -> NDArray[np.float64]:
        """The magnetometer sample times."""
        return self.data.t

    def magnetic_heading(self, index: int, c_b_n: NDArray[np.float64]) -> float:
        """Tilt-compensated heading ψ_mag (rad, eqs. 18–19) of sample ``index``, levelled with
        the roll and pitch of ``c_b_n``."""
        roll, pitch, _ = euler_from_dcm(c_b_n)
        levelled = dcm_from_euler(roll, pitch, 0.0) @ self.data.field[index]
        return math.atan2(-levelled[0], levelled[1]) + self.declination

    def indicator(
        self, t: float, field_b: NDArray[np.float64], u: NDArray[np.float64], p_att: NDArray
    ) -> tuple[float, float]:
        """χ² statistic ``q`` of the field norm and dip against the learned site field, and the
        least disturbance field that explains their deviation (µT); a sample that passes
        teaches the site field (module docstring).

        Parameters
        ----------
        t
            Sample time (s).
        field_b
            Measured body field (µT).
        u
            The same field rotated into n by the SINS attitude (µT).
        p_att
            Covariance of φ (rad²).
        """
        opts = self.options
        norm = float(np.linalg.norm(field_b))
        horizontal = math.hypot(u[0], u[1])
        dip = math.atan2(-u[2], horizontal)
        g = np.array([u[1], -u[0], 0.0]) / horizontal
        self.site_norm.predict(t)
        self.site_dip.predict(t)
        r_norm = opts.sigma_field_uT**2 + opts.field_tolerance_uT**2
        r_dip = (
            opts.sigma_field_uT**2 / norm**2
            + math.radians(opts.inclination_tolerance_deg) ** 2
            + float(g @ p_att @ g)
        )
        q = self.site_norm.distance(norm, r_norm) + self.site_dip.distance(dip, r_dip)
        if q > self.indicator_threshold:
            site = self.site_norm.value if math.isfinite(self.site_norm.variance) else norm
            return q, math.hypot(norm - site, site * (dip - self.site_dip.value))
        self.site_norm.learn(norm, r_norm)
        self.site_dip.learn(dip, r_dip)
        return q, 0.0

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        """Heading residual ``ψ̃ − ψ_mag`` with its full H, adaptive R and indicator flag."""
        opts = self.options
        field_b = self.data.field[index]
        u = ctx.c_b_n @ field_b
        att = ctx.layout.slice(ATTITUDE)
        if opts.disturbance_indicator:
            _, disturbance = self.indicator(ctx.t, field_b, u, ctx.covariance[att, att])
            if disturbance > 0.0:
                self._suspect_until = ctx.t + opts.indicator_hold_s
                self._disturbance_uT = disturbance
        suspect = ctx.t <= self._suspect_until
        if suspect and opts.skip_suspect:
            return None
        yaw = euler_from_dcm(ctx.c_b_n)[2]
        z = np.array([wrap_angle(yaw - self.magnetic_heading(index, ctx.c_b_n))])
        h = np.zeros((1, ctx.layout.dim))
        norm, dip = self._linearization_field(field_b, u)
        tan_dip = math.tan(dip)
        sin_d, cos_d = math.sin(self.declination), math.cos(self.declination)
        h[0, att] = [tan_dip * sin_d, tan_dip * cos_d, 1]
        if opts.declination_sigma_deg > 0.0:
            h[0, ctx.layout.slice(self.declination_block)] = -1.0
        if opts.hard_iron_sigma_uT > 0.0:  # z = heading(C̃ (B + h)) − D: ∂/∂h = gᵀ C̃
            g = np.array([cos_d, -sin_d, 0.0]) / (norm * math.cos(dip))
            h[0, ctx.layout.slice(self.hard_iron_block)] = g @ ctx.c_b_n
        site_field, site_dip = self._site_field(field_b, u)
        horizontal = site_field * math.cos(site_dip)
        floor = (opts.sigma_field_uT / horizontal) ** 2
        r = self._adaptive_variance(floor)
        if suspect:  # down-weight: the disturbance seen, and as much again unseen (module doc)
            r += (2.0 * self._disturbance_uT / horizontal) ** 2
        else:
            innovation = float(z[0] - h[0] @ ctx.x)
            self._window.append((innovation**2, float(h[0] @ ctx.covariance @ h[0])))
        return Measurement(z, h, np.array([[r]]), suspect=suspect)

    def _linearization_field(
        self, field_b: NDArray[np.float64], u: NDArray[np.float64]
    ) -> tuple[float, float]:
        """Norm (µT) and dip (rad) of the earth field H is evaluated at, fixed for the run:
        meta.yaml's, or the run's first sample's where meta.yaml states none (module
        docstring, first-estimates Jacobian)."""
        if self._linearization is None:
            meta = self.meta
            norm = float(np.linalg.norm(field_b)) if meta.field_uT is None else meta.field_uT
            dip = (
                math.atan2(-u[2], math.hypot(u[0], u[1]))
                if meta.inclination_deg is None
                else math.radians(meta.inclination_deg)
            )
            self._linearization = (norm, dip)
        return self._linearization

    def _site_field(
        self, field_b: NDArray[np.float64], u: NDArray[np.float64]
    ) -> tuple[float, float]:
        """Norm (µT) and dip (rad) of the site field R is scaled by: the learned ones, or this
        sample's before anything is learned."""
        norm = self.site_norm.value if math.isfinite(self.site_norm.variance) else None
        dip = self.site_dip.value if math.isfinite(self.site_dip.variance) else None
        if norm is None:
            norm = float(np.linalg.norm(field_b))
        if dip is None:
            dip = math.atan2(-u[2], math.hypot(u[0], u[1]))
        return norm, dip

    def _adaptive_variance(self, floor: float) -> float:
        """R from the innovation window (eq. 32, see the module docstring), at least ``floor``."""
        mode = self.options.adaptive_noise
        if mode == "off" or len(self._window) < self.options.adaptive_window:
            return floor
        squares, predicted = np.array(self._window).T
        estimate = float(np.mean(squares if mode == "window" else squares - predicted))
        return max(estimate, floor)
