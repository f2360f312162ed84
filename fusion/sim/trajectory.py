"""Truth trajectory of a longwall shearer (or of a test vehicle on a track), exact to order 2.

Geometry
--------
Positions are ENU metres about the scenario origin. A horizontal path is described in *face
coordinates* (ξ along the face azimuth ψ₀, η to its right = the AFC advance direction = body x)::

    E = ξ sinψ₀ + η cosψ₀,    N = ξ cosψ₀ − η sinψ₀,    U = Z(ξ, η) − Z(0, 0)

with the floor ``Z(ξ, η) = ξ tanα + η tanβ + Σ_j B_j sin(k_j ξ + m_j η + φ_j)``. Every leg of the
motion is a curve ``(ξ(s), η(s))`` in a parameter s:

* longwall AFC line (seed 000 Fig. 3, seed 002 Fig. 2): ``ξ = s``,
  ``η = a(s) + Σ_i A_i sin(2π s/λ_i + a(s)/ℓ_i + φ_i)`` with the advance offset a(s) constant
  on a straight pass and ``a(s) = a_k + d S₅((s − s_end)/(∓L_bend))`` along the bend of the
  terminal oblique cut (S₅(x) = 10x³ − 15x⁴ + 6x⁵, C² with zero slope and curvature at both
  ends, so heading and yaw rate are continuous);
* track (seed 002 rectangle, seed 003 broken line): a quintic spline in arc length through the
  integral of a heading profile that turns smoothly at each vertex.

All geometry is evaluated as *jets* (value, d/ds, d²/ds²), so that with the motion profile
``s(t), ṡ, s̈`` the kinematics are exact: ``p = q(s)``, ``ṗ = q′ṡ``, ``p̈ = q″ṡ² + q′s̈``.

Attitude
--------
Body y is the path tangent ``q′`` (the shearer never turns around: on a face it drives
backwards with ṡ < 0 and keeps its heading), body x lies in the floor's tangent plane::

    ψ = atan2(E′, N′),   θ = atan2(U′, √(E′² + N′²)),
    γ = −atan2(g_r, cosθ + g_f sinθ)

where g_f, g_r are the floor slopes along the heading and to its right; this makes body x
tangent to the floor (row 3 of C_b^n is ``[−cosθ sinγ, sinθ, cosθ cosγ]``). The rates are
``ψ̇ = ψ′ṡ`` etc. These angles are used *as attitude relative to the local level frame at the
current point* (:mod:`fusion.sim.kinematics`); the tangent is computed in the origin's ENU axes,
so the non-holonomic constraint holds up to the meridian convergence between the two frames
(≈ 1.6·10⁻⁷ rad per metre of distance from the origin: a lateral velocity ≤ 5·10⁻⁵ of the speed
on a 300 m face).

Motion
------
The parameter s(t) is piecewise: dwells (ṡ = 0), cruises (constant ṡ) and velocity ramps
``ṡ = v₀ + Δv S₅(τ/T)`` whose acceleration ``Δv S₅′(τ/T)/T`` is C¹ (jerk-limited), with the
position in closed form ``s = s₀ + v₀τ + Δv T P(τ/T)``, ``P(x) = 2.5x⁴ − 3x⁵ + x⁶``. The ramp
time is ``T = max(1.875 |Δv| / a_max, T_min)`` (1.875 is the peak of S₅′).

Cutting vibration (5–30 Hz sums of sinusoids) is multiplied by an envelope e(t) that follows the
same S₅ ramps (0 when stopped, 1 when cruising): a displacement ``δp = e Σ A sin(ωt+φ)`` in n
(with exact ``δṗ``, ``δp̈``) and an angle ``δ = e Σ B sin(ωt+φ)`` added to each Euler angle.

Mining cycle (longwall)
-----------------------
static start (cycle 0) → pass 1 along the whole face (cycle 1) → at the end: stop, reverse
along the bend of the AFC (one web d over L_bend) into the new web plus an overrun, stop while
the end is pushed straight (an AFC push event of d for the support sensor), cut back to the
end, stop (all cycle 0, as "the shearer processing the end coal" in seed 000 §4) → pass 2 in
the other direction on the line shifted by d (cycle 2) → … → static end.

That is the ``bidirectional`` pattern (one run per cycle). ``unidirectional`` cycles are a cut
and a cleaning run back (``cut, clean``), ``three_pass`` cycles a cut, a cleaning run back and
a return run (``cut, clean, return``); every run reverses the previous one's direction. The
manoeuvre with the push follows run ``face.push_after_run`` of each cycle (default its last);
the other runs end with a plain stop. ``truth.csv`` ``cycle`` is the cutting-cycle index on
every run of the cycle (cut, cleaning and return runs alike, re-cuts included) and 0 at the
static start and end and during the face-end manoeuvres. Cleaning and return runs draw their
speeds from ``motion.clean_speed_mpm`` and scale the vibration envelope by
``vibration.clean_scale``. A re-cut (``face.recut``) splits a run into forward, back-up and
forward drives with stops between them. The face ends may move along the face from cycle to
cycle (``face.end_skew_deg``, ``face.end_jitter_m``): a run then goes from where the shearer
stands to the end of the current cycle and line, and the manoeuvre returns to the new line's
end. Each push may also change the AFC's straightness (``face.line_deviation``): the lines
carry their own deviation terms, blended along the bend like the advance offset.

Random streams: stops, speeds, dwells and the advance jitter come from the motion stream, the
floor and waviness from the geometry stream, as they always have; the face ends, the line
deviations and the re-cuts draw from three further streams of their own, so that a scenario
that does not use them draws exactly the numbers it drew before they existed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import cumulative_trapezoid
from scipy.interpolate import BSpline, make_interp_spline

from fusion.sim.scenario import Face, Floor, Scenario, Track, Vibration

Array = NDArray[np.float64]


@dataclass(frozen=True)
class TruthChunk:
    """Truth and error-free IMU over one chunk of IMU samples (contract with ``sensors.py``)."""

    t: np.ndarray  # (N,) s, IMU sample times
    position_enu: np.ndarray  # (N,3) m about the origin
    velocity_enu: np.ndarray  # (N,3) m/s, local-level ENU
    attitude: np.ndarray  # (N,3) roll, pitch, yaw rad
    c_b_n: np.ndarray  # (N,3,3)
    velocity_body: np.ndarray  # (N,3) m/s, C_n^b v^n
    gyro: np.ndarray  # (N,3) error-free interval means (rad/s)
    accel: np.ndarray  # (N,3) error-free interval means (m/s²)
    cycle: np.ndarray  # (N,) int
    moving: np.ndarray  # (N,) bool: true motion state (False during stops/static)
    odometer_distance: np.ndarray  # (N,) m, cumulative path length along body y (signed)
    lat: np.ndarray
    lon: np.ndarray
    height: np.ndarray


# --------------------------------------------------------------------------------------------
# Jets: value and first two derivatives with respect to one parameter.
# --------------------------------------------------------------------------------------------


class Jet:
    """Truncated Taylor jet ``(v, d, dd)`` of a function of one parameter, element-wise."""

    __slots__ = ("d", "dd", "v")

    def __init__(self, v: Array, d: Array, dd: Array) -> None:
        self.v = v
        self.d = d
        self.dd = dd

    @staticmethod
    def const(c: float | Array, like: Array) -> Jet:
        """A constant jet broadcast like ``like``."""
        z = np.zeros_like(like)
        return Jet(z + c, z, z.copy())

    def __add__(self, o: Jet | float) -> Jet:
        if isinstance(o, Jet):
            return Jet(self.v + o.v, self.d + o.d, self.dd + o.dd)
        return Jet(self.v + o, self.d, self.dd)

    __radd__ = __add__

    def __neg__(self) -> Jet:
        return Jet(-self.v, -self.d, -self.dd)

    def __sub__(self, o: Jet | float) -> Jet:
        return self + (-o)

    def __rsub__(self, o: float) -> Jet:
        return (-self) + o

    def __mul__(self, o: Jet | float) -> Jet:
        if isinstance(o, Jet):
            return Jet(
                self.v * o.v,
                self.d * o.v + self.v * o.d,
                self.dd * o.v + 2.0 * self.d * o.d + self.v * o.dd,
            )
        return Jet(self.v * o, self.d * o, self.dd * o)

    __rmul__ = __mul__

    def derivative(self) -> Jet:
        """Jet of the first derivative (its second derivative is unknown: NaN)."""
        return Jet(self.d, self.dd, np.full_like(self.v, np.nan))


def jsin(x: Jet) -> Jet:
    """``sin`` of a jet."""
    s, c = np.sin(x.v), np.cos(x.v)
    return Jet(s, c * x.d, c * x.dd - s * x.d * x.d)


def jcos(x: Jet) -> Jet:
    """``cos`` of a jet."""
    s, c = np.sin(x.v), np.cos(x.v)
    return Jet(c, -s * x.d, -s * x.dd - c * x.d * x.d)


def jsqrt(x: Jet) -> Jet:
    """``sqrt`` of a (positive) jet."""
    r = np.sqrt(x.v)
    return Jet(r, x.d / (2.0 * r), x.dd / (2.0 * r) - x.d * x.d / (4.0 * r**3))


def jatan2(y: Jet, x: Jet) -> Jet:
    """``atan2`` of two jets, to first order (the second derivative is NaN)."""
    r2 = x.v * x.v + y.v * y.v
    return Jet(np.arctan2(y.v, x.v), (x.v * y.d - y.v * x.d) / r2, np.full_like(x.v, np.nan))


def smoothstep5(x: Jet) -> Jet:
    """``S₅(x) = 10x³ − 15x⁴ + 6x⁵`` clamped to 0 below 0 and 1 above 1, as a jet."""
    u = np.clip(x.v, 0.0, 1.0)
    inside = (x.v > 0.0) & (x.v < 1.0)
    s = u * u * u * (10.0 + u * (-15.0 + 6.0 * u))
    s1 = np.where(inside, 30.0 * u * u * (1.0 - u) ** 2, 0.0)
    s2 = np.where(inside, 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u), 0.0)
    return Jet(s, s1 * x.d, s1 * x.dd + s2 * x.d * x.d)


def _s5(x: Array) -> tuple[Array, Array, Array]:
    """S₅, S₅′, S₅″ on [0, 1] (no clamping)."""
    return (
        x * x * x * (10.0 + x * (-15.0 + 6.0 * x)),
        30.0 * x * x * (1.0 - x) ** 2,
        60.0 * x * (1.0 - x) * (1.0 - 2.0 * x),
    )


# --------------------------------------------------------------------------------------------
# Floor and leg geometries.
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FloorSurface:
    """``Z(ξ, η) = ξ tanα + η tanβ + Σ_j B_j sin(k_j ξ + m_j η + φ_j)`` (see module docstring)."""

    tan_along: float
    tan_across: float
    amp: Array
    k: Array
    m: Array
    phase: Array

    @classmethod
    def from_config(cls, cfg: Floor, rng: np.random.Generator) -> FloorSurface:
        """Draw the random phases of ``cfg``'s undulation terms."""
        n = len(cfg.wavelengths_m)
        amp = np.full(n, cfg.undulation_m / max(n, 1) ** 0.5)
        k = 2.0 * np.pi / np.asarray(cfg.wavelengths_m, dtype=float)
        m = 2.0 * np.pi / cfg.across_wavelength_m * rng.choice([-1.0, 1.0], size=n)
        return cls(
            math.tan(math.radians(cfg.slope_along_deg)),
            math.tan(math.radians(cfg.dip_across_deg)),
            amp,
            k,
            m,
            rng.uniform(0.0, 2.0 * np.pi, size=n),
        )

    def height(self, xi: Jet, eta: Jet) -> Jet:
        """Floor height as a jet."""
        z = xi * self.tan_along + eta * self.tan_across
        for b, k, m, ph in zip(self.amp, self.k, self.m, self.phase, strict=True):
            z = z + b * jsin(xi * k + eta * m + ph)
        return z

    def gradient(self, xi: Jet, eta: Jet) -> tuple[Jet, Jet]:
        """``(∂Z/∂ξ, ∂Z/∂η)`` as jets (only value and first derivative are used)."""
        gx = Jet.const(self.tan_along, xi.v)
        ge = Jet.const(self.tan_across, xi.v)
        for b, k, m, ph in zip(self.amp, self.k, self.m, self.phase, strict=True):
            c = jcos(xi * k + eta * m + ph)
            gx = gx + c * (b * k)
            ge = ge + c * (b * m)
        return gx, ge


