"""Rauch–Tung–Striebel smoothing that is correct under closed-loop feedback (seed 000 §3.4).

The trap. With feedback the forward filter resets its common error states to zero after every
correction, so the stored error estimates are relative to a nominal trajectory that keeps
moving; the textbook RTS run on them smooths the wrong quantity.

The derivation used here. Call e_k the error of the SINS state *before* the feedback of step k
(k indexes the filter's steps: covariance steps and aiding epochs). The forward filter holds
the prior x_k⁻, P_k⁻ and, after the updates of step k, the posterior x_k⁺, P_k⁺ of e_k; it then
feeds back u_k (the common states of x_k⁺; zero for open-loop plugin states), so the SINS after
feedback carries the error e_k − u_k, and the linearized dynamics between steps give

    e_{k+1} = Φ_k (e_k − u_k) + w_k,        x_{k+1}⁻ = Φ_k (x_k⁺ − u_k)

— a linear system with a known input −Φ_k u_k. The RTS recursion for such a system is the usual
one because the input cancels in the difference e_{k+1} − x_{k+1}⁻ (eqs. 28–31 of seed 000 in
this reference):

    C_k = P_k⁺ Φ_kᵀ (P_{k+1}⁻)⁻¹
    ê_k = x_k⁺ + C_k (ê_{k+1} − x_{k+1}⁻),      P_k^s = P_k⁺ + C_k (P_{k+1}^s − P_{k+1}⁻) C_kᵀ

started from ê_N = x_N⁺, P_N^s = P_N⁺. The smoothed error of the SINS state as output (after
feedback) is d_k = ê_k − u_k, removed like a feedback; σ comes from P_k^s. Everything the
recursion reads is what the forward filter stored — priors, posteriors, Φ and the feedback
actually applied — nothing is recomputed (Stone Soup's principle).

Federated filter: the smoother runs on the fused global estimate of the 15 common states (the
fused prior before and the fused posterior after each update round, Φ_cc). This is an
approximation: it treats the fused estimate as if it came from a centralized filter over the
common states alone, ignoring the locals' own states and the suboptimality of the fusion.

Folding between output epochs. Written as an affine map, one backward step is

    ê_k = a_k + C_k ê_{k+1},             a_k = x_k⁺ − C_k x_{k+1}⁻
    P_k^s = B_k + C_k P_{k+1}^s C_kᵀ,     B_k = P_k⁺ − C_k P_{k+1}⁻ C_kᵀ = P_k⁺ − M_k C_kᵀ

with M_k = P_k⁺ Φ_kᵀ (so C_k = M_k (P_{k+1}⁻)⁻¹). Affine maps compose, so the steps between
output epoch j and the next output epoch m fold into one map ê_j = A_j + G_j ê_m,
P_j^s = B̄_j + G_j P_m^s G_jᵀ, built in the forward pass as each step arrives
(A ← A + G a_k, B̄ ← B̄ + G B_k Gᵀ, G ← G C_k, starting from 0, 0, I at j). Only one row per
output epoch is kept — (A_j, G_j, B̄_j, u_j) — instead of one per step: an 8-hour shift with a
UWB range every 7 ms has 14 filter steps per 0.1-s output epoch. The backward pass then walks
the output epochs only, from ê_N = x_N⁺, P_N^s = P_N⁺ at the window's last step.

Where the linear model breaks. A step whose prior and posterior are not one filter's — a
federated local isolated or re-admitted (the fused estimate then comes from other members), a
jump taken in — is no Markov step of one system: the engine closes the smoothing window before
it, so that no window spans it (a window smoothed across an isolation returned a NaN σ, and
across an inconsistent pass a σ of centimetres where the forward pass had metres). And every
smoothed position is checked against the forward one (:func:`plausible_correction`): a
correction the forward statistics do not allow keeps the forward estimate, counted in
:attr:`WindowedSmoother.rejected`.

Where smoothing gains nothing one can tell. A window whose only news is weak (a pass with no
surveyed point, an encoder's scale seen through the millimetres per second left at one stop)
moves the track by little against what the smoother still does not know: by the model's own
statistics the smoothed track is then as likely worse than the forward one as better. A window's
horizontal track and its height (:data:`BLOCKS`) each replace their forward ones only when their
own expected gain exceeds ``smoother.significance_sigma`` standard deviations of that gain
(:class:`SmoothingGain`, exact over the window's lag covariances); the others keep the forward
estimates, counted in :attr:`WindowedSmoother.kept_forward`. The two are told apart because a
height the smoother knows well (a floor, a stop) would otherwise carry a horizontal correction
that is a coin toss. They are the output frame's axes (the origin's east-north plane and its
up): a kept block's output coordinates are the forward ones exactly. (A height correction along
the local vertical, a distance d from the origin, would move them by Δh·d/R⊕.)

Memory: a :class:`StepStore` keeps the rows of one smoothing window in chunks; chunks beyond a
memory budget are ``.npy`` files in a temporary directory (spill to disk). Online smoothing (at
each face end) keeps only the pass being smoothed.
"""

