"""Detection, estimation and accommodation of jumps in designated states (GLR).

A slipping wheel changes the odometer's scale abruptly: ``(1 + δk_D)`` becomes
``(1 + δk_D)(1 + s)``. The filter, which holds δk_D as a constant, absorbs most of the step into
the velocity within a second (at a shearer's speed nothing else explains the odometer), and a
windowed test of the innovations sees little once it has. Isolating the odometer does not help
either when it is the only velocity aid: a MEMS SINS coasting for the length of a slip drifts
further than the slip would have pulled it (on ``longwall-200m`` 1.1 m in 15 s, σ 0.46 m).
The generalized likelihood ratio of Willsky & Jones (1976, *IEEE TAC* 21(1)) models the
absorption instead, estimates the jump, and lets the filter take it in.

A state j that may jump (:attr:`fusion.error_model.StateBlock.may_jump`) is watched by
hypotheses "state j jumped by Δ at θ", one opened every ``spacing_s`` and dropped after
``window_s``. After a jump at θ every innovation carries the term ``H_k E_k Δ``, where ``E`` is
the part of a unit jump the filter has not absorbed:

    E(θ) = e_j,    E ← Φ E at each covariance step,    E ← (I − K H) E at each update

(the *signature columns* of :class:`~fusion.kalman.KalmanFilter`, fused and reset with the
estimates in a federated filter). With the whitened innovation ``w_k = L_k⁻¹ ν_k`` and the
whitened signature ``g_k = L_k⁻¹ H_k E_k`` of every later update (every plugin: a position fix
sees the position a slip has pulled), the log-likelihood ratio maximised over Δ is

    d = Σ g_kᵀ w_k,    c = Σ g_kᵀ g_k,    ℓ = d² / c ~ χ²_1 without a jump,
    Δ̂ = d / c,         σ²_Δ = 1 / c

A jump is declared when the likeliest onset (the largest ℓ over the open hypotheses) has
ℓ above the χ²_1 quantile of ``probability`` and at least ``min_updates`` updates. While the
likeliest onset is younger than that, nothing is declared: a large step lights up the older
hypotheses too, through whatever part of their signature lies along it, and one of those
could otherwise pass first with the wrong onset and sign (the end of a 30 % slip at 0.86 m/s
was taken as +0.04 at the onset a second earlier).

The filter takes it in (accommodation): ``x ← x + E Δ̂`` and
``P ← P + E σ²_Δ Eᵀ``, which moves the jumped state by the estimate and puts back what the
other states had absorbed (the velocity and position the slip had pulled). Every open
hypothesis of that state is then dropped, and the event is reported in ``faults.csv`` (action
``jump``).

A state may have a *rest* value it returns to exactly (a slip ratio is 0 once the wheel grips
again). A jump that brings it back within 3σ of rest — or past rest, for a state that leaves rest
in one direction only and so cannot be on the other side (a slip whose onset was estimated short
ends in a jump that overshoots zero) — is taken in as above and the state is then set to rest
by conditioning on ``x_j = rest`` (a Kalman update with H = e_jᵀ and a negligible R), which
also moves the states correlated with it: the slip estimated during the episode is
replaced by the known end value, and the velocity and position it had been traded against are
corrected with it. A state may also leave rest in one direction only (``leaves_rest``): a
slip whose onset went undetected (slow, at a crawl) ends in what looks like a jump the other
way, which must not be taken for a new slip; while the state is at rest, jumps against the
direction are not taken in.

The return test. A state held away from rest is also watched for its jump back there, a jump
whose size is known: Δ ~ N(rest − x̂_θ, σ²_θ), x̂_θ and σ²_θ the state's estimate and variance
when the hypothesis opened at θ. Its log-likelihood ratio against no jump, marginalised over
that Δ (with v = σ²_θ),

    ℓ_r = d²/c − (d − Δ̄ c)² / (c (1 + c v)) − ln(1 + c v),       Δ̄ = rest − x̂_θ,

is compared with the χ²_1 quantile η of ``return_probability`` (0.999: η = 10.8; with v = 0 a
test's false alarm is at most Q(√η) whatever the jump's size, against 2 Q(√η_GLR) for a free
jump), and taken only where the estimated jump is within 3σ of Δ̄ (:data:`RETURN_MISFIT`: the
return must explain the data, not only explain it better than no jump). It runs at every
update at which the GLR declares nothing. Every slip ends, so its end needs less evidence than
its onset: an end left undetected keeps the wheel's scale wrong until the next standstill,
and the federated filter then isolated the UWB local that disagreed with it
(docs/design/2026-11-29-slip-ends-and-skids.md).

A held state's return (:meth:`JumpDetector.held_return`). A slip ends after seconds to a
minute whether or not anything sees it end, and one whose end the tests miss (a harsh world's
skid ending as every anchor went into NLOS: the return test at 10.84 against 10.83 for 40 s)
left the filter 0.37 m off at an RMS(ε/σ) of 10. A state given a mean time ``τ`` away from rest
(:attr:`fusion.error_model.StateBlock.rest_return_s`) is, while held, the Gaussian collapse of
the jump-Markov model's two places (as in a GPB1 filter): it decays towards rest and gains the
variance of the chance that it has returned, so the other sensors can move it when they
disagree with it. It can then follow an end without a step for the return test to find; once
its estimate is within 1σ of rest it is set there, as a return is
(docs/design/2026-12-01-held-slip-uncertainty.md).

A jump no accepted update saw (:meth:`JumpDetector.unseen_jump`). A slip that begins while
nothing that sees the position can be used (a UWB dropout, every anchor in NLOS) pulls the
filter along the track while the slipping wheel itself holds it; when the ranges come back they
fail the gate, and the tests above, which take accepted updates only and keep a hypothesis for
``window_s``, never see them (docs/design/2026-12-01-slip-in-a-dropout.md). Each state also keeps
an *anchor* hypothesis, reopened (at most every ``spacing_s``) at each accepted update that sees
the position: its signature column E is the effect of a jump since a position source last
agreed with the filter. When every update of a source is rejected while another holds the
filter (a ``disputed`` lock, :mod:`fusion.lock`), its last rejected update — whitened innovation
w of m rows and NIS a, whitened signature g = L⁻¹ H E — is tested against such a jump. With a
prior Δ ~ N(0, σ²) its NIS is that of ``S + σ² H E Eᵀ Hᵀ``; the least σ² that brings it down to
m is (Sherman–Morrison)

    σ² = e / (b² − e c),    e = a − m,  b = gᵀ w,  c = gᵀ g,

which exists only when b² > e c: the jump must explain the whole excess, not part of it (NLOS
that moves the ranges' fix across the track does not). Given that update the jump is then

    Δ̂ = σ² b / (1 + σ² c) = e / b,    σ²_Δ = e / b²,

taken in as a detected jump is (x ← x + E Δ̂, P ← P + E σ²_Δ Eᵀ) when it lies within the state's
bound and its direction from rest; the state is then held like any other, and the disputed
source's next updates pass the gate and estimate it further.

A jump under way explains other sensors' innovations too. :meth:`JumpDetector.explanation`
gives the likeliest open hypothesis once its ratio passes η, in either direction; the federated
filter asks it before isolating a local (:class:`fusion.federated.FederatedFilter`).

A plugin may also know that a state is back at rest without any jump to detect: a wheel that
stands still does not slip, so a slip episode ends at the latest when the machine stops (at a
standstill s has no effect on any reading and nothing could detect its end). The plugin says so
in its measurement (:attr:`fusion.plugin.Measurement.at_rest`), and a state away from rest is
then *restarted* at rest with its prior σ and no correlation (:meth:`JumpDetector.rest`) — not
conditioned, since the state changed rather than being found to have been at rest all along.
Without this a slip that ended during a stop stayed in the odometer scale after the restart;
the detector then had to find the end among the restart's own transients and, on
``longwall-200m`` seed 1 (full_afkf, +20 % slip), the UWB local was isolated first for
disagreeing with the mis-scaled odometer.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.config import JumpDetectionOptions
from fusion.error_model import StateLayout
from fusion.fault_detection import FaultEvent
from fusion.filter_bank import FilterBank
from fusion.kalman import UpdateResult, chi2_threshold, whiten

JUMP = "jump"
RETURN_MISFIT = 9.0
"""Largest squared z-score of the estimated jump from the return to rest for the return test
(3σ: the data must be explained by the return, not only better than by no jump)."""


@dataclass(frozen=True)
class JumpState:
    """A state that may jump: its index in the full layout, its name for the report, the value
    it returns to (``None``: none) and the block that holds it (its plugin's)."""

    index: int
    name: str
    rest: float | None = None
    leaves_rest: int = 0
    block: str = ""
    bound: float | None = None
    rest_return_s: float | None = None


def _within_bound(state: JumpState, value: float) -> bool:
    """Whether ``value`` is within the state's physical bound (always, without one)."""
    return state.bound is None or abs(value) <= state.bound


def jump_states(layout: StateLayout) -> list[JumpState]:
    """The states of the layout's blocks declared ``may_jump``."""
    states = []
    for block in layout.blocks:
        if block.may_jump:
            start = layout.slice(block.name).start
            for k, label in enumerate(block.labels):
                name = block.name if block.size == 1 else f"{block.name}.{label}"
                states.append(
                    JumpState(
                        start + k,
                        name,
                        block.rest,
                        block.leaves_rest,
                        block.name,
                        block.bound,
                        block.rest_return_s,
                    )
                )
    return states


@dataclass(frozen=True)
class HeldReturn:
    """The held states' part of a time update (:meth:`JumpDetector.held_return`): Φ's rows
    scaled by ``decay`` and ``variance`` added to the diagonal of Q (full layout)."""

    decay: NDArray[np.float64]
    variance: NDArray[np.float64]


@dataclass(frozen=True)
class Explanation:
    """A jump under way that explains the innovations: the likeliest open hypothesis, past the
    return test's threshold (:meth:`JumpDetector.explanation`). ``allowed``: the detector may
    take it in (a jump against a one-way state's direction from rest may not)."""

    state: JumpState
    ratio: float
    jump: float
    onset: float
    allowed: bool


class JumpDetector:
    """GLR hypotheses of jumps in ``states``, their statistics and the accommodation.

    Parameters
    ----------
    layout
        The full state layout (the signature columns start as unit vectors in it).
    states
        The states that may jump.
    options
        Window, spacing, probability and minimum number of updates.
    on_jump
        Told of every jump taken in and every restart at rest, as ``(state, onset, before)``:
        the state held the estimate ``before`` until ``onset`` and the filter's estimate from
        then on (for a plugin whose model reads past samples through the state, see
        :meth:`fusion.plugin.Plugin.state_jumped`).
    """

    def __init__(
        self,
        layout: StateLayout,
        states: list[JumpState],
        options: JumpDetectionOptions,
        on_jump: Callable[[JumpState, float, float], None] | None = None,
    ) -> None:
        self.layout = layout
        self.states = states
        self.options = options
        self.on_jump = on_jump
        self.threshold = chi2_threshold(1, options.probability)
        self.return_threshold = chi2_threshold(1, options.return_probability)
        self._state = np.empty(0, np.intp)  # per column: which of ``states``
        self._onset = np.empty(0)
        self._held = np.empty(0)  # per column: the state's estimate and variance at its onset
        self._held_variance = np.empty(0)
        self._d = np.empty(0)
        self._c = np.empty(0)
        self._n = np.empty(0, np.intp)
        self._anchored = np.empty(0, bool)  # per column: an anchor (unseen_jump), not tested
        self._last_opened = -np.inf
        self._last_anchored = -np.inf
        self._at_rest = np.array([s.rest is not None for s in states])
        self._rest = np.array([np.nan if s.rest is None else s.rest for s in states])
        self._direction = np.array([s.leaves_rest for s in states])
        prior = np.diag(layout.initial_covariance())
        self._prior_variance = np.array([prior[s.index] for s in states])
        self._by_name = {s.name: k for k, s in enumerate(states)}
        self._seen = np.zeros(len(states), bool)  # by the update about to be observed
        self._return_rate = np.array(
            [0.0 if s.rest_return_s is None else 1.0 / s.rest_return_s for s in states]
        )

    def held_return(self, dt: float, bank: FilterBank) -> HeldReturn | None:
        """The transition over ``dt`` of the states held away from rest, or None.

        A state held away from rest returns there as a Poisson event of rate ``1/τ``
        (:attr:`fusion.error_model.StateBlock.rest_return_s`): over dt it is back at rest
        (0) with probability ``q = dt/τ``. The Gaussian with that two-place mixture's mean and
        variance (a GPB1 collapse) has

            x̂' = (1 − q) x̂,    P' = (1 − q) P + q (1 − q) x̂²

        that is, a decay ``(1 − q)`` in Φ and ``q (1 − q)(P + x̂²)`` of process noise. Unseen,
        a held state so decays to rest over τ, its variance growing by at most x̂²/4."""
        held = ~self._at_rest & (self._return_rate > 0)
        if not held.any():
            return None
        x, p = bank.estimate()
        decay = np.ones(self.layout.dim)
        variance = np.zeros(self.layout.dim)
        for k in np.flatnonzero(held):
            j = self.states[k].index
            q = min(dt * self._return_rate[k], 1.0)
            decay[j] = 1.0 - q
            variance[j] = q * (1.0 - q) * (p[j, j] + x[j] ** 2)
        return HeldReturn(decay, variance)

    def step(self, t: float, bank: FilterBank) -> None:
        """Open a hypothesis per state every ``spacing_s``; drop those older than the window."""
        old = (t - self._onset > self.options.window_s) & ~self._anchored
        if old.any():
            self._keep(~old, bank)
        if t - self._last_opened < self.options.spacing_s - 1e-9:
            return
        self._last_opened = t
        self._open(t, bank, anchored=False)

    def anchor(self, t: float, bank: FilterBank) -> None:
        """A source that sees the position agreed with the filter at ``t``: reopen every state's
        anchor hypothesis there (:meth:`unseen_jump`), at most every ``spacing_s``."""
        if self._anchored.any():  # opened at _last_anchored
            if t - self._last_anchored < self.options.spacing_s - 1e-9:
                return
            self._keep(~self._anchored, bank)
        self._last_anchored = t
        self._open(t, bank, anchored=True)

    def _open(self, t: float, bank: FilterBank, anchored: bool) -> None:
        """Open one hypothesis per state at ``t``."""
        columns = np.zeros((self.layout.dim, len(self.states)))
        for k, s in enumerate(self.states):
            columns[s.index, k] = 1.0
        bank.add_signatures(columns)
        count = len(self.states)
        held, held_variance = np.zeros(count), np.zeros(count)
        if not anchored:  # for the return test, which anchors do not enter
            x, p = bank.estimate()
            index = [s.index for s in self.states]
            held, held_variance = x[index], p[index, index]
        self._state = np.append(self._state, np.arange(count))
        self._onset = np.append(self._onset, np.full(count, t))
        self._held = np.append(self._held, held)
        self._held_variance = np.append(self._held_variance, held_variance)
        self._d = np.append(self._d, np.zeros(count))
        self._c = np.append(self._c, np.zeros(count))
        self._n = np.append(self._n, np.zeros(count, np.intp))
        self._anchored = np.append(self._anchored, np.full(count, anchored))

    def innovation_signature(
        self, bank: FilterBank, plugin: int, h: NDArray[np.float64], layout: StateLayout
    ) -> NDArray[np.float64]:
        """``H E`` of the filter that serves ``plugin`` (rows ``h`` in its ``layout``), taken
        before its update changes E. Also notes which watched states the rows see (for
        :meth:`observe`)."""
        self._seen[:] = False
        for k in np.flatnonzero(~self._at_rest & (self._return_rate > 0)):  # only held ones
            column = self._local_column(self.states[k], layout)
            self._seen[k] = column is not None and bool(np.any(h[:, column]))
        return h @ bank.signatures_of(plugin)

    def _local_column(self, state: JumpState, layout: StateLayout) -> int | None:
        """The state's column in ``layout`` (a federated local's), or None without it."""
        if state.block not in layout:
            return None
        return layout.slice(state.block).start + state.index - self.layout.slice(state.block).start

    def observe(
        self,
        t: float,
        bank: FilterBank,
        plugin: int,
        signature: NDArray[np.float64],
        result: UpdateResult,
    ) -> FaultEvent | None:
        """Add one accepted update to every hypothesis; take in a jump that passes the test."""
        if not result.accepted or not self._onset.size or not bank.in_fusion(plugin):
            return None
        g = whiten(result.whitening, signature)
        self._d += g.T @ result.whitened
        self._c += np.einsum("ij,ij->j", g, g)
        self._n += 1
        direction = np.where(self._at_rest, self._direction, 0)[self._state]
        possible = (self._c > 0) & (direction * self._d >= 0) & ~self._anchored  # rest: one way
        if not possible.any():
            return None
        ratio = np.where(possible, self._d**2 / np.where(possible, self._c, 1.0), 0.0)
        best = int(np.argmax(ratio))
        if ratio[best] <= self.threshold or self._n[best] < self.options.min_updates:
            returned = self._return_to_rest(t, bank)
            return returned if returned is not None else self._estimate_at_rest(t, bank)
        jump, variance = self._d[best] / self._c[best], 1.0 / self._c[best]
        k, onset = int(self._state[best]), float(self._onset[best])
        state = self.states[k]
        before = float(bank.estimate()[0][state.index])
        if not _within_bound(state, before + jump):
            self._keep(self._state != k, bank)  # its hypotheses start afresh
            reason = (
                f"a jump by {jump:+.4g} at {onset:.1f} s not taken in: {before + jump:+.4g} is"
                f" beyond the state's physical bound ±{state.bound:g}"
            )
            return FaultEvent(t, state.name, float(ratio[best]), self.threshold, JUMP, reason)
        bank.accommodate(best, jump, variance)
        self._keep(self._state != k, bank)
        reason = f"jumped by {jump:+.4g} ± {np.sqrt(variance):.2g} at {onset:.1f} s"
        if state.rest is not None:
            x, p = bank.estimate()
            offset = x[state.index] - state.rest
            within = abs(offset) <= 3.0 * np.sqrt(p[state.index, state.index])
            back = within or state.leaves_rest * offset < 0  # past rest: it cannot be there
            if back:
                bank.condition(state.index, state.rest)
                reason += f", back to rest {state.rest:g}"
            self._at_rest[k] = back
        self._report(state, onset, before)
        return FaultEvent(t, state.name, float(ratio[best]), self.threshold, JUMP, reason)

    def explanation(self) -> Explanation | None:
        """The likeliest open hypothesis with ``min_updates`` updates if its likelihood ratio
        passes :attr:`return_threshold`, in either direction; ``None`` otherwise. A local
        failing its fault test while a jump elsewhere explains its innovations is not the one
        at fault (:class:`fusion.federated.FederatedFilter`)."""
        ready = (self._c > 0) & (self._n >= self.options.min_updates) & ~self._anchored
        if not ready.any():
            return None
        ratio = np.where(ready, self._d**2 / np.where(ready, self._c, 1.0), 0.0)
        best = int(np.argmax(ratio))
        if ratio[best] <= self.return_threshold:
            return None
        k = int(self._state[best])
        direction = self._direction[k] if self._at_rest[k] else 0
        return Explanation(
            self.states[k],
            float(ratio[best]),
            float(self._d[best] / self._c[best]),
            float(self._onset[best]),
            bool(direction * self._d[best] >= 0),
        )

    def unseen_jump(
        self,
        t: float,
        bank: FilterBank,
        signature: NDArray[np.float64],
        result: UpdateResult,
        source: str,
    ) -> FaultEvent | None:
        """A source's rejected update ``result`` (its ``signature``, H E) disputes the filter
        while others hold it: take in the jump since the source last agreed that explains it,
        if one within the state's bound and direction does (module docstring); the event."""
        anchors = np.flatnonzero(self._anchored & self._at_rest[self._state])
        excess = result.nis - result.whitened.size
        if not anchors.size or excess <= 0.0:
            return None
        g = whiten(result.whitening, signature[:, anchors])
        b, c = g.T @ result.whitened, np.einsum("ij,ij->j", g, g)
        x = bank.estimate()[0]
        best, best_ratio = -1, 0.0
        for n in range(anchors.size):
            k = int(self._state[anchors[n]])
            state, jump = self.states[k], excess / b[n] if b[n] != 0.0 else math.inf
            explains = b[n] ** 2 > excess * c[n] and self._direction[k] * b[n] >= 0
            within = _within_bound(state, x[state.index] + jump)
            if explains and within and b[n] ** 2 / c[n] > best_ratio:
                best, best_ratio = n, float(b[n] ** 2 / c[n])
        if best < 0:
            return None
        column = int(anchors[best])
        k = int(self._state[column])
        state, onset = self.states[k], float(self._onset[column])
        jump, variance = float(excess / b[best]), float(excess / b[best] ** 2)
        before = float(x[state.index])
        bank.accommodate(column, jump, variance)
        self._keep(self._state != k, bank)  # its hypotheses and anchor start afresh
        self._at_rest[k] = False
        self._report(state, onset, before)
        reason = (
            f"jumped unseen by {jump:+.4g} ± {np.sqrt(variance):.2g} since {onset:.1f} s,"
            f" when {source} last agreed with the filter (what explains its rejected update)"
        )
        return FaultEvent(t, state.name, best_ratio, excess, JUMP, reason)

    def _return_to_rest(self, t: float, bank: FilterBank) -> FaultEvent | None:
        """The return test: take in the likeliest return to rest of a held state, if its
        statistic passes :attr:`return_threshold` (see the module docstring)."""
        rest = self._rest[self._state]
        held = ~self._at_rest[self._state] & np.isfinite(rest) & (self._c > 0)
        held &= (self._n >= self.options.min_updates) & ~self._anchored
        if not held.any():
            return None
        mean = np.where(held, rest - self._held, 0.0)  # the jump back to rest, N(mean, v)
        v, c, d = self._held_variance, np.where(held, self._c, 1.0), self._d
        spread = 1.0 + c * v
        misfit = (d - mean * c) ** 2 / (c * spread)  # (Δ̂ − mean)² over its variance
        statistic = d**2 / c - misfit - np.log(spread)
        statistic = np.where(held & (misfit <= RETURN_MISFIT), statistic, -np.inf)
        best = int(np.argmax(statistic))
        if statistic[best] <= self.return_threshold:
            return None
        jump = (mean[best] / v[best] + d[best]) / (1.0 / v[best] + c[best])
        variance = 1.0 / (1.0 / v[best] + c[best])
        k, onset = int(self._state[best]), float(self._onset[best])
        state = self.states[k]
        before = float(bank.estimate()[0][state.index])
        bank.accommodate(best, jump, variance)
        self._set_at_rest(k, bank, onset, before)
        reason = f"back to rest {state.rest:g} at {onset:.1f} s (return test, was {before:+.4g})"
        ratio = float(statistic[best])
        return FaultEvent(t, state.name, ratio, self.return_threshold, JUMP, reason)

    def _estimate_at_rest(self, t: float, bank: FilterBank) -> FaultEvent | None:
        """Set a held state that may return on its own (:meth:`held_return`) back at rest once
        its estimate, after an update that sees it, is nearer rest than its own σ. Such a state
        decays towards rest, and follows the updates there, without a step for the return test
        to find; it would otherwise stay a small free scale error beside δk_D. Unseen (an
        odometer dropout), its decay alone would bring it within 1σ after τ·ln 2 and end a slip
        that the next reading still shows."""
        held = np.flatnonzero(~self._at_rest & (self._return_rate > 0) & self._seen)
        if not held.size:
            return None
        x, p = bank.estimate()
        for k in held:
            state = self.states[k]
            before, variance = float(x[state.index]), float(p[state.index, state.index])
            statistic = (before - self._rest[k]) ** 2 / variance
            if statistic >= 1.0:
                continue
            self._set_at_rest(int(k), bank, t, before)
            reason = f"back to rest {self._rest[k]:g} (its estimate {before:+.4g} within 1σ)"
            return FaultEvent(t, state.name, statistic, 1.0, JUMP, reason)
        return None

    def _set_at_rest(self, k: int, bank: FilterBank, onset: float, before: float) -> None:
        """State ``k`` found back at rest (held ``before`` until ``onset``): condition on it,
        drop its hypotheses and tell its owner."""
        state = self.states[k]
        bank.condition(state.index, float(self._rest[k]))
        self._keep(self._state != k, bank)
        self._at_rest[k] = True
        self._report(state, onset, before)

    def rest(self, t: float, bank: FilterBank, name: str) -> FaultEvent | None:
        """The plugin reports state ``name`` physically back at rest (a wheel standing still
        does not slip): if a jump had taken it away, restart it there at its prior σ."""
        k = self._by_name[name]
        state = self.states[k]
        if self._at_rest[k] or state.rest is None:
            return None
        x, p = bank.estimate()
        was, sigma = float(x[state.index]), float(np.sqrt(p[state.index, state.index]))
        bank.restart(state.index, state.rest, float(self._prior_variance[k]))
        self._keep(self._state != k, bank)
        self._at_rest[k] = True
        self._report(state, t, was)
        statistic = (was - state.rest) ** 2 / sigma**2
        reason = f"back to rest {state.rest:g} at a standstill (was {was:+.4g} ± {sigma:.2g})"
        return FaultEvent(t, state.name, statistic, self.threshold, JUMP, reason)

    def _report(self, state: JumpState, onset: float, before: float) -> None:
        if self.on_jump is not None:
            self.on_jump(state, onset, before)

    def _keep(self, keep: NDArray[np.bool_], bank: FilterBank) -> None:
        bank.keep_signatures(keep)
        self._state, self._onset = self._state[keep], self._onset[keep]
        self._held, self._held_variance = self._held[keep], self._held_variance[keep]
        self._d, self._c, self._n = self._d[keep], self._c[keep], self._n[keep]
        self._anchored = self._anchored[keep]