class LegGeometry(Protocol):
    """A leg's horizontal curve in face coordinates: ``s ↦ (ξ, η)`` jets in s."""

    @property
    def lap_length(self) -> float | None:
        """Length of one lap of a closed track (None for open legs)."""
        ...

    def plan(self, s: Array) -> tuple[Jet, Jet]:
        """``(ξ, η)`` jets (value, d/ds, d²/ds²) at parameter values ``s``."""
        ...


@dataclass(frozen=True)
class AfcLine:
    """The AFC in one configuration: offset ``a0`` that bends to ``a1`` between ``s0`` and ``s1``.

    With ``s0 == s1`` (or ``a0 == a1``) it is a straight (wavy) line at offset ``a0``.
    """

    a0: float
    a1: float
    s0: float
    s1: float
    wav_amp: Array
    wav_k: Array
    wav_c: Array
    wav_phase: Array
    lap_length: float | None = None
    dev0: Deviation | None = None
    """Line deviation of the line at ``a0`` (:class:`~fusion.sim.scenario.LineDeviation`)."""
    dev1: Deviation | None = None
    """Line deviation of the line at ``a1``, blended in along the bend like the offset."""

    def plan(self, s: Array) -> tuple[Jet, Jet]:
        """See :class:`LegGeometry`."""
        sj = Jet(s, np.ones_like(s), np.zeros_like(s))
        blend: Jet | None = None
        if self.s1 != self.s0 and self.a1 != self.a0:
            blend = smoothstep5((sj - self.s0) * (1.0 / (self.s1 - self.s0)))
            a = blend * (self.a1 - self.a0)
            a = a + self.a0
        else:
            a = Jet.const(self.a0, s)
        eta = a
        for amp, k, c, ph in zip(self.wav_amp, self.wav_k, self.wav_c, self.wav_phase, strict=True):
            eta = eta + amp * jsin(sj * k + a * c + ph)
        if self.dev0 is not None:
            d0 = self.dev0.jet(sj)
            if blend is not None and self.dev1 is not None:
                d0 = d0 + blend * (self.dev1.jet(sj) - d0)
            eta = eta + d0
        return sj, eta


