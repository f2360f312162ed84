"""UWB ranges to surveyed anchors, tightly coupled (seed 004 §2, eqs. 13–25), and the UWB-only
least-squares baseline.

Tightly coupled ranges (:class:`UwbRanges`)
    The tag antenna sits at the lever arm ``ℓ`` (body frame, ``uwb.tag_lever_arm_b_m``); anchor
    ``i`` at ``a_i`` (origin ENU, ``uwb.anchors``). With ``C̃_b^n = (I − φ×) C_b^n``,
    ``p̃ = p + δp`` (local level metres) and ``R_local`` the rotation from the origin's ENU axes
    to the local level axes at the nominal point, the SINS-predicted tag is
    ``p̃_tag = p̃ + R_localᵀ C̃ ℓ`` and the range (eq. 14) ``r̃_i = ‖p̃_tag − a_i‖``. The
    measured range is ``ρ_i = r_i + b_i + v`` (eq. 18, with an optional per-anchor bias ``b_i``).
    With the unit line of sight in local axes ``u = R_local (p̃_tag − a_i) / r̃_i`` and
    ``C̃ ℓ = C ℓ + (C ℓ)× φ``, one scalar measurement per range ::

        z = r̃_i − ρ_i,      H = [0, uᵀ (C̃ℓ)×, uᵀ, 0, 0, …, −1 (b_i), …],      R = σ²

    Seed 004 differences the *squared* ranges (eqs. 15–20) and keeps the quadratic term of
    eq. 22 by evaluating H at the current estimate (eq. 25). Here the range itself is the
    measurement (its noise is the ranging noise, not ``2 r`` times it), and the same
    "linearize at the current estimate" is exact: when the filter's estimate ``x̂`` of the
    SINS errors is not yet fed back (several updates at one epoch, a federated local filter),
    the range is predicted from the corrected state ``p̂ = p̃ − R_localᵀ δp̂``,
    ``Ĉ = exp(φ̂×) C̃``, H is evaluated there, and ``z = r̂_i − ρ_i + H_nav x̂_nav`` so that the
    innovation ``z − H x̂`` is the residual ``r̂_i + b̂_i − ρ_i`` of the corrected state.
    The plugin adds the lever-arm (attitude) columns that seed 004's H (eq. 24) omits.

    Second order. A range curves across its line of sight; where the position σ there is
    metres and the anchor tens of metres away (the tag back at a face end after a pass), the
    predicted range takes the expected lengthening ``½ tr(M P)`` and R the spread
    ``½ tr(M P M P)``, ``M = (I − u uᵀ)/r̃`` (:func:`second_order_range`). Both vanish as the
    filter converges.

    Heading through the lever arm. The heading column ``(u × C̃ℓ)_z`` informs the heading only
    through a turn of the lever arm; a slow machine barely turns, and what the column then
    sees turning is the nominal attitude itself — its feedback corrections and the drift of
    an estimated vertical gyro bias — so that the heading and the vertical gyro bias were
    learned from nothing (docs/design/2026-11-26-unseen-worlds.md, "UWB: mirror solutions").
    Under ``filter.observable_force`` (a slow machine) the heading is therefore a
    consider state of the range update (:attr:`fusion.plugin.Measurement.consider`): its
    uncertainty enters S and, through its correlations, the position's σ, but the update
    does not correct it. A fast platform (``observable_force: false``) keeps the column as
    information.

    One scalar measurement per range (``epochs()`` are the ``uwb.csv`` row times), so that a
    non-line-of-sight (NLOS) range, whose bias is large and positive, is rejected alone by the
    engine's χ² gate (the block's ``gate_probability``) without taking the other anchors with it.

    NLOS test (``nlos_test``, on by default). The gate alone lets an NLOS episode drag the
    filter: NLOS on every anchor of a face end reads every range long, the clustered anchors
    see much of that as one shift of the tag, and the ranges that happen to be lengthened least
    pass the gate at 2–3σ, one after another, each pulling the estimate a little further
    (docs/design/2026-11-29-nlos-test.md). So an anchor's ranges
    are withheld (:attr:`fusion.plugin.Measurement.withheld`: logged and counted as rejected,
    nothing corrected) from the range whose whitened lengthening ``w = (ρ − r̂)/√S`` is at
    least :data:`NLOS_STEP` and as much above the anchor's previous range's, until a one-sided
    CUSUM of ``w`` started at :data:`NLOS_CAP` falls to zero (Page 1954; Basseville &
    Nikiforov, *Detection of Abrupt Changes*, 1993, §2.2). NLOS arrives in one range (a longer
    path), while a filter drifting towards the anchors lengthens its ranges smoothly: the
    step tells them apart, and a drift stays the gate's and the lost lock's to answer. The
    CUSUM holds the anchor out while its ranges keep reading long, even once the filter's σ,
    grown without them, makes single NLOS ranges look like 2σ ones; after the NLOS it takes
    some ``NLOS_CAP / NLOS_DRIFT`` (40) ranges that fit. Once that σ exceeds the smallest NLOS
    bias, the filter's own drift may centre the long ranges, and the CUSUM's end must be
    confirmed by the ranges alone: those of the last second fitting one position with this
    anchor's (:meth:`UwbRanges._contradicted`).

    Anchor exclusion (``anchor_exclusion``, on by default). An anchor surveyed metres from where
    it stands (or moved since) reads wrong for good, long or short, and no step starts it. Its
    ranges fail the gate one by one, and a run of gated ranges is what isolates a federated
    local and what says a filter is lost. So an anchor whose every range has failed the screen
    for :data:`EXCLUSION_RUN_S` is tested with the ranges alone (:meth:`UwbRanges._raim`: the
    fit of all anchors, then each left out) and withheld while it is the one anchor the others'
    fit excludes; it is let back in once its ranges fit with the others' again. Both are
    ``faults.csv`` lines (``exclude anchor``, ``include anchor``).

    Epoch grid (``epoch_grid_s``): a range system polls its anchors a few milliseconds apart
    (five anchors at 3.1 ms in ``longwall-200m``), and one epoch per range means one covariance
    step, one fusion and one SINS correction per range. On a grid, range k (time t_k) is taken
    at the first grid time t ≥ t_k, still as its own scalar update, with the tag moved back
    along the SINS velocity: ``p̃(t_k) = p̃(t) − ṽ (t − t_k)``, so H gains the velocity columns
    ``−(t − t_k) uᵀ`` (first order in the acceleration over t − t_k: 0.1 m/s² over 0.1 s moves
    the tag 0.5 mm). With a 0.1-s grid ``full_afkf`` runs 2.2× faster on ``longwall-200m``
    (200 s: 10.1 s against 21.9 s) at the same horizontal RMS (0.0216 against 0.0215 m).

    ``max_range_m``: a range whose predicted tag–anchor distance ``r̃_i`` *and* measured range
    both exceed it produces nothing (outside the anchor's working range; seed 004 §1 uses the
    anchors within ~10 m). None (the default, and every shipped filter): a range the tag
    reports is a measurement however long, and the gate and the second-order terms answer for
    it; a cut leaves the middle of a long face without ranges, and the filter then meets the
    next face end's clustered anchors off across the face at a small σ
    (docs/design/2026-11-29-uwb-reach.md). An NLOS-inflated reading of a near anchor still
    reaches the gate and is counted there, and so does a near anchor's reading when the SINS
    has drifted far: its rejections tell the engine that the lock is lost (:mod:`fusion.lock`), and
    :meth:`UwbRanges.reacquire` puts the filter back at a least-squares fix of the last
    ranges — never at one of two mirror solutions (see "Mirror solutions" below) that neither
    the face nor the SINS's own covariance tells apart: the shearer is on its face, so a
    solution farther than ``face_margin_m`` beyond a surveyed face end (meta.yaml
    ``face.ends_enu_m``) is the mirror image. A filter put on the mirror image of a row of
    anchors across the face end follows it with centimetres of σ while the tag moves the
    other way (random world 6 at its own length: 21 m off within 12 m of an anchor). Far from
    anchors clustered at one face end the ranges tell the height poorly, and the fit takes the face
    line's height (``face_height_sigma_m``) as one more row; its weakest axis is widened to the
    profile of its cost (:func:`_profiled_covariance`). The engine also asks for a fix when every
    range of one anchor has read short of the filter's distance for :data:`SHORT_RANGE_WINDOW_S`
    (:meth:`UwbRanges.off_solution`): NLOS lengthens ranges, only a wrong position shortens them.

    Range bias (``range_bias: true``): one state per anchor, block ``<name>.range_bias``, the
    bias ``b_i`` itself (m, never fed back), prior σ ``range_bias_sigma_m``; a first-order
    Gauss–Markov process of correlation time τ whose steady σ is the prior
    (``q = 2σ²/τ``) or, without τ, a random walk of ``range_bias_random_walk_m_rts`` (0: a
    random constant, e.g. an antenna delay).

    Adaptive noise (``adaptive_noise: variational_bayes``): the variational-Bayes step of the
    VB-UKF that seed 004 cites (ref. 28; Särkkä & Nummenmaa, IEEE TAC 54(3), 2009) with an
    inverse-gamma ``R_i ~ IG(α_i, β_i)`` per anchor, applied to the scalar range update.
    Between two ranges of the anchor, Δt apart, the statistics are forgotten with
    ``ρ = exp(−Δt/τ)`` (``τ = adaptive_window_s``): ``α⁻ = ρα``, ``β⁻ = ρβ``; when less than one
    range's weight is left (α⁻ < ½: the anchor was out of sight for several τ) the statistics
    restart from the prior, so an anchor met again after an hour starts from the datasheet R
    instead of 0/0 (the 8-hour shift reaches that underflow). At a range
    with prior innovation ``ν = z − H x̂`` and ``s = H P Hᵀ`` the fixed point ::

        R ← β/α,   α = α⁻ + ½,   β = β⁻ + ½ ν² R²/(s + R)² + ½ s R/(s + R)

    (the posterior residual and the posterior variance of ``H x`` of the scalar Kalman update
    with this R) is iterated three times and the resulting R is the one returned. The prior
    ``β₀/α₀ = sigma_range_m²`` weighs as much as one window of ranges (``α₀ = ½ n`` with ``n = τ
    · uwb.rate_hz / anchors``, the steady-state weight of one anchor's ranges). VB is used
    rather than a sliding-window innovation estimate because it needs no stored window, its
    weight decays smoothly with time (dropouts and rate changes are handled by Δt), and it stays
    positive by construction (a window estimate ``mean(ν²) − H P Hᵀ`` can go negative). An
    adaptive R cannot tell a larger noise from an NLOS bias, so an innovation whose NIS under
    the prior ``R = β⁻/α⁻`` exceeds the χ² quantile ``adaptive_screen_probability`` does not
    teach R (it is returned with the prior R, for the engine's gate to reject); set it equal to
    the block's ``gate_probability`` so that the plugin learns exactly from the ranges the
    engine accepts. The plugin keeps these statistics between calls, so one instance serves one
    filter run with its epochs in time order.

UWB-only least squares (:func:`least_squares_solution`)
    The baseline of seed 004's "UWB-only" solution. The ranges are grouped in consecutive
    windows of ``window_s`` (default 0.25 s, ten rounds of four anchors at 40 Hz); in a window
    the tag is taken at rest at its position ``p`` at the mean range time and Gauss–Newton
    minimizes ::

        Σ_k (ρ_k − ‖p − a_k‖)² / σ²      (+ (p_u − u_ref)² / σ_h²)

    from the prediction of the previous fixes (the first from meta.yaml's initial state). For
    a steady motion the fit refers to the mean time, except that the anchors are ranged at
    staggered times within a round: at 4 m/min and 40 Hz rounds their ranges refer to points
    ≤ 1.3 mm apart along the track, a few millimetres after the geometry's amplification —
    far below the ranging noise (estimating a velocity per window instead is hopeless far
    from the anchors: over 0.25 s its σ reaches metres per second). The covariance of ``p``
    is ``(JᵀR⁻¹J)⁻¹`` at the solution, at the learned σ below; the velocity is the slope of
    a line through the fixes within ``±velocity_span_s/2``.

    Mirror solutions: ranges to three anchors, or to more that lie nearly in one plane (a
    row along a roadway, anchors at one height on the roof), fit a point and its mirror image
    across that plane about equally well. Anchors at nearly one height determine the tag
    height poorly far from them (seed 004 §3.2 reports its larger z error for that reason)
    and put a mirror above a tag below them; a row of anchors in plan puts one beside it.
    Each window is solved from the prediction (the weighted line through the last
    ``velocity_span_s`` of fixes, extrapolated), from its mirror image and from the first
    solution's mirror image (:func:`_window_fix`); of the solutions that fit within the gate,
    the one nearest the prediction is kept. Continuity rules the other out when it is more
    than 3σ of the prediction (its scatter, plus ``max_speed_mps`` times the time without a
    fix) farther away; otherwise the kept one's covariance is widened by half the squared
    offset to the other, and once the two are separated by more than 3σ of the fit itself
    without continuity telling them apart, the branch counts as unknown and every later fix
    is widened likewise until a window's χ² rules its mirror out (a fourth anchor off the
    plane). From a start near the plane a fix may therefore sit on the mirror, metres off,
    with a σ that says so.

    Noise and outliers: ranges are gated at the block's ``gate_probability`` (χ²(1)) first
    against the prediction's ranges (variance σ² plus the prediction's), as long as
    ``min_anchors`` anchors pass — a non-line-of-sight (NLOS) range pulls a fit of four
    anchors towards it and hides among their residuals — then by the fit's own residuals,
    the largest dropped and the window solved again while it exceeds the gate. NLOS on every
    anchor at once reads every range long, and four anchors clustered at a face end fit that
    with small residuals metres away; such a fix is also farther from the prediction than
    the tag can have moved (the fix's covariance plus the prediction's, at the χ²(3)
    quantile of ``gate_probability``) and gives no fix (:func:`_reachable`). Every range
    is logged with its squared standardized residual and the verdict. The ranging σ is
    learned from the accepted residuals (:class:`_ResidualNoise`, forgetting time
    ``noise_window_s``, never below ``sigma_range_m``), and the covariance is
    ``(JᵀJ)⁻¹ σ²`` at that σ: per-anchor noise that differs by 2× and a tag moving within
    the window both show in the residuals.

    Optionally (``height_sigma_m``) a height constraint — the tag height of meta.yaml's
    initial state with that σ — is one more row: for a machine known to stay near one
    height. It is applied only when configured, never silently.

    A window with fewer than ``min_anchors`` distinct anchors, a singular normal matrix or no
    convergence gives no fix. The IMU point is the tag minus ``R_localᵀ C ℓ`` with the
    attitude of meta.yaml's initial state (UWB does not observe attitude; the solution
    carries that attitude, constant).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from fusion.attitude import dcm_from_euler, dcm_from_quat, quat_from_rotvec
from fusion.earth import LocalFrame
from fusion.error_model import ATTITUDE, POSITION, VELOCITY, StateBlock
from fusion.face import FaceLine
from fusion.innovations import InnovationLog
from fusion.kalman import chi2_threshold
from fusion.lock import Reacquisition
from fusion.plugin import (
    Measurement,
    MeasurementContext,
    MissingStream,
    Plugin,
    PluginError,
    PluginOptions,
)
from fusion.recording import Recording, UwbData, UwbMeta
from fusion.solution import Solution

VB_ITERATIONS = 3
"""Fixed-point iterations of the variational-Bayes noise update (converges in 2–3)."""
REACQUIRE_WINDOW_S = 1.0
"""Ranges fitted together when the filter has lost lock (:meth:`UwbRanges.reacquire`)."""
SHORT_RANGE_WINDOW_S = 3.0
"""How long every range of one anchor must read shorter than the filter's distance beyond the
gate before the filter is taken to be on a wrong solution (:meth:`UwbRanges.off_solution`)."""
REACQUIRE_SPREAD_M = 0.1
"""1σ per axis of the tag's travel over that window, and of the lever arm's turn."""
EXCLUSION_RUN_S = 1.0
"""How long every range of one anchor must fail the screen before the ranges of the last
:data:`REACQUIRE_WINDOW_S` are tested for a faulty anchor (:meth:`UwbRanges._anchor_test`),
and how often an excluded anchor is tested again."""
EXCLUDE, INCLUDE = "exclude anchor", "include anchor"
"""``faults.csv`` actions of an anchor taken out of the updates and let back in."""
NLOS_STEP = 6.0
"""A range that reads this many σ (of its innovation) longer than the anchor's previous one did,
and at least this long itself, starts the anchor's NLOS: a bias of 0.3 m and more arrives in
one range, a filter's drift moves the innovation by millimetres between two ranges."""
NLOS_STEP_GAP_S = 1.0
"""The anchor's previous range counts for the step only this recently (otherwise a lengthening
of 0 is taken: a range met after a gap that reads ``NLOS_STEP`` σ long starts NLOS as well)."""
NLOS_SMALLEST_BIAS_M = 0.3
"""The smallest NLOS bias the test is for (m): a blocked line of sight lengthens a range by
decimetres to metres."""
NLOS_DRIFT = 0.5
"""Least reference value k (σ) of the CUSUM that ends an anchor's NLOS; k is half the smallest
bias, ``NLOS_SMALLEST_BIAS_M / 2`` in metres, where that is more σ (Page's k = δ/2)."""
NLOS_CAP = 20.0
"""Where that CUSUM starts (σ): it falls to zero, and the NLOS ends, after some ``NLOS_CAP / k``
(40) ranges that fit, fewer if they read short; ranges that keep reading long hold it up."""