from __future__ import annotations

import shutil
import tempfile
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from fusion.kalman import cholesky_solve
from fusion.rows import RowBuffer
from fusion.strapdown import NAV_SIZE, remove_errors

CHUNK = 2048
POSITION = slice(6, 9)


@dataclass(frozen=True)
class Block:
    """A part of the smoothed track that replaces its forward one on its own evidence."""

    name: str
    position_axes: tuple[int, ...]
    """Its axes of the ENU position error: what its :class:`SmoothingGain` scores."""
    errors: tuple[int, ...]
    """The components of the error (velocity, attitude, position) it corrects."""


BLOCKS = (
    Block("horizontal", (0, 1), (0, 1, 3, 4, 5, 6, 7)),
    Block("vertical", (2,), (2, 8)),
)
"""The horizontal track (with the attitude, whose heading moves it) and the height: two products
(the face line and the horizon) whose smoothing gains are told apart, so that a confident gain in
one never carries a loss in the other."""
CORRECTION_PROBABILITY = 0.9999
CORRECTION_THRESHOLD = float(chi2.ppf(CORRECTION_PROBABILITY, 3))
"""χ²₃ bound of a plausible smoothing correction (:func:`plausible_correction`)."""
Rows = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
"""A window's or a run's output rows: times, navigation states, output positions, position
covariances."""
ToOutput = Callable[[NDArray[np.float64]], NDArray[np.float64]]
"""``navs (k, NAV_SIZE) → positions (k, 3)`` in the output frame, a point's bits independent of
the rows beside it (:meth:`fusion.earth.LocalFrame.to_enu`)."""
ToStandard = Callable[[NDArray[np.float64]], NDArray[np.float64]]
"""``nav → T``: the standard error is ``T x`` at the nominal state ``nav``, for a filter that keeps
another error (:mod:`fusion.invariant_error`)."""
FIELDS = ("offset", "gain", "covariance", "feedback")
MATRICES = ("gain", "covariance")
Segment = dict[str, NDArray[np.float64]]


