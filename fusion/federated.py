"""The adaptive federated master (AFKF, seed 003 §4, eqs. 27–35; Carlson's federated filter).

Local filters are index sets cut from the one centralized layout (PSINS style): local i holds
the 15 common SINS error states c and the states p_i of its plugins, so it shares every model
with the centralized filter. With information-sharing factors β_i and the master's own share β_m,
Σ β_i + β_m = 1:

* time update of local i: its common states carry the share β_i of the information, so their
  covariance propagates as P_i,cc ← Φ_cc P_i,cc Φ_ccᵀ + Q_cc / β_i. Its own states p_i are held
  as a regression on the common ones, p = K c + ε with ε ~ N(0, P_p|c), and that conditional
  propagates as in the centralized filter: the local is brought to unit share (P_cc β_i, K and
  P_p|c kept), propagated with Φ[i, i] and Q[i, i], and brought back (P_cc / β_i, the new K and
  P_p|c kept). Scaling Q_cc alone would add (1/β_i − 1) K (P_cc − P_cc Φᵀ P⁻⁻¹ Φ P_cc) Kᵀ,
  P⁻ = Φ P_cc Φᵀ + Q_cc, to P_p|c at every step: at a shearer's 0.1 m/s the mounting angles
  regress on the velocity errors with K ≈ 10 rad per m/s, and four locals left them at 3–4°
  where the centralized filter has 0.2°, after which they wandered to 15°. Propagated this way,
  a local whose own states no other local holds keeps the centralized filter's joint
  distribution of (c, p_i) up to the 1/β_i of the c marginal, and fusion and reset below are
  exact for it;
* measurement updates of each local with its own plugins (eqs. 29–31, Joseph form);
* fusion of the common states over the healthy locals (and the master when β_m > 0), eq. 35:

      P_g = (Σ P_i,cc⁻¹)⁻¹,    x_g = P_g Σ P_i,cc⁻¹ x_i,c

  computed in a diagonally scaled space (scale s = √diag of one local's P_cc) so that states of
  very different units do not make the inversions lose precision;
* closed-loop feedback: x_g corrects the SINS, after which every estimate of the common states
  is re-referenced to the corrected SINS (x_i,c ← x_i,c − x_g);
* reset (mode ``fusion_reset``, eq. 34): x_i,c ← x_g and P_i,cc ← P_g / β_i. The local's own
  states follow as a Gaussian conditional, keeping K = P_pc P_cc⁻¹ and P_p|c = P_pp − K P_cp:
  x_p ← x_p + K (x_g − x_i,c), P_pc ← K P_i,cc, P_pp ← P_p|c + K P_i,cc Kᵀ (an exact identity
  when nothing changes, so one local with β = 1 reproduces the centralized filter). Mode
  ``no_reset`` only re-references (each local keeps its own information) and keeps the equal
  shares it started with: a local's P_i,cc was built under its share, and re-dividing the shares
  without a reset rescales it — with ``trace`` the locals that lean on no absolute sensor got
  shares near 1 and the others near 0, and a 300-s full_afkf run stopped on a covariance that
  was no longer positive definite. The configuration refuses ``no_reset`` with another rule.

Fusion period: by default at every covariance step that carried an update. After a step of
prediction only, in ``fusion_reset`` mode every member holds (x_g, P_g/β_i) propagated through
the same Φ with Q/β_i, and eq. 35 returns the propagated global estimate, so fusing there
changes nothing (a test fuses at every step and finds the same trajectory). ``fusion_period_s``
fuses less often instead.

Sharing factors (``sharing``): ``equal``; ``trace`` — β_i ∝ tr(P_i,cc), seed 003 eq. 33: the local
whose estimate is *less* precise receives the larger share, i.e. the tighter reset P_g/β_i, so its
next measurements move it less and it leans on the global solution, while a precise local gets a
looser reset and its own measurements dominate it; ``inverse_trace`` — β_i ∝ 1/tr(P_i,cc): the
precise local gets the larger share and the imprecise one a loose reset (it learns from its own
sensor again). The trace mixes units (m², (m/s)², rad²) and is dominated by position and
velocity, as in the seed. Shares are recomputed at each fusion from the healthy locals' P_cc *at
unit share*, tr(β_i P_i,cc): the stored P_i,cc carries the 1/β_i of the last reset, and a rule
fed its own share back (β_i' ∝ tr(P_g)/β_i after a reset) alternates from fusion to fusion with
a ratio that random-walks as the updates differ — on BROAD trial 30 one local's share reached
2·10⁻¹⁰ within 40 s and its covariance (P_g/β_i) overflowed.

Jump hypotheses (:mod:`fusion.jumps`): their signature columns ride along with each local's
estimate — propagated and updated with it, fused with the same weights (E_g = P_g Σ P_i,cc⁻¹
E_i,c), reset like it (own rows through the regression), never fed back. The cross-covariances
of stored errors (:mod:`fusion.kalman`) ride along in the same way: since ε_g = P_g Σ P_i,cc⁻¹
ε_i,c, C_g = P_g Σ P_i,cc⁻¹ C_i,c exactly. The engine stores an estimate after an instant's
fusion and reset, from the plugin's local at unit share; every other local and the master take
its common rows (own rows through their regression), which is exact as every member then holds
the fused estimate (an isolated local, which does not, is given them all the same). A local
applies a measurement whose noise carries a stored error in its decorrelated form
(:meth:`fusion.kalman.KalmanFilter.update`), so that the fusion stays exact. A jump taken in moves
every local at unit share; between update rounds, where every local holds the fused estimate,
that is exactly the centralized filter's x + E Δ̂, P + E σ²_Δ Eᵀ.

Fault isolation (:mod:`fusion.fault_detection`): an isolated local is excluded from the fusion but
still reset to the global estimate (with the mean share of the healthy locals), so its fault
monitor keeps judging its sensor against the solution the healthy sensors give: it is
re-admitted when the sensor agrees with that again for ``hold_s``. A local isolated and left to
filter on its own instead was dragged by the fault it had been isolated for (6.5° of heading by
20 s of magnetic interference on seed003-brokenline) and, once the fault was over, judged
against that drifted estimate of its own: re-admission waited for it to re-converge. In
``no_reset`` mode an isolated local is only re-referenced and re-initialized from the global
estimate on re-admission. If every local is isolated the fusion uses them all (there is
nothing better to feed back). A local whose updates hold the SINS (fix its velocity or position)
stays a member while isolated as long as no healthy local holds it (:data:`LAST_HOLDER`): a MEMS
SINS left to coast drifts further than any one sensor's fault pulls (harsh random worlds,
docs/design/2026-11-27-harsh-worlds.md).

A local whose failure a jump of another local's state explains (the jump detector's
:meth:`~fusion.jumps.JumpDetector.explanation`) is not isolated for it: a slipping wheel drags
the master, and the UWB ranges that disagree with the master are the sensor in the right. If
the detector may take the jump in, the local waits for its decision; if the jump runs against
a one-way state's direction (an under-reading wheel where the odometer's slips may only read
long, ``slip_sign: positive``), the state's owner is isolated instead, and it is not
re-admitted while that hypothesis stands (docs/design/2026-11-29-slip-ends-and-skids.md).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from fusion.config import FederatedOptions
from fusion.error_model import N_COMMON, POSITION, StateLayout
from fusion.fault_detection import ISOLATE, READMIT, FaultEvent, FaultMonitor
from fusion.filter_bank import COMMON
from fusion.jumps import Explanation
from fusion.kalman import KalmanFilter, UpdateResult, cholesky_solve
from fusion.lock import inflation_variances

LAST_HOLDER = "kept in the fusion while no other local holds the SINS"
"""Appended to an isolation's reason when the local is the only one that holds the SINS: it
stays a member (:meth:`FederatedFilter._members`) until another local holds it."""

OWN = slice(N_COMMON, None)


@dataclass
class LocalFilter:
    """One local filter: an index set of the centralized layout and its own Kalman filter."""

    name: str
    index: NDArray[np.intp]
    layout: StateLayout
    kf: KalmanFilter
    beta: float
    monitor: FaultMonitor
    reinitialize: bool = False
    last_held: float = -np.inf
    """Time of the local's last update that held the SINS (:meth:`FederatedFilter.record`)."""
    block: tuple[NDArray[np.intp], ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.block = np.ix_(self.index, self.index)  # this local's block of a full matrix

    def regression(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The own states' regression on the common ones, K = P_pc P_cc⁻¹, and their
        conditional covariance P_p|c = P_pp − K P_cp."""
        p = self.kf.P
        gain = (_spd_inverse(p[COMMON, COMMON]) @ p[COMMON, OWN]).T
        return gain, p[OWN, OWN] - gain @ p[COMMON, OWN]

    def reset(
        self,
        x_global: NDArray[np.float64],
        p_global: NDArray[np.float64],
        e_global: NDArray[np.float64],
    ) -> None:
        """Reset the common states to the global estimate, carrying the own states along.

        ``x_global`` is relative to the SINS *before* feedback; afterwards the local's common
        error estimate is zero. The signature and cross-covariance columns follow the same
        regression to ``e_global`` (they are not fed back).
        """
        x, e = self.kf.x, self.kf.columns
        regression = self.regression() if x.size > N_COMMON else None
        if regression is not None:
            x[OWN] += regression[0] @ (x_global - x[COMMON])
            e[OWN] += regression[0] @ (e_global - e[COMMON])
        self.kf.P = self._with_common_covariance(p_global / self.beta, regression)
        x[COMMON] = 0.0
        e[COMMON] = e_global

    def accommodate(self, column: int, jump: float, variance: float) -> None:
        """Take in a jump along signature column E at unit share: x ← x + E·jump and
        P ← P + E·variance·Eᵀ with the common marginal at full share (then back to 1/β_i)."""
        self.kf.P = self.unit_share_covariance()
        self.kf.take_in(column, jump, variance)
        self._set_common_covariance(self.kf.P[COMMON, COMMON] / self.beta)

    def predict(self, phi: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """Time update with this local's share of the common information (see the module
        docstring): P_cc/β_i and Q_cc/β_i, the own states' conditional as the centralized
        filter propagates it."""
        if self.kf.x.size == N_COMMON:
            self.kf.predict(phi, qd / self.beta)
            return
        self._set_common_covariance(self.kf.P[COMMON, COMMON] * self.beta)
        self.kf.predict(phi, qd)
        self._set_common_covariance(self.kf.P[COMMON, COMMON] / self.beta)

    def unit_share_covariance(self) -> NDArray[np.float64]:
        """This local's covariance with the common marginal at full share (P_cc β_i, K and
        P_p|c kept): after a reset, the centralized filter's covariance of (c, p_i)."""
        return self._with_common_covariance(self.kf.P[COMMON, COMMON] * self.beta)

    def _set_common_covariance(self, p_cc: NDArray[np.float64]) -> None:
        self.kf.P = self._with_common_covariance(p_cc)

    def _with_common_covariance(
        self,
        p_cc: NDArray[np.float64],
        regression: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    ) -> NDArray[np.float64]:
        """P with P_cc replaced, keeping the own states' regression K and conditional P_p|c
        (``regression``, when the caller has it already): P_pc ← K P_cc and
        P_pp ← P_p|c + K P_cc Kᵀ."""
        p = self.kf.P.copy()
        if p.shape[0] > N_COMMON:
            gain, conditional = self.regression() if regression is None else regression
            p[OWN, COMMON] = gain @ p_cc
            p[COMMON, OWN] = p[OWN, COMMON].T
            p[OWN, OWN] = conditional + gain @ p_cc @ gain.T
        p[COMMON, COMMON] = p_cc
        return p


