"""CPOEM, the closing path optimal estimation model (seed 000 §2.2, eqs. 5–8, 21–24, Figs. 3–4).

A longwall shearer cuts the same face again and again, each cutting cycle on the AFC line of the
previous one pushed forward by the web depth d. *Optimal points* every Δ metres of odometer
mileage along the face are recorded in one cycle and predicted for the next (eq. 6)::

    p_{i,j+1} = p_{i,j} + C_b^n C_m^b D,    D = [d, 0, 0]ᵀ (eq. 5)

and the prediction is applied as a position measurement of the SINS (eqs. 8, 21–22); no point
is measured in the first cycle (eq. 24: there is nothing to predict from).

Measurement
-----------
With ``C̃_b^n = (I − φ×) C_b^n`` the advance direction ``u = C̃_b^n e_x`` (the m-frame is taken as
the body frame, the seed's ``C̃_b^m = I``) moves as ``u(φ) = u + (u×) φ``. In the local level
axes of the error states (``R_local`` turns the origin's ENU axes into them, as in
:mod:`plugins.position`)::

    z = R_local (p̃ − p̂) − d a(u),    H = [0, −d ∂a/∂φ, I, 0, …]   (columns δv, φ, δp, …)

``p̃`` is the nominal SINS position and ``p̂`` the stored point (origin ENU), ``d`` the sum of the
AFC advances logged in ``support.csv`` between the stored visit and this one (or
``face.advance_m`` per face end passed, ``advance_source: nominal``). The advance direction
``a(u)`` is, with ``advance_direction: attitude``, eq. 6 literally: ``a = u``,
``∂a/∂φ = (u×)``. The default ``face`` keeps the body's slope across the floor (``u_U``) but
turns its horizontal part onto the normal ``n`` of the surveyed face line (the supports push the
AFC square to the face): ``a = ±|u_h| n + u_U e_U``. The shearer's own heading differs from that
normal by the AFC's snaking and by the IMU's mounting yaw (neither of which this plugin
estimates); each advance would carry that angle × d as a *systematic* error into the chain of a
face-end point (measured on ``seed000-carrier``: 0.035 m per advance along the face).

Noise (eq. 8: the predicted point is never pretended exact)::

    R = k R_local P̂ R_localᵀ + m σ_d² a aᵀ + σ_g² I + σ_s² u_y u_yᵀ

with ``P̂`` the stored point's covariance (``k = 1``, or ``k = n`` for a point refreshed by the
smoother, below), m advances of 1σ ``advance_sigma_m``, the AFC line's
deviation from "previous line plus advance" (snaking, floor; ``geometry_sigma_m``) and the error
of finding the point again by mileage, along the track ``u_y = C̃_b^n e_y`` (``along_sigma_m``).

Where the points come from (seed 000 §2.2 and Fig. 4), and how their errors are treated
-------------------------------------------------------------------------------------
* The two face-end points are surveyed (``face.ends_enu_m``, 1σ ``survey_sigma_m``). They are
  never replaced by filter estimates: each visit predicts them from the previous visit plus the
  advance, and that chain, with its growing covariance, is what the next visit uses. Their error
  (survey, advances) is independent of the filter's: ``k = 1``.
* Every other (*interior*) point records, at its visit in the first cycle, the filter's estimate
  there (nominal position minus the position error estimate, covariance from
  ``ctx.covariance``); in each later cycle its measurement is applied and the filter's
  posterior at the same instant (after the update and feedback) replaces it for the next cycle
  (seed 000: "the positions of the current cutting cycle"). The smoother (issue #6) replaces
  those with smoothed ones after a pass (:meth:`Cpoem.refresh_points`).

An interior point's error is the filter's own error at the earlier visit: slowly varying states
(heading, odometer scale, mounting) make it correlated with the current state error and from
one point to the next along the whole face. The filter tracks that correlation exactly
(stochastic cloning without refining the clone, :mod:`fusion.kalman`'s stored errors): each
point owns three stored-error variables; recording it stores ``e_i = R_localᵀ (δp − δp̂)``, so the
filter keeps ``Cov(ε, e_i)`` (propagated and updated with its estimate) and ``Cov(e_i, e_j)``;
the measurement's noise is ``w = −R_local e_i + v`` (:class:`~fusion.kalman.CorrelatedNoise`),
with ``k = 1``. A filter that took the stored errors for independent noise counted the same
error once per point (measured on ``seed000-carrier`` with the MEMS grade: position RMS(err/σ)
up to 3.9 along the face and vertically by cycle 4, and a worse SEP than with the face ends
alone); the weighting that preceded this one, ``k = n`` (the n interior points of a pass carry
the information of one), kept it consistent but pessimistic (whitened innovations 0.2).

A point refreshed by the smoother (:meth:`Cpoem.refresh_points`) has a smoothed error whose
correlation with the filter's is not known (the smoother would have to carry the
cross-covariance of its smoothed states with the window's last one): until its next visit
re-records it, it falls back to ``k = n`` and uncorrelated noise.

Cycle and face-end detection (from the odometer only; ``truth.csv`` is never read)
--------------------------------------------------------------------------------
The mileage ``S(t)`` is the integral of the signed odometer speed (each sample is the mean over
its interval, so S is piecewise linear). A *turning point* is a reversal of S confirmed once S
has come back ``reversal_hysteresis_m`` from its extreme (stops and odometer noise at a stop
never make one); its arrival and departure times are the first and last samples within
``AT_EXTREME_M`` of the extreme. The recording must start at a face end (the one of
``face.ends_enu_m`` nearest to ``initial.position_enu_m``, within ``end_tolerance_m``). Then,
over the turning points in time order (a state machine that needs nothing from the future beyond
the hysteresis):

* the first departure starts pass 1 (cycle 1) and sets the along-face direction;
* a pass ends at the first turning point at least ``min_pass_fraction`` × face length of mileage
  from its start: that is a face end (the end's mileage is updated to it); reversals before that
  (the shearer backing up mid-face) do not end the pass; when the data end after that much
  travel, the last arrival is a face end too;
* at a face end the shearer does the terminal oblique cut (Fig. 3): it runs into the face, turns
  back to the end and turns again. The next pass starts at the first turning point that heads
  into the face, lies within ``end_tolerance_m`` of the end's mileage and comes after a turn back
  towards the end. Everything between two passes is cycle 0 ("processing the end coal").

A point sits at along-face mileage ``iΔ`` from the starting end (interior points at least
``end_clearance_m`` from either end); in each pass it is visited when S first crosses it in the
pass direction (time interpolated between odometer samples), the face ends at the pass's
departure and arrival times. :meth:`Cpoem.epochs` returns every visit time (the measurement),
:meth:`Cpoem.store_epochs` every interior point's (the record of the posterior, which the engine
calls after that instant's update and feedback, so a federated filter stores its fused
estimate). The visits are computed from the whole odometer stream before the run;
the face-end visits at the pass boundaries use the hindsight of the reversal's confirmation
(``reversal_hysteresis_m`` of travel), which an online system would apply that much later.
:meth:`Cpoem.window_ends` gives the engine's online smoother the face ends (from the second
pass on), and the smoothed positions come back through :meth:`Cpoem.receive_smoothed`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator

from fusion.attitude import skew
from fusion.error_model import ATTITUDE, POSITION
from fusion.kalman import CorrelatedNoise
from fusion.plugin import Measurement, MeasurementContext, Plugin, PluginOptions, StoredEstimate
from fusion.recording import OdometerData, Recording

AT_EXTREME_M = 0.01
"""A sample within this distance of a turning point's extreme mileage is "at" it (m)."""