@dataclass(frozen=True)
class Deviation:
    """A smooth lateral deviation ``Σ_i C_i sin(k_i s + φ_i)`` of one AFC line (m)."""

    amp: Array
    k: Array
    phase: Array

    def jet(self, sj: Jet) -> Jet:
        """The deviation as a jet in s."""
        out = Jet.const(0.0, sj.v)
        for c, k, ph in zip(self.amp, self.k, self.phase, strict=True):
            out = out + c * jsin(sj * k + ph)
        return out

    def next(
        self, persistence: float, sigma: float, wavelengths: tuple[float, float], n: int, rng: Any
    ) -> Deviation:
        """``ρ δ + ε`` with a new draw ε (terms whose amplitude fell below 10 µm are dropped)."""
        c = np.full(n, sigma * math.sqrt(2.0 / n))
        k = 2.0 * np.pi / rng.uniform(wavelengths[0], wavelengths[1], size=n)
        ph = rng.uniform(0.0, 2.0 * np.pi, size=n)
        old = self.amp * persistence
        keep = np.abs(old) >= 1e-5
        return Deviation(
            np.concatenate([old[keep], c]),
            np.concatenate([self.k[keep], k]),
            np.concatenate([self.phase[keep], ph]),
        )


@dataclass(frozen=True)
class SplineTrack:
    """A track as a quintic spline ``s ↦ (ξ, η)`` in arc length; periodic if ``lap_length``."""

    spline: BSpline
    d1: BSpline
    d2: BSpline
    lap_length: float | None

    @classmethod
    def from_config(cls, cfg: Track, step: float = 0.02) -> SplineTrack:
        """Integrate the smoothed heading profile of ``cfg``'s polygon and fit the spline."""
        pts = np.asarray(cfg.waypoints_m, dtype=float)
        if cfg.closed:
            # start (and end each lap) in the middle of the first side, not inside a corner
            if np.allclose(pts[0], pts[-1]):
                pts = pts[:-1]
            mid = 0.5 * (pts[0] + pts[1])
            pts = np.vstack([mid, pts[1:], pts[:1], mid[None, :]])
        seg = np.diff(pts, axis=0)
        lengths = np.hypot(seg[:, 0], seg[:, 1])
        if np.any(lengths <= 0.0):
            raise ValueError("track waypoints must be distinct")
        heads = np.arctan2(seg[:, 1], seg[:, 0])  # angle from ξ towards η
        vert_s = np.concatenate([[0.0], np.cumsum(lengths)])
        total = float(vert_s[-1])
        turns = np.angle(np.exp(1j * np.diff(heads)))
        n = max(math.ceil(total / step), 8)
        s = np.linspace(0.0, total, n + 1)
        lc = cfg.corner_length_m

        def corner(center: float) -> Array:
            return _s5(np.clip((s - center + 0.5 * lc) / lc, 0.0, 1.0))[0]

        head = np.full_like(s, heads[0])
        for sv, dturn in zip(vert_s[1:-1], turns, strict=True):
            head = head + dturn * corner(sv)
        if cfg.closed:
            # the corner at the closing vertex is centred on s = 0 ≡ s = total
            close = float(np.angle(np.exp(1j * (heads[0] - heads[-1]))))
            head = head + close * (corner(total) + corner(0.0) - 1.0)
        xi = cumulative_trapezoid(np.cos(head), s, initial=0.0) + pts[0, 0]
        eta = cumulative_trapezoid(np.sin(head), s, initial=0.0) + pts[0, 1]
        xy = np.column_stack([xi, eta])
        if cfg.closed:
            # distribute the (tiny) closure error of the integration linearly
            err = xy[-1] - xy[0]
            xy = xy - np.outer(s / total, err)
            spl = make_interp_spline(s, xy, k=5, bc_type="periodic")
        else:
            spl = make_interp_spline(s, xy, k=5)
        return cls(spl, spl.derivative(1), spl.derivative(2), total if cfg.closed else None)

    @property
    def length(self) -> float:
        """Arc length of one lap / of the open track."""
        return float(self.spline.t[-6])

    def plan(self, s: Array) -> tuple[Jet, Jet]:
        """See :class:`LegGeometry`."""
        if self.lap_length is not None:
            u = np.mod(s, self.lap_length)
        else:
            u = np.clip(s, 0.0, self.length)
        v, d, dd = self.spline(u), self.d1(u), self.d2(u)
        return Jet(v[:, 0], d[:, 0], dd[:, 0]), Jet(v[:, 1], d[:, 1], dd[:, 1])