class LeastSquaresOptions(BaseModel):
    """Options of the UWB-only least-squares baseline (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")

    sigma_range_m: float = Field(0.05, gt=0, description="ranging noise 1σ")
    window_s: float = Field(0.25, gt=0, description="ranges fitted together per fix")
    max_range_m: float | None = Field(None, gt=0, description="longer ranges are not used")
    min_anchors: int = Field(3, ge=3, description="distinct anchors needed in a window")
    height_sigma_m: float | None = Field(
        None, gt=0, description="σ of the optional height constraint (None: none)"
    )
    velocity_span_s: float = Field(
        2.0, gt=0, description="fixes regressed for the velocity and for the next fix's guess"
    )
    max_speed_mps: float = Field(
        1.0,
        gt=0,
        description="fastest tag motion between two fixes: how far continuity may move the"
        " guess that picks one of two mirror solutions (a shearer's haulage ≤ 30–40 m/min)",
    )
    max_iterations: int = Field(20, ge=1, description="Gauss–Newton iterations per window")
    tolerance_m: float = Field(1e-4, gt=0, description="Gauss–Newton convergence step")
    noise_window_s: float | None = Field(
        30.0,
        gt=0,
        description="forgetting time of the ranging noise learned from the fits' residuals"
        " (never below sigma_range_m; None: sigma_range_m throughout)",
    )


class UwbOptions(PluginOptions):
    """Options of the tightly coupled UWB range plugin."""

    sigma_range_m: float = Field(
        0.05, gt=0, description="ranging noise 1σ (seed 004 §3.2: 2–5 cm underground)"
    )
    max_range_m: float | None = Field(
        None, gt=0, description="anchors predicted farther than this produce nothing"
    )
    epoch_grid_s: float | None = Field(
        None,
        gt=0,
        description="process each range at the first time of this grid at or after it, the tag"
        " taken back along the SINS velocity to the range time (None: at its own time)",
    )
    range_bias: bool = Field(False, description="one bias state per anchor")
    range_bias_sigma_m: float = Field(0.1, gt=0, description="prior σ of each range bias")
    range_bias_correlation_time_s: float | None = Field(
        None, gt=0, description="Gauss–Markov τ (steady σ = prior σ); None: random walk"
    )
    range_bias_random_walk_m_rts: float = Field(
        0.0, ge=0, description="random-walk density (m/√s) when no correlation time is given"
    )
    adaptive_noise: Literal["off", "variational_bayes"] = "off"
    adaptive_window_s: float = Field(3.0, gt=0, description="VB forgetting time constant τ")
    adaptive_screen_probability: float = Field(
        0.999, gt=0, lt=1, description="χ² quantile beyond which a range does not teach R"
    )
    nlos_test: bool = Field(
        True,
        description="withhold an anchor's ranges from a step to reading long until they fit"
        " again (NLOS; module docstring)",
    )
    anchor_exclusion: bool = Field(
        True,
        description="withhold an anchor whose ranges fail the gate while the other anchors'"
        " ranges fit one position without them, until they fit together again (module"
        " docstring)",
    )
    least_squares: LeastSquaresOptions = Field(
        default_factory=LeastSquaresOptions,
        description="the UWB-only baseline (filter.architecture: standalone)",
    )
    face_margin_m: float | None = Field(
        10.0,
        ge=0,
        description="how far beyond a surveyed face end (meta.yaml face.ends_enu_m) the tag can"
        " be along the face — overrun, lever arm, a face end not square to the face; a"
        " re-acquisition fix farther out is a mirror image, not the tag (None: not used)",
    )
    face_height_sigma_m: float | None = Field(
        3.0,
        gt=0,
        description="1σ of the IMU's height about the straight line between the surveyed face"
        " ends (meta.yaml face.ends_enu_m): the seam's rolls between them and its dip over the"
        " recording's advance; a re-acquisition fix takes it as one more row, since ranges to"
        " anchors clustered at a face end tell the height poorly from tens of metres away"
        " (None: not used)",
    )

    @model_validator(mode="after")
    def _one_bias_process(self) -> UwbOptions:
        if self.range_bias_correlation_time_s is not None and self.range_bias_random_walk_m_rts:
            raise ValueError(
                "range_bias_correlation_time_s and range_bias_random_walk_m_rts are exclusive:"
                " a Gauss–Markov bias takes its noise from its prior σ and τ"
            )
        return self


def _uwb_stream(recording: Recording, who: str) -> tuple[UwbData, UwbMeta]:
    """The recording's ranges and their meta section, or a clear error."""
    if recording.uwb is None or recording.meta.uwb is None:
        raise MissingStream(
            f"{who} needs uwb.csv and the uwb section of meta.yaml in the recording"
        )
    return recording.uwb, recording.meta.uwb


