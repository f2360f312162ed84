"""CPOEM, the closing path optimal estimation model (seed 000 §2.2, eqs. 5–8, 21–24, Figs. 3–4).

A longwall shearer rides the AFC along the same face again and again, each cutting cycle on the
line of the previous one pushed forward by the web depth d. *Optimal points* recorded on one
pass are predicted for a later pass over the same stretch of face (eq. 6)::

    p_{i,j+1} = p_{i,j} + C_b^n C_m^b D,    D = [d, 0, 0]ᵀ (eq. 5)

and the prediction is applied as a position measurement of the SINS (eqs. 8, 21–22).

Where the points are, and when the shearer is at one (causal, any mining cycle)
-----------------------------------------------------------------------------
Seed 000 places the points every Δ metres of odometer mileage and counts cutting cycles from
the reversals of the mileage. That needs a face walked end to end, one pass per cycle, the
same odometer scale on every pass and the future of the recording (a pass is a pass once it
has reached the far end); it broke on uni-directional cutting (a cleaning run and a return run
between cuts), re-cuts, slips, and a recording that stops mid-pass (its last arrival was taken
for a face end and 12 m of error was thrown into the filter). Here the points are *stations*
fixed on the face: along-face coordinate ``s = a · (p − A)`` of the nominal SINS position p on
the surveyed face line from end A to end B (``face.ends_enu_m``, horizontal unit vector a,
length L), stations at ``s_i = iΔ`` strictly inside the face. Every ``1/check_rate_hz`` the
plugin looks at s: a station is *visited* when s crosses it since the previous check (the one
nearest to s when several were crossed). What a visit stores and measures does not depend on
cycles, directions, speeds or stops, nothing needs a later sample, and the store is bounded
by the face: L/Δ stations, whatever the distance travelled.

The station is found by the SINS's own along-face position, so the visit is where the filter
*believes* s_i is: the along-face component of ``p − p̂_i`` is zero by construction and is not
measured. What is measured is the rest, across the face (horizontal normal n of the face line)
and up: the AFC line's shape is the same at the same along-face place.

The two face ends are the absolute part: the surveyed points (1σ ``survey_sigma_m``) are
predicted for every later visit from the previous one plus the advance (never replaced by a
filter estimate, so their error stays independent of the filter's, k = 1 below). The shearer
visits an end when it comes to a stop (odometer speed averaged over ``stop_window_s`` below
``stop_speed_mps``) within ``end_tolerance_m`` of it along the face. End visits close the
online smoother's windows (:meth:`Cpoem.window_end_due`).

The along-face coordinate is never measured, at the ends neither: a face end is not square to
the face (the turning point moves along it by the advance × the skew every cycle), and the
shearer stops short of it or overruns it by a metre. A visit a distance Δs along the face from
where its point was stored (an end stop a few metres from the surveyed end; a station crossed
between two checks) adds ``(Δs σ_slope)²`` across and up for the line's slope and curvature
there (``line_slope_sigma``).

Terminal oblique cut (Fig. 3). At a face end the shearer cuts back into the face along the
AFC's bend towards the new web, while the supports snake the line over: until the push is
logged, the line near the shearer lies between the old web and the new one, and "previous
point plus logged advance" is off by up to the web. After a visit to a face end that followed a
push (an arrival from the face, not the return to the end after the push), station visits are
ignored until the next push is logged.

Measurement
-----------
With ``C̃_b^n = (I − φ×) C_b^n`` the advance direction ``u = C̃_b^n e_x`` (the m-frame is taken as
the body frame, the seed's ``C̃_b^m = I``) moves as ``u(φ) = u + (u×) φ``. In the local level
axes of the error states (``R_local`` turns the origin's ENU axes into them, as in
:mod:`fusion.aiding.position`)::

    z₃ = R_local (p̃ − p̂) − d a(u),    H₃ = [0, −d ∂a/∂φ, I, 0, …]   (columns δv, φ, δp, …)

``p̃`` is the nominal SINS position and ``p̂`` the stored point (origin ENU), ``d`` the sum of the
AFC advances logged in ``support.csv`` between the stored visit and this one, m their number.
Every visit measures ``z = T z₃``, ``H = T H₃`` with ``T = [n, e_U]ᵀ`` (across the face and
up). The advance direction ``a(u)`` is, with ``advance_direction:
attitude``, eq. 6 literally: ``a = u``, ``∂a/∂φ = (u×)``. The default ``face`` keeps the body's
slope across the floor (``u_U``) but turns its horizontal part onto the normal n of the surveyed
face line (the supports push the AFC square to the face): ``a = ±|u_h| n + u_U e_U``. The
shearer's own heading differs from that normal by the AFC's snaking and by the IMU's mounting
yaw (neither of which this plugin estimates); each advance would carry that angle × d as a
*systematic* error into the chain of a face-end point.

Noise (eq. 8: the predicted point is never pretended exact)::

    R = T (k R_local P̂ R_localᵀ + m σ_d² a aᵀ) Tᵀ + diag(σ_g²) + (Δs σ_slope)² I

with ``P̂`` the stored point's covariance, m advances of 1σ ``advance_sigma_m`` and the AFC
line's deviation from "previous line plus advance" σ_g (at a face end, the survey chain's
``geometry_sigma_m`` per visit). σ_g is *learned*: a face's AFC changes its
straightness from cycle to cycle by centimetres to decimetres, and a fixed 2 cm made the
filter confident and wrong on such a face. From the last ``adaptive_window`` station visits
the innovations ν across and up give ``σ_g² = max(σ_g,0², median(ν² − s) / 0.455)`` per axis
(a Sage–Husa estimate made robust with the median, 0.455 being χ²₁'s, so that the odd visit
the model does not explain neither teaches it nor passes the χ² gate; s is the innovation
variance without σ_g; ``geometry_sigma_m`` is the floor σ_g,0). This is the
plugin's own consistency check: when the learned σ_g exceeds ``max_geometry_sigma_m`` the
model does not describe this face (a push not logged, a line that moved), and CPOEM
*suspends itself* — it keeps looking at its innovations but measures nothing — until they are
consistent with ``max_geometry_sigma_m`` again. A visit without a stored point, or whose
advance is unknown (no ``support.csv``: the recording has not seen its first push), measures
nothing; CPOEM waits.

Stored points and their errors
------------------------------
An interior station records, at each visit, the filter's posterior there (after the update and
feedback of that instant; the engine calls :meth:`Cpoem.store` then), and the next visit is
measured against it (seed 000: "the positions of the current cutting cycle"). Its error is the
filter's own error at the earlier visit, correlated with the current one through slowly varying
states (heading, odometer scale, mounting) and from one station to the next. The filter tracks
that correlation exactly (stochastic cloning without refining the clone, :mod:`fusion.kalman`'s
stored errors): each station owns three stored-error variables; recording it stores
``e_i = R_localᵀ (δp − δp̂)``, so the filter keeps ``Cov(ε, e_i)`` and ``Cov(e_i, e_j)``; the
measurement's noise is ``w = −T R_local e_i + v`` (:class:`~fusion.kalman.CorrelatedNoise`) with
``k = 1``. A filter that took the stored errors for independent noise counted the same error
once per point (position RMS(err/σ) up to 3.9 on ``seed000-carrier``).

A point refreshed by the online smoother (:meth:`Cpoem.refresh_points`) has a smoothed error
whose correlation with the filter's is not known (the smoother would have to carry the
cross-covariance of its smoothed states with the window's last one): until its next visit
re-records it, it falls back to ``k = n`` (the n stations of the face carry the information of
one) and uncorrelated noise.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from fusion.attitude import skew
from fusion.encoder import reading_intervals
from fusion.error_model import ATTITUDE, POSITION
from fusion.face import FaceLine
from fusion.kalman import CorrelatedNoise
from fusion.plugin import (
    Measurement,
    MeasurementContext,
    MissingStream,
    Plugin,
    PluginOptions,
    StoredEstimate,
)
from fusion.recording import Recording

_log = logging.getLogger(__name__)

UP = np.array([0.0, 0.0, 1.0])
REVISIT_DISTANCE_M = 0.25
"""A station visited is visited again only after the SINS has been this far from it (m)."""
CHI2_1_MEDIAN = 0.4549364
"""Median of χ²₁: the median of ν²/σ² over consistent innovations (the robust scale)."""


class CpoemOptions(PluginOptions):
    """Options of the CPOEM plugin."""

    interval_m: float = Field(2.0, gt=0, description="Δ, spacing of the stations along the face")
    check_rate_hz: float = Field(
        5.0, gt=0, description="how often the plugin looks for a station crossing or an end stop"
    )
    end_tolerance_m: float = Field(
        5.0, gt=0, description="a stop this close to a surveyed face end (along the face) visits it"
    )
    stop_speed_mps: float = Field(
        0.01,
        gt=0,
        description="the shearer stands once its odometer speed, averaged over stop_window_s,"
        " falls below this, and moves again above twice it (m/s; cutting is ≥ 2 m/min)",
    )
    stop_window_s: float = Field(
        1.0, gt=0, description="odometer speed averaged over this window to find stops (s)"
    )
    advance_direction: Literal["face", "attitude"] = Field(
        "face", description="horizontal advance ⊥ the surveyed face line, or along body x"
    )
    survey_sigma_m: float = Field(0.02, gt=0, description="1σ of the surveyed face ends (m)")
    advance_sigma_m: float = Field(0.01, ge=0, description="1σ of each advance (m)")
    geometry_sigma_m: float = Field(
        0.02, gt=0, description="least 1σ deviation of a line from the previous line + advance"
    )
    max_geometry_sigma_m: float = Field(
        0.3,
        gt=0,
        description="a learned line deviation beyond this suspends CPOEM (its model does not fit)",
    )
    adaptive_window: int = Field(
        20, ge=2, description="station visits whose innovations teach the line deviation"
    )
    line_slope_sigma: float = Field(
        0.05,
        ge=0,
        description="1σ slope (m/m) of the line across and up: the error of a visit Δs along the"
        " face from its stored point is Δs times this",
    )


@dataclass
class StoredPoint:
    """A station's stored point: visit time (NaN: none yet; −inf: the survey), along-face
    coordinate, position (origin ENU), covariance, and whether the filter tracks its error (a
    stored posterior)."""

    t: float
    along: float
    position: NDArray[np.float64]
    covariance: NDArray[np.float64]
    tracked: bool = False


@dataclass(frozen=True)
class Visit:
    """The shearer at station ``station`` (0: end A, ``n``: end B) at check ``index``."""

    index: int
    station: int


class Cpoem(Plugin):
    """Face stations predicted from the previous visit plus the AFC advance.

    Attributes
    ----------
    stations
        Along-face coordinate of every station (m from end A; index 0 and -1 are the ends).
    """

    Options = CpoemOptions
    options: CpoemOptions
    closes_windows = True

    def __init__(self, name: str, options: CpoemOptions, recording: Recording) -> None:
        super().__init__(name, options, recording)
        face = recording.meta.face
        if recording.odometer is None:
            raise MissingStream(
                f"plugin {name!r} (cpoem) needs odometer.csv (stops at the face ends)"
            )
        if face is None or face.ends_enu_m is None:
            raise MissingStream(
                f"plugin {name!r} (cpoem) needs meta.yaml face.ends_enu_m (the surveyed face ends)"
            )
        if recording.support is None:
            _log.warning(
                "%s: no support.csv, so no AFC push is known: CPOEM records its stations and"
                " waits for a push it will never see (it measures nothing)",
                recording.meta.name,
            )
        self.ends_enu = np.array(face.ends_enu_m, dtype=float)
        self.face = FaceLine.from_ends(self.ends_enu)
        length = self.face.length
        if length <= 2.0 * options.interval_m:
            raise ValueError(
                f"plugin {name!r} (cpoem): the surveyed face ends are {length:.2f} m apart, not"
                f" enough for stations every interval_m = {options.interval_m} m"
            )
        count = math.ceil(length / options.interval_m)
        self.stations = np.concatenate([options.interval_m * np.arange(count), [length]])
        odo = recording.odometer
        dt = reading_intervals(odo.t)
        self._odometer_t = odo.t
        self._mileage = np.cumsum(odo.speed * dt)  # each speed is its interval's mean
        support = recording.support
        self._push_t = support.t if support is not None else None
        self._push_sum = np.concatenate([[0.0], np.cumsum(support.advance)]) if support else None
        t0 = float(recording.imu.t[0])
        t1 = float(recording.imu.t[-1])
        self._epochs = np.arange(t0, t1 + 1e-9, 1.0 / options.check_rate_hz)[1:]
        self._innovations: deque[NDArray[np.float64]] = deque(maxlen=options.adaptive_window)
        self.start_run()

    def start_run(self) -> None:
        """Start a run over the recording: the survey, no stored point, nothing seen."""
        n, length = self.stations.size, float(self.stations[-1])
        survey = self.options.survey_sigma_m**2 * np.eye(3)
        self.points = [StoredPoint(math.nan, 0.0, np.zeros(3), np.zeros((3, 3))) for _ in range(n)]
        self.points[0] = StoredPoint(-math.inf, 0.0, self.ends_enu[0].copy(), survey.copy())
        self.points[-1] = StoredPoint(-math.inf, length, self.ends_enu[1].copy(), survey.copy())
        self._last_along: float | None = None
        self._last_station: int | None = None
        self._standing = True
        self._visit: Visit | None = None
        self._ends_reached: list[float] = []
        self._snake_from: float | None = None
        self._windows_closed = 0
        self._innovations.clear()
        self.suspended = False

    # ------------------------------------------------------------------ plugin interface

    def stored_errors(self) -> int:
        """Three per station (the ENU error of its stored point; the face ends' stay unused)."""
        return 3 * self.stations.size

    def epochs(self) -> NDArray[np.float64]:
        """The checks, every ``1/check_rate_hz`` over the IMU span."""
        return self._epochs

    def store_epochs(self) -> NDArray[np.float64]:
        """The same checks: a visit's posterior is stored after that instant's fusion."""
        return self._epochs

    def along_face(self, position_enu: NDArray[np.float64]) -> float:
        """Along-face coordinate s of an origin-ENU position (m from end A)."""
        return self.face.along_face(position_enu)

    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        """A visit's point predicted from its previous visit plus the advance, or None."""
        self._visit = self._find_visit(index, ctx)
        if self._visit is None:
            return None
        station = self._visit.station
        point = self.points[station]
        advance = self._advance(point.t, ctx.t)
        if advance is None:
            return None
        z, h, r, correlated = self._model(station, point, advance, ctx)
        if self._is_end(station):
            return Measurement(z, h, r + self.options.geometry_sigma_m**2 * np.eye(2))
        nu = z - h @ ctx.x
        self._innovations.append(nu**2 - np.diag(h @ ctx.covariance @ h.T + r))
        geometry = self._learned_geometry()
        self.suspended = bool(np.any(geometry > self.options.max_geometry_sigma_m**2))
        if self.suspended:
            return None
        return Measurement(z, h, r + np.diag(geometry), correlated=correlated)

    def store(self, index: int, ctx: MeasurementContext) -> StoredEstimate | None:
        """After a visit's fusion: an interior station records the filter's posterior, an end
        its predicted chain point (:meth:`measure`)."""
        visit = self._visit
        if visit is None or visit.index != index:
            return None
        self._visit = None
        station = visit.station
        if self._is_end(station):
            self._advance_chain(station, ctx)
            return None
        rot = ctx.rotation_to_local
        pos = ctx.layout.slice(POSITION)
        covariance = ctx.position_covariance_enu
        position = ctx.position_enu - rot.T @ ctx.x[pos]
        self.points[station] = StoredPoint(
            ctx.t, self.along_face(position), position, 0.5 * (covariance + covariance.T), True
        )
        h = np.zeros((3, ctx.layout.dim))
        h[:, pos] = rot.T  # the stored point's error: Rᵀ (δp − δp̂), δp̂ the estimate
        return StoredEstimate(self._columns(station), h)

    def window_end_due(self, t: float) -> bool:
        """Whether a face end was reached at or before ``t`` since the last window closed."""
        reached = sum(1 for te in self._ends_reached if te <= t)
        if reached > self._windows_closed:
            self._windows_closed = reached
            return True
        return False

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

    # ------------------------------------------------------------------ visits

    def _find_visit(self, index: int, ctx: MeasurementContext) -> Visit | None:
        """The station crossed since the previous check, or the face end the shearer has just
        stopped at (module docstring)."""
        along = self.along_face(ctx.position_enu)
        previous, self._last_along = self._last_along, along
        stopped_now = self._stops(ctx.t)
        tolerance = self.options.end_tolerance_m
        if stopped_now and min(abs(along), abs(self.stations[-1] - along)) <= tolerance:
            self._reach_end(ctx.t)
            end = 0 if along < 0.5 * self.stations[-1] else self.stations.size - 1
            return Visit(index, end)
        if previous is None or self._snaking(ctx.t):
            return None
        last = self._last_station
        if last is not None and abs(along - self.stations[last]) > REVISIT_DISTANCE_M:
            self._last_station = last = None
        lo, hi = min(previous, along), max(previous, along)
        crossed = np.flatnonzero((self.stations[1:-1] > lo) & (self.stations[1:-1] <= hi)) + 1
        crossed = crossed[crossed != last]  # standing on a station is no new visit
        if crossed.size == 0:
            return None
        self._last_station = int(crossed[np.argmin(np.abs(self.stations[crossed] - along))])
        return Visit(index, self._last_station)

    def _pushes_between(self, t0: float, t1: float) -> int:
        """Number of pushes logged in (t0, t1]."""
        if self._push_t is None:
            return 0
        return int(
            np.searchsorted(self._push_t, t1, "right") - np.searchsorted(self._push_t, t0, "right")
        )

    def _reach_end(self, t: float) -> None:
        """A face end is reached: an arrival from the face (no push since the previous end
        visit) starts the terminal oblique cut, whose station visits wait for the next push."""
        previous = self._ends_reached[-1] if self._ends_reached else -math.inf
        if self._pushes_between(previous, t) == 0:
            self._snake_from = t
        self._ends_reached.append(t)

    def _snaking(self, t: float) -> bool:
        """Whether the AFC may be bent near the shearer: a terminal oblique cut started and no
        push has been logged since (module docstring)."""
        if self._snake_from is None:
            return False
        if self._pushes_between(self._snake_from, t) > 0:
            self._snake_from = None
            return False
        return True

    def _stops(self, t: float) -> bool:
        """Whether the shearer has just come to a stop: its odometer speed over the last
        ``stop_window_s`` fell below ``stop_speed_mps`` after exceeding twice that."""
        t_odo, mileage = self._odometer_t, self._mileage
        last = int(np.searchsorted(t_odo, t, side="right")) - 1
        first = int(np.searchsorted(t_odo, t - self.options.stop_window_s, side="right")) - 1
        if first < 0 or last <= first:
            return False
        speed = abs(mileage[last] - mileage[first]) / (t_odo[last] - t_odo[first])
        limit = self.options.stop_speed_mps
        if self._standing:
            self._standing = speed < 2.0 * limit
            return False
        self._standing = speed < limit
        return self._standing

    def _is_end(self, station: int) -> bool:
        return station == 0 or station == self.stations.size - 1

    def _advance(self, t_stored: float, t_now: float) -> tuple[float, int] | None:
        """AFC advance between a stored visit and now, and the number of pushes it sums; None
        when it cannot be known (no stored visit, no support.csv)."""
        if math.isnan(t_stored) or self._push_t is None or self._push_sum is None:
            return None
        lo = int(np.searchsorted(self._push_t, t_stored, side="right"))
        hi = int(np.searchsorted(self._push_t, t_now, side="right"))
        return float(self._push_sum[hi] - self._push_sum[lo]), hi - lo

    def _advance_chain(self, station: int, ctx: MeasurementContext) -> None:
        """Predict a face end's chain point to this visit (survey + advances: never the filter's
        estimate, so its error stays independent of the filter's)."""
        point = self.points[station]
        advance = self._advance(point.t, ctx.t)
        if advance is None:
            return
        rot = ctx.rotation_to_local
        direction, _ = self._advance_direction(ctx.c_b_n[:, 0], rot)
        chain = rot @ point.covariance @ rot.T + self._push_noise(advance[1], direction)
        chain += self.options.geometry_sigma_m**2 * np.eye(3)
        self.points[station] = StoredPoint(
            ctx.t,
            point.along,
            point.position + advance[0] * (rot.T @ direction),
            rot.T @ chain @ rot,
        )

    # ------------------------------------------------------------------ the model

    def _model(
        self,
        station: int,
        point: StoredPoint,
        advance: tuple[float, int],
        ctx: MeasurementContext,
    ) -> tuple[
        NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], CorrelatedNoise | None
    ]:
        """``z, H, R`` and the stored-error noise of a visit (module docstring), R without the
        line's deviation σ_g."""
        opts = self.options
        rot = ctx.rotation_to_local  # origin ENU → local ENU
        distance, pushes = advance
        direction, d_direction = self._advance_direction(ctx.c_b_n[:, 0], rot)
        shared_by = 1 if point.tracked or self._is_end(station) else self.stations.size - 2
        r3 = shared_by * rot @ point.covariance @ rot.T + self._push_noise(pushes, direction)
        z3 = rot @ (ctx.position_enu - point.position) - distance * direction
        h3 = np.zeros((3, ctx.layout.dim))
        h3[:, ctx.layout.slice(ATTITUDE)] = -distance * d_direction
        h3[:, ctx.layout.slice(POSITION)] = np.eye(3)
        rows = np.vstack([rot @ self.face.normal, UP])  # T: across the face and up
        offset = (self.along_face(ctx.position_enu) - point.along) * opts.line_slope_sigma
        r = rows @ r3 @ rows.T + offset**2 * np.eye(2)
        correlated = CorrelatedNoise(self._columns(station), -rows @ rot) if point.tracked else None
        return rows @ z3, rows @ h3, r, correlated

    def _push_noise(self, pushes: int, direction: NDArray[np.float64]) -> NDArray[np.float64]:
        return pushes * self.options.advance_sigma_m**2 * np.outer(direction, direction)

    def _learned_geometry(self) -> NDArray[np.float64]:
        """σ_g² across and up over the last visits (robust Sage–Husa), at least the floor."""
        floor = self.options.geometry_sigma_m**2
        if len(self._innovations) < self.options.adaptive_window:
            return np.full(2, floor)
        excess = np.median(np.array(self._innovations), axis=0) / CHI2_1_MEDIAN
        return np.maximum(excess, floor)

    @staticmethod
    def _columns(station: int) -> NDArray[np.intp]:
        """The stored-error variables of a station's point."""
        return np.arange(3 * station, 3 * station + 3, dtype=np.intp)

    def _advance_direction(
        self, u_x: NDArray[np.float64], rot: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Unit advance direction (local level) and its derivative with respect to φ."""
        d_u = skew(u_x)  # u_x(φ) = (I − φ×) u_x = u_x + (u_x×) φ
        if self.options.advance_direction == "attitude":
            return u_x, d_u
        normal = rot @ self.face.normal
        across = float(np.hypot(u_x[0], u_x[1]))
        side = 1.0 if normal[:2] @ u_x[:2] >= 0 else -1.0
        direction = side * across * normal + u_x[2] * UP
        d_across = np.array([u_x[0], u_x[1], 0.0]) / across
        return direction, (side * np.outer(normal, d_across) + np.outer(UP, UP)) @ d_u

    # ------------------------------------------------------------------ smoothing

    def stored_points(
        self,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Visit time (NaN: not yet visited, −inf: the survey), position (origin ENU m) and
        covariance of every station's stored point, as the next visit will use them (copies)."""
        return (
            np.array([p.t for p in self.points]),
            np.array([p.position for p in self.points]),
            np.array([p.covariance for p in self.points]),
        )

    def refresh_points(
        self,
        times: NDArray[np.float64],
        positions_enu: NDArray[np.float64],
        covariances: NDArray[np.float64],
    ) -> int:
        """Replace the stored interior points visited within ``times`` by a smoothed trajectory.

        The smoother (seed 000 Fig. 4) calls this after the window it smoothed: every stored
        interior point whose last visit lies in ``[times[0], times[-1]]`` takes the position
        and covariance interpolated linearly in time at its visit (the surveyed face ends keep
        their chain, which is better than any estimate).

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
        for i, point in enumerate(self.points):
            if self._is_end(i) or not times[0] <= point.t <= times[-1]:
                continue
            k = min(int(np.searchsorted(times, point.t, side="right")), times.size - 1)
            w = (point.t - times[k - 1]) / (times[k] - times[k - 1])
            cov = (1 - w) * covariances[k - 1] + w * covariances[k]
            self.points[i] = StoredPoint(
                point.t,
                point.along,
                (1 - w) * positions_enu[k - 1] + w * positions_enu[k],
                0.5 * (cov + cov.T),
            )
            replaced += 1
        return replaced