# --------------------------------------------------------------------------------------------
# Motion schedule.
# --------------------------------------------------------------------------------------------


@dataclass
class _Schedule:
    """Piecewise motion profile: dwell, cruise and S₅ velocity-ramp segments."""

    accel: float
    min_ramp: float
    t: float = 0.0
    s: float = 0.0
    leg: int = 0
    env_scale: float = 1.0
    """Factor on the vibration envelope of the segments added (cleaning runs: reduced)."""
    rows: list[tuple[float, float, float, float, float, float, float, int, int]] = field(
        default_factory=list
    )

    def _add(self, duration: float, v0: float, dv: float, e0: float, de: float, cycle: int) -> None:
        if duration <= 0.0:
            return
        if self.env_scale != 1.0:
            e0, de = e0 * self.env_scale, de * self.env_scale
        self.rows.append((self.t, duration, self.s, v0, dv, e0, de, self.leg, cycle))
        self.t += duration
        self.s += v0 * duration + 0.5 * dv * duration

    def ramp_time(self, dv: float) -> float:
        return max(1.875 * abs(dv) / self.accel, self.min_ramp)

    def dwell(self, duration: float, cycle: int) -> None:
        self._add(duration, 0.0, 0.0, 0.0, 0.0, cycle)

    def cruise(self, distance: float, v: float, cycle: int) -> None:
        if distance > 1e-12:
            self._add(distance / abs(v), v, 0.0, 1.0, 0.0, cycle)

    def ramp(self, v0: float, v1: float, cycle: int) -> float:
        """Ramp ``v0 → v1``; returns the distance covered (|·|)."""
        t = self.ramp_time(v1 - v0)
        e0 = 0.0 if v0 == 0.0 else 1.0
        e1 = 0.0 if v1 == 0.0 else 1.0
        self._add(t, v0, v1 - v0, e0, e1 - e0, cycle)
        return abs(0.5 * (v0 + v1) * t)

    def drive(
        self,
        length: float,
        sign: float,
        speed_range: tuple[float, float],
        rng: np.random.Generator,
        cycle: int,
        stop_rate_h: float = 0.0,
        stop_duration: tuple[float, float] = (0.0, 0.0),
        change_rate_h: float = 0.0,
        stop_count: int | None = None,
    ) -> None:
        """Travel ``length`` (≥ 0) in direction ``sign`` from rest to rest, with random events."""
        target = self.s + sign * length
        lo, hi = speed_range

        def fit(v: float, room: float) -> float:
            # ramp up + ramp down cover v·T with T = max(1.875 v/a, T_min)
            while v > 1e-6 and v * self.ramp_time(v) > room:
                v *= 0.8
            return v

        def ramp_dist(v0: float, v1: float) -> float:
            return abs(0.5 * (v0 + v1) * self.ramp_time(v1 - v0))

        v = fit(rng.uniform(lo, hi), 0.98 * length)
        mean_time = length / max(0.5 * (lo + hi), 1e-9)
        events: list[tuple[float, int, float]] = []
        n_stops = rng.poisson(stop_rate_h * mean_time / 3600.0)
        for _ in range(n_stops if stop_count is None else stop_count):
            events.append((rng.uniform(0.0, length), 0, rng.uniform(*stop_duration)))
        for _ in range(rng.poisson(change_rate_h * mean_time / 3600.0)):
            events.append((rng.uniform(0.0, length), 1, rng.uniform(lo, hi)))
        events.sort()
        pos = self.ramp(0.0, sign * v, cycle)
        for p, kind, val in events:
            if kind == 0:
                d_dn = ramp_dist(v, 0.0)
                v_next = fit(rng.uniform(lo, hi), 0.98 * (length - p))
                if p - d_dn < pos or v_next <= 1e-6:
                    continue
                self.cruise(p - d_dn - pos, sign * v, cycle)
                self.ramp(sign * v, 0.0, cycle)
                self.dwell(val, cycle)
                v = v_next
                pos = p + self.ramp(0.0, sign * v, cycle)
            else:
                d_ch = ramp_dist(v, val)
                if p < pos or p + d_ch + ramp_dist(val, 0.0) > length:
                    continue
                self.cruise(p - pos, sign * v, cycle)
                self.ramp(sign * v, sign * val, cycle)
                v = val
                pos = p + d_ch
        d_dn = ramp_dist(v, 0.0)
        self.cruise(length - d_dn - pos, sign * v, cycle)
        self.ramp(sign * v, 0.0, cycle)
        self.s = target  # remove float round-off of the accumulated segment lengths

    def arrays(self) -> dict[str, NDArray[np.float64] | NDArray[np.int64]]:
        a = np.array(self.rows, dtype=float)
        return {
            "t0": a[:, 0],
            "dur": a[:, 1],
            "s0": a[:, 2],
            "v0": a[:, 3],
            "dv": a[:, 4],
            "e0": a[:, 5],
            "de": a[:, 6],
            "leg": a[:, 7].astype(np.int64),
            "cycle": a[:, 8].astype(np.int64),
        }


