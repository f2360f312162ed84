"""The engine: the one time-ordered loop over IMU intervals, covariance steps and aiding epochs.

Every event time — a covariance step ``t0 + j·Δt`` (default Δt = 0.1 s), an aiding epoch of a
plugin, an output epoch — is visited in order. At each one the SINS is advanced to exactly that
time (splitting the IMU interval that contains it, KF-GINS style), the covariance is propagated
over the interval since the previous event with F evaluated at the current nominal state and the
mean specific force of the interval, the due plugins are asked for ``(z, H, R)``, and after the
updates the common error estimate is fed back into the SINS and reset (closed loop). The
navigation state therefore runs at the IMU rate and the covariance at the configured step. A
bridged IMU gap adds its own process noise at the first step that reaches into it
(:mod:`fusion.imu_gaps`).

Before anything reads the recording, every stream is screened for physical plausibility
(:mod:`fusion.screening`): the plugins, the SINS and the dead reckoning see only the accepted
samples, rejected IMU runs are bridged as gaps, and the counts are in
:attr:`RunResult.screening`. A plugin whose stream the recording lacks (every aiding file is
optional in the format) is left out with a warning, unless its block says ``required: true``:
the run uses the configuration as it stands for this recording (:func:`present_plugins`),
and :attr:`RunResult.left_out` says what was left out. An IMU whose white noise at rest, over
the recording's first seconds, is grossly worse than its datasheet's gives the filter the
measured figures instead (:mod:`fusion.noise_at_rest`, :attr:`RunResult.rest_noise`); one whose
turn-on bias there lies beyond what its datasheet's covers gives the filter, the ZUPT detector
and the ZARU the measured magnitude (:mod:`fusion.bias_at_rest`, :attr:`RunResult.rest_bias`).

The error-state estimates live in a filter bank (:mod:`fusion.filter_bank`): one centralized
Kalman filter, or the federated master of :mod:`fusion.federated` whose local filters are index
sets of the same layout. Φ and Q_d are always computed once over the full layout.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from fusion import attitude
from fusion.bias_at_rest import RestBias, with_bias_at_rest
from fusion.config import ConfigError, FusionConfig, ImuTuning
from fusion.covariance_analysis import CovarianceAnalysis
from fusion.dead_reckoning import dead_reckon
from fusion.earth import LocalFrame
from fusion.encoder import combine_readings
from fusion.error_model import (
    ACCEL_BIAS,
    ATTITUDE,
    COMMON_BLOCKS,
    GYRO_BIAS,
    N_COMMON,
    POSITION,
    VELOCITY,
    ErrorModel,
    ImuNoise,
    SpecificForceFilter,
    StateLayout,
    common_blocks,
    heading_coupling,
    misalignment_prior,
    observable_force,
)
from fusion.fault_detection import FaultEvent
from fusion.federated import FederatedFilter
from fusion.filter_bank import CentralizedFilter, FilterBank
from fusion.imu_gaps import GapBridge, bridge_imu_gaps
from fusion.innovations import InnovationLog
from fusion.invariant_error import AXES, InvariantCoordinates
from fusion.jumps import JumpDetector, JumpState, jump_states
from fusion.kalman import CorrelatedNoise, KalmanFilter, UpdateResult
from fusion.lock import (
    DISPUTED,
    FIX_GATE_PROBABILITY,
    LOST_LOCK,
    REACQUIRE,
    LockMonitor,
    Reacquisition,
    fading_factor,
)
from fusion.memory import release_freed_memory
from fusion.noise_at_rest import RestNoise, with_noise_at_rest
from fusion.observability import Observability, ObservabilityTracker
from fusion.plugin import (
    WIDEN,
    Measurement,
    MeasurementContext,
    MissingStream,
    Plugin,
    PluginError,
    create_plugin,
    load_plugin_class,
)
from fusion.recording import ImuSpec, InitialSigma, Recording, check_recording
from fusion.rows import RowBuffer
from fusion.screening import STREAMS, ScreeningReport, screen_recording
from fusion.smoother import Rows, WindowedSmoother
from fusion.solution import Solution
from fusion.state_history import StateHistory, StateRecorder
from fusion.strapdown import HGT, LAT, LON, NAV_SIZE, Q0, VEL, NavState, Strapdown

_log = logging.getLogger(__name__)
ProgressCallback = Callable[[float], None]
GRID, OUTPUT, STORE = -1, -2, -3
"""Event sources that are not a plugin's measurement; plugin i's store epochs are STORE − i."""


@dataclass
class RunResult:
    """Everything a run produced (the Python API's return value)."""

    solution: Solution
    layout: StateLayout
    final_state: NDArray[np.float64]
    """Final estimates of every state: SINS biases and plugin states (fed-back ones included)."""
    final_covariance: NDArray[np.float64]
    innovations: dict[str, InnovationLog]
    faults: list[FaultEvent]
    """Isolations and re-admissions of the federated master's local filters (time order)."""
    wall_time_s: float
    config: FusionConfig
    recording_name: str
    smoothed: Solution | None = None
    """The RTS-smoothed solution when smoothing is configured."""
    smoother_peak_steps: int = 0
    """Most filter steps held in memory at once for smoothing."""
    smoother_rejected: int = 0
    """Output epochs whose smoothed position the forward filter's statistics did not allow
    (:func:`fusion.smoother.plausible_correction`): they keep the forward estimate."""
    smoother_windows: int = 0
    """Smoothing windows closed (one per pass online, one for the whole recording)."""
    smoother_unresolved_windows: int = 0
    """Windows that kept their whole forward track: the smoother's expected gain was within its
    own spread (:class:`fusion.smoother.SmoothingGain`, ``smoother.significance_sigma``) for the
    horizontal track and for the height alike."""
    smoother_kept_forward: dict[str, int] = field(default_factory=dict)
    """Per part of the track (:data:`fusion.smoother.BLOCKS`: horizontal, vertical), the windows
    in which that part kept its forward estimates."""
    screening: ScreeningReport = field(default_factory=lambda: ScreeningReport(enabled=False))
    """Implausible samples rejected per stream and rule before the run (fusion.screening)."""
    rest_noise: RestNoise = field(default_factory=RestNoise)
    """The IMU's white noise measured at rest at the start against its datasheet, and the
    figures the filter took from it (:mod:`fusion.noise_at_rest`)."""
    rest_bias: RestBias = field(default_factory=RestBias)
    """The IMU's turn-on biases measured at rest at the start against its datasheet, and the
    figures the filter took from them (:mod:`fusion.bias_at_rest`)."""
    left_out: tuple[str, ...] = ()
    """The configured plugins the run went without, each with why: the recording lacks its
    stream (:func:`present_plugins`). ``config`` has them disabled."""
    observability: Observability | None = None
    """Share of each state's prior variance the data removed (:mod:`fusion.observability`);
    None for an architecture that estimates nothing (dead reckoning, standalone)."""
    states: StateHistory | None = None
    """Every estimated state and its 1-σ at the output epochs (:mod:`fusion.state_history`);
    None with ``output.states: false`` or an architecture that estimates nothing."""

    @property
    def duration_s(self) -> float:
        """Recording time covered."""
        return float(self.solution.t[-1] - self.solution.t[0])

    @property
    def realtime_factor(self) -> float:
        """Recording duration ÷ wall time."""
        return self.duration_s / max(self.wall_time_s, 1e-9)

    def state_estimate(self, block: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Final estimate and 1-σ of a state block (e.g. ``"gyro_bias"``)."""
        s = self.layout.slice(block)
        return self.final_state[s], np.sqrt(np.diag(self.final_covariance)[s])


IMU_FIGURE_FLOOR = {
    "gyro_arw_deg_rth": 0.002,
    "accel_vrw_mg_rthz": 0.01,
    "gyro_bias_deg_h": 0.003,
    "accel_bias_mg": 0.025,
}
"""The least IMU error the filter assumes, in datasheet units: a navigation-grade unit's
(ring-laser gyros: angle random walk about 0.002 deg/√h, bias 0.003–0.01 deg/h;
accelerometers: 5–25 µg/√Hz, bias about 25 µg). No inertial sensor is better, and a figure of
zero (a simulator's error-free sensor, a datasheet field left at 0) leaves a state without
uncertainty. Without white noise the velocity's or the attitude's covariance collapses, the
filter stops listening to its aiding, and the mechanization's own errors grow unseen (seed
000's grade par5, an error-free accelerometer: vertical error 0.8 m at RMS(ε/σ) 9.3;
docs/design/2026-11-30-white-noise-floor.md). A bias of σ 0 makes the covariance singular, which
the federated master cannot invert."""

INITIAL_SIGMA_FLOOR = {"position_m": 0.001, "velocity_mps": 0.001, "attitude_deg": 0.01}
"""The least initial uncertainty the filter takes (a total station's millimetre, a
navigation-grade gyrocompass's 0.01°): meta.yaml may state a start known exactly (σ 0), and a
singular covariance cannot be inverted by the federated master."""


ASSUMED_IMU_SPEC = {
    "gyro_bias_deg_h": 720.0,
    "gyro_arw_deg_rth": 0.6,
    "accel_bias_mg": 3.0,
    "accel_vrw_mg_rthz": 0.08,
}
"""The datasheet figures taken for a figure that neither the configuration (``imu.KEY``) nor
meta.yaml's ``imu.spec`` gives (the format makes the datasheet optional): the Xsens MTi-G-700's,
the shearer IMU of seed 000 (Table 1: 720 deg/h, 0.6 deg/√h, 3 mg, 0.08 mg/√Hz), an
industrial MEMS unit of the class a shearer carries; a warning names each figure taken
(docs/design/2026-11-30-unusual-recordings.md)."""


def with_imu_spec(recording: Recording, tuning: ImuTuning) -> Recording:
    """``recording`` whose ``imu.spec`` holds all four datasheet figures, which the filter's
    noise and the plugins' thresholds (ZUPT, ZARU) are derived from: a figure meta.yaml lacks is
    the configuration's ``imu.KEY`` if set, else :data:`ASSUMED_IMU_SPEC`'s, with a warning."""
    meta = recording.meta
    stated = meta.imu.spec.model_dump() if meta.imu.spec is not None else {}
    figures = {key: stated.get(key) for key in ASSUMED_IMU_SPEC}
    for key, value in figures.items():
        if value is None:
            figures[key] = getattr(tuning, key)
    assumed = [key for key, value in figures.items() if value is None]
    if assumed:
        _log.warning(
            "neither meta.yaml's imu.spec nor the configuration's imu section gives %s: taking"
            " %s, an industrial MEMS unit's (fusion.engine.ASSUMED_IMU_SPEC)",
            ", ".join(assumed),
            ", ".join(f"{key} {ASSUMED_IMU_SPEC[key]:g}" for key in assumed),
        )
        figures.update({key: ASSUMED_IMU_SPEC[key] for key in assumed})
    if figures == stated:
        return recording
    return recording.with_imu_figures(figures)


def resolve_imu_noise(tuning: ImuTuning, spec: ImuSpec) -> ImuNoise:
    """IMU noise from the configuration, falling back to the datasheet figures ``spec`` (all
    four given: :func:`with_imu_spec`); an ``imu.bias_instability_fraction`` scales the turn-on
    biases so resolved into the in-run instability. Figures below :data:`IMU_FIGURE_FLOOR` are
    raised to it, with a warning."""
    figures = {}
    for key in ASSUMED_IMU_SPEC:
        value = getattr(tuning, key)
        figures[key] = float(getattr(spec, key) if value is None else value)
    for key in ("gyro_arw_deg_rth", "accel_vrw_mg_rthz"):
        figures[key] *= tuning.noise_scale
    for key, floor in IMU_FIGURE_FLOOR.items():
        if figures[key] < floor:
            _log.warning(
                "imu.%s: %g is below any inertial sensor's; the filter takes %g",
                key,
                figures[key],
                floor,
            )
            figures[key] = floor
    gyro_instability = tuning.gyro_bias_instability_deg_h
    accel_instability = tuning.accel_bias_instability_mg
    if tuning.bias_instability_fraction is not None:
        gyro_instability = tuning.bias_instability_fraction * figures["gyro_bias_deg_h"]
        accel_instability = tuning.bias_instability_fraction * figures["accel_bias_mg"]
    noise = ImuNoise.from_datasheet(
        gyro_arw_deg_rth=figures["gyro_arw_deg_rth"],
        accel_vrw_mg_rthz=figures["accel_vrw_mg_rthz"],
        gyro_bias_deg_h=figures["gyro_bias_deg_h"],
        accel_bias_mg=figures["accel_bias_mg"],
        gyro_bias_instability_deg_h=gyro_instability,
        accel_bias_instability_mg=accel_instability,
        bias_correlation_time_s=tuning.bias_correlation_time_s,
        bias_random_walk=tuning.bias_model == "random_walk",
    )
    return noise


def initial_sigma(sigma: InitialSigma, scale: float) -> dict[str, NDArray[np.float64]]:
    """meta.yaml's initial 1-σ (datasheet units) times ``filter.initial_sigma_scale``, raised to
    :data:`INITIAL_SIGMA_FLOOR` with a warning where below it."""
    floored = {}
    for key, floor in INITIAL_SIGMA_FLOOR.items():
        value = np.asarray(getattr(sigma, key), dtype=float) * scale
        if (value < floor).any():
            _log.warning(
                "initial.sigma.%s: %s is below what any survey gives; the filter takes %g there",
                key,
                value.tolist(),
                floor,
            )
        floored[key] = np.maximum(value, floor)
    return floored


def without_unusable_streams(recording: Recording) -> Recording:
    """``recording`` with every aiding stream it cannot use taken as absent, with a warning: a
    file of its header only (a sensor that recorded nothing, or every reading rejected by the
    screening), and an odometer.csv of one reading, which has no interval to be the mean speed
    over (the format's reading is the mean since the previous one). The plugins that read it are
    then left out as for a missing file."""
    unusable = [
        name
        for name in STREAMS[1:]  # the aiding streams, after the IMU
        if (data := getattr(recording, name)) is not None
        and data.t.size < (2 if name == "odometer" else 1)
    ]
    for name in unusable:
        count = getattr(recording, name).t.size
        _log.warning("%s.csv holds %d reading(s): taken as absent", name, count)
    absent: dict[str, Any] = dict.fromkeys(unusable)
    return replace(recording, **absent) if unusable else recording


def present_plugins(
    config: FusionConfig, recording: Recording
) -> tuple[list[Plugin], dict[str, str], FusionConfig]:
    """The configuration's enabled plugins on ``recording``, why each of those left out was
    (by instance name) and the configuration as it stands for this recording (those left out
    disabled).

    A plugin whose stream the recording lacks (:class:`fusion.plugin.MissingStream`: every
    aiding file is optional in the format) is left out with a warning. It is an error
    instead where its block says ``required: true``, and where every enabled plugin would be
    left out: nothing of the configured combination is in the recording, which is the wrong
    recording or the wrong configuration, not a recording with a sensor less.
    """
    plugins: list[Plugin] = []
    left_out: dict[str, str] = {}
    blocks = list(config.plugins)
    for i, block in enumerate(config.plugins):
        if not block.enabled:
            continue
        try:
            plugins.append(
                create_plugin(
                    block.type, block.instance_name, block.options, recording, ("plugins", i)
                )
            )
        except MissingStream as exc:
            if block.required:
                raise
            left_out[block.instance_name] = str(exc)
            blocks[i] = block.model_copy(update={"enabled": False})
    if not left_out:
        return plugins, {}, config
    if not plugins:
        raise MissingStream(
            "\n".join(left_out.values())
            + "\nno plugin of the configuration has its stream in the recording"
        )
    for reason in left_out.values():
        _log.warning("left out: %s", reason)
    return plugins, left_out, config.model_copy(update={"plugins": blocks})


def _at_most(epochs: NDArray[np.float64], rate: float | None) -> NDArray[np.bool_]:
    """Epochs kept when thinning to at most ``rate`` (greedy in time; epochs sharing a time
    stamp, such as the ranges of one UWB cycle, are kept or dropped together)."""
    if rate is None:
        return np.ones(epochs.size, dtype=bool)
    times = np.unique(epochs)
    kept = []
    k = 0
    while k < times.size:  # one step per kept time: the next one at least 1/rate later
        kept.append(k)
        k = int(np.searchsorted(times, times[k] + 1.0 / rate - 1e-9))
    return np.isin(epochs, times[kept])


def _event_schedule(
    t0: float,
    t_end: float,
    step: float,
    plugin_epochs: list[NDArray[np.float64]],
    max_rates: list[float | None],
    output_times: NDArray[np.float64],
    store_epochs: list[NDArray[np.float64]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int16], NDArray[np.int32]]:
    """Merge all event times; return times, source and index.

    The source is ``GRID`` for a covariance step, ``OUTPUT`` for an output epoch, ``STORE − i``
    for a store epoch of plugin i, otherwise the plugin's position in the list (and the index
    is the plugin's epoch index).
    """
    n_grid = int(np.floor((t_end - t0) / step + 1e-9))
    grid = t0 + step * np.arange(1, n_grid + 1)
    if grid.size == 0 or t_end - grid[-1] > 1e-9:
        grid = np.append(grid, t_end)
    times = [grid, output_times]
    # Compact integer types: an 8-hour shift with UWB ranges has about 4 million events.
    sources = [np.full(grid.size, GRID, np.int16), np.full(output_times.size, OUTPUT, np.int16)]
    indices = [np.full(grid.size, -1, np.int32), np.full(output_times.size, -1, np.int32)]
    streams = [
        (ep, i, rate) for i, (ep, rate) in enumerate(zip(plugin_epochs, max_rates, strict=True))
    ]
    streams += [(ep, STORE - i, None) for i, ep in enumerate(store_epochs or [])]
    for ep, source, rate in streams:
        keep = np.flatnonzero((ep > t0) & (ep <= t_end) & _at_most(ep, rate))
        times.append(ep[keep])
        sources.append(np.full(keep.size, source, np.int16))
        indices.append(keep.astype(np.int32))
    t_all = np.concatenate(times)
    order = np.argsort(t_all, kind="stable")
    return t_all[order], np.concatenate(sources)[order], np.concatenate(indices)[order]


BOUND = "bound"
"""``faults.csv`` action: an estimate reached its physical bound and is held there
(:meth:`fusion.kalman.KalmanFilter.hold_bounds`); one row when it reaches the bound, again only
after it has come back within :data:`BOUND_RELEASE` of it."""
BOUND_RELEASE = 0.9
"""Share of its bound an estimate must come back within before reaching the bound again is a
new ``faults.csv`` row."""
HOLD_CONDITION = 1e-9
"""det(HᵀH) over a block, relative to trace(HᵀH)³, above which rows ``H`` fix the block in
all three axes (:func:`_holds`); round-off leaves ≈ 10⁻¹⁶ in a rank-deficient block."""


def _rows_velocity(
    velocity_at: NDArray[np.float64] | None, ctx: MeasurementContext
) -> NDArray[np.float64]:
    """The velocity a measurement's attitude columns were evaluated at
    (:attr:`fusion.plugin.Measurement.velocity_at`; the nominal one unless it says)."""
    return ctx.velocity if velocity_at is None else velocity_at


def _holds(h: NDArray[np.float64], layout: StateLayout) -> bool:
    """Whether measurement rows ``h`` determine the velocity or the position in all three
    axes (an odometer with its constraint rows, a zero velocity, a position fix): the
    updates that keep a SINS from drifting off."""
    if h.shape[0] < 3:
        return False
    for block in (VELOCITY, POSITION):
        columns = h[:, layout.slice(block)]
        gram = columns.T @ columns
        scale = np.trace(gram)
        if scale > 0.0 and np.linalg.det(gram) > HOLD_CONDITION * scale**3:
            return True
    return False


@dataclass
class _OutputRows:
    """What the engine keeps at each output epoch (:meth:`Engine._output_epoch`)."""

    t: RowBuffer
    nav: RowBuffer
    position_covariance: RowBuffer
    recorder: StateRecorder | None
    observed: ObservabilityTracker


class Engine:
    """A configured filter over one recording.

    Parameters
    ----------
    config
        The sensor combination and filter options.
    recording
        The recording to process.
    """

    def __init__(self, config: FusionConfig, recording: Recording) -> None:
        self.config = config
        self._at_bound: dict[str, tuple[KalmanFilter, int]] = {}
        """States held at their bound in this run, by label: their filter and index."""
        recording = check_recording(recording, bridge_imu_gaps=config.bridge_imu_gaps)
        recording = with_imu_spec(recording, config.imu)
        self.rest_noise = RestNoise(reason="imu.noise_at_rest is off")
        if config.imu.noise_at_rest:
            recording, self.rest_noise = with_noise_at_rest(recording, config.imu)
            if self.rest_noise.taken:
                _log.warning("IMU noise at rest: %s", self.rest_noise.describe())
        self.rest_bias = RestBias(reason="imu.bias_at_rest is off")
        if config.imu.bias_at_rest:
            recording, self.rest_bias = with_bias_at_rest(recording, config.imu)
            if self.rest_bias.taken:
                _log.warning("IMU bias at rest: %s", self.rest_bias.describe())
        screened, self.screening = screen_recording(recording, config.screening)
        rate = config.streams.odometer_max_rate_hz
        if screened.odometer is not None and rate is not None:
            screened = replace(screened, odometer=combine_readings(screened.odometer, rate))
        screened = without_unusable_streams(screened)
        bridged, self.gap_bridges = bridge_imu_gaps(screened.imu, screened.imu_gaps)
        self.recording = replace(screened, imu=bridged) if self.gap_bridges else screened
        meta = recording.meta
        self.frame = LocalFrame(meta.origin.lat_deg, meta.origin.lon_deg, meta.origin.height_m)
        self.plugins, self.left_out, config = present_plugins(config, screened)
        self.config = config
        self.gates = [b.gate_probability for b in config.plugins if b.enabled]
        self._noise_sources = frozenset(  # plugins with a process_noise of their own
            k
            for k, p in enumerate(self.plugins)
            if type(p).process_noise is not Plugin.process_noise
        )
        self.plugin_blocks = [p.state_blocks() for p in self.plugins]
        counts = [p.stored_errors() for p in self.plugins]
        self.stored_error_offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.intp)
        assert meta.imu.spec is not None  # with_imu_spec
        imu = resolve_imu_noise(config.imu, meta.imu.spec)
        self.imu_noise = imu
        sigma = initial_sigma(meta.initial.sigma, config.filter.initial_sigma_scale)
        attitude = meta.initial.attitude_deg
        sigma_attitude, attitude_correlation = misalignment_prior(
            np.deg2rad([attitude.roll, attitude.pitch, attitude.yaw]),
            np.deg2rad(sigma["attitude_deg"]),
        )
        blocks = common_blocks(
            imu,
            sigma["velocity_mps"],
            sigma_attitude,
            sigma["position_m"],
            attitude_correlation,
        )
        self.layout = StateLayout(blocks).extended(b for own in self.plugin_blocks for b in own)
        axes = config.filter.invariant_error
        self._coordinates = None if axes == "none" else InvariantCoordinates(AXES[axes])
        self._specific_force = SpecificForceFilter(config.filter.specific_force_time_constant_s)
        """The low-passed specific force of F, a run's (:meth:`run` starts a new one)."""
        self._analysis: CovarianceAnalysis | None = None  # set per run
        if config.filter.reported_covariance == "invariant_analysis":
            self._check_analysable()
        self.model = ErrorModel(
            self.layout,
            imu,
            form=config.filter.error_model,
            discretization=config.filter.discretization,
        )

    def _check_analysable(self) -> None:
        """:class:`fusion.covariance_analysis.CovarianceAnalysis` follows updates and time
        updates; a stored error (CPOEM) or a jump taken in changes the state otherwise."""
        for plugin, blocks, stored in zip(
            self.plugins, self.plugin_blocks, np.diff(self.stored_error_offsets), strict=True
        ):
            if stored or any(b.may_jump for b in blocks):
                raise ConfigError(
                    f"plugin {plugin.name!r}: filter.reported_covariance invariant_analysis"
                    " cannot follow its stored errors or state jumps; use"
                    " filter.reported_covariance filter with it"
                )

    def filter_bank(self) -> FilterBank:
        """The configured architecture over this engine's layout."""
        opts = self.config.filter
        stored = int(self.stored_error_offsets[-1])
        if opts.architecture == "centralized":
            return CentralizedFilter(self.layout, stored)
        enabled = [b for b in self.config.plugins if b.enabled]
        return FederatedFilter(
            self.layout,
            [[b.name for b in own] for own in self.plugin_blocks],
            [b.local_name for b in enabled],
            opts.federated,
            opts.jump_detection.min_updates,
            [b.instance_name for b in enabled],
            stored,
        )

    def initial_state(self) -> NavState:
        """Navigation state at the first IMU sample, from meta.yaml."""
        init = self.recording.meta.initial
        att = np.deg2rad([init.attitude_deg.roll, init.attitude_deg.pitch, init.attitude_deg.yaw])
        return NavState.from_enu(
            self.frame, init.position_enu_m, init.velocity_enu_mps, att[0], att[1], att[2]
        )

    def run(self, progress: ProgressCallback | None = None) -> RunResult:
        """Process the whole recording."""
        wall0 = time.perf_counter()
        imu = self.recording.imu
        cfg = self.config.filter
        if cfg.architecture == "dead_reckoning":
            return self._without_filter(wall0, self._dead_reckoning())
        if cfg.architecture == "standalone":
            log = InnovationLog()
            solution = self.plugins[0].standalone_solution(self.gates[0], log)
            return self._without_filter(wall0, solution, {self.plugins[0].name: log})
        sins = Strapdown(
            imu.t, imu.gyro, imu.accel, self.initial_state(), coning_sculling=cfg.coning_sculling
        )
        for plugin in self.plugins:
            plugin.start_run()
        bank = self.filter_bank()
        if self._coordinates is not None:
            bank.change_coordinates(self._inverse_transform(sins))
        self._analysis = (
            CovarianceAnalysis(bank.estimate()[1], *self._point(sins.nav))
            if cfg.reported_covariance == "invariant_analysis"
            else None
        )
        observed = ObservabilityTracker(self.layout)
        self._locks = [
            LockMonitor(cfg.lock_window_s, cfg.lock_min_updates) if gate is not None else None
            for gate in self.gates
        ]
        self._last_held = [-math.inf] * len(self.plugins)
        self._at_bound = {}
        watched = any(lock is not None for lock in self._locks)  # else _holders is unasked
        self._needs_holds = watched or cfg.architecture == "federated"  # FederatedFilter
        states = jump_states(self.layout)
        jumps = (
            JumpDetector(self.layout, states, cfg.jump_detection, self._tell_owner)
            if states
            else None
        )
        if jumps is not None and isinstance(bank, FederatedFilter):
            bank.explain = jumps.explanation
        t0, t_end = float(imu.t[0]), float(imu.t[-1])
        rate = self.config.output.rate_hz
        output_times = np.arange(t0 + 1.0 / rate, t_end + 1e-9, 1.0 / rate) if rate else np.empty(0)
        times, sources, indices = _event_schedule(
            t0,
            t_end,
            cfg.covariance_step_s,
            [p.epochs() for p in self.plugins],
            [b.max_rate_hz for b in self.config.plugins if b.enabled],
            output_times,
            [p.store_epochs() for p in self.plugins],
        )
        release_freed_memory()  # the schedule's sort temporaries
        logs = {p.name: InnovationLog() for p in self.plugins}
        out_t, out_nav, out_cov = RowBuffer(), RowBuffer((NAV_SIZE,)), RowBuffer((3, 3))
        recorder = StateRecorder(self.layout) if self.config.output.states else None
        rows = _OutputRows(out_t, out_nav, out_cov, recorder, observed)
        self._output_epoch(rows, bank, sins, t0)
        smoother = self._smoother(bank)
        if smoother is not None:
            state = bank.smoothing_state()
            eye = np.eye(bank.smoothing_dim)
            smoother.step(t0, eye, state, state, np.zeros(bank.smoothing_dim), sins.nav)
        t_cov = t0
        self._specific_force = SpecificForceFilter(cfg.specific_force_time_constant_s)
        gaps = iter(self.gap_bridges)
        next_gap = next(gaps, None)
        n_events = len(times)
        report_every = max(n_events // 100, 1)
        i = 0
        while i < n_events:
            te = float(times[i])
            j = i
            while j < n_events and times[j] - te < 1e-9:
                j += 1
            sins.advance_to(te)
            events = len(bank.faults)
            dt = te - t_cov
            phi = None
            if dt > 1e-9:
                f_n = self._specific_force(sins.take_velocity_increment() / dt, dt)
                common = bank.common_covariance()
                if cfg.observable_force:
                    f_n = observable_force(f_n, sins.c_b_n, common)
                phi, qd = self._transition(sins, f_n, dt, heading_coupling(common))
                gap_noise = None
                while next_gap is not None and te > next_gap.t_start:
                    noise = self._gap_noise(next_gap, sins, f_n)
                    qd = qd + self._in_filter_coordinates(noise, sins)
                    gap_noise = noise if gap_noise is None else gap_noise + noise
                    next_gap = next(gaps, None)
                if self._analysis is not None:
                    self._analysis_predict(sins, f_n, dt, gap_noise)
                held = jumps.held_return(dt, bank) if jumps is not None else None
                if held is not None:  # held states that may have returned to rest
                    phi = held.decay[:, None] * phi
                    qd = qd + np.diag(held.variance)
                bank.predict(phi, qd)
                observed.predict(phi, qd)
                t_cov = te
                if jumps is not None:
                    jumps.step(te, bank)
            widened: list[FaultEvent] = []
            released = (
                self._process_noise(sources[i:j], indices[i:j], te, widened)
                if self._noise_sources
                else None
            )
            if released is not None:  # an identity time update: the smoother's prior has it
                if self._analysis is not None:
                    self._analysis.add(released, *self._point(sins.nav))
                released = self._in_filter_coordinates(released, sins)
                identity = np.eye(self.layout.dim)
                bank.predict(identity, released)
                observed.predict(identity, released)
            prior = bank.smoothing_state() if smoother is not None else None
            updated = False
            is_output = False
            stores = []
            for k in range(i, j):
                src = int(sources[k])
                if src <= STORE:  # after the round's feedback
                    stores.append((STORE - src, int(indices[k])))
                    continue
                if src < 0:
                    is_output |= src == OUTPUT or (src == GRID and rate is None)
                    continue
                updated |= self._update(src, int(indices[k]), te, sins, bank, logs, jumps)
            posterior = bank.smoothing_state() if smoother is not None else None
            dx = np.zeros(15)
            if bank.fusion_due(te, updated):
                dx = bank.feedback(te)  # the smoother takes it in the filter's coordinates
                self._correct(sins, dx)
            for src, index in stores:
                self._store(src, index, te, sins, bank)
            if smoother is not None and prior is not None and posterior is not None:
                if len(bank.faults) != events:  # not one filter's prior and posterior
                    self._hand_smoothed(smoother.close_window())
                self._smoothing_step(
                    smoother, bank, te, phi, prior, posterior, dx, sins.nav if is_output else None
                )
            bank.faults.extend(widened)  # after the smoothing step: one filter throughout
            if is_output:
                self._output_epoch(rows, bank, sins, te)
            if progress is not None and (i // report_every) != (j // report_every):
                progress(j / n_events)
            i = j
        navs = out_nav.take()
        solution = self._solution(out_t.take(), navs, self._positions(navs), out_cov.take())
        smoothed = None
        if smoother is not None:
            smoother.close_window()
            smoothed = self._solution(*smoother.take_rows())
        final, final_covariance, tracked = self._reported(bank, sins)
        return RunResult(
            solution=solution,
            layout=self.layout,
            final_state=final,
            final_covariance=final_covariance,
            innovations=logs,
            faults=list(bank.faults),
            wall_time_s=time.perf_counter() - wall0,
            config=self.config,
            recording_name=self.recording.meta.name,
            smoothed=smoothed,
            smoother_peak_steps=smoother.peak_steps if smoother is not None else 0,
            smoother_rejected=smoother.rejected if smoother is not None else 0,
            smoother_windows=smoother.windows if smoother is not None else 0,
            smoother_unresolved_windows=smoother.unresolved_windows if smoother is not None else 0,
            smoother_kept_forward=dict(smoother.kept_forward) if smoother is not None else {},
            screening=self.screening,
            rest_noise=self.rest_noise,
            rest_bias=self.rest_bias,
            left_out=tuple(self.left_out.values()),
            observability=observed.report(tracked),
            states=recorder.history(solution, self.frame) if recorder is not None else None,
        )

    def _output_epoch(self, rows: _OutputRows, bank: FilterBank, sins: Strapdown, t: float) -> None:
        """One output row: time, nominal state and position covariance, and where they are
        kept, the state history and the observability sample, from one estimate of the bank
        (a federated estimate fuses every local)."""
        rows.t.append(t)
        rows.nav.append(sins.nav)
        sampled = rows.observed.due(t)
        if rows.recorder is None and not sampled:
            rows.position_covariance.append(self._position_covariance(bank, sins))
            return
        estimate, covariance, tracked = self._reported(bank, sins)
        position = self.layout.slice(POSITION)
        rows.position_covariance.append(covariance[position, position])
        if rows.recorder is not None:
            rows.recorder.record(estimate, covariance)
        if sampled:
            rows.observed.sample(t, tracked)

    def _reported(
        self, bank: FilterBank, sins: Strapdown
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """From one estimate of the bank: every state's estimate and the covariance the
        outputs report (:meth:`_estimate`, or the covariance analysis's), and the covariance
        the observability tracker samples, in the coordinates of its prior (the filter's; with
        the analysis, the standard error, the filter's own there)."""
        filter_estimate = bank.estimate()
        estimate, covariance = self._estimate(filter_estimate, sins)
        if self._analysis is None:
            return estimate, covariance, filter_estimate[1]
        analysed = self._analysis.standard(*self._point(sins.nav))
        return estimate, analysed, analysed

    def _estimate(
        self, filter_estimate: tuple[NDArray[np.float64], NDArray[np.float64]], sins: Strapdown
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Estimate and covariance of every state, in the standard error, from the bank's
        ``filter_estimate`` (:meth:`FilterBank.estimate`, in the filter's coordinates); the IMU
        biases whole (the part the SINS already compensates added to the filter's residual)."""
        estimate, covariance = filter_estimate
        if self._coordinates is not None:
            estimate, covariance = self._coordinates.to_standard(
                estimate, covariance, *self._point(sins.nav)
            )
        estimate[self.layout.slice(GYRO_BIAS)] += sins.gyro_bias
        estimate[self.layout.slice(ACCEL_BIAS)] += sins.accel_bias
        return estimate, covariance

    def _correct(self, sins: Strapdown, dx: NDArray[np.float64]) -> None:
        """Feed the common-state estimate ``dx`` back into the SINS, which takes the standard
        error (``T dx`` with ``filter.invariant_error``)."""
        if self._coordinates is not None:
            dx = self._coordinates.apply(dx, *self._point(sins.nav))
        self._feed_back(sins, *(dx[self.layout.slice(block)] for block in COMMON_BLOCKS))

    def _feed_back(
        self,
        sins: Strapdown,
        velocity_error: NDArray[np.float64],
        attitude_error: NDArray[np.float64],
        position_error_enu: NDArray[np.float64],
        gyro_bias_error: NDArray[np.float64],
        accel_bias_error: NDArray[np.float64],
    ) -> None:
        """:meth:`Strapdown.correct`, the specific force held for F moved with the nominal
        state (:meth:`fusion.error_model.SpecificForceFilter.follow`)."""
        held = self._specific_force.holds_force  # τ = 0: nothing to move, no DCMs to build
        c_b_n = sins.c_b_n if held else None
        sins.correct(
            velocity_error, attitude_error, position_error_enu, gyro_bias_error, accel_bias_error
        )
        if c_b_n is not None:
            self._specific_force.follow(sins.c_b_n @ c_b_n.T, -sins.c_b_n @ accel_bias_error)

    def _point(self, nav: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """ENU velocity and ENU position about the origin of the packed navigation state
        ``nav``: where ``T`` is evaluated (:mod:`fusion.invariant_error`)."""
        position = self.frame.point(float(nav[LAT]), float(nav[LON]), float(nav[HGT]))[0]
        return nav[VEL : VEL + 3].copy(), position

    def _transform(self, sins: Strapdown) -> NDArray[np.float64]:
        """``T`` at the nominal state over the full layout."""
        if self._coordinates is None:
            return np.eye(self.layout.dim)
        return self._coordinates.transform(self.layout.dim, *self._point(sins.nav))

    def _inverse_transform(self, sins: Strapdown) -> NDArray[np.float64]:
        """``T⁻¹`` at the nominal state over the full layout."""
        if self._coordinates is None:
            return np.eye(self.layout.dim)
        return self._coordinates.inverse_transform(self.layout.dim, *self._point(sins.nav))

    def _in_filter_coordinates(
        self, noise: NDArray[np.float64], sins: Strapdown
    ) -> NDArray[np.float64]:
        """Process noise over the standard error as the filter holds it (``T⁻¹ Q T⁻ᵀ`` with
        ``filter.invariant_error``)."""
        if self._coordinates is None:
            return noise
        return self._coordinates.congruent(noise, *self._point(sins.nav), -1.0)

    def _transition(
        self, sins: Strapdown, f_n: NDArray[np.float64], dt: float, coupling: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Φ and Q_d over ``dt`` in the filter's coordinates, the specific force ``f_n`` and the
        heading's coupling into the tilt (:func:`fusion.error_model.heading_coupling`) in F
        (:meth:`fusion.invariant_error.InvariantCoordinates.transition`)."""
        if self._coordinates is None:
            return self.model.discrete(sins.nav, f_n, sins.c_b_n, dt, coupling)
        position = self._point(sins.nav)[1]
        return self._coordinates.transition(
            self.model, sins.nav, f_n, sins.c_b_n, position, dt, coupling
        )

    def _analysis_predict(
        self,
        sins: Strapdown,
        f_n: NDArray[np.float64],
        dt: float,
        noise: NDArray[np.float64] | None,
    ) -> None:
        """The covariance analysis's time update over ``dt`` at the filter's specific force,
        with ``noise`` (over the standard error, an IMU gap's) added; the heading's coupling
        into the tilt is the expectation over the analysed error (``P_a``)."""
        assert self._analysis is not None
        velocity, position = self._point(sins.nav)
        coordinates = self._analysis.coordinates
        coupling = heading_coupling(self._analysis.P)
        phi, qd = coordinates.transition(
            self.model, sins.nav, f_n, sins.c_b_n, position, dt, coupling
        )
        if noise is not None:
            qd = qd + coordinates.congruent(noise, velocity, position, -1.0)
        self._analysis.predict(phi, qd)

    def _position_covariance(self, bank: FilterBank, sins: Strapdown) -> NDArray[np.float64]:
        """The position error's covariance in local metres."""
        if self._analysis is not None:
            position = self.layout.slice(POSITION)
            return self._analysis.standard(*self._point(sins.nav))[position, position]
        if self._coordinates is None:
            return bank.position_covariance()
        common = self._coordinates.congruent(bank.common_covariance(), *self._point(sins.nav))
        position = self.layout.slice(POSITION)
        return common[position, position]

    def _hold_bounds(
        self, kf: KalmanFilter, layout: StateLayout, t: float, bank: FilterBank
    ) -> None:
        """Hold ``kf``'s estimates inside their bounds; a ``faults.csv`` row (:data:`BOUND`)
        when one reaches its bound. Nothing to do past the projection unless a state is or
        was at its bound (this runs after every accepted update)."""
        held = kf.hold_bounds(layout.bounds)
        if not held and not self._at_bound:
            return
        bounds = dict(layout.bounds)
        for index, value in held:
            label = layout.labels[index]
            if label not in self._at_bound:
                self._at_bound[label] = (kf, index)
                reason = "estimate held at its physical bound (StateBlock.bound)"
                bank.faults.append(FaultEvent(t, label, value, bounds[index], BOUND, reason))
        for label, (owner, index) in list(self._at_bound.items()):
            if owner is kf and abs(kf.x[index]) < BOUND_RELEASE * bounds[index]:
                del self._at_bound[label]

    def _gap_noise(
        self, gap: GapBridge, sins: Strapdown, f_n: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Process noise of a bridged IMU gap (fusion/imu_gaps.py)."""
        f, _ = self.model.continuous(sins.nav, f_n, sins.c_b_n)
        return gap.noise(f, self.layout.slice(GYRO_BIAS), self.layout.slice(ACCEL_BIAS))

    def _smoother(self, bank: FilterBank) -> WindowedSmoother | None:
        """The configured smoother, its windows closing at the plugins' window ends (online)."""
        opts = self.config.smoother
        if opts.mode == "off":
            return None
        coordinates, dim = self._coordinates, bank.smoothing_dim
        to_standard = (
            None
            if coordinates is None
            else lambda nav: coordinates.transform(dim, *self._point(nav))
        )
        reporters = [p for p in self.plugins if p.closes_windows] if opts.mode == "online" else []
        if opts.mode == "online" and not reporters:
            self._online_without_window_ends()

        def due(t: float) -> bool:  # without reporters: one window, the whole recording
            return any([p.window_end_due(t) for p in reporters])  # ask every one: each counts

        return WindowedSmoother(
            bank.smoothing_dim,
            due,
            opts.memory_budget_mb,
            self._positions,
            to_standard,
            opts.significance_sigma,
        )

    def _online_without_window_ends(self) -> None:
        """Online smoothing with no plugin to end its windows: a configuration error, unless
        the one that would have was left out for a missing stream; then a warning, and the
        whole recording is smoothed as one window."""
        ends = [
            b
            for b in self.config.plugins
            if b.instance_name in self.left_out and load_plugin_class(b.type).closes_windows
        ]
        if not ends:
            raise ConfigError(
                "config key smoother.mode: online smoothing needs a plugin that reports"
                " window ends (face ends), e.g. cpoem; none of the configured plugins does"
            )
        _log.warning(
            "smoother.mode online: %s, which ends its windows, was left out (no stream);"
            " the whole recording is smoothed as one window instead",
            ends[0].instance_name,
        )

    def _smoothing_step(
        self,
        smoother: WindowedSmoother,
        bank: FilterBank,
        t: float,
        phi: NDArray[np.float64] | None,
        prior: tuple[NDArray[np.float64], NDArray[np.float64]],
        posterior: tuple[NDArray[np.float64], NDArray[np.float64]],
        correction: NDArray[np.float64],
        nav_after: NDArray[np.float64] | None,
    ) -> None:
        """Store one step; when it closes a window, hand the smoothed positions to the plugins."""
        dim = bank.smoothing_dim
        feedback = np.zeros(dim)
        feedback[:N_COMMON] = correction
        transition = np.eye(dim) if phi is None else bank.smoothing_transition(phi)
        window = smoother.step(t, transition, prior, posterior, feedback, nav_after)
        if window is not None:
            self._hand_smoothed(window)

    def _hand_smoothed(self, window: Rows) -> None:
        """Hand the smoothed positions of a window just closed to the plugins."""
        t_s, _, enu, cov_s = window
        if t_s.size:
            for plugin in self.plugins:
                plugin.receive_smoothed(t_s, enu, cov_s)

    def _dead_reckoning(self) -> Solution:
        return dead_reckon(
            self.recording,
            self.initial_state(),
            self.frame,
            self.imu_noise,
            self.config.filter.dead_reckoning,
        )

    def _without_filter(
        self, wall0: float, solution: Solution, logs: dict[str, InnovationLog] | None = None
    ) -> RunResult:
        """Result of an architecture that estimates nothing (dead reckoning, standalone)."""
        return RunResult(
            solution=solution,
            layout=self.layout,
            final_state=np.zeros(self.layout.dim),
            final_covariance=self.layout.initial_covariance(),
            innovations={} if logs is None else logs,
            faults=[],
            wall_time_s=time.perf_counter() - wall0,
            config=self.config,
            recording_name=self.recording.meta.name,
            screening=self.screening,
            rest_noise=self.rest_noise,
            rest_bias=self.rest_bias,
            left_out=tuple(self.left_out.values()),
        )

    def _context(
        self,
        sins: Strapdown,
        layout: StateLayout,
        kf: KalmanFilter,
        t: float,
        shared: NDArray[np.float64] | None,
    ) -> MeasurementContext:
        nav = sins.nav
        x, covariance = kf.x.copy(), (kf.P if shared is None else shared).view()
        if self._coordinates is not None:  # plugins read the standard error
            velocity, position = self._point(nav)
            x, covariance = self._coordinates.to_standard(x, covariance, velocity, position)
        covariance.flags.writeable = False
        return MeasurementContext(
            t=t,
            lat=float(nav[LAT]),
            lon=float(nav[LON]),
            height=float(nav[HGT]),
            velocity=nav[VEL : VEL + 3].copy(),
            c_b_n=sins.c_b_n,
            layout=layout,
            x=x,
            covariance=covariance,
            frame=self.frame,
            gyro_bias=sins.gyro_bias.copy(),
            accel_bias=sins.accel_bias.copy(),
            travel=sins.travel.copy(),
            observable_force=self.config.filter.observable_force,
        )

    def _tell_owner(self, state: JumpState, onset: float, before: float) -> None:
        """Pass a jump taken in to the plugin that owns the state."""
        for plugin, blocks in zip(self.plugins, self.plugin_blocks, strict=True):
            if any(b.name == state.block for b in blocks):
                plugin.state_jumped(state.name, onset, before)

    def _update(
        self,
        src: int,
        index: int,
        t: float,
        sins: Strapdown,
        bank: FilterBank,
        logs: dict[str, InnovationLog],
        jumps: JumpDetector | None,
    ) -> bool:
        plugin = self.plugins[src]
        layout, kf = bank.filter_of(src)
        shared = bank.shared_covariance(src)
        ctx = self._context(sins, layout, kf, t, shared)
        if plugin.beyond_linearization(index, ctx):  # a fix from the plugin alone, or nothing
            return self._reacquire(src, t, sins, bank)
        if plugin.off_solution(index):  # the position is off, not the velocity
            return self._reacquire(src, t, sins, bank, velocity=False)
        m = plugin.measure(index, ctx)
        if m is None:
            return False
        if m.fault is not None:
            bank.faults.append(FaultEvent(t, plugin.name, math.nan, math.nan, *m.fault))
        if not (np.isfinite(m.z).all() and np.isfinite(m.H).all() and np.isfinite(m.R).all()):
            raise PluginError(
                f"plugin {plugin.name!r} returned a measurement with a NaN or an infinity in z,"
                f" H or R at t = {t:.3f} s: a fault of the plugin (the reader passes only finite"
                " readings)"
            )
        rows = self._filter_rows(m.H, m.velocity_at, ctx)
        correlated = m.correlated
        if correlated is not None:
            offset = self.stored_error_offsets[src]
            correlated = replace(correlated, columns=correlated.columns + offset)
        signature = (
            jumps.innovation_signature(bank, src, rows, layout) if jumps is not None else None
        )
        try:
            res = self._kalman_update(kf, m, rows, self.gates[src], shared, correlated, ctx)
        except np.linalg.LinAlgError:  # S not positive definite: the update is not usable
            logs[plugin.name].record(t, math.inf, len(m.z), False, m.suspect)
            return False
        if res.gain is not None and self._analysis is not None:
            velocity = _rows_velocity(m.velocity_at, ctx)
            self._analysis.update(res.gain, m.H, m.R, velocity, ctx.velocity, ctx.position_enu)
        if res.accepted:
            self._hold_bounds(kf, layout, t, bank)
        holds = res.accepted and self._needs_holds and _holds(m.H, layout)
        if not m.withheld:  # the plugin's own test has dealt with it: not the monitor's
            bank.record(src, t, res, m.suspect, holds)
        if holds:
            self._last_held[src] = t
        lock = self._locks[src]
        if lock is not None and lock.observe(t, res.accepted):
            holders = self._holders(src, t)
            if not holders:
                span = lock.span_s(t)
                lock.reset()
                if not self._reacquire(src, t, sins, bank):
                    factor, doubt = 1.0, plugin.lost_lock_doubt(t, ctx)
                    if doubt is None and lock.first_inflation():
                        statistic_covariance = kf.P if shared is None else shared
                        factor = self._inflate(rows, statistic_covariance, res, bank)
                    bank.faults.append(self._lost_lock(src, t, res, factor, doubt, span))
            elif lock.first_dispute():
                bank.faults.append(self._disputed_lock(src, t, res, holders))
                if jumps is not None and signature is not None:
                    opened = jumps.unseen_jump(t, bank, signature, res, plugin.name)
                    bank.faults.extend([opened] if opened is not None else [])
        if jumps is not None and signature is not None:
            events = [jumps.observe(t, bank, src, signature, res)]
            events += [jumps.rest(t, bank, name) for name in m.at_rest]
            bank.faults.extend(e for e in events if e is not None)
            if res.accepted and bank.in_fusion(src) and np.any(rows[:, layout.slice(POSITION)]):
                jumps.anchor(t, bank)  # a position source agrees with the fused filter
        logs[plugin.name].append(t, res, m.suspect)
        return res.accepted

    def _kalman_update(
        self,
        kf: KalmanFilter,
        m: Measurement,
        rows: NDArray[np.float64],
        gate: float | None,
        shared: NDArray[np.float64] | None,
        correlated: CorrelatedNoise | None,
        ctx: MeasurementContext,
    ) -> UpdateResult:
        """``kf``'s update with ``m`` over ``rows``. A consider state is a statement about the
        standard error (a heading the update leaves alone, the rest corrected as far as it
        can be): Schmidt's gain depends on the coordinates, and over the invariant error the
        same heading column is mostly the turn about the origin, which left uncorrected froze
        the position's rotational part (sins_uwb 0.28 m against 0.01 m on a random world).
        With ``filter.invariant_error`` such an update runs in the standard error."""
        coordinates = self._coordinates
        if coordinates is None or not m.consider:
            return kf.update(m.z, rows, m.R, gate, shared, correlated, m.consider, m.withheld)
        to_standard = coordinates.transform(kf.x.size, ctx.velocity, ctx.position_enu)
        kf.change_coordinates(to_standard)
        try:
            if shared is not None:
                shared = to_standard @ shared @ to_standard.T
            return kf.update(m.z, m.H, m.R, gate, shared, correlated, m.consider, m.withheld)
        finally:
            size = kf.x.size
            kf.change_coordinates(
                coordinates.inverse_transform(size, ctx.velocity, ctx.position_enu)
            )

    def _filter_rows(
        self,
        h: NDArray[np.float64],
        velocity_at: NDArray[np.float64] | None,
        ctx: MeasurementContext,
    ) -> NDArray[np.float64]:
        """A plugin's rows over the invariant error, ``H T`` at the velocity its attitude
        columns were evaluated at (the nominal one unless it says) and the nominal position;
        ``h`` itself without ``filter.invariant_error``."""
        coordinates = self._coordinates
        if coordinates is None:
            return h
        velocity = _rows_velocity(velocity_at, ctx)
        return coordinates.rows(h, velocity, ctx.position_enu)

    def _process_noise(
        self,
        sources: NDArray[np.integer],
        indices: NDArray[np.integer],
        t: float,
        widened: list[FaultEvent],
    ) -> NDArray[np.float64] | None:
        """The process noise (full layout) the plugins measured at instant ``t`` add
        (:meth:`fusion.plugin.Plugin.process_noise`), or None; the ``faults.csv`` line of each
        that gives a reason goes to ``widened``."""
        added = None
        for src, index in zip(sources.tolist(), indices.tolist(), strict=True):
            if src not in self._noise_sources:  # outputs, grid and store epochs are negative
                continue
            noise = self.plugins[src].process_noise(index)
            if noise is None:
                continue
            for block, variances in noise.variances.items():
                if added is None:
                    added = np.zeros(self.layout.dim)
                added[self.layout.slice(block)] += variances
            if noise.reason is not None:
                name = self.plugins[src].name
                widened.append(FaultEvent(t, name, math.nan, math.nan, WIDEN, noise.reason))
        return None if added is None else np.diag(added)

    def _holders(self, src: int, t: float) -> list[int]:
        """The other plugins that had an update accepted within the lock window before ``t``
        that holds the filter (:func:`_holds`). Only with none is a plugin whose updates are all
        rejected taken to show a filter that lost its way (one that other sensors still hold
        is the suspect itself: a burst of NLOS on every anchor, which re-acquiring from would
        have moved the SINS by the NLOS bias). A motion constraint or a ZARU does not hold it:
        the SINS drifts along the track under them, and a UWB tag back in reach of the
        anchors after the middle of the face found every range rejected for good."""
        since = t - self.config.filter.lock_window_s
        return [k for k, last in enumerate(self._last_held) if k != src and last > since]

    @staticmethod
    def _inflate(
        h: NDArray[np.float64],
        covariance: NDArray[np.float64],
        res: UpdateResult,
        bank: FilterBank,
    ) -> float:
        """Inflate the SINS covariance by the fading factor of the last rejected update ``res``
        (rows ``h``, gated against ``covariance``) of a lost lock the plugin cannot re-acquire
        (:mod:`fusion.lock`); the factor."""
        predicted = h @ covariance @ h.T
        noise = res.whitening @ res.whitening.T - predicted
        factor = fading_factor(res.innovation, predicted, noise)
        bank.inflate_common(factor)
        return factor

    def _lost_lock(
        self,
        src: int,
        t: float,
        res: UpdateResult,
        factor: float,
        doubt: str | None,
        span_s: float,
    ) -> FaultEvent:
        """The ``faults.csv`` line of plugin ``src``'s lost lock over the last ``span_s``, with
        the inflation (1: none, for the plugin's ``doubt`` or the last one having brought no
        update back)."""
        name = self.plugins[src].name
        reason = f"every update of {name} rejected for {span_s:.3g} s; "
        if doubt is not None:
            reason += f"not inflated: {doubt}"
        elif factor > 1.0:
            reason += f"variances of the SINS states inflated x{factor:.3g}"
        else:
            reason += "not inflated again: the last inflation did not bring its updates back"
        return FaultEvent(t, name, res.nis, math.nan, LOST_LOCK, reason)

    def _disputed_lock(
        self, src: int, t: float, res: UpdateResult, holders: list[int]
    ) -> FaultEvent:
        """The ``faults.csv`` line of plugin ``src`` whose every update is rejected while the
        plugins ``holders`` hold the filter (:meth:`_holders`): no re-acquisition, so that an
        NLOS burst on every anchor does not move the SINS, but the user is told, once until an
        update of ``src`` is accepted again (:meth:`fusion.lock.LockMonitor.first_dispute`),
        that either the sensor or the filter is wrong. Before, such
        a plugin was rejected in silence however long it lasted
        (docs/design/2026-11-30-anchor-exclusion.md). The caller then asks the jump detector
        whether a jump since the plugin last agreed explains it
        (:meth:`fusion.jumps.JumpDetector.unseen_jump`)."""
        name = self.plugins[src].name
        held_by = ", ".join(self.plugins[k].name for k in holders)
        reason = (
            f"every update of {name} rejected for {self.config.filter.lock_window_s:g} s while"
            f" {held_by} held the filter: {name} is faulty, or the filter is off by"
            " more than its σ (not re-acquired from it)"
        )
        return FaultEvent(t, name, res.nis, math.nan, DISPUTED, reason)

    def _reacquire(
        self, src: int, t: float, sins: Strapdown, bank: FilterBank, velocity: bool = True
    ) -> bool:
        """Move the SINS to where plugin ``src`` alone puts it, restart position and (unless
        ``velocity`` is false) velocity there and report it (:mod:`fusion.lock`); False when
        the plugin cannot say. A filter on a wrong solution (:meth:`Plugin.off_solution`)
        keeps its velocity: restarting a held velocity from two fixes a second apart cost a
        full filter its odometer's lock (59 m off on random world 2 at its own length). A fix
        with a level (a ZUPT: the machine stands) restarts the velocity, the tilt and the
        position together (:meth:`_restart_at_fix`)."""
        plugin = self.plugins[src]
        layout, kf = bank.filter_of(src)
        ctx = self._context(sins, layout, kf, t, bank.shared_covariance(src))
        fix = plugin.reacquire(t, ctx)
        if fix is None:
            return False
        rot = ctx.rotation_to_local
        error = rot @ (ctx.position_enu - fix.position_enu)  # δp of the nominal, local metres
        covariance = rot @ fix.covariance @ rot.T
        shared = bank.shared_covariance(src)
        taken_in = None
        if fix.level is None:  # at rest the position restarts too (_restart_at_fix)
            taken_in = self._take_in_fix(src, kf, layout, shared, error, covariance, ctx)
        if taken_in is None:
            moved, reason = self._restart_at_fix(sins, bank, fix, error, covariance, ctx, velocity)
        else:
            moved, reason = taken_in
        reason = f"{plugin.name} {reason}"
        bank.faults.append(FaultEvent(t, plugin.name, moved, math.nan, REACQUIRE, reason))
        lock = self._locks[src]
        if lock is not None:
            lock.reset()
        return True

    def _restart_at_fix(
        self,
        sins: Strapdown,
        bank: FilterBank,
        fix: Reacquisition,
        error: NDArray[np.float64],
        covariance: NDArray[np.float64],
        ctx: MeasurementContext,
        velocity: bool,
    ) -> tuple[float, str]:
        """Restart the position (local ``error`` and ``covariance`` of the fix), and, if
        ``velocity`` or the fix has a level, the velocity at ``fix``, uncorrelated with the
        rest; how far the position moved and the ``faults.csv`` reason.

        A fix with a level (:class:`fusion.lock.Level`: a machine at rest) restarts the tilt
        too, the heading and the biases kept, and its position even where it agrees with the
        filter: the velocity error that lost the lock came with position correlations far
        beyond the first-order model (a SINS that coasted a pass on a wrong tilt and
        heading), and a zero velocity taken in through them moved the position kilometres
        from the fix at a σ of a few hundred metres."""
        rot = ctx.rotation_to_local
        moved = float(np.linalg.norm(error))
        v, a, p = (self.layout.slice(block) for block in (VELOCITY, ATTITUDE, POSITION))
        velocity_error, tilt, states = np.zeros(3), np.zeros(3), np.r_[p]
        level = fix.level
        if velocity or level is not None:
            velocity_error = ctx.velocity - rot @ fix.velocity_enu
            states = np.r_[v, p]
            blocks = [rot @ fix.velocity_covariance @ rot.T, covariance]
            if level is not None:
                tilt = level.attitude_error
                states = np.r_[v, a.start : a.start + 2, p]  # the tilt
                blocks.insert(1, level.variance * np.eye(2))
            covariance = scipy.linalg.block_diag(*blocks)
        self._restart(sins, bank, ctx, states, covariance, velocity_error, tilt, error)
        if level is None:
            return moved, f"alone moved the position by {moved:.3g} m"
        speed = float(np.linalg.norm(fix.velocity_enu))
        return moved, (
            (
                f"in motion: restarted the velocity at {speed:.3g} m/s"
                if speed
                else "at rest: restarted the velocity at zero"
            )
            + f" (it was {np.linalg.norm(velocity_error):.3g} m/s off), levelled the attitude by"
            f" {math.degrees(np.linalg.norm(tilt)):.3g}° and moved the position by {moved:.3g} m"
        )

    def _restart(
        self,
        sins: Strapdown,
        bank: FilterBank,
        ctx: MeasurementContext,
        states: NDArray[np.intp],
        covariance: NDArray[np.float64],
        velocity_error: NDArray[np.float64],
        attitude_error: NDArray[np.float64],
        position_error: NDArray[np.float64],
    ) -> None:
        """Remove the given errors (local axes) from the SINS and restart the common
        ``states`` with ``covariance``, uncorrelated with the rest (in the standard error)."""
        if self._coordinates is not None:  # the restart is of standard states
            bank.change_coordinates(self._transform(sins))
        self._feed_back(sins, velocity_error, attitude_error, np.zeros(3), np.zeros(3), np.zeros(3))
        if position_error.any():
            self._move(sins, ctx.position_enu - ctx.rotation_to_local.T @ position_error)
        bank.restart_common(states, covariance)
        if self._analysis is not None:
            self._analysis.restart_block(states, covariance, *self._point(sins.nav))
        if self._coordinates is not None:
            bank.change_coordinates(self._inverse_transform(sins))

    def _move(self, sins: Strapdown, position_enu: NDArray[np.float64]) -> None:
        """Put the SINS at ``position_enu`` (origin ENU) exactly, its velocity and attitude
        carried into the local frame there. A position error removed to first order
        (:func:`fusion.strapdown.remove_errors`) misses by ``d²/R`` (a ZUPT re-acquisition of a
        SINS that coasted 800 km: 59 km), and a level frame 800 km away is turned by 7°."""
        nav = sins.nav
        before = self.frame.rotation_to_local(nav[LAT], nav[LON])
        lat, lon, height = (float(v) for v in self.frame.to_geodetic(position_enu))
        turn = self.frame.rotation_to_local(lat, lon) @ before.T  # old local → new local axes
        nav[LAT], nav[LON], nav[HGT] = lat, lon, height
        nav[VEL : VEL + 3] = turn @ nav[VEL : VEL + 3]
        nav[Q0 : Q0 + 4] = attitude.quat_from_dcm(turn @ sins.c_b_n)

    def _take_in_fix(
        self,
        src: int,
        kf: KalmanFilter,
        layout: StateLayout,
        shared: NDArray[np.float64] | None,
        error: NDArray[np.float64],
        covariance: NDArray[np.float64],
        ctx: MeasurementContext,
    ) -> tuple[float, str] | None:
        """Take plugin ``src``'s re-acquisition fix in as a position update of its filter
        ``kf`` when it agrees with the filter (within the plugin's gate, or
        :data:`fusion.lock.FIX_GATE_PROBABILITY` for an ungated one; χ² with 3 degrees of
        freedom; gated against ``shared``, a federated local's covariance at unit share): how
        far it moved the position and the ``faults.csv`` reason, or None. ``error``: the
        nominal position minus the fix's (local metres), ``covariance`` the fix's (local
        axes).

        A fix that agrees shows a filter that is uncertain, not lost (the SINS back among
        the anchors after a pass, its σ metres along the face): restarting there would throw
        away what the SINS still knows where the fix is weak — the height and the across-face
        position, seen from anchors clustered at a face end 40 m away — and the ranges that
        follow, linearized about a height the fix left 13 m uncertain, slid the filter along
        their sphere to 8 m off at a σ of 0.2 m (random world 12 at its own length). The
        update adds the fix's information to the filter's position alone: every other state
        is a consider state (:attr:`fusion.plugin.Measurement.consider`), since a fix that
        moves the position by 160 m after a pass moves the heading and the gyro bias through
        correlations far beyond their linearization; the ranges that follow correct them
        through the correlations the update leaves right."""
        position = layout.slice(POSITION)
        h = np.zeros((3, layout.dim))
        h[:, position] = np.eye(3)
        others = tuple(i for i in range(layout.dim) if not position.start <= i < position.stop)
        m = Measurement(error, h, covariance, consider=others)
        rows = self._filter_rows(h, None, ctx)
        gate = self.gates[src] or FIX_GATE_PROBABILITY  # an ungated plugin's fix is still tested
        res = self._kalman_update(kf, m, rows, gate, shared, None, ctx)
        if not res.accepted or res.gain is None:
            return None
        moved = float(np.linalg.norm(res.gain[position] @ res.innovation))
        reason = (
            f"alone gave a fix within the filter's σ (χ² {res.nis:.3g}"
            f" of 3 degrees of freedom), taken in as a position update that moved it {moved:.3g} m"
        )
        return moved, reason

    def _store(self, src: int, index: int, t: float, sins: Strapdown, bank: FilterBank) -> None:
        """A plugin's store epoch: the filter takes on the stored error's covariances."""
        layout, kf = bank.filter_of(src)
        context = self._context(sins, layout, kf, t, bank.shared_covariance(src))
        stored = self.plugins[src].store(index, context)
        if stored is not None:
            offset = self.stored_error_offsets[src]
            bank.store_error(
                src, stored.columns + offset, self._filter_rows(stored.h, None, context)
            )

    def _positions(self, nav: NDArray[np.float64]) -> NDArray[np.float64]:
        """Output (origin ENU) positions of packed navigation states (n, NAV_SIZE)."""
        return self.frame.to_enu(nav[:, LAT], nav[:, LON], nav[:, HGT])

    @staticmethod
    def _solution(
        t: NDArray[np.float64],
        nav: NDArray[np.float64],
        position: NDArray[np.float64],
        cov: NDArray[np.float64],
    ) -> Solution:
        return Solution(
            t=t,
            position=position,
            velocity=nav[:, VEL : VEL + 3].copy(),
            attitude=attitude.euler_from_quat(nav[:, Q0 : Q0 + 4]),
            sigma_position=np.sqrt(np.diagonal(cov, axis1=1, axis2=2)),
            position_covariance=cov,
        )
