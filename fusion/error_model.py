"""Error-state model of the SINS: state layout, dynamics F, process noise Q and discretization.

Conventions (seed 000 eq. 11; PSINS/Qin's φ-angle model, ENU):

* ``δv = ṽ − v`` (m/s, local-level ENU);
* ``φ``: ``C̃_b^n = (I − φ×) C_b^n`` (rad), the misalignment of the computed n-frame;
* ``δp = [δE, δN, δU]`` (m), the position error in local metres:
  ``δE = (R_N+h) cos L δλ``, ``δN = (R_M+h) δL``, ``δU = δh`` (metres keep P well conditioned;
  geodetic angle errors of 1e-8 rad would not);
* ``ε^b``, ``∇^b``: residual gyro and accelerometer biases, estimate minus truth of the error the
  SINS still carries after the compensation it applies (``ω̂ = ω + ε``, ``f̂ = f + ∇``).

Dynamics (seed 000 eqs. 13–15 with the velocity-dependent terms the seed drops restored)::

    φ̇  = −ω_in^n × φ + M_av δv + M_ap δp − C_b^n ε
    δv̇ = f^n × φ + [v× M_av − (2ω_ie^n + ω_en^n)×] δv + [v× (2M_1 + M_2) + ∂g] δp + C_b^n ∇
    δṗ = δv + F_pp δp
    ε̇  = −ε/τ_g + w_g,   ∇̇ = −∇/τ_a + w_a       (τ = ∞: random constant)

with ``M_av``, ``M_1``, ``M_2`` the partials of ``ω_in^n`` with respect to velocity and latitude /
height (Qin, *Kalman Filtering and Integrated Navigation*, ch. 4, the seed's ref. 5), rewritten
for metre position errors: a geodetic column ``∂/∂L`` becomes ``∂/∂N = ∂/∂L / (R_M+h)``, and
``F_pp = T M_pp T⁻¹ + Ṫ T⁻¹`` with ``T = ∂(δE, δN, δU)/∂(δL, δλ, δh)``, which gives::

    F_pp = [[v_U/(R_N+h) − v_N tanL/(R_M+h), v_E tanL/(R_M+h), −v_E/(R_N+h)],
            [0,                              v_U/(R_M+h),      −v_N/(R_M+h)],
            [0,                              0,                 0          ]]

``∂g`` is the normal-gravity gradient (``δg_U = −∂γ/∂L δL − ∂γ/∂h δh``; the height term,
+3.1e-6 s⁻², is what makes the free vertical channel unstable). The option ``low_speed`` is the
seed's simplified eq. 13: ``φ̇ = −ω_ie×φ − Cε``, ``δv̇ = −2ω_ie×δv + f×φ + C∇``, ``δṗ = δv``.

Process noise from datasheet units (seed 000 Appendix A): ARW deg/√h → rad/√s (× π/180/60),
VRW as a noise density mg/√Hz → m/s/√s (× 1e-3 g₀), biases deg/h → rad/s, mg → m/s². A
Gauss–Markov bias of steady σ and correlation time τ has ``q = 2σ²/τ``. The white noise enters
through ``−C_b^n`` (attitude) and ``C_b^n`` (velocity).

The ``f^n`` in F is the mean specific force of the covariance step, optionally low-passed
(:class:`SpecificForceFilter`, option ``filter.specific_force_time_constant_s``): 5–30 Hz cutting
vibration aliases into the 0.1-s step means as ±0.05 m/s² of horizontal force, and ``f^n × φ``
then lets 10-Hz velocity aiding "see" the heading through couplings that its interval means
cannot resolve. The filter grew overconfident in the yaw (``longwall-200m``, SINS + odometer at
the encoder's 2–3 mm/s, 8 seeds of 300 s: yaw RMS(ε/σ) 2.1; without vibration 0.9; with
τ = 1 s 1.2). The configs of the shearer set τ = 1 s (README, "Configurations"). The force held
is of the nominal state, so a feedback of the attitude or the accelerometer bias moves it at once
(:meth:`SpecificForceFilter.follow`).

Discretization over a covariance step Δt: ``series`` (default) uses
``Φ = I + FΔt + (FΔt)²/2 + (FΔt)³/6`` (third order: position ← attitude ← gyro bias is a
three-integration path) and ``Q_d = QΔt + (FQ + QFᵀ)Δt²/2 + FQFᵀΔt³/3``; ``van_loan`` uses
the exact matrix exponential of ``[[−F, Q], [0, Fᵀ]] Δt``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from fusion import earth, kernels
from fusion.attitude import dcm_from_quat, misalignment_jacobian
from fusion.strapdown import HGT, LAT, LON, Q0, VEL

G0 = 9.80665
"""Standard gravity used by datasheets for mg (m/s²)."""
DEG = math.pi / 180.0

VELOCITY, ATTITUDE, POSITION, GYRO_BIAS, ACCEL_BIAS = (
    "velocity",
    "attitude",
    "position",
    "gyro_bias",
    "accel_bias",
)
COMMON_BLOCKS = (VELOCITY, ATTITUDE, POSITION, GYRO_BIAS, ACCEL_BIAS)
N_COMMON = 15

STATE_UNITS: dict[str, float] = {
    "": 1.0,  # not declared: the state's own unit, named nowhere
    "m": 1.0,
    "m_s": 1.0,
    "uT": 1.0,
    "deg": 180.0 / math.pi,  # from rad
    "deg_h": 180.0 / math.pi * 3600.0,  # from rad/s
    "mg": 1.0 / (1e-3 * G0),  # from m/s²
    "ppm": 1e6,  # from a ratio
    "pct": 100.0,  # from a ratio
}
"""The units a state is shown in (``states.csv`` column names) and the factor from the state's
own unit (SI: m, m/s, rad, rad/s, m/s², ratio; µT for a magnetic field) to it."""


@dataclass(frozen=True)
class StateBlock:
    """A named group of error states with its own prior and (for plugin states) dynamics.

    Parameters
    ----------
    name
        Unique name, e.g. ``"odometer.scale_error"``.
    labels
        One label per state (for tables and plots).
    initial_sigma
        Prior 1-σ of each state (SI units).
    noise_density
        Continuous process-noise density (σ² per second) of each state; 0 for a constant.
    correlation_time_s
        First-order Gauss–Markov correlation time, or ``None`` for a random walk / constant.
    may_jump
        The state can change abruptly (a wheel starting to slip): its jumps are detected,
        estimated and taken in (:mod:`fusion.jumps`).
    rest
        A value a jumping state returns to exactly (a slip ends): a jump that brings it back
        within 3σ of ``rest`` sets it there. ``None``: no such value.
    leaves_rest
        +1 or −1: the only direction in which the state leaves ``rest`` (a slipping wheel turns
        more than the machine travels, so its slip ratio only rises from 0); 0: either.
    rest_return_s
        Mean time a state held away from ``rest`` (which must be 0) stays there before it
        returns on its own (a slip ends after seconds to a minute, whether or not anything sees
        it end): while held, it decays towards rest and its variance grows as that return's
        chance (:mod:`fusion.jumps`). ``None``: it returns only when a jump back is detected or
        its plugin reports it at rest.
    bound
        The largest magnitude the state can physically reach: a jump that would take it beyond
        is not taken in (:mod:`fusion.jumps`), and an update that takes the estimate beyond is
        projected back onto it (:meth:`fusion.kalman.KalmanFilter.hold_bounds`). ``None``:
        unbounded.
    unit
        The unit users read the state in, a key of :data:`STATE_UNITS` (``"deg_h"`` for a gyro
        bias held in rad/s); ``""``: its own unit, unnamed.
    initial_correlation
        Prior correlation matrix of the block's states (rows of ``size`` numbers), or ``None``
        for uncorrelated states. The initial misalignment is one: meta.yaml states the σ of the
        roll, pitch and yaw, which turn into the local-level axes of φ with the heading
        (:func:`misalignment_prior`).
    """

    name: str
    labels: tuple[str, ...]
    initial_sigma: tuple[float, ...]
    noise_density: tuple[float, ...] = ()
    correlation_time_s: float | None = None
    may_jump: bool = False
    rest: float | None = None
    leaves_rest: int = 0
    rest_return_s: float | None = None
    bound: float | None = None
    unit: str = ""
    initial_correlation: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        if self.rest_return_s is not None and self.rest != 0.0:
            raise ValueError(
                f"state block {self.name!r}: rest_return_s needs a rest value of 0 (the return"
                f" is a decay towards it), not {self.rest!r}"
            )
        if self.unit not in STATE_UNITS:
            raise ValueError(
                f"state block {self.name!r}: unit {self.unit!r} is not one of {list(STATE_UNITS)}"
            )
        if self.initial_correlation is not None and np.shape(self.initial_correlation) != (
            self.size,
            self.size,
        ):
            raise ValueError(
                f"state block {self.name!r}: initial_correlation must be {self.size} x"
                f" {self.size}, not {np.shape(self.initial_correlation)}"
            )

    @property
    def size(self) -> int:
        """Number of states."""
        return len(self.labels)

    def initial_covariance(self) -> NDArray[np.float64]:
        """The block's prior covariance ``D R D`` (``D = diag(initial_sigma)``)."""
        sigma = np.asarray(self.initial_sigma, dtype=float)
        if self.initial_correlation is None:
            return np.diag(sigma**2)
        return np.asarray(self.initial_correlation, dtype=float) * np.outer(sigma, sigma)