# --------------------------------------------------------------------------------------------
# The trajectory.
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MotionState:
    """Pointwise truth in the origin's ENU axes with exact derivatives.

    ``euler`` (roll, pitch, yaw) and ``euler_rate`` are the attitude relative to the local level
    frame at the point (see module docstring); ``s_dot`` is the path-parameter rate.
    """

    position: Array
    velocity: Array
    acceleration: Array
    euler: Array
    euler_rate: Array
    s_dot: Array
    cycle: NDArray[np.int64]
    moving: NDArray[np.bool_]


@dataclass(frozen=True)
class PushEvent:
    """An AFC push: at ``t`` the AFC (its end section, completing the line) advanced ``advance``."""

    t: float
    advance: float
    cycle: int


@dataclass(frozen=True)
class _VibrationTerms:
    lin_amp: Array  # (3, K) displacement amplitude (m)
    lin_w: Array
    lin_ph: Array
    ang_amp: Array  # (3, K) angle amplitude (rad)
    ang_w: Array
    ang_ph: Array

    @classmethod
    def draw(cls, cfg: Vibration, rng: np.random.Generator) -> _VibrationTerms | None:
        if not cfg.enabled or (cfg.linear_mps2 == 0.0 and cfg.angular_dps == 0.0):
            return None
        k = cfg.components
        w1 = 2.0 * np.pi * rng.uniform(*cfg.freq_hz, size=(3, k))
        w2 = 2.0 * np.pi * rng.uniform(*cfg.freq_hz, size=(3, k))
        return cls(
            cfg.linear_mps2 / w1**2,
            w1,
            rng.uniform(0.0, 2.0 * np.pi, size=(3, k)),
            math.radians(cfg.angular_dps) / w2,
            w2,
            rng.uniform(0.0, 2.0 * np.pi, size=(3, k)),
        )