class CpoemOptions(PluginOptions):
    """Options of the CPOEM plugin."""

    interval_m: float = Field(2.0, gt=0, description="Δ, mileage between optimal points (m)")
    min_pass_fraction: float = Field(
        0.8, gt=0, le=1, description="a reversal is a face end after this fraction of the face"
    )
    reversal_hysteresis_m: float = Field(
        0.3, gt=0, description="travel back from an extreme that confirms a reversal (m)"
    )
    end_tolerance_m: float = Field(
        3.0, gt=0, description="a pass starts at a turning point this close to a face end (m)"
    )
    end_clearance_m: float = Field(
        1.0, ge=0, description="interior points keep this mileage from both face ends (m)"
    )
    advance_source: Literal["support", "nominal"] = Field(
        "support", description="support.csv pushes, or face.advance_m per face end passed"
    )
    advance_direction: Literal["face", "attitude"] = Field(
        "face", description="horizontal advance ⊥ the surveyed face line, or along body x"
    )
    survey_sigma_m: float = Field(0.02, gt=0, description="1σ of the surveyed face ends (m)")
    advance_sigma_m: float = Field(0.01, ge=0, description="1σ of each advance (m)")
    geometry_sigma_m: float = Field(
        0.02, ge=0, description="1σ deviation of a line from the previous line + advance (m)"
    )
    along_sigma_m: float = Field(
        0.05, ge=0, description="1σ of finding a point again by mileage, along the track (m)"
    )

    @model_validator(mode="after")
    def _clearance_after_confirmation(self) -> CpoemOptions:
        if self.end_clearance_m < self.reversal_hysteresis_m:
            raise ValueError(
                "end_clearance_m must be at least reversal_hysteresis_m (a point crossed before "
                "its pass is confirmed could not be measured)"
            )
        return self