class StepStore:
    """The RTS recursion of one smoothing window, folded between output epochs as the forward
    filter stores its steps (see the module docstring).

    One row per output epoch holds the fields of :data:`FIELDS` side by side: the folded map's
    offset A_j, gain G_j and covariance B̄_j, and the feedback u_j applied at that epoch. Rows are
    kept in chunks of :data:`CHUNK`; completed chunks beyond the memory budget are written to a
    temporary directory and read back one at a time by :meth:`backward`.

    Parameters
    ----------
    dim
        Dimension of the smoothed state.
    memory_budget_mb
        In-memory size beyond which completed chunks are written to disk.
    """

    def __init__(self, dim: int, memory_budget_mb: float = 512.0) -> None:
        self.dim = dim
        self.budget = memory_budget_mb * 1e6
        widths = [dim * dim if f in MATRICES else dim for f in FIELDS]
        ends = np.cumsum(widths)
        self._columns = {f: slice(e - w, e) for f, w, e in zip(FIELDS, widths, ends, strict=True)}
        self._width = int(ends[-1])
        self._chunks: list[NDArray[np.float64] | Path] = []
        self.t = array("d")
        self.n = 0  # steps stored
        self.n_rows = 0  # output epochs stored
        self._bytes = 0.0
        self._spill: Path | None = None
        self._latest: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._open: Segment | None = None

    @property
    def spilled(self) -> bool:
        """Whether some chunks live on disk."""
        return self._spill is not None

    @property
    def last_posterior(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """x_N⁺, P_N⁺ of the latest step: where the backward recursion starts."""
        assert self._latest is not None
        return self._latest

    def append(
        self,
        t: float,
        phi: NDArray[np.float64],
        prior: tuple[NDArray[np.float64], NDArray[np.float64]],
        posterior: tuple[NDArray[np.float64], NDArray[np.float64]],
        feedback: NDArray[np.float64],
        output: bool,
    ) -> None:
        """Fold one step — Φ from the previous step, prior, posterior, applied feedback — into
        the open segment; an output epoch closes it and opens the next."""
        if self._open is not None:
            self._fold(phi, prior)
        if output:
            self.close_segment()
            dim = self.dim
            self._open = {
                "offset": np.zeros(dim),
                "gain": np.eye(dim),
                "covariance": np.zeros((dim, dim)),
                "feedback": np.array(feedback, dtype=float),
            }
            self.t.append(t)
        self._latest = (np.array(posterior[0], dtype=float), np.array(posterior[1], dtype=float))
        self.n += 1

    def _fold(
        self, phi: NDArray[np.float64], prior: tuple[NDArray[np.float64], NDArray[np.float64]]
    ) -> None:
        """Compose the open segment's map with the backward step from the latest step k to the
        step k + 1 arriving (``phi`` = Φ_k, ``prior`` = x_{k+1}⁻, P_{k+1}⁻)."""
        assert self._open is not None and self._latest is not None
        x_post, p_post = self._latest
        x_prior, p_prior = prior
        m = p_post @ phi.T
        gain = _solve_psd(p_prior, m.T).T
        seg = self._open
        g = seg["gain"]
        seg["offset"] += g @ (x_post - gain @ x_prior)
        seg["covariance"] += g @ (p_post - m @ gain.T) @ g.T
        seg["gain"] = g @ gain

    def close_segment(self) -> None:
        """Store the open segment as a row (its map then ends at the latest step)."""
        seg = self._open
        if seg is None:
            return
        self._open = None
        seg["covariance"] = 0.5 * (seg["covariance"] + seg["covariance"].T)
        i = self.n_rows % CHUNK
        if i == 0:
            self._chunks.append(np.empty((CHUNK, self._width)))
        row = self._chunks[-1][i]  # type: ignore[index]
        for field, value in seg.items():
            row[self._columns[field]] = value.ravel()
        self.n_rows += 1
        if self.n_rows % CHUNK == 0:
            self._retire()

    def _retire(self) -> None:
        """Keep the chunk just completed in memory while the budget allows, else write it out."""
        chunk = self._chunks[-1]
        assert isinstance(chunk, np.ndarray)
        if self._bytes + chunk.nbytes <= self.budget:
            self._bytes += chunk.nbytes
            return
        if self._spill is None:
            self._spill = Path(tempfile.mkdtemp(prefix="fusion-smoother-"))
        path = self._spill / f"{len(self._chunks) - 1}.npy"
        np.save(path, chunk)
        self._chunks[-1] = path

    def _row(self, block: NDArray[np.float64], i: int) -> Segment:
        n = self.dim
        row = block[i]
        return {
            f: row[c].reshape(n, n) if f in MATRICES else row[c] for f, c in self._columns.items()
        }

    def backward(self) -> Iterator[tuple[int, Segment]]:
        """Every stored row, last first, as ``(j, fields)``; a spilled chunk is read when the
        recursion reaches it and released after."""
        for index in range(len(self._chunks) - 1, -1, -1):
            chunk = self._chunks[index]
            block = np.load(chunk) if isinstance(chunk, Path) else chunk
            count = min(CHUNK, self.n_rows - index * CHUNK)
            for i in range(count - 1, -1, -1):
                yield index * CHUNK + i, self._row(block, i)

    def close(self) -> None:
        """Free the memory and delete any spill files."""
        self._chunks.clear()
        if self._spill is not None:
            shutil.rmtree(self._spill, ignore_errors=True)
            self._spill = None


def _solve_psd(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a⁻¹ b`` for a covariance ``a``; a singular one (a state with zero prior and no process
    noise, e.g. a datasheet figure of 0) is solved in the least-squares sense."""
    solution = cholesky_solve(a, b)
    if solution is not None:
        return solution
    return np.asarray(np.linalg.lstsq(a, b, rcond=None)[0], dtype=np.float64)


def rts(
    store: StepStore,
) -> Iterator[tuple[int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]]:
    """Smoothed errors d_j = ê_j − u_j of the fed-back state, and P_j^s, at the output epochs:
    ``(j, d_j, P_j^s, G_j)``, last epoch first; ``G_j`` maps the next output epoch's smoothed
    error (the window's last step's for the last epoch) to this one's, so that the smoothed
    errors' cross-covariance is ``Cov(ε_j, ε_m) = G_j P_m^s`` for consecutive epochs j < m.

    The recursion starts at the window's last step (where the smoothed estimate is the filtered
    one) and walks the folded rows back to the first output epoch. Yielded one at a time, so a
    caller that keeps only the position block never holds every P_j^s of a pass.
    """
    store.close_segment()
    e, p = store.last_posterior
    for j, row in store.backward():
        g = row["gain"]
        e = row["offset"] + g @ e
        p = row["covariance"] + g @ p @ g.T
        p = 0.5 * (p + p.T)
        yield j, e - row["feedback"], p, g


def plausible_correction(
    correction: NDArray[np.float64],
    smoothed: NDArray[np.float64],
    forward: NDArray[np.float64],
) -> bool:
    """Whether a smoothed position is one the forward filter's own statistics allow.

    For a filter whose model holds, the smoothed estimate knows at least what the filtered one
    does (``P_f − P_s`` is positive semi-definite) and the correction it applies,
    ``x_s − x_f``, has that covariance. A correction beyond the χ²₃ quantile
    :data:`CORRECTION_PROBABILITY` of it, a smoothed covariance larger than the forward one or a
    non-finite value says the window held steps the smoother's linear model did not describe
    (a sensor that should have been isolated earlier, a divergence): the forward estimate is
    kept for that epoch. On the open-loop problem nothing is rejected (the smoother equals
    filterpy's RTS, ``tests/test_smoother.py``).
    """
    if not (np.all(np.isfinite(correction)) and np.all(np.isfinite(smoothed))):
        return False
    gained = 0.5 * (forward - smoothed + (forward - smoothed).T)
    values, vectors = np.linalg.eigh(gained)
    scale = max(float(np.trace(forward)), 1e-30)
    if values.min() < -1e-6 * scale or np.linalg.eigvalsh(smoothed).min() < -1e-9 * scale:
        return False
    along = vectors.T @ correction
    keep = values > 1e-9 * scale
    if np.any(np.abs(along[~keep]) > 1e-6 * np.sqrt(scale)):
        return False  # a correction where the smoother gained nothing
    return float(np.sum(along[keep] ** 2 / values[keep])) <= CORRECTION_THRESHOLD


class SmoothingGain:
    """What a window's smoothed positions gain over its forward ones, by the smoother's own
    statistics, accumulated over the backward pass.

    With ``d_j = x_s − x_f`` the position correction at output epoch j and ``ε_j`` the smoothed
    error, the forward error is ``ε_j − d_j`` and the window's summed squared position error
    changes by ``Δ = Σ_j (2 ε_jᵀ d_j − |d_j|²)``. Under the smoother's model ``ε`` is zero-mean
    and independent of the data that fixed ``d``, so ``E[Δ] = −Σ_j |d_j|²`` (:attr:`expected`) and
    ``Var Δ = 4 Var(Σ_j D_jᵀ ε_j)`` with ``D_j = T_jᵀ Sᵀ d_j`` (``S`` the position rows, ``T_j``
    the conversion to the standard error). With the lag covariances ``Cov(ε_j, ε_m) = G_j P_m^s``
    that variance is one backward recursion (:meth:`add`):

        w_j = P_j^s D_j + G_j w_m,        Var = Σ_j D_jᵀ (P_j^s D_j + 2 G_j w_m)

    Where the corrections are small against what the smoother still does not know, the two
    tracks are a coin toss by the model's own account (a pass whose only news is the noise of
    one stop, an encoder's scale seen through millimetres per second): :meth:`significant`.
    """

    def __init__(self, dim: int, axes: tuple[int, ...] = (0, 1, 2)) -> None:
        self.axes = list(axes)
        """The position axes (east, north, up) whose corrections it scores."""
        self.expected = 0.0
        """The expected reduction of the summed squared position error, ``Σ_j |d_j|²``."""
        self.variance = 0.0
        """``Var(Σ_j D_jᵀ ε_j)``; Δ's standard deviation is twice its root."""
        self._w = np.zeros(dim)

    def skip(self, fold: NDArray[np.float64]) -> None:
        """An epoch that keeps its forward position (``D_j = 0``): ``w_j = G_j w_m``."""
        self._w = fold @ self._w

    def add(
        self,
        correction: NDArray[np.float64],
        covariance: NDArray[np.float64],
        fold: NDArray[np.float64],
        position_rows: NDArray[np.float64] | None,
    ) -> None:
        """Epoch j (walking backward): its position correction ``d_j`` (standard error), its
        ``P_j^s`` and the folded gain ``G_j`` (:func:`rts`) in the filter's coordinates, and
        ``S T_j``, the position rows of the conversion (``None``: the identity). Only the
        correction's components on :attr:`axes` count."""
        scored = np.zeros(3)
        scored[self.axes] = correction[self.axes]
        correction = scored
        self.expected += float(correction @ correction)
        if position_rows is None:
            weights = np.zeros(self._w.size)
            weights[POSITION] = correction
        else:
            weights = position_rows.T @ correction
        later = fold @ self._w
        own = covariance @ weights
        self.variance += float(weights @ (own + 2.0 * later))
        self._w = own + later

    def significant(self, sigmas: float) -> bool:
        """Whether the expected gain is at least ``sigmas`` standard deviations of ``Δ``."""
        return self.expected >= sigmas * 2.0 * float(np.sqrt(max(self.variance, 0.0)))


class WindowedSmoother:
    """Forward-pass bookkeeping for smoothing over windows that end at given times.

    With no window ends the whole recording is one window (fixed-interval smoothing); with the
    face-end times of a pass it smooths each pass as soon as the shearer reaches the end
    (seed 000 Fig. 4), keeping only that pass in memory.

    Parameters
    ----------
    dim
        Dimension of the smoothed state.
    window_end_due
        Called with each step's time (after the step is stored): whether a window closes there.
    memory_budget_mb
        Per-window in-memory budget before spilling to disk.
    to_output
        The output positions of navigation states: where the kept blocks are held.
    to_standard
        Where the filter's error is not the standard one: its conversion at an output epoch's
        nominal state (the recursion runs in the filter's own coordinates, as it stored them).
    """

    def __init__(
        self,
        dim: int,
        window_end_due: Callable[[float], bool],
        memory_budget_mb: float,
        to_output: ToOutput,
        to_standard: ToStandard | None = None,
        significance_sigma: float = 0.0,
    ) -> None:
        self.dim = dim
        self.to_output = to_output
        self.significance_sigma = significance_sigma
        self.to_standard = to_standard
        self.window_end_due = window_end_due
        self.budget = memory_budget_mb
        self.store = StepStore(dim, memory_budget_mb)
        self._navs = RowBuffer((NAV_SIZE,))
        self.t = RowBuffer()
        self.nav = RowBuffer((NAV_SIZE,))
        self.position = RowBuffer((3,))
        self.covariance = RowBuffer((3, 3))
        self._forward = RowBuffer((3, 3))
        self.peak_steps = 0
        self.spilled = False
        self.rejected = 0
        """Output epochs whose smoothed position failed :func:`plausible_correction` and kept
        the forward estimate."""
        self.windows = 0
        self.unresolved_windows = 0
        """Windows in which no block's gain was :meth:`SmoothingGain.significant`: they keep
        the forward estimates."""
        self.kept_forward = {block.name: 0 for block in BLOCKS}
        """Per :data:`BLOCKS` entry, the windows in which that block kept its forward track."""

    def step(
        self,
        t: float,
        phi: NDArray[np.float64],
        prior: tuple[NDArray[np.float64], NDArray[np.float64]],
        posterior: tuple[NDArray[np.float64], NDArray[np.float64]],
        feedback: NDArray[np.float64],
        nav_after: NDArray[np.float64] | None,
    ) -> Rows | None:
        """Store a step (``nav_after`` at output epochs); when it closes a window, return that
        window's smoothed rows."""
        self.store.append(t, phi, prior, posterior, feedback, nav_after is not None)
        if nav_after is not None:
            self._navs.append(nav_after)
            covariance = posterior[1]
            if self.to_standard is None:
                self._forward.append(covariance[POSITION, POSITION])
            else:
                rows = self.to_standard(nav_after)[POSITION]
                self._forward.append(rows @ covariance @ rows.T)
        return self.close_window() if self.window_end_due(t) and self.store.n > 1 else None

    def close_window(self) -> Rows:
        """Smooth the stored window, keep its output rows, start an empty window; return the
        window's :data:`Rows`."""
        store = self.store
        self.peak_steps = max(self.peak_steps, store.n)
        self.spilled |= store.spilled
        times = np.array(store.t)
        navs = self._navs.take()
        positions = self.to_output(navs)
        covariances = self._forward.take().copy()
        if times.size:
            self.windows += 1
            if not self._smooth(store, navs, positions, covariances):
                self.unresolved_windows += 1
        self.t.extend(times)
        self.nav.extend(navs)
        self.position.extend(positions)
        self.covariance.extend(covariances)
        store.close()
        self.store = StepStore(self.dim, self.budget)
        return times, navs, positions, covariances

    def _smooth(
        self,
        store: StepStore,
        navs: NDArray[np.float64],
        positions: NDArray[np.float64],
        covariances: NDArray[np.float64],
    ) -> bool:
        """Run the backward pass over ``store``; for each :data:`BLOCKS` entry whose gain is
        significant, correct ``navs``, replace its axes of ``positions`` and its block of
        ``covariances`` (all forward on entry) in place. Whether any block was smoothed."""
        epochs, errors, smoothed = RowBuffer(), RowBuffer((9,)), RowBuffer((3, 3))
        gains = [SmoothingGain(self.dim, block.position_axes) for block in BLOCKS]
        for j, d, p, fold in rts(store):
            rows = None if self.to_standard is None else self.to_standard(navs[j])[:9]
            error = d[:9] if rows is None else rows @ d
            position = rows[POSITION] if rows is not None else None
            p_pos = p[POSITION, POSITION] if position is None else position @ p @ position.T
            if not plausible_correction(error[POSITION], p_pos, covariances[j]):
                self.rejected += 1
                for gain in gains:
                    gain.skip(fold)
                continue
            for gain in gains:
                gain.add(error[POSITION], p, fold, position)
            epochs.append(j)
            errors.append(error)
            smoothed.append(p_pos)
        chosen = [gain.significant(self.significance_sigma) for gain in gains]
        for block, smooth in zip(BLOCKS, chosen, strict=True):
            self.kept_forward[block.name] += not smooth
        if not any(chosen):
            return False
        index = epochs.take().astype(np.intp)
        mask = np.zeros(9)
        kept = np.zeros(3, dtype=bool)
        for block, smooth in zip(BLOCKS, chosen, strict=True):
            if smooth:
                mask[list(block.errors)] = 1.0
            else:
                kept[list(block.position_axes)] = True
        for j, dj in zip(index, errors.take() * mask, strict=True):
            remove_errors(navs[j], dj[0:3], dj[3:6], dj[6:9])
        positions[np.ix_(index, ~kept)] = self.to_output(navs[index])[:, ~kept]
        mixed = smoothed.take()
        # A kept block's error is ε_s − d with Cov(ε_s, d) = 0: its own block is the forward
        # one, its cross-covariance with a smoothed block the smoothed one.
        if kept.any():
            part = np.ix_(np.arange(index.size), kept, kept)
            mixed[part] = covariances[index][part]
        covariances[index] = mixed
        return True

    def take_rows(self) -> Rows:
        """All smoothed rows, without a copy; the smoother's row buffers are left empty."""
        return self.t.take(), self.nav.take(), self.position.take(), self.covariance.take()