class Trajectory:
    """Exact truth trajectory built from a scenario (see the module docstring).

    Parameters
    ----------
    scenario
        The validated scenario.
    rng
        Generator for stops, speeds, waviness and vibration phases.
    """

    def __init__(self, scenario: Scenario, rng: np.random.Generator) -> None:
        self.scenario = scenario
        r_geom, r_motion, r_vib = rng.spawn(3)
        # the patterns, ends, line deviations and re-cuts draw from streams of their own, so
        # that a scenario without them draws exactly what it drew before they existed
        (r_face,) = rng.spawn(1)
        motion = scenario.motion
        sched = _Schedule(motion.accel_mps2, motion.min_ramp_s)
        self.legs: list[LegGeometry] = []
        self.push_events: list[PushEvent] = []
        if scenario.face is not None:
            self.azimuth = math.radians(scenario.face.azimuth_deg)
            self.floor = FloorSurface.from_config(scenario.face.floor, r_geom)
            self._plan_face(scenario, scenario.face, sched, r_geom, r_motion, r_face)
        else:
            assert scenario.track is not None
            self.azimuth = math.radians(scenario.track.azimuth_deg)
            self.floor = FloorSurface.from_config(scenario.track.floor, r_geom)
            self._plan_track(scenario, scenario.track, sched, r_motion)
        sched.dwell(scenario.static_end_s if scenario.static_end_s > 0 else 1.0, 0)
        if scenario.duration_s is not None and scenario.duration_s > sched.t:
            sched.dwell(scenario.duration_s - sched.t, 0)
        self._seg = sched.arrays()
        self.duration = (
            float(scenario.duration_s) if scenario.duration_s is not None else float(sched.t)
        )
        self.push_events = [e for e in self.push_events if e.t <= self.duration]
        self._vib = _VibrationTerms.draw(motion.vibration, r_vib)
        self._p0 = np.zeros(3)
        east, north, up = self._raw_enu(self.legs[0], np.zeros(1))
        self._p0 = np.array([east.v[0], north.v[0], up.v[0]])

    def _raw_enu(self, leg: LegGeometry, s: Array) -> tuple[Jet, Jet, Jet]:
        """ENU jets (in s) of ``leg`` at ``s``, relative to the start point of the trajectory."""
        xi, eta = leg.plan(s)
        sa, ca = math.sin(self.azimuth), math.cos(self.azimuth)
        east = xi * sa + eta * ca - self._p0[0]
        north = xi * ca - eta * sa - self._p0[1]
        up = self.floor.height(xi, eta) - self._p0[2]
        return east, north, up

    # ---------------------------------------------------------------- planning

    def _plan_face(
        self,
        sc: Scenario,
        face: Face,
        sched: _Schedule,
        r_geom: np.random.Generator,
        r_motion: np.random.Generator,
        r_face: np.random.Generator,
    ) -> None:
        wav = face.waviness
        n = len(wav.wavelengths_m)
        amp = np.full(n, wav.amplitude_m / max(n, 1) ** 0.5)
        k = 2.0 * np.pi / np.asarray(wav.wavelengths_m, dtype=float)
        c = r_geom.choice([-1.0, 1.0], size=n) / wav.decorrelation_m
        ph = r_geom.uniform(0.0, 2.0 * np.pi, size=n)
        r_ends, r_dev, r_recut = r_face.spawn(3)

        dev_cfg = face.line_deviation
        deviation: Deviation | None = None
        if dev_cfg.sigma_m > 0:
            deviation = Deviation(np.zeros(0), np.zeros(0), np.zeros(0))

        def next_deviation() -> Deviation | None:
            if deviation is None:
                return None
            return deviation.next(
                dev_cfg.persistence,
                dev_cfg.sigma_m,
                dev_cfg.wavelengths_m,
                dev_cfg.components,
                r_dev,
            )

        def line(
            a0: float,
            a1: float = 0.0,
            s0: float = 0.0,
            s1: float = 0.0,
            dev1: Deviation | None = None,
        ) -> int:
            self.legs.append(
                AfcLine(a0, a1 if s1 != s0 else a0, s0, s1, amp, k, c, ph, None, deviation, dev1)
            )
            return len(self.legs) - 1

        m = sc.motion
        cut = (m.speed_mpm[0] / 60.0, m.speed_mpm[1] / 60.0)
        clean_mpm = m.clean_speed_mpm if m.clean_speed_mpm is not None else m.speed_mpm
        clean = (clean_mpm[0] / 60.0, clean_mpm[1] / 60.0)
        man = face.maneuver_speed_mpm / 60.0
        length = face.length_m
        runs = face.runs
        push_after = face.push_after_run if face.push_after_run is not None else len(runs) - 1
        fixed_ends = face.end_skew_deg == (0.0, 0.0) and face.end_jitter_m == 0.0
        tan_skew = [math.tan(math.radians(x)) for x in face.end_skew_deg]
        jitter = np.zeros((face.cycles + 2, 2))
        if face.end_jitter_m > 0:
            jitter[2:] = r_ends.uniform(-face.end_jitter_m, face.end_jitter_m, (face.cycles, 2))

        def end_at(sign: float, a: float, cycle: int) -> float:
            """ξ of the face end that a run in direction ``sign`` reaches (line offset a)."""
            if sign > 0:
                return length + a * tan_skew[1] + float(jitter[cycle, 1])
            return a * tan_skew[0] + float(jitter[cycle, 0])

        sched.leg = line(0.0)
        sched.s = 0.0
        sched.dwell(sc.static_start_s, 0)
        a_k, sign = 0.0, 1.0
        self.face_lines: list[float] = [0.0]
        for cyc in range(1, face.cycles + 1):
            for run, kind in enumerate(runs):
                sched.leg = line(a_k)
                run_length = length if fixed_ends else sign * (end_at(sign, a_k, cyc) - sched.s)
                sched.env_scale = 1.0 if kind == "cut" else m.vibration.clean_scale
                self._run(
                    sched, run_length, sign, cut if kind == "cut" else clean, r_motion, r_recut, cyc
                )
                sched.env_scale = 1.0
                if cyc == face.cycles and run == len(runs) - 1:
                    break
                if run != push_after:
                    sched.dwell(r_motion.uniform(*face.end_dwell_s), 0)
                    sign = -sign
                    continue
                d = face.advance_m + (
                    face.advance_jitter_m * float(r_motion.standard_normal())
                    if face.advance_jitter_m > 0
                    else 0.0
                )
                a_next = a_k + d
                s_end = (length if sign > 0 else 0.0) if fixed_ends else sched.s
                bend = min(face.bend_length_m, 0.5 * length)
                travel = min(bend + face.sump_overrun_m, 0.9 * length)
                sched.dwell(r_motion.uniform(*face.end_dwell_s), 0)
                new_dev = next_deviation()
                sched.leg = line(a_k, a_next, s_end, s_end - sign * bend, new_dev)
                sched.drive(travel, -sign, (man, man), r_motion, 0)
                push = r_motion.uniform(*face.push_dwell_s)
                sched.dwell(push, 0)
                self.push_events.append(PushEvent(sched.t - 0.5 * push, d, cyc))
                deviation = new_dev
                sched.leg = line(a_next)
                back = travel
                if not fixed_ends:  # to the end of the new line (the next run's start)
                    next_cycle = cyc + 1 if run == len(runs) - 1 else cyc
                    back = sign * (end_at(sign, a_next, next_cycle) - sched.s)
                sched.drive(back, sign, (man, man), r_motion, 0)
                sched.dwell(r_motion.uniform(*face.end_dwell_s), 0)
                a_k, sign = a_next, -sign
                self.face_lines.append(a_k)

    def _run(
        self,
        sched: _Schedule,
        length: float,
        sign: float,
        speed: tuple[float, float],
        r_motion: np.random.Generator,
        r_recut: np.random.Generator,
        cycle: int,
    ) -> None:
        """One face traversal from rest to rest, with its random stops, speed changes and (with
        the scenario's re-cut probability) a re-cut: back up mid-face, then go on."""
        m = self.scenario.motion
        recut = self.scenario.face.recut if self.scenario.face is not None else None

        def drive(dist: float, direction: float) -> None:
            sched.drive(
                dist,
                direction,
                speed,
                r_motion,
                cycle,
                m.stops.rate_per_hour,
                m.stops.duration_s,
                m.speed_changes_per_hour,
                m.stops.count,
            )

        if recut is None or recut.probability <= 0 or r_recut.random() >= recut.probability:
            drive(length, sign)
            return
        start = sched.s
        at = r_recut.uniform(0.2, 0.8) * length
        back = min(r_recut.uniform(*recut.distance_m), 0.9 * at)
        dwell = r_recut.uniform(*recut.dwell_s, size=2)
        drive(at, sign)
        sched.dwell(float(dwell[0]), cycle)
        drive(back, -sign)
        sched.dwell(float(dwell[1]), cycle)
        drive(length - at + back, sign)
        sched.s = start + sign * length

    def _plan_track(
        self, sc: Scenario, track: Track, sched: _Schedule, r_motion: np.random.Generator
    ) -> None:
        geom = SplineTrack.from_config(track)
        self.legs.append(geom)
        m = sc.motion
        sched.leg = 0
        sched.s = 0.0
        sched.dwell(sc.static_start_s, 0)
        total = geom.length * (track.laps if track.closed else 1)
        sched.drive(
            total,
            1.0,
            (m.speed_mpm[0] / 60.0, m.speed_mpm[1] / 60.0),
            r_motion,
            1,
            m.stops.rate_per_hour,
            m.stops.duration_s,
            m.speed_changes_per_hour,
            m.stops.count,
        )

    # ---------------------------------------------------------------- evaluation
    def profile(
        self, t: Array
    ) -> tuple[Array, Array, Array, Array, Array, Array, NDArray[np.int64]]:
        """``s, ṡ, s̈``, envelope ``e, ė, ë`` and segment index at times ``t``.

        Times before the start / after the end hold the first / last (static) state.
        """
        g = self._seg
        i = np.clip(np.searchsorted(g["t0"], t, side="right") - 1, 0, len(g["t0"]) - 1)
        dur = g["dur"][i]
        tau = np.clip(t - g["t0"][i], 0.0, dur)
        x = tau / dur
        s5, s5d, s5dd = _s5(x)
        p = x**4 * (2.5 + x * (-3.0 + x))
        v0, dv = g["v0"][i], g["dv"][i]
        s = g["s0"][i] + v0 * tau + dv * dur * p
        sd = v0 + dv * s5
        sdd = dv / dur * s5d
        e0, de = g["e0"][i], g["de"][i]
        e = e0 + de * s5
        ed = de / dur * s5d
        edd = de / dur**2 * s5dd
        return s, sd, sdd, e, ed, edd, i

    def evaluate(self, t: Array) -> MotionState:
        """Exact position, velocity, acceleration (origin ENU) and attitude with rates at ``t``."""
        t = np.asarray(t, dtype=float)
        s, sd, sdd, e, ed, edd, seg = self.profile(t)
        legs = self._seg["leg"][seg]
        n = t.shape[0]
        pos = np.empty((n, 3))
        d1 = np.empty((n, 3))
        d2 = np.empty((n, 3))
        eul = np.empty((n, 3))
        eul_s = np.empty((n, 3))
        for leg in np.unique(legs):
            sel = legs == leg
            geom = self.legs[int(leg)]
            east, north, up = self._raw_enu(geom, s[sel])
            xi, eta = geom.plan(s[sel])
            for j, q in enumerate((east, north, up)):
                pos[sel, j], d1[sel, j], d2[sel, j] = q.v, q.d, q.dd
            de_, dn_, du_ = east.derivative(), north.derivative(), up.derivative()
            yaw = jatan2(de_, dn_)
            horiz = jsqrt(de_ * de_ + dn_ * dn_)
            pitch = jatan2(du_, horiz)
            phi = yaw - self.azimuth
            gx, ge = self.floor.gradient(xi, eta)
            cphi, sphi = jcos(phi), jsin(phi)
            g_f = gx * cphi + ge * sphi
            g_r = ge * cphi - gx * sphi
            roll = -jatan2(g_r, jcos(pitch) + g_f * jsin(pitch))
            for j, a in enumerate((roll, pitch, yaw)):
                eul[sel, j], eul_s[sel, j] = a.v, a.d
        sd_col = sd[:, None]
        vel = d1 * sd_col
        acc = d2 * sd_col**2 + d1 * sdd[:, None]
        rate = eul_s * sd_col
        if self._vib is not None:
            vb = self._vib
            ph = vb.lin_w[None] * t[:, None, None] + vb.lin_ph[None]
            sn, cs = np.sin(ph), np.cos(ph)
            a_ = vb.lin_amp[None]
            w_ = vb.lin_w[None]
            dp = (a_ * sn).sum(-1)
            dpd = (a_ * w_ * cs).sum(-1)
            dpdd = -(a_ * w_**2 * sn).sum(-1)
            ec, edc, eddc = e[:, None], ed[:, None], edd[:, None]
            pos = pos + ec * dp
            vel = vel + edc * dp + ec * dpd
            acc = acc + eddc * dp + 2.0 * edc * dpd + ec * dpdd
            ph = vb.ang_w[None] * t[:, None, None] + vb.ang_ph[None]
            da = (vb.ang_amp[None] * np.sin(ph)).sum(-1)
            dad = (vb.ang_amp[None] * vb.ang_w[None] * np.cos(ph)).sum(-1)
            eul = eul + ec * da
            rate = rate + edc * da + ec * dad
        cyc = np.asarray(self._seg["cycle"][seg], dtype=np.int64).copy()
        for leg in np.unique(legs):
            lap = self.legs[int(leg)].lap_length
            if lap is not None:
                sel = (legs == leg) & (cyc > 0)
                cyc[sel] = np.minimum(
                    1 + np.floor(s[sel] / lap + 1e-9).astype(np.int64),
                    max(1, self.scenario.track.laps if self.scenario.track else 1),
                )
        return MotionState(pos, vel, acc, eul, rate, sd, cyc, np.abs(sd) > 0.0)

    # ---------------------------------------------------------------- face info
    def face_ends_enu(self) -> list[list[float]]:
        """ENU of the two ends (s = 0 and s = L) of the first cutting line (longwall only)."""
        if self.scenario.face is None:
            st = self.evaluate(np.array([0.0, self.duration]))
            return st.position.round(4).tolist()
        east, north, up = self._raw_enu(self.legs[0], np.array([0.0, self.scenario.face.length_m]))
        return np.column_stack([east.v, north.v, up.v]).tolist()

    def enu_from_face(self, along: float, right: float, up: float = 0.0) -> Array:
        """ENU of a point given in face coordinates (ξ, η) and a height above the floor."""
        sa, ca = math.sin(self.azimuth), math.cos(self.azimuth)
        xi = Jet.const(along, np.zeros(1))
        eta = Jet.const(right, np.zeros(1))
        z = self.floor.height(xi, eta).v[0]
        return np.array([along * sa + right * ca, along * ca - right * sa, z + up]) - self._p0