@dataclass(frozen=True)
class TurningPoint:
    """A confirmed reversal of the mileage (or the first departure, ``arrive`` = start)."""

    mileage: float
    arrive: float
    """First time at the extreme (s)."""
    depart: float
    """Last time at the extreme before leaving it (s)."""
    direction: int
    """Sign of the mileage rate after the turn (0: the data end there)."""


@dataclass(frozen=True)
class CuttingPass:
    """One straight cutting pass (a cutting cycle) from one face end to the other."""

    number: int
    """1, 2, … (the cutting-cycle index)."""
    t_start: float
    t_end: float
    """Arrival at the far end, or the last odometer time when ``complete`` is False."""
    direction: int
    """Sign of the mileage rate during the pass."""
    start_mileage: float
    end_mileage: float
    complete: bool


@dataclass(frozen=True)
class Visit:
    """The shearer at optimal point ``point`` during pass ``pass_number`` at time ``t``."""

    t: float
    pass_number: int
    point: int


def odometer_mileage(odometer: OdometerData) -> NDArray[np.float64]:
    """Signed mileage (m) at each odometer time: ``S_k = Σ_{j≤k} v_j (t_j − t_{j−1})``.

    Each speed is the mean over its interval; the first sample's interval is the median one.
    """
    t = odometer.t
    if t.size < 2:
        raise ValueError("odometer.csv: CPOEM needs at least two odometer samples")
    dt = np.diff(t, prepend=t[0] - float(np.median(np.diff(t))))
    return np.cumsum(odometer.speed * dt)


def turning_points(
    t: NDArray[np.float64], mileage: NDArray[np.float64], hysteresis: float
) -> list[TurningPoint]:
    """Reversals of the mileage confirmed by ``hysteresis`` metres of travel back.

    The first element is the first departure from the start (its ``arrive`` is the start time),
    the last the extreme of the final run when the data end (``direction`` 0).
    """
    out: list[TurningPoint] = []
    n = mileage.size
    k_lo = k_hi = 0
    k = 1
    direction = 0
    while k < n and direction == 0:  # at rest at the start: wait for the first departure
        if mileage[k] < mileage[k_lo]:
            k_lo = k
        if mileage[k] > mileage[k_hi]:
            k_hi = k
        if mileage[k] - mileage[k_lo] >= hysteresis:
            direction, k_ext = 1, k_lo
        elif mileage[k_hi] - mileage[k] >= hysteresis:
            direction, k_ext = -1, k_hi
        k += 1
    if direction == 0:
        return out
    out.append(_turning_point(t, mileage, 0, k_ext, k - 1, direction))
    run_start = k_ext
    k_ext += int(np.argmax(mileage[k_ext:k] * direction))
    while k < n:
        step = (mileage[k] - mileage[k_ext]) * direction
        if step > 0:
            k_ext = k
        elif -step >= hysteresis:
            out.append(_turning_point(t, mileage, run_start, k_ext, k, -direction))
            direction = -direction
            segment = mileage[k_ext : k + 1] * direction
            run_start = k_ext
            k_ext = k_ext + int(np.argmax(segment))
        k += 1
    end = _turning_point(t, mileage, run_start, k_ext, n - 1, 0)
    out.append(TurningPoint(end.mileage, end.arrive, float(t[-1]), 0))
    return out