@functools.cache
def _identity(n: int) -> NDArray[np.float64]:
    eye = np.eye(n)
    eye.flags.writeable = False
    return eye


def _spd_inverse(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of a (scaled) covariance; if rounding has made it indefinite, the inverse of its
    nearest positive definite matrix (eigenvalues floored at 1e-12 of the largest)."""
    sym = 0.5 * (p + p.T)
    inverse = cholesky_solve(sym, _identity(sym.shape[0]))
    if inverse is not None:
        return inverse
    w, v = np.linalg.eigh(sym)
    w = np.maximum(w, 1e-12 * w.max())
    return (v / w) @ v.T


def _fuse(
    locals_: Sequence[LocalFilter], master: KalmanFilter | None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Information fusion of the common states (eq. 35) in a diagonally scaled space; the
    signature and cross-covariance columns are fused with the same weights. Returns x_g, P_g and
    E_g (all columns)."""
    members = [(f.kf.x[COMMON], f.kf.columns[COMMON], f.kf.P[COMMON, COMMON]) for f in locals_]
    if master is not None:
        members.append((master.x, master.columns, master.P))
    scale = np.sqrt(np.diag(members[0][2]))
    scale2 = np.outer(scale, scale)
    info = np.zeros((N_COMMON, N_COMMON))
    vector = np.zeros((N_COMMON, 1 + members[0][1].shape[1]))
    estimates = np.empty_like(vector)
    for x, e, p in members:
        info_i = _spd_inverse(p / scale2)
        info += info_i
        estimates[:, 0], estimates[:, 1:] = x, e
        vector += info_i @ (estimates / scale[:, None])
    p_hat = _spd_inverse(info)
    fused = scale[:, None] * (p_hat @ vector)
    p_g = p_hat * scale2
    return fused[:, 0], 0.5 * (p_g + p_g.T), fused[:, 1:]


class FederatedFilter:
    """Local filters per plugin group, fused by a master with adaptive sharing and isolation.

    Parameters
    ----------
    layout
        The centralized layout (common states, then every plugin's blocks in plugin order).
    plugin_blocks
        Names of each plugin's state blocks, in plugin order.
    plugin_locals
        The local-filter name of each plugin (plugins with equal names share a local).
    options
        Mode, sharing rule, master share, fusion period and fault detection.
    confirm_updates
        Failing updates a local owning a state that may jump waits before its isolation
        (:class:`~fusion.fault_detection.FaultMonitor`; the jump detector's ``min_updates``).
    plugin_names
        Each plugin's name, for the fault report (default: its index).
    stored_errors
        Number of stored-error variables every filter tracks (:mod:`fusion.kalman`).
    """

    def __init__(
        self,
        layout: StateLayout,
        plugin_blocks: Sequence[Sequence[str]],
        plugin_locals: Sequence[str],
        options: FederatedOptions,
        confirm_updates: int = 0,
        plugin_names: Sequence[str] | None = None,
        stored_errors: int = 0,
    ) -> None:
        if not plugin_locals:
            raise ValueError("a federated filter needs at least one aiding plugin")
        self.layout = layout
        self.options = options
        self.faults: list[FaultEvent] = []
        names = list(dict.fromkeys(plugin_locals))
        share = (1.0 - options.master_share) / len(names)
        p0 = layout.initial_covariance()
        by_name = {b.name: b for b in layout.blocks}
        self.locals: list[LocalFilter] = []
        for name in names:
            members = [i for i, n in enumerate(plugin_locals) if n == name]
            blocks = [b for i in members for b in plugin_blocks[i]]
            index = np.concatenate(
                [np.arange(N_COMMON)] + [np.arange(layout.dim)[layout.slice(b)] for b in blocks]
            )
            local_layout = StateLayout(layout.blocks[:5] + tuple(by_name[b] for b in blocks))
            p = p0[np.ix_(index, index)]
            p[COMMON, COMMON] /= share
            self.locals.append(
                LocalFilter(
                    name,
                    index,
                    local_layout,
                    KalmanFilter(np.zeros(index.size), p, stored_errors),
                    share,
                    FaultMonitor(
                        name,
                        options.fault_detection,
                        confirm_updates if any(by_name[b].may_jump for b in blocks) else 0,
                    ),
                )
            )
        self._local_of_plugin = [names.index(n) for n in plugin_locals]
        self._plugin_names = list(plugin_names or map(str, range(len(plugin_locals))))
        self.master = (
            KalmanFilter(
                np.zeros(N_COMMON), p0[COMMON, COMMON] / options.master_share, stored_errors
            )
            if options.master_share > 0
            else None
        )
        self.explain: Callable[[], Explanation | None] | None = None
        """The jump detector's :meth:`~fusion.jumps.JumpDetector.explanation`, if any: asked
        before a local is isolated (:meth:`_excused`)."""
        self._last_fusion = -np.inf
        self._now = -np.inf
        self._position = layout.slice(POSITION)
        self._fused: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = (
            None
        )

    def predict(self, phi: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """Time update of every local (common process noise scaled by 1/β_i) and the master."""
        for f in self.locals:
            f.predict(phi[f.block], qd[f.block])
        if self.master is not None:
            self.master.predict(phi[COMMON, COMMON], qd[COMMON, COMMON] / self.options.master_share)
        self._fused = None

    def filter_of(self, plugin: int) -> tuple[StateLayout, KalmanFilter]:
        """The local filter of plugin ``plugin``."""
        f = self.locals[self._local_of_plugin[plugin]]
        return f.layout, f.kf

    def shared_covariance(self, plugin: int) -> NDArray[np.float64] | None:
        """A local that takes part in fusion and reset holds the fused estimate with its common
        covariance inflated by 1/β_i; its measurements are judged against the local at unit
        share, which is the centralized filter's covariance; so does an isolated local, which
        is reset without taking part in the fusion. A local in ``no_reset`` mode filters on its
        own: its own P."""
        if self.options.mode != "fusion_reset":
            return None
        return self.locals[self._local_of_plugin[plugin]].unit_share_covariance()

    def record(
        self, plugin: int, t: float, result: UpdateResult, suspect: bool, holds: bool = False
    ) -> None:
        """Feed the local's fault monitor; note isolation and re-admission events. ``holds``:
        the update was accepted and determines the velocity or the position (the engine's
        ``_holds``), which keeps the local a holder (:meth:`_members`) for a χ² window."""
        self._fused = None  # the local has just been updated
        self._now = t
        f = self.locals[self._local_of_plugin[plugin]]
        if holds:
            f.last_held = t
        source = self._plugin_names[plugin]
        event = f.monitor.observe(t, result.nis, result.dof, suspect, source, result.whitened)
        if event is not None and event.action == ISOLATE and self._excused(f, t):
            f.monitor.excuse()
            event = None
        elif event is not None and event.action == READMIT and self._blamed(f):
            f.monitor.keep_isolated(t)
            event = None
        if event is not None:
            if event.action == ISOLATE and self._holding(f) and f in self._members():
                event = replace(event, reason=f"{event.reason}; {LAST_HOLDER}")
            self.faults.append(event)
            f.reinitialize = event.action == READMIT

    def _explanation(self) -> Explanation | None:
        return self.explain() if self.explain is not None else None

    def _blamed(self, f: LocalFilter) -> bool:
        """Whether a jump against the direction of one of local ``f``'s states is still under
        way (its sensor is still at fault: no re-admission)."""
        explanation = self._explanation()
        return (
            explanation is not None
            and not explanation.allowed
            and explanation.state.block in f.layout
        )

    def _excused(self, f: LocalFilter, t: float) -> bool:
        """Whether a jump of another local's state explains local ``f``'s failure: a jump the
        detector may take in (``f`` waits for its decision), or one against a one-way state's
        direction (a wheel that under-reads: its owner is isolated instead of ``f``)."""
        explanation = self._explanation()
        if explanation is None:
            return False
        owner = next(g for g in self.locals if explanation.state.block in g.layout)
        if owner is f:
            return False
        if not explanation.allowed and not owner.monitor.isolated:
            reason = (
                f"{explanation.state.name} jumped by {explanation.jump:+.3g} at"
                f" {explanation.onset:.1f} s, against its direction: {f.name} disagrees with it"
            )
            self.faults.append(owner.monitor.isolate(t, explanation.ratio, math.nan, reason))
        return True

    def _holding(self, f: LocalFilter) -> bool:
        """Whether local ``f`` had an update that holds the SINS within the last χ² window."""
        return f.last_held >= self._now - self.options.fault_detection.window_s

    def in_fusion(self, plugin: int) -> bool:
        """Whether the plugin's local is a member of the fusion (not isolated)."""
        return self.locals[self._local_of_plugin[plugin]] in self._members()

    def signatures_of(self, plugin: int) -> NDArray[np.float64]:
        """The signature columns of the plugin's local."""
        return self.filter_of(plugin)[1].signatures

    def add_signatures(self, columns: NDArray[np.float64]) -> None:
        """Append columns to every local (its index set's rows) and the master."""
        for f in self.locals:
            f.kf.signatures = np.hstack([f.kf.signatures, columns[f.index]])
        if self.master is not None:
            self.master.signatures = np.hstack([self.master.signatures, columns[COMMON]])
        self._fused = None

    def keep_signatures(self, keep: NDArray[np.bool_]) -> None:
        """Drop the unmarked columns everywhere."""
        for kf in self._filters():
            kf.signatures = kf.signatures[:, keep]
        self._fused = None

    def accommodate(self, column: int, jump: float, variance: float) -> None:
        """Take the jump into every local and the master, each along its own signature column
        (fused, the global estimate moves by E_g·jump and P_g grows by E_g·variance·E_gᵀ); the
        innovations the monitors hold are explained by it and forgotten."""
        for f in self.locals:
            f.accommodate(column, jump, variance)
            f.monitor.forget()
        if self.master is not None:
            self.master.take_in(column, jump, variance / self.options.master_share)
        self._fused = None

    def store_error(self, plugin: int, columns: NDArray[np.intp], h: NDArray[np.float64]) -> None:
        """Store in the plugin's local (at unit share when it takes part in the resets); the
        other locals and the master take its common rows (module docstring) and its covariance
        of the stored errors (any local may later carry them)."""
        local = self.locals[self._local_of_plugin[plugin]]
        local.kf.store_error(columns, h, self.shared_covariance(plugin))
        common = local.kf.cross[COMMON][:, columns]
        for f in self.locals:
            if f is not local:
                f.kf.cross[COMMON, columns] = common
                if f.kf.dim > N_COMMON:
                    f.kf.cross[OWN, columns] = f.regression()[0] @ common
        for kf in self._filters():
            kf.stored_covariance = local.kf.stored_covariance.copy()
        if self.master is not None:
            self.master.cross[:, columns] = common
        self._fused = None

    def condition(self, index: int, value: float) -> None:
        """Condition the local that holds state ``index`` (a plugin state) on its value."""
        for kf, own in self._holders(index):
            kf.condition(own, value)
        self._fused = None

    def restart(self, index: int, value: float, variance: float) -> None:
        """Restart plugin state ``index`` in the local that holds it (a plugin state is
        uncorrelated with the common states afterwards, so the local's share needs no care)."""
        for kf, own in self._holders(index):
            kf.restart(own, value, variance)
        self._fused = None

    def _holders(self, index: int) -> Iterator[tuple[KalmanFilter, int]]:
        """The local filters holding state ``index`` of the full layout, and its index there."""
        for f in self.locals:
            where = np.flatnonzero(f.index == index)
            if where.size:
                yield f.kf, int(where[0])

    def _filters(self) -> list[KalmanFilter]:
        return [f.kf for f in self.locals] + ([self.master] if self.master is not None else [])

    def fusion_due(self, t: float, updated: bool) -> bool:
        """After every covariance step that carried an update, or every ``fusion_period_s``."""
        period = self.options.fusion_period_s
        if period is None:
            return updated
        return t - self._last_fusion >= period - 1e-9

    def _members(self) -> list[LocalFilter]:
        healthy = [f for f in self.locals if not f.monitor.isolated and not f.reinitialize]
        if not any(self._holding(f) for f in healthy):  # the isolated holders stay in
            healthy += [
                f
                for f in self.locals
                if f.monitor.isolated and self._holding(f) and not f.reinitialize
            ]
        return healthy or [f for f in self.locals if not f.reinitialize] or self.locals

    def _global(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The fused estimate (eq. 35) of the current members, computed once per change: the
        output, the smoother and the feedback all ask for it at the same step."""
        return self._fusion()[:2]

    def _fusion(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        if self._fused is None:
            self._fused = _fuse(self._members(), self.master)
        return self._fused

    def feedback(self, t: float) -> NDArray[np.float64]:
        """Fuse, update the shares, reset or re-reference every local; return x_g."""
        self._last_fusion = t
        members = self._members()
        x_g, p_g, e_g = self._fusion()
        if self.options.mode == "fusion_reset":
            self._update_shares(members)
        rejoined = False
        for f in self.locals:
            if self.options.mode == "fusion_reset":
                if f not in members:  # isolated: held at the global estimate, not fused
                    f.beta = float(np.mean([m.beta for m in members]))
                rejoined |= f.reinitialize
                f.reinitialize = False
                f.reset(x_g, p_g, e_g)
            elif f.reinitialize:
                f.beta = float(np.mean([m.beta for m in members]))
                f.reset(x_g, p_g, e_g)
                f.reinitialize = False
                rejoined = True
            else:
                f.kf.x[COMMON] -= x_g
        if self.master is not None:
            if self.options.mode == "fusion_reset":
                self.master.x[:] = 0.0
                self.master.P = p_g / self.options.master_share
                self.master.columns = e_g.copy()
            else:
                self.master.x -= x_g
        # Reset or re-referenced, the same members fuse to (0, P_g); a re-admitted local changes
        # the members.
        self._fused = None if rejoined else (np.zeros(N_COMMON), p_g, e_g)
        return x_g

    def _update_shares(self, members: Sequence[LocalFilter]) -> None:
        rule = self.options.sharing
        traces = np.array([f.beta * np.trace(f.kf.P[COMMON, COMMON]) for f in members])
        if rule == "trace":
            weights = traces
        elif rule == "inverse_trace":
            weights = 1.0 / traces
        else:
            weights = np.ones(len(members))
        shares = (1.0 - self.options.master_share) * weights / weights.sum()
        for f, beta in zip(members, shares, strict=True):
            f.beta = float(beta)

    def restart_common(self, indices: NDArray[np.intp], covariance: NDArray[np.float64]) -> None:
        """Restart common states in every local (at its share: P/β_i) and the master."""
        for f in self.locals:
            f.kf.restart_block(indices, covariance / f.beta)
        if self.master is not None:
            self.master.restart_block(indices, covariance / self.options.master_share)
        self._fused = None

    def inflate_common(self, factor: float) -> None:
        """Add the inflation of the fused common variances by ``factor``
        (:func:`fusion.lock.inflation_variances`) as uncorrelated process noise: an identity
        time update, of which every local and the master take their shares, as the centralized
        filter takes it at once."""
        dim = self.layout.dim
        noise = np.zeros((dim, dim))
        noise[COMMON, COMMON] = np.diag(
            inflation_variances(np.diagonal(self.common_covariance()), factor)
        )
        self.predict(np.eye(dim), noise)

    def change_coordinates(self, a: NDArray[np.float64]) -> None:
        """Every local in its own index set and the master in the common states (A mixes only
        common states, so each one's block of A is its own change of coordinates; the shares
        scale P and commute with it)."""
        for f in self.locals:
            f.kf.change_coordinates(a[f.block])
        if self.master is not None:
            self.master.change_coordinates(a[COMMON, COMMON])
        self._fused = None

    def common_covariance(self) -> NDArray[np.float64]:
        """The fused covariance of the common states (eq. 35)."""
        return self._global()[1]

    def position_covariance(self) -> NDArray[np.float64]:
        """Position block of the fused covariance (no side effects)."""
        p_g = self._global()[1]
        return p_g[self._position, self._position].copy()

    @property
    def smoothing_dim(self) -> int:
        """The fused common states are smoothed (see :mod:`fusion.smoother`)."""
        return N_COMMON

    def smoothing_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The fused common-state estimate (eq. 35)."""
        return self._global()

    def smoothing_transition(self, phi: NDArray[np.float64]) -> NDArray[np.float64]:
        """Φ of the common states."""
        return phi[COMMON, COMMON]

    def estimate(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The global estimate over the full layout.

        Common states: the fusion. Each local's own states: its estimate, correlated with the
        common states through its regression K_i (P_pc = K_i P_g, P_pq = K_i P_g K_jᵀ across
        locals) with its own conditional covariance.
        """
        x_g, p_g = self._global()
        x = np.zeros(self.layout.dim)
        p = np.zeros((self.layout.dim, self.layout.dim))
        x[COMMON], p[COMMON, COMMON] = x_g, p_g
        gains: list[tuple[NDArray[np.intp], NDArray[np.float64]]] = []
        for f in self.locals:
            own = f.index[N_COMMON:]
            if own.size == 0:
                continue
            gain, conditional = f.regression()
            xl = f.kf.x
            x[own] = xl[OWN] + gain @ (x_g - xl[COMMON])
            p[np.ix_(own, own)] = conditional
            p[own, :N_COMMON] = gain @ p_g
            p[:N_COMMON, own] = p[own, :N_COMMON].T
            for other, other_gain in gains:
                p[np.ix_(own, other)] = gain @ p_g @ other_gain.T
                p[np.ix_(other, own)] = p[np.ix_(own, other)].T
            p[np.ix_(own, own)] += gain @ p_g @ gain.T
            gains.append((own, gain))
        return x, p