class UwbRanges(Plugin):
    """Ranges to surveyed UWB anchors, one scalar update per range (see the module docstring)."""

    Options = UwbOptions
    options: UwbOptions

    def __init__(self, name: str, options: UwbOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        self.data, meta = _uwb_stream(recording, f"plugin {name!r}")
        self.anchors = np.array([meta.anchors[a] for a in self.data.anchor_ids], dtype=float)
        self.lever_arm = np.array(meta.tag_lever_arm_b_m, dtype=float)
        self.bias_block = f"{name}.range_bias"
        n = len(self.data.anchor_ids)
        self.adaptive = options.adaptive_noise == "variational_bayes"
        # Inverse-gamma statistics per anchor; the prior weighs one window of the anchor's
        # ranges (uwb.rate_hz is the nominal rate of all anchors together).
        self._alpha0 = 0.5 * max(meta.rate_hz / n * options.adaptive_window_s, 1.0)
        self._beta0 = self._alpha0 * options.sigma_range_m**2
        self._screen = chi2_threshold(1, options.adaptive_screen_probability)
        self.face = FaceLine.from_meta(recording.meta.face)
        self.start_run()

    def start_run(self) -> None:
        """Start every anchor's noise statistics from the prior."""
        n = len(self.data.anchor_ids)
        self.alpha = np.full(n, self._alpha0)
        self.beta = np.full(n, self._beta0)
        self.t_last = np.full(n, np.nan)
        self.short_since = np.full(n, np.nan)
        self.lengthening = np.zeros(n)
        self.t_lengthening = np.full(n, -np.inf)
        self.reads_long = np.zeros(n)
        self.excluded = np.zeros(n, dtype=bool)
        self.failing_since = np.full(n, np.nan)
        self.next_test = np.full(n, -np.inf)

    def standalone_solution(self, gate_probability: float | None, log: InnovationLog) -> Solution:
        """The UWB-only least-squares baseline with ``options.least_squares``."""
        return least_squares_solution(
            self.recording, self.options.least_squares, gate_probability, log
        )

    def state_blocks(self) -> tuple[StateBlock, ...]:
        """One range bias per anchor when ``range_bias`` is on."""
        if not self.options.range_bias:
            return ()
        o = self.options
        n = len(self.data.anchor_ids)
        tau = o.range_bias_correlation_time_s
        density = 2.0 * o.range_bias_sigma_m**2 / tau if tau else o.range_bias_random_walk_m_rts**2
        return (
            StateBlock(
                self.bias_block,
                tuple(self.data.anchor_ids),
                (o.range_bias_sigma_m,) * n,
                (density,) * n,
                tau,
                unit="m",
            ),
        )

    def epochs(self) -> NDArray[np.float64]:
        """One epoch per ``uwb.csv`` row: its time, or the first ``epoch_grid_s`` grid time at
        or after it (the ranges of one round then share an epoch)."""
        grid = self.options.epoch_grid_s
        if grid is None:
            return self.data.t
        return np.ceil(self.data.t / grid - 1e-9) * grid

    def reacquire(self, t: float, ctx: MeasurementContext) -> Reacquisition | None:
        """The IMU's position and velocity at ``t`` from the last ranges alone, or None.

        Two least-squares fixes (:func:`_gauss_newton`, the tag taken at rest over each) of the
        ranges in the two halves of the last ``2 ×`` :data:`REACQUIRE_WINDOW_S`, each from at
        least three anchors: the position is the later one, the velocity their difference over
        their spacing. A fit starts from the SINS position pulled to within the anchors' reach
        (:meth:`_fix`: None while the ranges cannot tell the tag from its mirror image).
        The position covariance adds the tag's travel over a window and the lever arm's turn
        with an attitude that coasted too (:data:`REACQUIRE_SPREAD_M` per axis each).
        """
        window = REACQUIRE_WINDOW_S
        arm_enu = ctx.rotation_to_local.T @ ctx.c_b_n @ self.lever_arm
        prior = _tag_prior(ctx.position_enu + arm_enu, ctx)
        earlier = self._fix(t - 2 * window, t - window, prior, float(arm_enu[2]))
        later = self._fix(t - window, t, prior, float(arm_enu[2]))
        if earlier is None or later is None:
            return None
        (p0, c0), (p1, c1) = earlier, later
        spread = 2 * REACQUIRE_SPREAD_M**2 * np.eye(3)
        self.t_lengthening[:] = -np.inf  # the filter restarts at the fix: old residuals are moot
        self.reads_long[:] = 0.0
        return Reacquisition(
            p1 - arm_enu, c1 + spread, (p1 - p0) / window, (c0 + c1 + 2 * spread) / window**2
        )

    def beyond_linearization(self, index: int, ctx: MeasurementContext) -> bool:
        """The filter's horizontal position σ exceeds a tenth of the distance to the anchor of
        range ``index`` (and a metre): the line of sight is then uncertain by more than 6°, and
        a linearized range update would claim centimetres where the truth is metres away (a
        SINS back among the anchors after 120 s of outage: 16 m off at a σ of 0.3 m)."""
        pos = ctx.layout.slice(POSITION)
        sigma = math.sqrt(float(ctx.covariance[pos, pos][0, 0] + ctx.covariance[pos, pos][1, 1]))
        anchor = self.anchors[int(self.data.anchor_index[index])]
        return sigma > max(1.0, 0.1 * float(np.linalg.norm(ctx.position_enu - anchor)))

    def off_solution(self, index: int) -> bool:
        """Every range of this anchor for :data:`SHORT_RANGE_WINDOW_S` read shorter than its
        distance from the filter by more than the gate (:meth:`measure` keeps the count).

        No NLOS shortens a range; a filter that fits two anchors of a face end on the circle
        about them does that to the third (random world 0 at its own length: 2.6 m off at a σ
        of 6 cm, the third anchor's ranges 2.8 m short and rejected one by one). Each
        re-acquisition attempt starts the count again. The engine restarts the position only
        (``Engine._reacquire``)."""
        k = int(self.data.anchor_index[index])
        since = self.short_since[k]
        if np.isfinite(since) and float(self.data.t[index]) - since >= SHORT_RANGE_WINDOW_S:
            self.short_since[:] = np.nan
            return True
        return False

    def _fix(
        self,
        t0: float,
        t1: float,
        prior: tuple[NDArray[np.float64], NDArray[np.float64]],
        arm_up: float,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """Least-squares tag position and covariance from the ranges in (t0, t1] that agree
        with each other (:meth:`_raim`), or None."""
        found = self._raim(t0, t1, prior, arm_up)
        return None if found is None else found[0][:2]

    def _raim(
        self,
        t0: float,
        t1: float,
        prior: tuple[NDArray[np.float64], NDArray[np.float64]],
        arm_up: float,
    ) -> tuple[tuple[NDArray[np.float64], NDArray[np.float64], float, int], int | None] | None:
        """The window fit (:meth:`_window_fit`) of the ranges in (t0, t1] that agree with each
        other, and the anchor left out of it (None: none), or None.

        A fit is taken only if its ranges fit it (:meth:`_consistent`). Otherwise, or when they
        give none (Gauss–Newton does not settle on ranges that contradict each other), each
        anchor is left out in turn (receiver autonomous integrity monitoring: the
        sum-of-squares test and exclusion of Parkinson & Axelrad, *Navigation* 35(2), 1988):
        the fit of the others is taken if it is the one subset that fits. None fitting, or more
        than one (a bad anchor absorbed by three anchors and the face's height), none is given:
        an anchor surveyed metres from where it stands must not restart a filter that is right
        (docs/design/2026-11-30-unusual-recordings.md).
        """
        index, ranges = self._window(t0, t1)
        fit = self._window_fit(index, ranges, prior, arm_up)
        if fit is not None and self._consistent(fit):
            return fit, None
        fits = []
        for k in np.unique(index):
            kept = index != k
            subset = self._window_fit(index[kept], ranges[kept], prior, arm_up)
            if subset is not None and self._consistent(subset):
                fits.append((subset, int(k)))
        return fits[0] if len(fits) == 1 else None

    def _window(self, t0: float, t1: float) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """The anchor indices and ranges of the rows in (t0, t1]."""
        lo = int(np.searchsorted(self.data.t, t0, side="right"))
        hi = int(np.searchsorted(self.data.t, t1, side="right"))
        return self.data.anchor_index[lo:hi], self.data.range[lo:hi]

    def _anchor_test(
        self,
        index: int,
        nis: float,
        prior: Callable[[], tuple[tuple[NDArray[np.float64], NDArray[np.float64]], float]],
    ) -> tuple[str, str] | None:
        """Take anchor k of range ``index`` out of the updates, or let it back in; the
        ``faults.csv`` line (action, reason) when it does either.

        An anchor whose every range has failed the screen (``nis``, the range's normalized
        innovation squared, above the ``adaptive_screen_probability`` quantile) for
        :data:`EXCLUSION_RUN_S` is tested with the ranges of all anchors over the last
        :data:`REACQUIRE_WINDOW_S`, the filter left out but for the start of the fit
        (:meth:`_raim`; ``prior()``: the tag's prior and its height above the IMU, computed
        only for a test): it is excluded when
        it is the one anchor whose removal makes them fit. An anchor surveyed metres from where
        it stands, or moved since, then costs its own ranges only: gated one by one, they
        isolated the federated filter's whole UWB local (window χ² 998 against 462) and kept
        it out, and, reading short of a right filter, restarted it every 3 s
        (:meth:`off_solution`). A filter that drifted fails the ranges of every anchor that
        looks along its error; the ranges alone then fit, and nothing is excluded. An excluded
        anchor is let back in once its ranges fit together with the others' again (all of
        them, or all but another anchor's), tested every :data:`EXCLUSION_RUN_S`.
        """
        if not self.options.anchor_exclusion:
            return None
        k = int(self.data.anchor_index[index])
        t = float(self.data.t[index])
        anchor = self.data.anchor_ids[k]
        if self.excluded[k]:
            if t < self.next_test[k]:
                return None
            self.next_test[k] = t + EXCLUSION_RUN_S
            found = self._raim(t - REACQUIRE_WINDOW_S, t, *prior())
            if found is None or found[1] == k:
                return None
            self.excluded[k] = False
            return INCLUDE, f"anchor {anchor}: its ranges fit one position with the others' again"
        since = _run_start(self.failing_since, k, t, nis > self._screen)
        if not t - since >= EXCLUSION_RUN_S:  # NaN: the range passed the screen
            return None
        self.failing_since[k] = t  # the next test after another run
        found = self._raim(t - REACQUIRE_WINDOW_S, t, *prior())
        if found is None or found[1] != k:
            return None
        self.excluded[k] = True
        self.next_test[k] = t + EXCLUSION_RUN_S
        self.short_since[k] = np.nan  # its short ranges no longer say the filter is off
        _, _, cost, dof = found[0]
        return EXCLUDE, (
            f"anchor {anchor}: its ranges failed the gate for {EXCLUSION_RUN_S:g} s, and the"
            f" ranges of the other anchors alone fit one position (χ² {cost:.3g} of {dof}"
            " degrees of freedom) while all together do not"
        )

    def _consistent(self, fit: tuple[NDArray[np.float64], NDArray[np.float64], float, int]) -> bool:
        """Whether a window fit's ranges fit it: its χ² (:func:`_chi2` at the anchors' noise)
        within the ``adaptive_screen_probability`` quantile of its degrees of freedom, the tag's
        travel over the window (:data:`REACQUIRE_SPREAD_M`) counted as range noise."""
        _, _, cost, dof = fit
        sigma = float(np.max(self.noise_sigma()))
        scale = sigma**2 / (sigma**2 + REACQUIRE_SPREAD_M**2)
        return dof <= 0 or cost * scale <= chi2_threshold(
            dof, self.options.adaptive_screen_probability
        )

    def _window_fit(
        self,
        index: NDArray[np.int64],
        ranges: NDArray[np.float64],
        prior: tuple[NDArray[np.float64], NDArray[np.float64]],
        arm_up: float,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], float, int] | None:
        """Least-squares tag position and covariance of ``ranges`` to anchors ``index``, its χ²
        and degrees of freedom, or None when they give none or cannot tell it from its mirror
        image.

        ``prior`` is the SINS's tag position and its covariance (origin ENU), ``arm_up`` the
        tag's height above the IMU. With surveyed face ends the fit has one more row, the tag
        at the face line's height plus ``arm_up`` within ``face_height_sigma_m``
        (:meth:`_face_height`): 40 m from three anchors clustered within 9 m, a fix 15 m off
        in height claimed a σ of 1.6 m there, and the filter restarted on it stayed 5 m off
        at a σ of 6 cm (random world 19 at its own length). Of the solutions
        that fit (three anchors, or more nearly in one plane, fit a point and its mirror image
        about equally well), those beyond ``face_margin_m`` of the surveyed face ends are
        dropped — the shearer is on its face —, and of the rest the one nearest the prior in
        its metric is kept, if the prior makes any other at least ``margin`` (χ²) less likely;
        otherwise the fix is ambiguous and none is given: a filter put on the mirror image
        then follows it, with centimetre σ, while the tag moves the other way.
        """
        if np.unique(index).size < 3:
            return None
        anchors = self.anchors[index]
        guess, guess_covariance = prior
        found, height = self._solutions(anchors, ranges, guess, arm_up)
        if not found:
            return None
        sigma, options = self._fit_noise()
        margin = chi2_threshold(1, self.options.adaptive_screen_probability)
        candidates = _plausible(found, margin, guess)
        best, covariance, cost = candidates[0]
        covariance = _profiled_covariance(best, covariance, cost, anchors, ranges, height, options)
        candidates[0] = (best, covariance, cost)
        mirror = _fitting_mirror(best, cost, anchors, ranges, height, sigma, margin)
        if mirror is not None:
            candidates.append((mirror, covariance, cost))
        margin_m = self.options.face_margin_m
        if self.face is not None and margin_m is not None:
            candidates = [c for c in candidates if self.face.reaches(c[0], margin_m)]
        if not candidates:
            return None
        metric = np.linalg.inv(guess_covariance + covariance)
        distance2 = [float((c[0] - guess) @ metric @ (c[0] - guess)) for c in candidates]
        kept = int(np.argmin(distance2))
        for k, (position, _, _) in enumerate(candidates):
            distinct = _beyond_fit(position - candidates[kept][0], covariance)
            if distinct and distance2[k] - distance2[kept] <= margin:
                return None
        position, covariance, cost = candidates[kept]
        return position, covariance, cost, ranges.size + (height is not None) - 3

    def _fit_noise(self) -> tuple[float, LeastSquaresOptions]:
        """The window fits' range σ (the largest of the anchors' noise, learned or fixed) and
        the least-squares options at it."""
        sigma = float(np.max(self.noise_sigma()))
        return sigma, self.options.least_squares.model_copy(update={"sigma_range_m": sigma})

    def _solutions(
        self,
        anchors: NDArray[np.float64],
        ranges: NDArray[np.float64],
        guess: NDArray[np.float64],
        arm_up: float,
    ) -> tuple[list[_Candidate], tuple[float, float] | None]:
        """The Gauss–Newton solutions of ``ranges`` to ``anchors`` (:func:`_solutions`), started
        from ``guess`` pulled to within the ranges' reach of the anchors' centre, and the face
        height row they were solved with (:meth:`_face_height`, at the first solution)."""
        centre = anchors.mean(axis=0)
        reach = float(np.max(ranges))
        offset = guess - centre
        start = centre + offset * min(1.0, reach / max(float(np.linalg.norm(offset)), 1e-9))
        sigma, options = self._fit_noise()
        height = self._face_height(start, arm_up)
        found = _solutions(anchors, ranges, start, height, options, sigma)
        if found and height is not None:  # the face's height where the fit put the tag
            height = self._face_height(found[0][0], arm_up)
            found = _solutions(anchors, ranges, found[0][0], height, options, sigma)
        return found, height

    def _face_height(self, tag: NDArray[np.float64], arm_up: float) -> tuple[float, float] | None:
        """The height row of a fix of a tag near ``tag``: the face line's height there plus
        the tag's ``arm_up`` above the IMU, and ``face_height_sigma_m``; None without
        surveyed face ends or with the option off."""
        sigma = self.options.face_height_sigma_m
        if self.face is None or sigma is None:
            return None
        return self.face.height(tag) + arm_up, sigma

    def noise_sigma(self) -> NDArray[np.float64]:
        """Current range-noise σ per anchor (m): the configured one, or the learned one."""
        return np.sqrt(self.beta / self.alpha)

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        """Residual of the expected range against row ``index``, linearized at the estimate,
        with the range's second-order terms in z and R."""
        k = int(self.data.anchor_index[index])
        layout = ctx.layout
        att, pos, vel = layout.slice(ATTITUDE), layout.slice(POSITION), layout.slice(VELOCITY)
        rot = ctx.rotation_to_local  # origin ENU → local ENU
        x_att, x_pos, x_vel = ctx.x[att], ctx.x[pos], ctx.x[vel]
        position, velocity = ctx.position_enu, ctx.velocity
        c_b_n = ctx.c_b_n
        corrected = bool(np.any(x_att) or np.any(x_pos) or np.any(x_vel))
        if corrected:  # linearize at the estimate: the SINS state corrected by x̂
            position = position - rot.T @ x_pos
            velocity = velocity - x_vel
            c_b_n = dcm_from_quat(quat_from_rotvec(x_att)) @ c_b_n
        arm_n = c_b_n @ self.lever_arm
        back = ctx.t - float(self.data.t[index])  # > 0 on an epoch grid: the range came earlier
        line = rot @ (position - self.anchors[k]) - back * velocity + arm_n
        predicted = math.sqrt(float(line @ line))
        reach = self.options.max_range_m
        if reach is not None and min(predicted, float(self.data.range[index])) > reach:
            return None
        u = line / predicted
        h = np.zeros(layout.dim)
        h[att] = (  # uᵀ (C̃ℓ)× φ = (u × C̃ℓ) · φ
            u[1] * arm_n[2] - u[2] * arm_n[1],
            u[2] * arm_n[0] - u[0] * arm_n[2],
            u[0] * arm_n[1] - u[1] * arm_n[0],
        )
        h[pos] = u
        h[vel] = -back * u
        bias, spread = second_order_range(u, predicted, ctx.covariance[pos, pos])
        z = predicted + bias - float(self.data.range[index])
        if corrected:
            z += float(h[att] @ x_att + h[pos] @ x_pos + h[vel] @ x_vel)
        if self.options.range_bias:
            h[layout.slice(self.bias_block).start + k] = -1.0
        innovation = z - float(h @ ctx.x)  # against the corrected estimate, as the gate sees it
        predicted = float(h @ ctx.covariance @ h) + spread
        # A slow machine: the lever arm's heading column is the consider state (docstring).
        consider = (att.start + 2,) if ctx.observable_force else ()
        current = self._noise(k)

        def prior() -> tuple[tuple[NDArray[np.float64], NDArray[np.float64]], float]:
            tag = position + rot.T @ arm_n
            return _tag_prior(tag, ctx), float(tag[2] - position[2])

        nis = innovation * innovation / (predicted + current)
        fault = self._anchor_test(index, nis, prior)
        if self.excluded[k] or self._in_nlos(index, k, innovation, predicted + current, prior):
            variance = current + spread
            return Measurement(
                np.array([z]),
                h[None, :],
                np.array([[variance]]),
                withheld=True,
                consider=consider,
                fault=fault,
            )
        noise = self._variance(index, k, innovation, predicted)
        self._count_short(index, k, innovation, predicted + noise)
        variance = noise + spread
        return Measurement(
            np.array([z]), h[None, :], np.array([[variance]]), consider=consider, fault=fault
        )

    def _noise(self, k: int) -> float:
        """Anchor ``k``'s current ranging variance (configured or learned), as it stands."""
        if not self.adaptive:
            return self.options.sigma_range_m**2
        return float(self.beta[k] / self.alpha[k])

    def _in_nlos(
        self,
        index: int,
        k: int,
        innovation: float,
        s: float,
        prior: Callable[[], tuple[tuple[NDArray[np.float64], NDArray[np.float64]], float]],
    ) -> bool:
        """Whether range ``index`` of anchor ``k`` (innovation ``r̂ − ρ``, variance ``s``) is
        withheld as NLOS. Its whitened lengthening ``w = (ρ − r̂)/√s`` starts the anchor's NLOS
        by a step of :data:`NLOS_STEP` over the anchor's previous range; Page's one-sided
        CUSUM ``g ← min(cap, max(0, g + w − k))``, started at the cap, then ends it at zero
        (:data:`NLOS_CAP`). A step, because a drifting filter moves the innovation smoothly; a
        CUSUM, because the filter's σ grows while the anchor is withheld, and single NLOS ranges
        then read long by only a few σ. Its reference k is half the smallest NLOS bias,
        ``max(NLOS_DRIFT, NLOS_SMALLEST_BIAS_M / (2√s))``: a filter a few centimetres off
        lengthens every range by a σ or two where σ is centimetres, and with k fixed at half a
        σ its anchors never left NLOS (docs/design/2026-11-30-skids-taken-in.md).

        Where √s exceeds the smallest NLOS bias, the CUSUM's zero is no evidence: the filter's
        own drift, not the range, sets the sign of ``w``. The NLOS then ends only if the ranges
        of the last :data:`REACQUIRE_WINDOW_S` do not contradict each other about this anchor
        (:meth:`_contradicted`); otherwise the CUSUM starts again at the cap
        (docs/design/2026-11-29-nlos-test.md, "an NLOS episode ended by the filter's drift")."""
        if not self.options.nlos_test:
            return False
        t = float(self.data.t[index])
        root = math.sqrt(s)
        w = -innovation / root
        recent = t - self.t_lengthening[k] <= NLOS_STEP_GAP_S
        step = w - (float(self.lengthening[k]) if recent else 0.0)
        self.lengthening[k], self.t_lengthening[k] = w, t
        g = float(self.reads_long[k])  # > 0: the anchor is in NLOS
        if g > 0.0:
            drift = max(NLOS_DRIFT, NLOS_SMALLEST_BIAS_M / (2.0 * root))
            g = min(NLOS_CAP, max(0.0, g + w - drift))
            if g == 0.0 and root > NLOS_SMALLEST_BIAS_M and self._contradicted(t, k, *prior()):
                g = NLOS_CAP
            self.reads_long[k] = g
        elif w >= NLOS_STEP and step >= NLOS_STEP:
            self.reads_long[k] = NLOS_CAP
        return bool(self.reads_long[k] > 0.0)

    def _contradicted(
        self,
        t: float,
        k: int,
        prior: tuple[NDArray[np.float64], NDArray[np.float64]],
        arm_up: float,
    ) -> bool:
        """Whether the ranges of the last :data:`REACQUIRE_WINDOW_S` to ``t`` contradict anchor
        ``k``'s: their fit leaves it out (:meth:`_raim`), or, from three anchors and more, no
        position fits them all (:meth:`_consistent`; Gauss–Newton finds none on ranges that
        contradict each other). Ranges of fewer anchors, or that fit a point and its mirror
        image, contradict nothing."""
        found = self._raim(t - REACQUIRE_WINDOW_S, t, prior, arm_up)
        if found is not None:
            return found[1] == k
        index, ranges = self._window(t - REACQUIRE_WINDOW_S, t)
        if np.unique(index).size < 3:
            return False
        solutions, height = self._solutions(self.anchors[index], ranges, prior[0], arm_up)
        dof = ranges.size + (height is not None) - 3
        return not any(self._consistent((p, c, cost, dof)) for p, c, cost in solutions)

    def _count_short(self, index: int, k: int, innovation: float, s: float) -> None:
        """Track how long anchor ``k``'s ranges have read short of the filter's distance by
        more than the screen's gate (``innovation = r̃ − r`` against its variance ``s``)."""
        short = innovation > 0.0 and innovation * innovation > self._screen * s
        _run_start(self.short_since, k, float(self.data.t[index]), short)

    def _variance(self, index: int, k: int, nu: float, s: float) -> float:
        """R of anchor ``k``: fixed, or the variational-Bayes update (module docstring) from
        the innovation ``nu`` and its predicted variance ``s = h P hᵀ`` plus the range's
        spread over the position's uncertainty (:func:`second_order_range`), which is part of
        the innovation's variance, not a ranging noise to learn."""
        if not self.adaptive:
            return self._noise(k)
        t = float(self.data.t[index])
        if np.isfinite(self.t_last[k]):
            forget = math.exp(-(t - self.t_last[k]) / self.options.adaptive_window_s)
            self.alpha[k] *= forget
            self.beta[k] *= forget
            if self.alpha[k] < 0.5:
                self.alpha[k], self.beta[k] = self._alpha0, self._beta0
        self.t_last[k] = t
        r = self._noise(k)
        if nu * nu / (s + r) > self._screen:
            return r
        alpha = self.alpha[k] + 0.5
        beta = self.beta[k]
        for _ in range(VB_ITERATIONS):
            gain = r / (s + r)
            beta = self.beta[k] + 0.5 * (nu * gain) ** 2 + 0.5 * s * gain
            r = beta / alpha
        self.alpha[k], self.beta[k] = alpha, beta
        return r


def _run_start(since: NDArray[np.float64], k: int, t: float, failing: bool) -> float:
    """Start of anchor ``k``'s current run of failing ranges in ``since`` (NaN: the last range
    did not fail), updated with one range at ``t``."""
    if not failing:
        since[k] = np.nan
    elif not np.isfinite(since[k]):
        since[k] = t
    return float(since[k])


def _tag_prior(
    tag: NDArray[np.float64], ctx: MeasurementContext
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The prior of a window fit: the SINS's tag position ``tag`` (origin ENU) and the
    filter's position covariance turned to origin ENU axes."""
    return tag, ctx.position_covariance_enu


def second_order_range(
    line_of_sight: NDArray[np.float64], distance: float, covariance: NDArray[np.float64]
) -> tuple[float, float]:
    """The mean offset and the extra variance of a range over the position's uncertainty.

    The range ``r(p) = ‖p − a‖`` curves with ``∂²r/∂p² = (I − u uᵀ)/r`` (``u`` the unit line
    of sight): across the line of sight a position error ``e`` lengthens the range by
    ``‖e‖²/(2r)``. For ``p ~ N(p̂, P)`` the Gaussian second-order filter (Jazwinski 1970,
    §9.3; Bar-Shalom, Li & Kirubarajan 2001, §10.3) therefore predicts the range
    ``r(p̂) + ½ tr(M P)`` and adds ``½ tr(M P M P)`` to the innovation variance, ``M = ∂²r/∂p²``.
    Both vanish as P shrinks; they matter where the filter meets the anchors after a long
    pass, its position σ metres across the line of sight of anchors ten metres away, where a
    first-order update would take the chord for the arc and claim centimetres.
    """
    u = line_of_sight
    curvature = (np.eye(3) - np.outer(u, u)) / max(distance, 1e-9)
    spread = curvature @ covariance
    return 0.5 * float(np.trace(spread)), 0.5 * float(np.sum(spread * spread.T))


def _gauss_newton(
    anchors: NDArray[np.float64],
    ranges: NDArray[np.float64],
    start: NDArray[np.float64],
    height: tuple[float, float] | None,
    options: LeastSquaresOptions,
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Solve one window for the tag position; return it and its covariance, or None."""
    p = start.copy()
    weight = 1.0 / options.sigma_range_m**2
    for _ in range(options.max_iterations):
        line = p - anchors
        dist = np.linalg.norm(line, axis=1)
        u = line / dist[:, None]
        normal = weight * u.T @ u
        rhs = weight * u.T @ (ranges - dist)
        if height is not None:
            ref, sigma = height
            normal[2, 2] += 1.0 / sigma**2
            rhs[2] += (ref - p[2]) / sigma**2
        try:
            factor = scipy.linalg.cho_factor(normal, check_finite=False)
        except np.linalg.LinAlgError:
            return None
        step = scipy.linalg.cho_solve(factor, rhs, check_finite=False)
        p = p + step
        if np.linalg.norm(step) < options.tolerance_m:
            return p, scipy.linalg.cho_solve(factor, np.eye(3), check_finite=False)
    return None


def _local_slope(
    t: NDArray[np.float64], values: NDArray[np.float64], span: float
) -> NDArray[np.float64]:
    """Slope of the least-squares line through the samples within ``±span/2`` of each time."""
    lo = np.searchsorted(t, t - 0.5 * span, side="left")
    hi = np.searchsorted(t, t + 0.5 * span, side="right")
    tc = t - t[0]  # keep the sums well conditioned

    def window_sum(x: NDArray[np.float64]) -> NDArray[np.float64]:
        c = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(x, axis=0)])
        return c[hi] - c[lo]

    n = (hi - lo).astype(float)
    st, stt = window_sum(tc), window_sum(tc * tc)
    sp, stp = window_sum(values), window_sum(tc[:, None] * values)
    denom = n * stt - st * st
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = (n[:, None] * stp - st[:, None] * sp) / denom[:, None]
    return np.where(denom[:, None] > 0, slope, 0.0)


class _ResidualNoise:
    """Ranging-noise σ of the least-squares fits, learned from their residuals.

    ``σ² = (S + n₀ σ₀²) / (D + n₀)``, never below the configured ``σ₀``, with ``S`` the sum of
    the accepted ranges' squared residuals and ``D`` their degrees of freedom (ranges − 3 per
    window), both forgotten with ``exp(−Δt/τ)``, and the prior weighing :data:`PRIOR_DOF`.
    ``τ`` None: σ₀ always.
    """

    PRIOR_DOF = 10.0

    def __init__(self, sigma: float, window_s: float | None) -> None:
        self.floor = sigma
        self.window_s = window_s
        self.sum = 0.0
        self.dof = 0.0
        self.t: float | None = None

    def sigma(self, t: float) -> float:
        """The noise σ to weigh and gate the window at ``t`` with."""
        if self.window_s is None:
            return self.floor
        self._forget(t)
        variance = (self.sum + self.PRIOR_DOF * self.floor**2) / (self.dof + self.PRIOR_DOF)
        return max(self.floor, math.sqrt(variance))

    def add(self, t: float, squared_residuals_m2: float, dof: int) -> None:
        """Learn from one fit's accepted residuals."""
        if self.window_s is None or dof <= 0:
            return
        self._forget(t)
        self.sum += squared_residuals_m2
        self.dof += dof

    def _forget(self, t: float) -> None:
        if self.t is not None and self.window_s is not None:
            rho = math.exp(-max(t - self.t, 0.0) / self.window_s)
            self.sum *= rho
            self.dof *= rho
        self.t = t


def _predicted_tag(
    times: list[float],
    tags: list[NDArray[np.float64]],
    weights: list[float],
    t: float,
    options: LeastSquaresOptions,
) -> tuple[NDArray[np.float64], float]:
    """Where the tag is expected at ``t`` and the variance (m², summed over the axes) of that
    guess: the weighted line through the fixes of the last ``velocity_span_s`` (weights
    1/tr(cov): an ambiguous fix barely counts; its speed at most ``max_speed_mps``),
    extrapolated by at most that span; their
    weighted mean when there are fewer than three. The variance is the weighted mean's plus
    ``max_speed_mps`` times the time of the windows without a fix, squared. ``times`` is
    not empty."""
    span = options.velocity_span_s
    gap = max(t - times[-1] - options.window_s, 0.0)  # windows without a fix
    first = bisect.bisect_left(times, times[-1] - span)
    w = np.asarray(weights[first:])
    pp = np.asarray(tags[first:])
    centre = w @ pp / w.sum()
    variance = 1.0 / float(w.sum()) + (options.max_speed_mps * gap) ** 2
    if w.size < 3:
        return centre, variance
    tt = np.asarray(times[first:]) - times[-1]
    t_mean = float(w @ tt / w.sum())
    tc = tt - t_mean
    slope = (w * tc) @ (pp - centre) / float((w * tc) @ tc)
    speed = float(np.linalg.norm(slope))
    if speed > options.max_speed_mps:  # fixes scattered by ranges the gate let through
        slope *= options.max_speed_mps / speed
    return centre + slope * (min(t - times[-1], span) - t_mean), variance


def _mirrored(point: NDArray[np.float64], anchors: NDArray[np.float64]) -> NDArray[np.float64]:
    """``point`` reflected across the plane that best fits the anchors (the other solution of
    three anchors' ranges; for more, nearly coplanar, anchors the other local minimum)."""
    distinct = np.unique(anchors, axis=0)
    centre = distinct.mean(axis=0)
    normal = np.linalg.svd(distinct - centre)[2][-1]
    return point - 2.0 * float((point - centre) @ normal) * normal


def _fitting_mirror(
    point: NDArray[np.float64],
    cost: float,
    anchors: NDArray[np.float64],
    ranges: NDArray[np.float64],
    height: tuple[float, float] | None,
    sigma: float,
    margin: float,
) -> NDArray[np.float64] | None:
    """The mirror image of a solution ``point`` of χ² ``cost`` (:func:`_mirrored`), if its own
    χ² is within ``margin`` of it: a second solution Gauss–Newton may not have found."""
    mirror = _mirrored(point, anchors)
    if _chi2(mirror, anchors, ranges, height, sigma) - cost <= margin:
        return mirror
    return None


_Candidate = tuple[NDArray[np.float64], NDArray[np.float64], float]
"""One Gauss–Newton solution of a window: position, covariance, χ²."""


@dataclass(frozen=True)
class _Fit:
    """One window's solution: position, covariance at the learned σ, the ranges kept, every
    range's squared standardized residual, and the other solution that fits within the gate
    (its rival), if any."""

    position: NDArray[np.float64]
    covariance: NDArray[np.float64]
    used: NDArray[np.bool_]
    squared: NDArray[np.float64]
    rival: NDArray[np.float64] | None


def _window_fix(
    anchors: NDArray[np.float64],
    index: NDArray[np.int64],
    ranges: NDArray[np.float64],
    expected: tuple[NDArray[np.float64], float],
    height: tuple[float, float] | None,
    options: LeastSquaresOptions,
    sigma: float,
    gate: float | None,
) -> _Fit | None:
    """Fix of one window, or None.

    Gauss–Newton runs from the prediction, from its mirror image across the anchors' plane
    and from the first solution's mirror image; of the solutions whose χ² is within the gate
    of the best, the one nearest the prediction is kept and the next one is its rival
    (three anchors always have two). ``expected`` is the prediction and its variance (m², all
    axes). Ranges are gated first against the prediction (when its variance is finite, and
    as long as ``min_anchors`` anchors pass), then, while the largest residual exceeds the
    gate, that range is dropped and the window solved again; a window left with fewer than
    ``min_anchors`` anchors gives no fix.
    """
    prediction, spread = expected
    used = np.ones(ranges.size, dtype=bool)
    if gate is not None and math.isfinite(spread):
        expected_range = np.linalg.norm(prediction - anchors, axis=1)
        near = (ranges - expected_range) ** 2 <= gate * (sigma**2 + spread / 3.0)
        if np.unique(index[near]).size >= options.min_anchors:
            used = near
    margin = chi2_threshold(1, 0.999) if gate is None else gate
    while True:
        solutions = _solutions(anchors[used], ranges[used], prediction, height, options, sigma)
        if not solutions:
            return None
        plausible = _plausible(solutions, margin, prediction)
        p, cov, cost = plausible[0]
        squared = ((ranges - np.linalg.norm(p - anchors, axis=1)) / sigma) ** 2
        worst = int(np.argmax(np.where(used, squared, -1.0)))
        if gate is None or squared[worst] <= gate:
            rivals = [q for q, _, _ in plausible[1:] if _apart(q, p, options)]
            if not rivals:  # no second minimum found: is the mirror point itself ruled out?
                q = _fitting_mirror(p, cost, anchors[used], ranges[used], height, sigma, margin)
                if q is not None and _apart(q, p, options):
                    rivals.append(q)
            return _Fit(p, cov, used, squared, rivals[0] if rivals else None)
        used[worst] = False
        if np.unique(index[used]).size < options.min_anchors:
            return None


def _solutions(
    anchors: NDArray[np.float64],
    ranges: NDArray[np.float64],
    prediction: NDArray[np.float64],
    height: tuple[float, float] | None,
    options: LeastSquaresOptions,
    sigma: float,
) -> list[_Candidate]:
    """Gauss–Newton solutions (position, covariance at ``sigma``, χ²) from the prediction,
    from its mirror image and from the first solution's mirror image (both starts may fall
    into one basin)."""
    found: list[_Candidate] = []
    scale = (sigma / options.sigma_range_m) ** 2
    for start in (prediction, _mirrored(prediction, anchors), None):
        if start is None:
            if not found:
                break
            start = _mirrored(found[0][0], anchors)
        fit = _gauss_newton(anchors, ranges, start, height, options)
        if fit is not None:
            found.append((fit[0], fit[1] * scale, _chi2(fit[0], anchors, ranges, height, sigma)))
    return found


def _plausible(
    solutions: list[_Candidate], margin: float, target: NDArray[np.float64]
) -> list[_Candidate]:
    """The solutions whose χ² is within ``margin`` of the best, nearest ``target`` first."""
    best = min(cost for _, _, cost in solutions)
    return sorted(
        (fit for fit in solutions if fit[2] <= best + margin),
        key=lambda fit: float(np.linalg.norm(fit[0] - target)),
    )


def _apart(a: NDArray[np.float64], b: NDArray[np.float64], options: LeastSquaresOptions) -> bool:
    """Two solutions are distinct: farther apart than Gauss–Newton's convergence step."""
    return float(np.linalg.norm(a - b)) > options.tolerance_m


class _Branch:
    """Which of two mirror solutions the tag is on (module docstring, "Mirror solutions").

    While the branch is known, a rival more than 3σ of the prediction farther from it than
    the kept solution is ruled out by continuity. A rival that is not widens the kept
    solution's covariance by half the squared offset to it (the second moment about the kept
    one of two equally likely solutions), and when the two are also more than 3σ of the fit
    apart the branch becomes unknown: every later rival widens the covariance, until a window
    whose χ² rules the mirror out makes it known again.
    """

    def __init__(self) -> None:
        self.known = True  # meta.yaml's initial state tells the two apart

    def spread(self, spread: float) -> float:
        """The prediction's variance as far as continuity goes (infinite: branch unknown)."""
        return spread if self.known else math.inf

    def resolve(
        self, fit: _Fit, prediction: NDArray[np.float64], spread: float
    ) -> NDArray[np.float64]:
        """The covariance to report with ``fit``'s position (``spread`` from :meth:`spread`)."""
        if fit.rival is None:
            self.known = True
            return fit.covariance
        rival = fit.rival
        nearest = float(np.linalg.norm(fit.position - prediction))
        if float(np.linalg.norm(rival - prediction)) >= nearest + 3.0 * math.sqrt(spread):
            return fit.covariance
        offset = rival - fit.position
        if _beyond_fit(offset, fit.covariance):
            self.known = False
        return fit.covariance + 0.5 * np.outer(offset, offset)


PROFILE_SIGMAS = (3.0, 6.0)
"""Offsets along a fix's weakest axis, in its σ, at which :func:`_profiled_covariance` reads
the least-squares cost."""


def _profiled_covariance(
    best: NDArray[np.float64],
    covariance: NDArray[np.float64],
    cost: float,
    anchors: NDArray[np.float64],
    ranges: NDArray[np.float64],
    height: tuple[float, float] | None,
    options: LeastSquaresOptions,
) -> NDArray[np.float64]:
    """The fix's covariance with the variance along its weakest axis read off the cost
    (the ranges' and, if given, the height row's; :func:`_chi2`):
    at each offset ``s`` of :data:`PROFILE_SIGMAS` σ on either side of ``best`` the cost is
    minimized over the plane normal to the axis (:func:`_profile_minimum`), and the axis
    takes the largest ``s² / max(Δχ², 1)`` (on a paraboloid Δχ² = s²/σ²: nothing changes).

    Far from anchors clustered at one face end the ranges see one direction only through
    their curvature, and their cost there is a long curved valley, not the paraboloid its
    linearization describes: 70 m from the anchors a fit 12 m off in height had a linearized
    σ of 4.5 m along that axis, and the filter, put on it, held its height 5 m off at a σ of
    0.44 m (random world 2 at its own length). Widened by the profile, the horizontal error of
    fixes 15–60 m from four such anchors has RMS(ε/σ) 0.9–1.1, against 1.6–1.7 linearized
    (``tests/test_uwb_plugin.py``). (The profile likelihood: Pawitan, *In All Likelihood*,
    2001.)
    """
    variances, axes = np.linalg.eigh(covariance)
    axis, largest = axes[:, -1], float(variances[-1])
    variance = largest
    for k in PROFILE_SIGMAS:
        for sign in (-1.0, 1.0):
            offset = sign * k * math.sqrt(largest)
            start = best + offset * axis
            _, chi2 = _profile_minimum(start, axis, anchors, ranges, height, options)
            variance = max(variance, offset**2 / max(chi2 - cost, 1.0))
    return covariance + (variance - largest) * np.outer(axis, axis)


def _profile_minimum(
    start: NDArray[np.float64],
    axis: NDArray[np.float64],
    anchors: NDArray[np.float64],
    ranges: NDArray[np.float64],
    height: tuple[float, float] | None,
    options: LeastSquaresOptions,
) -> tuple[NDArray[np.float64], float]:
    """The position of least χ² (:func:`_chi2`: the ranges and the optional height row) on
    the plane through ``start`` normal to ``axis`` (unit), and that χ²: Gauss–Newton steps
    projected onto the plane."""
    basis = np.linalg.svd(np.eye(3) - np.outer(axis, axis))[0][:, :2]
    sigma = options.sigma_range_m
    p = start.copy()
    for _ in range(options.max_iterations):
        line = p - anchors
        dist = np.linalg.norm(line, axis=1)
        jac = (line / dist[:, None]) @ basis / sigma
        residual = (ranges - dist) / sigma
        if height is not None:
            ref, sigma_h = height
            jac = np.vstack([jac, basis[2] / sigma_h])
            residual = np.append(residual, (ref - p[2]) / sigma_h)
        step = basis @ np.linalg.lstsq(jac, residual, rcond=None)[0]
        p = p + step
        if np.linalg.norm(step) < options.tolerance_m:
            break
    return p, _chi2(p, anchors, ranges, height, sigma)


def _reachable(fit: _Fit, prediction: NDArray[np.float64], spread: float, gate: float) -> bool:
    """Whether a window's fix is a place the tag can have reached: its offset from the
    prediction within the χ²₃ ``gate`` of the fix's covariance plus the prediction's
    (``spread``, m² over the three axes, taken as isotropic; infinite while the branch is
    unknown, when everything is reachable). The prediction's variance grows with
    ``max_speed_mps`` times the time without a fix, so a tag that really moved is fixed
    again once that time allows the move."""
    if not math.isfinite(spread):
        return True
    offset = fit.position - prediction
    innovation = fit.covariance + (spread / 3.0) * np.eye(3)
    return float(offset @ np.linalg.solve(innovation, offset)) <= gate


def _beyond_fit(offset: NDArray[np.float64], covariance: NDArray[np.float64]) -> bool:
    """Two solutions ``offset`` apart are different places as far as a fit of ``covariance``
    goes: more than 3σ of it apart, σ taken along the offset."""
    apart2 = float(offset @ offset)
    return apart2**2 > 9.0 * float(offset @ covariance @ offset)


def _chi2(
    p: NDArray[np.float64],
    anchors: NDArray[np.float64],
    ranges: NDArray[np.float64],
    height: tuple[float, float] | None,
    sigma: float,
) -> float:
    """The fit's cost: squared standardized range residuals (+ the height constraint's)."""
    cost = float(np.sum(((ranges - np.linalg.norm(p - anchors, axis=1)) / sigma) ** 2))
    if height is not None:
        cost += ((p[2] - height[0]) / height[1]) ** 2
    return cost


def least_squares_solution(
    recording: Recording,
    options: LeastSquaresOptions | None = None,
    gate_probability: float | None = None,
    log: InnovationLog | None = None,
) -> Solution:
    """UWB-only Gauss–Newton fixes of the IMU point, one per window of ranges.

    Parameters
    ----------
    recording
        A recording with ``uwb.csv`` (the IMU stream is not used).
    options
        Noise, window, constraints (defaults: :class:`LeastSquaresOptions`).
    gate_probability
        χ²(1) quantile of a range's residual beyond which it is dropped from its window's fit
        (None: every range enters the fit).
    log
        When given, receives one record per range of the windows that were solved: its
        squared standardized residual and whether the gate kept it (a window without a fix:
        every range rejected, residual NaN).

    Returns
    -------
    Solution
        One epoch per window that gives a fix (at the window's mean range time): IMU-point
        position, the velocity regressed over ``velocity_span_s`` of fixes, meta.yaml's initial
        attitude (constant), the position σ and covariance from ``(JᵀR⁻¹J)⁻¹``.

    Raises
    ------
    ValueError
        When the recording has no UWB stream or no window gives a fix.
    """
    opts = LeastSquaresOptions() if options is None else options
    data, meta = _uwb_stream(recording, "the UWB least-squares solution")
    init = recording.meta.initial
    origin = recording.meta.origin
    frame = LocalFrame(origin.lat_deg, origin.lon_deg, origin.height_m)
    lat, lon, _ = frame.to_geodetic(np.asarray(init.position_enu_m, dtype=float))
    rot = frame.rotation_to_local(lat, lon)
    euler = np.deg2rad([init.attitude_deg.roll, init.attitude_deg.pitch, init.attitude_deg.yaw])
    arm_enu = rot.T @ dcm_from_euler(*euler) @ np.array(meta.tag_lever_arm_b_m, dtype=float)
    tag = np.asarray(init.position_enu_m, dtype=float) + arm_enu
    height = None if opts.height_sigma_m is None else (float(tag[2]), opts.height_sigma_m)
    anchors = np.array([meta.anchors[a] for a in data.anchor_ids], dtype=float)
    gate = None if gate_probability is None else chi2_threshold(1, gate_probability)
    fix_gate = None if gate_probability is None else chi2_threshold(3, gate_probability)
    noise = _ResidualNoise(opts.sigma_range_m, opts.noise_window_s)

    keep = np.ones(data.t.size, dtype=bool)
    if opts.max_range_m is not None:
        keep = data.range <= opts.max_range_m
    t, index, ranges = data.t[keep], data.anchor_index[keep], data.range[keep]
    window = np.floor((t - data.t[0]) / opts.window_s).astype(np.int64)
    out_t: list[float] = []
    out_p: list[NDArray[np.float64]] = []
    out_cov: list[NDArray[np.float64]] = []
    out_w: list[float] = []
    branch = _Branch()
    for sel in np.split(np.arange(t.size), np.flatnonzero(np.diff(window)) + 1):
        if np.unique(index[sel]).size < opts.min_anchors:
            continue
        t_mean = float(np.mean(t[sel]))
        sigma = noise.sigma(t_mean)
        if out_t:
            prediction, spread = _predicted_tag(out_t, out_p, out_w, t_mean, opts)
        else:
            prediction, spread = tag, float(np.sum(np.square(init.sigma.position_m)))
        spread = branch.spread(spread)
        fit = _window_fix(
            anchors[index[sel]],
            index[sel],
            ranges[sel],
            (prediction, spread),
            height,
            opts,
            sigma,
            gate,
        )
        if fit is None:  # no fit, or the gate left too few anchors: none of them used
            if log is not None:
                for t_k in t[sel]:
                    log.record(float(t_k), math.nan, 1, False, False)
            continue
        if fix_gate is not None and not _reachable(fit, prediction, spread, fix_gate):
            if log is not None:  # a place the tag cannot have reached: no fix
                for t_k, nis in zip(t[sel], fit.squared, strict=True):
                    log.record(float(t_k), float(nis), 1, False, False)
            continue
        tag, cov = fit.position, branch.resolve(fit, prediction, spread)
        used, squared = fit.used, fit.squared
        noise.add(t_mean, float(np.sum(squared[used])) * sigma**2, int(used.sum()) - 3)
        if log is not None:
            for t_k, nis, accepted in zip(t[sel], squared, used, strict=True):
                log.record(float(t_k), float(nis), 1, bool(accepted), False)
        out_t.append(t_mean)
        out_p.append(tag)
        out_cov.append(cov)
        out_w.append(1.0 / float(np.trace(cov)))
    if not out_t:
        raise PluginError(
            f"UWB least squares: no window of {opts.window_s} s of uwb.csv in"
            f" {recording.meta.name!r} holds ranges to {opts.min_anchors} anchors with a"
            " converged fix; widen window_s or lower min_anchors"
        )
    times = np.array(out_t)
    tags = np.array(out_p)
    cov = np.array(out_cov)
    return Solution(
        t=times,
        position=tags - arm_enu,
        velocity=_local_slope(times, tags, opts.velocity_span_s),
        attitude=np.tile(euler, (times.size, 1)),
        sigma_position=np.sqrt(np.diagonal(cov, axis1=1, axis2=2)),
        position_covariance=cov,
    )