def _turning_point(
    t: NDArray[np.float64],
    mileage: NDArray[np.float64],
    run_start: int,
    k_ext: int,
    k_confirm: int,
    direction: int,
) -> TurningPoint:
    """Turning point at the extreme ``k_ext`` with its arrival and departure samples."""
    at = np.abs(mileage - mileage[k_ext]) <= AT_EXTREME_M
    before = np.flatnonzero(at[run_start : k_ext + 1])
    after = np.flatnonzero(at[k_ext : k_confirm + 1])
    return TurningPoint(
        mileage=float(mileage[k_ext]),
        arrive=float(t[run_start + before[0]]),
        depart=float(t[k_ext + after[-1]]),
        direction=direction,
    )


def detect_passes(
    t: NDArray[np.float64],
    mileage: NDArray[np.float64],
    face_length_m: float,
    min_pass_fraction: float,
    hysteresis: float,
    end_tolerance: float,
) -> list[CuttingPass]:
    """Cutting passes from the mileage (the state machine of the module docstring)."""
    passes: list[CuttingPass] = []
    points = turning_points(t, mileage, hysteresis)
    if not points:
        return passes
    min_travel = min_pass_fraction * face_length_m
    end_mileage = {0: points[0].mileage}  # 0: starting end, 1: the other end
    inward = {0: points[0].direction, 1: -points[0].direction}
    current: TurningPoint | None = points[0]  # the turning point that started the open pass
    end = 0  # the end the shearer is at (when no pass is open)
    ready = True
    for tp in points[1:]:
        if current is not None:
            if abs(tp.mileage - current.mileage) >= min_travel:  # a face end
                passes.append(
                    CuttingPass(
                        len(passes) + 1,
                        current.depart,
                        tp.arrive,
                        current.direction,
                        current.mileage,
                        tp.mileage,
                        True,
                    )
                )
                end = 1 - end
                end_mileage[end] = tp.mileage
                current, ready = None, False
            continue
        if tp.direction == 0:
            break
        if tp.direction == -inward[end]:
            ready = True
        elif ready and abs(tp.mileage - end_mileage[end]) <= end_tolerance:
            current = tp
    if current is not None:
        passes.append(
            CuttingPass(
                len(passes) + 1,
                current.depart,
                float(t[-1]),
                current.direction,
                current.mileage,
                float(mileage[-1]),
                False,
            )
        )
    return passes


def _crossing_time(
    t: NDArray[np.float64], along: NDArray[np.float64], k0: int, k1: int, target: float
) -> float | None:
    """First time in samples ``k0..k1`` at which the increasing-ish ``along`` reaches ``target``
    (linear interpolation between samples), or None."""
    hit = np.flatnonzero(along[k0 : k1 + 1] >= target)
    if hit.size == 0:
        return None
    k = k0 + int(hit[0])
    if k == 0 or along[k] == along[k - 1]:
        return float(t[k])
    w = (target - along[k - 1]) / (along[k] - along[k - 1])
    return float(t[k - 1] + min(max(w, 0.0), 1.0) * (t[k] - t[k - 1]))