@dataclass(frozen=True)
class StateLayout:
    """Ordered state blocks: the 15 common SINS error states first, then those of plugins."""

    blocks: tuple[StateBlock, ...]
    _slices: dict[str, slice] = field(init=False, repr=False, compare=False)
    _bounds: tuple[tuple[int, float], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        slices: dict[str, slice] = {}
        start = 0
        for block in self.blocks:
            if block.name in slices:
                raise ValueError(f"state block {block.name!r} is declared twice")
            slices[block.name] = slice(start, start + block.size)
            start += block.size
        object.__setattr__(self, "_slices", slices)
        bounds = tuple(
            (slices[b.name].start + k, b.bound)
            for b in self.blocks
            if b.bound is not None
            for k in range(b.size)
        )
        object.__setattr__(self, "_bounds", bounds)

    @property
    def dim(self) -> int:
        """Total number of states."""
        return sum(b.size for b in self.blocks)

    def slice(self, name: str) -> slice:
        """Index range of block ``name``."""
        try:
            return self._slices[name]
        except KeyError:
            raise KeyError(
                f"no state block {name!r}; the layout has {list(self._slices)}"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self._slices

    def extended(self, blocks: Iterable[StateBlock]) -> StateLayout:
        """A new layout with ``blocks`` appended."""
        return StateLayout((*self.blocks, *blocks))

    @property
    def bounds(self) -> tuple[tuple[int, float], ...]:
        """``(index, bound)`` of every state with a physical bound (:attr:`StateBlock.bound`)."""
        return self._bounds

    @property
    def labels(self) -> list[str]:
        """Full label of every state, ``block.label``."""
        return [f"{b.name}.{lab}" for b in self.blocks for lab in b.labels]

    def initial_covariance(self) -> NDArray[np.float64]:
        """Prior covariance: block diagonal, each block ``D R D`` of its σ and correlation."""
        return scipy.linalg.block_diag(*(b.initial_covariance() for b in self.blocks))


@dataclass(frozen=True)
class ImuNoise:
    """IMU error figures in SI units.

    Parameters
    ----------
    gyro_arw
        Angle random walk (rad/√s).
    accel_vrw
        Velocity random walk (m/s/√s).
    gyro_bias, accel_bias
        1-σ bias at start (rad/s, m/s²): prior of the bias states.
    gyro_bias_instability, accel_bias_instability
        Steady σ of the Gauss–Markov part (rad/s, m/s²); 0 for a random constant.
    bias_correlation_time_s
        Gauss–Markov correlation time.
    bias_random_walk
        Model the in-run part as a random walk of the same density 2σ²/τ instead of a
        Gauss–Markov decay of the whole bias state (one state cannot hold a constant *and* a
        Gauss–Markov part: with decay, the constant turn-on bias would be forgotten in τ).
    """

    gyro_arw: float
    accel_vrw: float
    gyro_bias: float
    accel_bias: float
    gyro_bias_instability: float = 0.0
    accel_bias_instability: float = 0.0
    bias_correlation_time_s: float = 3600.0
    bias_random_walk: bool = False

    @classmethod
    def from_datasheet(
        cls,
        *,
        gyro_arw_deg_rth: float,
        accel_vrw_mg_rthz: float,
        gyro_bias_deg_h: float,
        accel_bias_mg: float,
        gyro_bias_instability_deg_h: float = 0.0,
        accel_bias_instability_mg: float = 0.0,
        bias_correlation_time_s: float = 3600.0,
        bias_random_walk: bool = False,
    ) -> ImuNoise:
        """Convert datasheet units (deg/√h, mg/√Hz, deg/h, mg) to SI."""
        return cls(
            gyro_arw=gyro_arw_deg_rth * DEG / 60.0,
            accel_vrw=accel_vrw_mg_rthz * 1e-3 * G0,
            gyro_bias=gyro_bias_deg_h * DEG / 3600.0,
            accel_bias=accel_bias_mg * 1e-3 * G0,
            gyro_bias_instability=gyro_bias_instability_deg_h * DEG / 3600.0,
            accel_bias_instability=accel_bias_instability_mg * 1e-3 * G0,
            bias_correlation_time_s=bias_correlation_time_s,
            bias_random_walk=bias_random_walk,
        )


def misalignment_prior(
    euler: ArrayLike, sigma_euler: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """σ and correlation matrix of the misalignment φ (local-level E, N, U; rad) of an attitude
    whose roll, pitch and yaw ``euler`` (rad) are uncertain by ``sigma_euler`` (rad, 1-σ each,
    independent): ``P_φ = G diag(σ²) Gᵀ`` with ``G = ∂φ/∂(roll, pitch, yaw)``
    (:func:`fusion.attitude.misalignment_jacobian`), no axis taken as known better than the
    best-known angle: P_φ's eigenvalues are floored at ``min(σ)²``.

    Facing north a pitch error is a turn about east and a roll error one about north; facing
    south the same, mirrored; facing north-east each is a mix of both, and a roll known better
    than the pitch leaves φ_E and φ_N correlated. Taking meta.yaml's ``[roll, pitch, yaw]`` σ as
    ``[φ_E, φ_N, φ_U]`` gave a shearer facing south, pitch σ 1.3° and roll σ 0.4°, a φ_E σ of
    0.4° against a 3.9° pitch error: the odometer's first zero speeds were rejected at NIS 62
    and the run ended 900 km off (docs/design/2026-12-02-initial-attitude-covariance.md).

    The floor is for a steep pitch. There roll and yaw turn about nearly one axis, and
    independent Euler σ would claim the turn about the horizontal axis across the pitch axis
    known far better than any angle (at pitch 60°, σ 0.3° / 0.3° / 1° give it 0.15°; at ±90°,
    nothing): an artefact of the angles, not what an alignment knows. With those σ the floor
    moves no σ by more than 7 % below 20° of pitch, and by less than 0.5 % below 5°."""
    sigma_angles = np.asarray(sigma_euler, dtype=float)
    jacobian = misalignment_jacobian(np.asarray(euler, dtype=float))
    covariance = jacobian @ np.diag(np.square(sigma_angles)) @ jacobian.T
    values, vectors = np.linalg.eigh(covariance)
    floored = np.maximum(values, np.min(sigma_angles) ** 2)
    covariance = (vectors * floored) @ vectors.T
    sigma = np.sqrt(np.diag(covariance))
    return sigma, covariance / np.outer(sigma, sigma)


def common_blocks(
    imu: ImuNoise,
    sigma_velocity: ArrayLike,
    sigma_attitude: ArrayLike,
    sigma_position: ArrayLike,
    attitude_correlation: NDArray[np.float64] | None = None,
) -> tuple[StateBlock, ...]:
    """The 15 common error-state blocks with their priors (SI units); ``sigma_attitude`` and
    ``attitude_correlation`` are the misalignment φ's (:func:`misalignment_prior`)."""
    xyz = ("x", "y", "z")
    enu = ("e", "n", "u")
    tau = imu.bias_correlation_time_s
    gm = (imu.gyro_bias_instability > 0 or imu.accel_bias_instability > 0) and not (
        imu.bias_random_walk
    )
    return (
        StateBlock(
            VELOCITY, enu, tuple(np.asarray(sigma_velocity, dtype=float).tolist()), unit="m_s"
        ),
        StateBlock(
            ATTITUDE,
            enu,
            tuple(np.asarray(sigma_attitude, dtype=float).tolist()),
            unit="deg",
            initial_correlation=None
            if attitude_correlation is None
            else tuple(map(tuple, attitude_correlation.tolist())),
        ),
        StateBlock(
            POSITION, enu, tuple(np.asarray(sigma_position, dtype=float).tolist()), unit="m"
        ),
        StateBlock(
            GYRO_BIAS,
            xyz,
            (imu.gyro_bias,) * 3,
            (2.0 * imu.gyro_bias_instability**2 / tau,) * 3,
            tau if gm else None,
            unit="deg_h",
        ),
        StateBlock(
            ACCEL_BIAS,
            xyz,
            (imu.accel_bias,) * 3,
            (2.0 * imu.accel_bias_instability**2 / tau,) * 3,
            tau if gm else None,
            unit="mg",
        ),
    )


@kernels.jit
def _fill_sins_dynamics(
    f: NDArray[np.float64],
    nav: NDArray[np.float64],
    f_n: NDArray[np.float64],
    c_b_n: NDArray[np.float64],
    full: bool,
) -> None:
    """Write the 15×15 SINS block of F (velocity, attitude, position, biases) into ``f``."""
    v = nav[VEL : VEL + 3]
    lat, h = nav[LAT], nav[HGT]
    rmh, rnh, w_ie, w_en = kernels.frame_rates(lat, h, v)
    sl, cl = math.sin(lat), math.cos(lat)
    tl = sl / cl
    wie = earth.OMEGA_IE
    for i in range(3):
        for j in range(3):
            f[3 + i, 9 + j] = -c_b_n[i, j]
            f[0 + i, 12 + j] = c_b_n[i, j]
            f[6 + i, 0 + j] = 1.0 if i == j else 0.0
    f[0:3, 3:6] = kernels.skew(f_n)
    if not full:
        f[3:6, 3:6] = -kernels.skew(w_ie)
        f[0:3, 0:3] = -2.0 * kernels.skew(w_ie)
        return
    # Partials of ω_in^n: M_av (velocity), M_1 (latitude, earth rate), M_2 (latitude, height).
    m_av = np.zeros((3, 3))
    m_av[0, 1] = -1.0 / rmh
    m_av[1, 0] = 1.0 / rnh
    m_av[2, 0] = tl / rnh
    m_1 = np.zeros((3, 3))
    m_1[1, 0] = -wie * sl
    m_1[2, 0] = wie * cl
    m_2 = np.zeros((3, 3))
    m_2[0, 2] = v[1] / rmh**2
    m_2[1, 2] = -v[0] / rnh**2
    m_2[2, 0] = v[0] / (cl * cl) / rnh
    m_2[2, 2] = -v[0] * tl / rnh**2
    # Geodetic (δL, δλ, δh) columns → metre (δE, δN, δU) columns:
    # E ← λ/((R_N+h)cosL), N ← L/(R_M+h).
    to_metres = np.zeros((3, 3))
    to_metres[1, 0] = 1.0 / (rnh * cl)
    to_metres[0, 1] = 1.0 / rmh
    to_metres[2, 2] = 1.0
    v_skew = kernels.skew(v)
    f[3:6, 3:6] = -kernels.skew(w_ie + w_en)
    f[3:6, 0:3] = m_av
    f[3:6, 6:9] = (m_1 + m_2) @ to_metres
    f[0:3, 0:3] = v_skew @ m_av - kernels.skew(2.0 * w_ie + w_en)
    m_vp = v_skew @ (2.0 * m_1 + m_2)
    m_vp[2, 0] -= kernels.gravity_dlat(lat, h)
    m_vp[2, 2] -= kernels.gravity_dh(lat, h)
    f[0:3, 6:9] = m_vp @ to_metres
    f[6, 6] = v[2] / rnh - v[1] * tl / rmh
    f[6, 7] = v[0] * tl / rmh
    f[6, 8] = -v[0] / rnh
    f[7, 7] = v[2] / rmh
    f[7, 8] = -v[1] / rmh


class ErrorModel:
    """Continuous dynamics and discretization over a whole :class:`StateLayout`.

    Parameters
    ----------
    layout
        The filter's states; the five common blocks must come first.
    imu
        IMU noise figures (white-noise densities drive velocity and attitude).
    form
        ``"full"`` or the seed's ``"low_speed"`` simplification.
    discretization
        ``"series"`` or ``"van_loan"``.
    """

    def __init__(
        self,
        layout: StateLayout,
        imu: ImuNoise,
        *,
        form: Literal["full", "low_speed"] = "full",
        discretization: Literal["series", "van_loan"] = "series",
    ) -> None:
        if tuple(b.name for b in layout.blocks[:5]) != COMMON_BLOCKS:
            raise ValueError(f"the layout must start with the common blocks {COMMON_BLOCKS}")
        self.layout = layout
        self.imu = imu
        self.full = form == "full"
        self.discretization = discretization
        n = layout.dim
        # The part of F that does not depend on the navigation state, and all of Q.
        self._f_static = np.zeros((n, n))
        q_diag = np.zeros(n)
        for block in layout.blocks[3:]:
            s = layout.slice(block.name)
            if block.correlation_time_s is not None:
                self._f_static[s, s] = -np.eye(block.size) / block.correlation_time_s
            if block.noise_density:
                q_diag[s] = block.noise_density
        q_diag[0:3] = imu.accel_vrw**2
        q_diag[3:6] = imu.gyro_arw**2
        self._q = np.diag(q_diag)

    def continuous(
        self,
        nav: NDArray[np.float64],
        f_n: NDArray[np.float64],
        c_b_n: NDArray[np.float64],
        heading_coupling: float = 1.0,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``F`` and the state-space noise density ``Q`` (n×n) at a nominal state; the heading's
        column in the tilt rows times ``heading_coupling`` (:func:`heading_coupling`)."""
        f = self._f_static.copy()
        _fill_sins_dynamics(f, nav, f_n, c_b_n, self.full)
        f[_TILT, _HEADING] *= heading_coupling
        return f, self._q.copy()

    def discrete(
        self,
        nav: NDArray[np.float64],
        f_n: NDArray[np.float64],
        c_b_n: NDArray[np.float64],
        dt: float,
        heading_coupling: float = 1.0,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Transition matrix Φ and process noise Q_d over ``dt``."""
        f, q = self.continuous(nav, f_n, c_b_n, heading_coupling)
        return discretize(f, q, dt, self.discretization)


_TILT = slice(3, 5)
_HEADING = 5


def heading_coupling(p_common: NDArray[np.float64]) -> float:
    """How much of the rotation rate's coupling of the heading error into the tilt F keeps:
    ``E[cos ψ] = exp(−σ_ψ²/2)`` for a heading error ψ ~ N(0, σ_ψ²), σ_ψ² from ``p_common``.

    The Earth's rate (and the transport rate) resolved through the estimated attitude is off by
    ``(R_z(ψ) − I) ω`` for a heading error ψ. F keeps its first-order term, ``−ψ (e_U × ω)``:
    a heading error turns the horizontal Earth rate into a tilt drift, which a filter that
    sees the tilt (zero velocities, a level) then reads back as heading — gyrocompassing. That
    linearization holds for a heading known to a few degrees; for a heading beyond the
    small-angle model the tilt drift is ``ω_N sin ψ``, bounded by ω_N, while the linear model
    lets it grow with ψ. Statistical linearization (Gelb, *Applied Optimal Estimation*, 1974,
    §6.2) replaces the Jacobian by its expectation over the error's distribution: for the
    zero-mean error a filter assumes, the sine's derivative averages to ``E[cos ψ]``. A heading
    known to 10° keeps 98.5 % of the coupling (a navigation-grade IMU gyrocompasses as
    before), one of 60° 58 %, one of 150° 3 %. With the linear coupling, SINS + ZUPT on a
    random world (19) took a 150°-σ heading to 47° at one standstill while turning the
    estimate 110° the wrong way (docs/design/2026-11-30-heading-beyond-the-small-angle.md).
    """
    variance = float(p_common[_HEADING, _HEADING])
    return math.exp(-0.5 * variance) if variance > 0.0 else 1.0


def observable_force(
    f_n: NDArray[np.float64], c_b_n: NDArray[np.float64], p_common: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The specific force for F with its horizontal part shrunk by its own uncertainty.

    ``f^n × φ`` couples the heading error to the velocity error through the horizontal specific
    force. A slow machine's true horizontal force is a few mg at most; what the nominal state
    shows is mostly its own error, ``δf^n = f^n × φ + C_b^n ∇`` (a tilt error turns gravity
    into the horizontal, an accelerometer bias adds to it). Taken at face value it makes the
    heading observable where it is not: velocity aiding then walks the heading (and the vertical
    gyro bias) along that spurious coupling — on a random world whose gyros had an in-run bias
    instability of 24 °/h the yaw ran 40° away with a σ of 6° in 25 minutes. With ``s²`` the
    variance of the horizontal part of δf^n (from the tilt and accelerometer-bias block of the
    covariance ``p_common``), the horizontal force enters F as
    ``f_h · |f_h|² / (|f_h|² + k² s²)``, ``k`` = :data:`KNOWN_SIGMAS`: a force known to
    many σ observes the heading as before, one within a few σ of its error (a shearer's few mg:
    with k = 10 its coupling is ~1 %) does not. Measured on that world (SINS + odometer,
    1500 s): k = 1 yaw error 43° at σ 8°, k = 3 28° at 15°, k = 5 16° at 16°, the horizontal
    force removed altogether 5° at 16°. It is for a slow machine only: a foot's swing or a
    car's braking is brief against the covariance step and partly shrunk, and the velocity
    error it really causes is then missing from the model (PyShoe's foot-mounted trials: ARMSE
    a median 16× the dataset's best_error with it, 3.4× without), so the configs of such
    platforms set ``filter.observable_force: false``.
    """
    jacobian = np.empty((2, 6))  # the horizontal rows of δf^n over (φ, ∇): [(f^n×)ᵀ… | C_b^n]
    jacobian[0, :3] = (0.0, -f_n[2], f_n[1])
    jacobian[1, :3] = (f_n[2], 0.0, -f_n[0])
    jacobian[:, 3:] = c_b_n[:2]
    spread = float(np.sum((jacobian @ p_common[_TILT_AND_ACCEL_BIAS]) * jacobian))  # tr(J P Jᵀ)
    horizontal = float(f_n[0] ** 2 + f_n[1] ** 2)
    noise = KNOWN_SIGMAS**2 * spread
    gain = horizontal / (horizontal + noise) if horizontal > 0.0 else 0.0
    return np.array([gain * f_n[0], gain * f_n[1], f_n[2]])


_TILT_AND_ACCEL_BIAS = np.ix_(np.r_[3:6, 12:15], np.r_[3:6, 12:15])

KNOWN_SIGMAS = 10.0
"""How many σ of its own error a nominal quantity in a Jacobian must exceed to inform the
heading: the horizontal specific force (:func:`observable_force`), the SINS velocity of the
motion constraint's attitude columns (:meth:`fusion.aiding.odometer.Odometer`)."""


class SpecificForceFilter:
    """First-order low-pass of the step-mean specific force ``f^n`` that enters F.

    ``f ← f + Δt/(τ + Δt) (f_step − f)``, starting from the first step; τ = 0 passes the step
    mean through unchanged.
    """

    def __init__(self, time_constant_s: float) -> None:
        self.time_constant_s = time_constant_s
        self._value: NDArray[np.float64] | None = None

    @property
    def holds_force(self) -> bool:
        """Whether a force is held (τ > 0 after the first step): else :meth:`follow` has
        nothing to move."""
        return self._value is not None

    def follow(self, rotation: NDArray[np.float64], shift: NDArray[np.float64]) -> None:
        """Move the force held to a feedback of the nominal state, ``f ← R f + s``.

        A feedback turns the nominal attitude by ``R = C_b^n⁺ (C_b^n)ᵀ`` and moves the nominal
        accelerometer bias by ∇, which changes the nominal force at once by ``s = −C_b^n⁺ ∇``.
        Held unmoved, the memory would keep for τ the horizontal force of a tilt error the
        feedback has removed (g × 1.5° at a coarse start), and ``f^n × φ`` would read the
        heading from a standstill through that force.
        """
        if self._value is not None:
            self._value = rotation @ self._value + shift

    def __call__(self, f_step: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        """The specific force for F after a step of length ``dt`` whose mean was ``f_step``."""
        if self.time_constant_s <= 0.0:
            return f_step
        if self._value is None:
            self._value = f_step.copy()
        else:
            self._value = self._value + dt / (self.time_constant_s + dt) * (f_step - self._value)
        return self._value


def discretize(
    f: NDArray[np.float64],
    q: NDArray[np.float64],
    dt: float,
    method: Literal["series", "van_loan"] = "series",
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Discretize ``ẋ = F x + w``, ``E[w wᵀ] = Q δ(t)`` over ``dt`` (see module docstring)."""
    n = f.shape[0]
    if method == "van_loan":
        m = np.zeros((2 * n, 2 * n))
        m[:n, :n] = -f
        m[:n, n:] = q
        m[n:, n:] = f.T
        e = scipy.linalg.expm(m * dt)
        phi = e[n:, n:].T
        qd = phi @ e[:n, n:]
        return phi, 0.5 * (qd + qd.T)
    fdt = f * dt
    fdt2 = fdt @ fdt
    phi = np.eye(n) + fdt + fdt2 / 2.0 + fdt2 @ fdt / 6.0
    fq = f @ q
    qd = q * dt + 0.5 * (fq + fq.T) * dt**2 + (fq @ f.T) * dt**3 / 3.0
    return phi, qd


def navigation_error(
    estimate: NDArray[np.float64], truth: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Error states ``[δv, φ, δp]`` (9,) of a packed nominal state against a true one.

    Both are packed navigation arrays (:mod:`fusion.strapdown` layout); ``φ`` is taken from
    ``C̃_b^n C_n^b = I − φ×`` exactly (rotation vector), ``δp`` in local metres.
    """
    c_est = dcm_from_quat(estimate[Q0 : Q0 + 4])
    c_true = dcm_from_quat(truth[Q0 : Q0 + 4])
    phi = -Rotation.from_matrix(c_est @ c_true.T).as_rotvec()
    rm, rn = earth.radii(truth[LAT])
    h = truth[HGT]
    dp = np.array(
        [
            (rn + h) * math.cos(truth[LAT]) * (estimate[LON] - truth[LON]),
            (rm + h) * (estimate[LAT] - truth[LAT]),
            estimate[HGT] - truth[HGT],
        ]
    )
    return np.concatenate([estimate[VEL : VEL + 3] - truth[VEL : VEL + 3], phi, dp])