class Cpoem(Plugin):
    """Optimal points predicted from the previous cutting cycle plus the AFC advance.

    Attributes
    ----------
    passes
        The detected cutting passes (cycle ``number`` 1, 2, …).
    point_mileage
        Along-face mileage of each optimal point from the starting end (index 0 and -1 are the
        face ends).
    visits
        Every visit of a point, in time order (:meth:`epochs` lists each twice).
    """

    Options = CpoemOptions
    options: CpoemOptions

    def __init__(self, name: str, options: CpoemOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        face = recording.meta.face
        if recording.odometer is None:
            raise ValueError(f"plugin {name!r} (cpoem) needs odometer.csv (the mileage)")
        if face is None or face.ends_enu_m is None:
            raise ValueError(
                f"plugin {name!r} (cpoem) needs meta.yaml face.ends_enu_m (the surveyed face ends)"
            )
        if options.advance_source == "support" and recording.support is None:
            raise ValueError(
                f"plugin {name!r} (cpoem) needs support.csv (the AFC advances) with "
                "advance_source: support; use advance_source: nominal to take face.advance_m"
            )
        if options.advance_source == "nominal" and face.advance_m is None:
            raise ValueError(
                f"plugin {name!r} (cpoem): advance_source: nominal needs meta.yaml face.advance_m"
            )
        ends = np.array(face.ends_enu_m, dtype=float)
        length = (
            face.length_m if face.length_m is not None else float(np.linalg.norm(ends[1] - ends[0]))
        )
        start = np.array(recording.meta.initial.position_enu_m, dtype=float)
        gap = np.linalg.norm(ends - start, axis=1)
        if gap.min() > options.end_tolerance_m:
            raise ValueError(
                f"plugin {name!r} (cpoem): the recording starts {gap.min():.2f} m from the nearest"
                f" face end (meta.yaml face.ends_enu_m); CPOEM needs the shearer to start at a"
                f" face end (within end_tolerance_m = {options.end_tolerance_m} m)"
            )
        first = int(np.argmin(gap))
        self.ends_enu = ends[[first, 1 - first]]  # starting end, then the other
        east, north = ends[1, :2] - ends[0, :2]
        self.face_normal_enu = np.array([north, -east, 0.0]) / np.hypot(east, north)
        odo = recording.odometer
        mileage = odometer_mileage(odo)
        self.passes = detect_passes(
            odo.t,
            mileage,
            length,
            options.min_pass_fraction,
            options.reversal_hysteresis_m,
            options.end_tolerance_m,
        )
        self.point_mileage, self.visits = self._plan_visits(odo.t, mileage)
        n = self.point_mileage.size
        self._stored_t = np.full(n, np.nan)
        self._stored_p = np.zeros((n, 3))
        self._stored_cov = np.zeros((n, 3, 3))
        self._tracked = np.zeros(n, dtype=bool)
        self._pass_ends = np.array([p.t_end for p in self.passes if p.complete])
        self._interior_visits = [k for k, v in enumerate(self.visits) if not self.is_end(v.point)]

    def _plan_visits(
        self, t: NDArray[np.float64], mileage: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], list[Visit]]:
        """Point mileages (from the starting end) and the visits of every pass."""
        if not self.passes:
            return np.zeros(0), []
        first = self.passes[0]
        along = first.direction * (mileage - first.start_mileage)
        far = (
            first.direction * (first.end_mileage - first.start_mileage) if first.complete else None
        )
        clearance = self.options.end_clearance_m
        top = far - clearance if far is not None else float(along.max())
        step = self.options.interval_m
        interior = step * np.arange(1, int(np.floor(top / step)) + 1)
        interior = interior[interior >= clearance]
        points = np.concatenate([[0.0], interior, [far] if far is not None else []])
        n_far = points.size - 1 if far is not None else None
        visits: list[Visit] = []
        for p in self.passes:
            k0 = int(np.searchsorted(t, p.t_start))
            k1 = int(np.searchsorted(t, p.t_end))
            outward = p.direction == first.direction  # from the starting end to the other
            start_point, end_point = (0, n_far) if outward else (n_far, 0)
            if start_point is not None:
                visits.append(Visit(p.t_start, p.number, start_point))
            sign = 1.0 if outward else -1.0
            for i in range(1, 1 + interior.size):
                crossing = _crossing_time(t, sign * along, k0, k1, sign * points[i])
                if crossing is not None:
                    visits.append(Visit(crossing, p.number, i))
            if p.complete and end_point is not None:
                visits.append(Visit(p.t_end, p.number, end_point))
        visits.sort(key=lambda v: v.t)
        return points, visits

    def stored_errors(self) -> int:
        """Three per point (the ENU error of its stored position; the face ends' stay unused)."""
        return 3 * self.point_mileage.size

    def epochs(self) -> NDArray[np.float64]:
        """Every visit time (the measurement)."""
        return np.array([v.t for v in self.visits], dtype=float)

    def store_epochs(self) -> NDArray[np.float64]:
        """The visit time of every interior point (the record of the posterior)."""
        return np.array([self.visits[k].t for k in self._interior_visits], dtype=float)

    def is_end(self, point: int) -> bool:
        """Whether ``point`` is one of the two surveyed face ends."""
        return point == 0 or (
            bool(self.passes) and self.passes[0].complete and point == self.point_mileage.size - 1
        )

    def store(self, index: int, ctx: MeasurementContext) -> StoredEstimate:
        """Record the filter's posterior at an interior point's visit (:meth:`store_epochs`)."""
        visit = self.visits[self._interior_visits[index]]
        rot = ctx.rotation_to_local
        pos = ctx.layout.slice(POSITION)
        self._store(
            visit, ctx.position_enu - rot.T @ ctx.x[pos], rot.T @ ctx.covariance[pos, pos] @ rot
        )
        self._tracked[visit.point] = True
        h = np.zeros((3, ctx.layout.dim))
        h[:, pos] = rot.T  # the stored point's error: Rᵀ (δp − δp̂), δp̂ the estimate
        return StoredEstimate(self._columns(visit.point), h)

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        """The point's position predicted from its previous visit plus the advance."""
        visit = self.visits[index]
        rot = ctx.rotation_to_local  # origin ENU → local ENU
        i = visit.point
        if np.isnan(self._stored_t[i]):
            if self.is_end(i):
                end = 0 if i == 0 else 1
                self._store(visit, self.ends_enu[end], self.options.survey_sigma_m**2 * np.eye(3))
            return None
        advance, count = self._advance(self._stored_t[i], visit.t)
        u_x, u_y = ctx.c_b_n[:, 0], ctx.c_b_n[:, 1]
        direction, d_direction = self._advance_direction(u_x, rot)
        shift_n = advance * direction  # eq. 6 in the local level axes
        opts = self.options
        tracked = bool(self._tracked[i])
        shared_by = 1 if self.is_end(i) or tracked else self.point_mileage.size - 2  # k
        chain_local = (
            shared_by * rot @ self._stored_cov[i] @ rot.T
            + count * opts.advance_sigma_m**2 * np.outer(direction, direction)
            + opts.geometry_sigma_m**2 * np.eye(3)
        )
        r = chain_local + opts.along_sigma_m**2 * np.outer(u_y, u_y)
        z = rot @ (ctx.position_enu - self._stored_p[i]) - shift_n
        h = np.zeros((3, ctx.layout.dim))
        h[:, ctx.layout.slice(ATTITUDE)] = -advance * d_direction
        h[:, ctx.layout.slice(POSITION)] = np.eye(3)
        if self.is_end(i):  # the survey chain: predicted point, never the filter's estimate
            self._store(visit, self._stored_p[i] + rot.T @ shift_n, rot.T @ chain_local @ rot)
        correlated = CorrelatedNoise(self._columns(i), -rot) if tracked else None
        return Measurement(z, h, r, correlated=correlated)

    @staticmethod
    def _columns(point: int) -> NDArray[np.intp]:
        """The stored-error variables of a point's position."""
        return np.arange(3 * point, 3 * point + 3, dtype=np.intp)

    def _advance_direction(
        self, u_x: NDArray[np.float64], rot: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Unit advance direction (local level) and its derivative with respect to φ."""
        d_u = skew(u_x)  # u_x(φ) = (I − φ×) u_x = u_x + (u_x×) φ
        if self.options.advance_direction == "attitude":
            return u_x, d_u
        normal = rot @ self.face_normal_enu
        across = float(np.hypot(u_x[0], u_x[1]))
        side = 1.0 if normal[:2] @ u_x[:2] >= 0 else -1.0
        up = np.array([0.0, 0.0, 1.0])
        direction = side * across * normal + u_x[2] * up
        d_across = np.array([u_x[0], u_x[1], 0.0]) / across
        return direction, (side * np.outer(normal, d_across) + np.outer(up, up)) @ d_u

    def _store(
        self, visit: Visit, position_enu: NDArray[np.float64], covariance: NDArray[np.float64]
    ) -> None:
        i = visit.point
        self._stored_t[i] = visit.t
        self._stored_p[i] = position_enu
        self._stored_cov[i] = 0.5 * (covariance + covariance.T)

    def _advance(self, t_stored: float, t_now: float) -> tuple[float, int]:
        """AFC advance between two visits and the number of advances it sums."""
        if self.options.advance_source == "support":
            support = self.recording.support
            assert support is not None
            inside = (support.t > t_stored) & (support.t <= t_now)
            return float(support.advance[inside].sum()), int(inside.sum())
        face = self.recording.meta.face
        assert face is not None and face.advance_m is not None
        count = int(np.count_nonzero((self._pass_ends >= t_stored) & (self._pass_ends < t_now)))
        return count * face.advance_m, count

    def window_ends(self) -> NDArray[np.float64]:
        """Face-end arrivals where online smoothing closes a window: the end of every complete
        pass but the first (seed 000 Fig. 4: "not in the first cutting cycle")."""
        return np.array([p.t_end for p in self.passes[1:] if p.complete], dtype=float)

    def receive_smoothed(
        self,
        t: NDArray[np.float64],
        position_enu: NDArray[np.float64],
        position_covariance: NDArray[np.float64],
    ) -> None:
        """Refresh the stored points from a window the smoother just closed
        (:meth:`refresh_points`)."""
        if t.size >= 2:
            self.refresh_points(t, position_enu, position_covariance)

    def stored_points(
        self,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Visit time (NaN: not yet visited), position (origin ENU m) and covariance of every
        stored point, as the next cycle will use them (copies)."""
        return self._stored_t.copy(), self._stored_p.copy(), self._stored_cov.copy()

    def refresh_points(
        self,
        times: NDArray[np.float64],
        positions_enu: NDArray[np.float64],
        covariances: NDArray[np.float64],
    ) -> int:
        """Replace the stored interior points visited within ``times`` by a smoothed trajectory.

        The smoother (seed 000 Fig. 4) calls this after the pass it smoothed: every stored point
        (except the surveyed face ends, whose chain is better than any estimate) whose last visit
        lies in ``[times[0], times[-1]]`` takes the position and covariance interpolated linearly
        in time at its visit.

        Parameters
        ----------
        times
            (N,) increasing times (s) of the smoothed trajectory.
        positions_enu
            (N, 3) smoothed positions, origin ENU metres.
        covariances
            (N, 3, 3) their covariances in the same axes.

        Returns
        -------
        int
            The number of points replaced.
        """
        times = np.asarray(times, dtype=float)
        positions_enu = np.asarray(positions_enu, dtype=float)
        covariances = np.asarray(covariances, dtype=float)
        if times.ndim != 1 or times.size < 2 or np.any(np.diff(times) <= 0):
            raise ValueError("refresh_points: times must be 1-D, strictly increasing, ≥ 2 values")
        if positions_enu.shape != (times.size, 3) or covariances.shape != (times.size, 3, 3):
            raise ValueError(
                "refresh_points: positions_enu must be (N, 3) and covariances (N, 3, 3) for "
                f"N = {times.size} times, got {positions_enu.shape} and {covariances.shape}"
            )
        replaced = 0
        for i, t_visit in enumerate(self._stored_t):
            if np.isnan(t_visit) or self.is_end(i) or not times[0] <= t_visit <= times[-1]:
                continue
            k = min(int(np.searchsorted(times, t_visit, side="right")), times.size - 1)
            w = (t_visit - times[k - 1]) / (times[k] - times[k - 1])
            self._stored_p[i] = (1 - w) * positions_enu[k - 1] + w * positions_enu[k]
            cov = (1 - w) * covariances[k - 1] + w * covariances[k]
            self._stored_cov[i] = 0.5 * (cov + cov.T)
            self._tracked[i] = False
            replaced += 1
        return replaced
