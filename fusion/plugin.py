"""The aiding-plugin interface and the entry-point registry.

A plugin turns one sensor stream of a recording into error-state measurements. It knows nothing
of the filter architecture: at each of its epochs the engine hands it a :class:`MeasurementContext`
(the nominal SINS state, the filter's :class:`~fusion.error_model.StateLayout` and the current
error estimate) and the plugin returns a :class:`Measurement` ``(z, H, R)`` over that layout, or
``None`` when it has nothing to say. ``z`` is the predicted-minus-measured residual, so that
``z = H δx + v`` with ``δx`` the error state (estimate minus truth). A plugin owns the extra states
its model needs (odometer scale, mounting angles, range biases) by declaring
:class:`~fusion.error_model.StateBlock` objects, which the engine appends to the layout. A plugin
that stores the filter's estimate to measure against it later (CPOEM's optimal points) declares
:meth:`Plugin.stored_errors` variables, stores into them at its :meth:`Plugin.store_epochs`
(after that instant's update round and feedback) by returning a :class:`StoredEstimate`, and
names them in a later measurement's :class:`~fusion.kalman.CorrelatedNoise`: the filter then
accounts for the stored estimate's error being correlated with its own (:mod:`fusion.kalman`).

Plugins are found through the ``fusion.plugins`` entry-point group (``name = "module:Class"``),
so a third party adds one by packaging it, without touching the core; a plugin defined in a
script or a notebook is named to the registry at run time by :func:`register_plugin` instead.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from importlib.metadata import entry_points
from typing import Any, ClassVar

import numpy as np
import scipy.linalg
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, ValidationError

from fusion.config import FusionConfig
from fusion.earth import LocalFrame
from fusion.error_model import POSITION, StateBlock, StateLayout
from fusion.innovations import InnovationLog
from fusion.kalman import CorrelatedNoise
from fusion.lock import Reacquisition
from fusion.recording import Recording
from fusion.solution import Solution
from fusion.validation import dotted, error_lines

ENTRY_POINT_GROUP = "fusion.plugins"


class PluginOptions(BaseModel):
    """Base of every plugin's options model (unknown keys are errors)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=True)


@dataclass(frozen=True)
class ProcessNoise:
    """What a plugin's readings show the filter's model missed before one of its epochs
    (:meth:`Plugin.process_noise`)."""

    variances: dict[str, NDArray[np.float64]]
    """Variances to add, by state block name (e.g. ``VELOCITY``)."""
    reason: str | None = None
    """Why, when it is the filter's own belief found wrong (a ``faults.csv`` line, action
    :data:`WIDEN`); None for noise the model merely leaves out (a start the encoder shows)."""


WIDEN = "widen"
"""``faults.csv`` action of a plugin's :class:`ProcessNoise` that gives a reason."""


@dataclass(frozen=True)
class Measurement:
    """An error-state measurement ``z = H δx + v``, ``v ~ N(0, R)``."""

    z: NDArray[np.float64]
    H: NDArray[np.float64]
    R: NDArray[np.float64]
    suspect: bool = False
    """The plugin's own fault indicator flags this epoch (e.g. a magnetic field whose norm or
    dip is off the expected earth field). The centralized filter logs it; the federated master
    counts it toward isolating the plugin's local filter."""
    withheld: bool = False
    """The plugin's own test says this reading is faulty (an NLOS range): the engine treats it
    as its gate would treat an outlier — innovation logged, update rejected, counted towards a
    lost lock — and corrects nothing. The federated master's fault monitor does not see it:
    the plugin has dealt with it, and a run of withheld readings would otherwise isolate a
    local whose other readings are sound."""
    at_rest: tuple[str, ...] = ()
    """Names of the plugin's states that are physically back at their rest value at this epoch
    (a slip ratio while the wheel stands still): a state that had left rest through a jump is
    restarted there (:meth:`fusion.jumps.JumpDetector.rest`)."""
    correlated: CorrelatedNoise | None = None
    """The noise carries the errors of the plugin's stored estimates (columns numbered from 0
    within the plugin's :meth:`Plugin.stored_errors`); ``R`` includes their covariance."""
    consider: tuple[int, ...] = ()
    """States (indices of the filter's layout) that the update leaves alone — Schmidt's
    consider states: their uncertainty enters S and the other states' gains through their
    columns of H and their covariances, their own gain is zero (:meth:`KalmanFilter.update`).
    For a column that only a linearization at an erroneous state makes informative."""
    velocity_at: NDArray[np.float64] | None = None
    """The ENU velocity (m/s) at which the rows' attitude columns were evaluated, where it is not
    the nominal one: zero for a zero-velocity update, the column velocity of a motion
    constraint. With ``filter.invariant_error`` the engine takes ``δv = ξ_v + v × ξ_φ`` at this
    velocity (:mod:`fusion.invariant_error`), so that a source that cannot see a turn finds no
    heading column; None: the nominal velocity."""
    fault: tuple[str, str] | None = None
    """A ``faults.csv`` line (action, reason) of the plugin's own test at this epoch: one of
    its sensor's parts taken out of the updates or let back in (an anchor that disagrees with
    the others, :class:`fusion.aiding.uwb.UwbRanges`)."""

    def stacked_with(self, other: Measurement) -> Measurement:
        """This measurement and ``other`` as one (rows appended, independent noise apart from
        the stored errors one of them may carry). It leaves alone only the states both leave
        alone: a part that informs a state (a zero angular rate the vertical gyro bias) makes
        the whole update inform it."""
        consider = tuple(i for i in self.consider if i in other.consider)
        return Measurement(
            np.concatenate([self.z, other.z]),
            np.vstack([self.H, other.H]),
            scipy.linalg.block_diag(self.R, other.R),
            self.suspect or other.suspect,
            self.withheld or other.withheld,
            self.at_rest + tuple(n for n in other.at_rest if n not in self.at_rest),
            _stacked_noise(self, other),
            consider,
            self.velocity_at if self.velocity_at is not None else other.velocity_at,
            self.fault if self.fault is not None else other.fault,
        )


def _stacked_noise(first: Measurement, second: Measurement) -> CorrelatedNoise | None:
    """The stored errors of two stacked measurements, of which at most one carries any (two
    would need the covariance of their stored errors in R's off-diagonal block)."""
    if first.correlated is not None and second.correlated is not None:
        raise ValueError("cannot stack two measurements that both carry stored errors")
    part = first.correlated or second.correlated
    if part is None:
        return None
    mixing = np.zeros((first.z.size + second.z.size, part.columns.size))
    rows = slice(0, first.z.size) if first.correlated is not None else slice(first.z.size, None)
    mixing[rows] = part.mixing
    return CorrelatedNoise(part.columns, mixing)


@dataclass(frozen=True)
class StoredEstimate:
    """The plugin stores an estimate of the filter now: the error of stored-error variables
    ``columns`` (numbered within the plugin) is ``h (δx − δx̂)``, the part of the error state
    the filter has not estimated, ``h`` over the layout of the filter serving the plugin
    (:meth:`fusion.kalman.KalmanFilter.store_error`)."""

    columns: NDArray[np.intp]
    h: NDArray[np.float64]


@dataclass(frozen=True)
class MeasurementContext:
    """What a plugin sees at one of its epochs.

    Attributes
    ----------
    t
        Epoch (s, recording clock).
    lat, lon, height
        Nominal geodetic position (rad, rad, m).
    velocity
        Nominal ENU velocity (m/s).
    c_b_n
        Nominal attitude matrix.
    position_enu, rotation_to_local
        Nominal position in ENU metres about the recording origin, and the rotation from the
        origin's ENU axes to the local ones there (computed on first use).
    position_covariance_enu
        The position error's covariance turned to the origin's ENU axes.
    layout
        States of the filter being served.
    x
        Its current error estimate (plugin states may be non-zero; SINS states are zero after
        closed-loop feedback).
    covariance
        Its current covariance (a read-only view of the filter's own matrix: do not modify).
    gyro_bias, accel_bias
        The biases the SINS currently removes from the IMU (the fed-back estimates; rad/s,
        m/s²): a plugin reading raw IMU samples (zero angular rate) subtracts them.
    frame
        The recording's ENU frame.
    travel
        ``∫ v^n dt`` of the nominal velocity since the start (ENU metres; position feedback
        does not enter it): its difference between two epochs over their spacing is the mean
        nominal velocity in between, what an interval-mean sensor (an odometer's counts per
        sample) is to be compared with.
    observable_force
        ``filter.observable_force``: a slow machine, whose nominal quantities inform the
        heading only where they are known to many σ (:func:`fusion.error_model.observable_force`).
    """

    t: float
    lat: float
    lon: float
    height: float
    velocity: NDArray[np.float64]
    c_b_n: NDArray[np.float64]
    layout: StateLayout
    x: NDArray[np.float64]
    covariance: NDArray[np.float64]
    frame: LocalFrame
    gyro_bias: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    accel_bias: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    travel: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    observable_force: bool = True

    @cached_property
    def _local_point(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The nominal position's ENU metres and rotation to local axes, asked of the frame
        once per context (:meth:`fusion.earth.LocalFrame.point`)."""
        return self.frame.point(self.lat, self.lon, self.height)

    @property
    def position_enu(self) -> NDArray[np.float64]:
        """Nominal position in ENU metres about the recording origin."""
        return self._local_point[0]

    @property
    def rotation_to_local(self) -> NDArray[np.float64]:
        """Rotation from the origin's ENU axes to the local ENU axes at the nominal position."""
        return self._local_point[1]

    @property
    def position_covariance_enu(self) -> NDArray[np.float64]:
        """The position error's covariance in the origin's ENU axes (the filter keeps it in the
        local ones), to go with :attr:`position_enu`: a place to go back to
        (:meth:`Plugin.reacquire`), a stored point, a fit's prior."""
        rot = self.rotation_to_local
        rows = self.layout.slice(POSITION)
        covariance: NDArray[np.float64] = rot.T @ self.covariance[rows, rows] @ rot
        return covariance


class Plugin(ABC):
    """Base class of aiding sources.

    Subclasses set :attr:`Options` to their pydantic options model and implement
    :meth:`epochs` and :meth:`measure`; they may override :meth:`state_blocks`.

    Parameters
    ----------
    name
        Instance name (prefix of its state blocks).
    options
        Validated options.
    recording
        The recording the plugin reads its stream from.
    """

    Options: ClassVar[type[PluginOptions]] = PluginOptions

    def __init__(self, name: str, options: PluginOptions, recording: Recording) -> None:
        self.name = name
        self.options = options
        self.recording = recording

    def state_blocks(self) -> tuple[StateBlock, ...]:
        """Extra error states this plugin owns (default: none)."""
        return ()

    def stored_errors(self) -> int:
        """Number of stored-error variables (:class:`StoredEstimate`) this plugin uses (default:
        none)."""
        return 0

    def state_jumped(self, state: str, onset: float, before: float) -> None:
        """A jump of ``state``, one of this plugin's ``may_jump`` states, was taken in or the
        state restarted at rest (:mod:`fusion.jumps`): it held the estimate ``before`` until
        ``onset`` and holds the filter's estimate from then on. For a plugin whose measurement
        reads earlier samples through the state (the odometer's reference speed); default:
        ignored."""
        return None

    def start_run(self) -> None:
        """Forget what a run over the recording learned (adaptive noise, stored points,
        flags): the engine calls it before its first epoch, so that one plugin serves any
        number of runs. A plugin that keeps anything from one epoch to the next resets it
        here. Default: nothing to forget."""
        return None

    def process_noise(self, index: int) -> ProcessNoise | None:
        """Variances to add to state blocks before epoch ``index`` is measured: what this
        sensor's readings show the filter's model missed since its last epoch (a machine that
        began to move where zero-velocity updates held it still). The engine adds them as an
        identity time update of every filter, so the federated locals, the smoother and the
        observability report see process noise, and writes a ``faults.csv`` line for one that
        gives a reason. Default: none."""
        return None

    @abstractmethod
    def epochs(self) -> NDArray[np.float64]:
        """Sorted times at which :meth:`measure` is to be called."""

    @abstractmethod
    def measure(self, index: int, ctx: MeasurementContext) -> Measurement | None:
        """The measurement of epoch ``index``, or ``None``."""

    def store_epochs(self) -> NDArray[np.float64]:
        """Sorted times at which :meth:`store` is to be called (default: none)."""
        return np.empty(0)

    def store(self, index: int, ctx: MeasurementContext) -> StoredEstimate | None:
        """Store the filter's estimate at store epoch ``index``. It is called after the update
        round and the feedback of that instant, so ``ctx`` holds the posterior (fused, in a
        federated filter); the plugin keeps what it needs and returns the error it stored
        (default: nothing)."""
        return None

    def reacquire(self, t: float, ctx: MeasurementContext) -> Reacquisition | None:
        """Where the IMU is at ``t`` from this sensor's readings alone, for a filter whose every
        update of this plugin was rejected (:mod:`fusion.lock`), or that is too uncertain for
        its linearized measurement (:meth:`beyond_linearization`); default: the plugin cannot
        say (the lost lock is only reported). A fix the filter's covariance explains is taken
        in as a position update, one it does not replaces the position (``Engine._reacquire``)."""
        return None

    def lost_lock_doubt(self, t: float, ctx: MeasurementContext) -> str | None:
        """Why a lost lock of this plugin at ``t`` (every update rejected, no other plugin
        holding the filter, nothing re-acquired) need not show the SINS wrong, or None. The
        engine inflates the SINS covariance only for a lost lock without a doubt
        (:mod:`fusion.lock`): the inflation takes the sensor's reading for right and throws the
        filter's information away to admit it. Default: no doubt."""
        return None

    def beyond_linearization(self, index: int, ctx: MeasurementContext) -> bool:
        """Whether the filter is too uncertain for this plugin's linearized measurement of
        epoch ``index`` (its nonlinearity would make the update overconfident): the engine then
        asks :meth:`reacquire` instead, and applies nothing until the plugin can say where the
        machine is. Default: never."""
        return False

    def off_solution(self, index: int) -> bool:
        """Whether this plugin's readings show the filter on a wrong solution at epoch
        ``index`` although its gate still passes some of them (e.g. UWB ranges that read
        shorter than the filter's distance, which no NLOS does): the engine then asks
        :meth:`reacquire` and restarts the position there, the velocity kept. Default:
        never."""
        return False

    def standalone_solution(self, gate_probability: float | None, log: InnovationLog) -> Solution:
        """A solution from this sensor alone, without the SINS (``filter.architecture:
        standalone``), e.g. UWB least squares, its readings gated at the block's
        ``gate_probability`` and each one used or rejected logged in ``log``; default: the
        plugin cannot do that."""
        raise PluginError(
            f"plugin {self.name!r} ({type(self).__name__}) has no standalone solution;"
            " filter.architecture standalone needs one that has (e.g. uwb)"
        )

    closes_windows: ClassVar[bool] = False
    """Whether the plugin tells online smoothing where to close its windows
    (:meth:`window_end_due`, e.g. CPOEM at the face ends)."""

    def window_end_due(self, t: float) -> bool:
        """Whether online smoothing should close a window at ``t`` (called after each filter
        step of a plugin with :attr:`closes_windows`; causal: from what the plugin has seen up
        to ``t``, e.g. a face end just reached). Default: never."""
        return False

    def receive_smoothed(
        self,
        t: NDArray[np.float64],
        position_enu: NDArray[np.float64],
        position_covariance: NDArray[np.float64],
    ) -> None:
        """Smoothed positions (origin ENU, m) and their covariances of a window just smoothed
        online, in time order (e.g. to refresh stored points); default: ignored."""
        return None


class PluginError(ValueError):
    """A plugin cannot be found or its options are invalid."""


class MissingStream(PluginError):
    """The recording lacks a stream the plugin reads: its file, or the meta.yaml section that
    describes it (``uwb.csv`` and ``uwb.anchors``). The format makes every aiding stream
    optional; the engine then runs the configuration without the plugin, unless its block
    says ``required: true`` (:class:`fusion.engine.Engine`)."""


_registered_at_run_time: dict[str, type[Plugin]] = {}
"""Plugins named by :func:`register_plugin` in this process, by name."""


def register_plugin(name: str, cls: type[Plugin]) -> None:
    """Make ``cls`` usable as ``type: name`` in a configuration of this process, without
    packaging it (a plugin written in a script or a notebook).

    Registering a name again replaces the earlier class (a notebook cell run twice); a name
    an installed package registers through the ``fusion.plugins`` entry points cannot be
    taken. The registration lives in this process only: worker processes (a benchmark's
    process pool) do not see it.

    Raises
    ------
    PluginError
        When ``cls`` is not a :class:`Plugin` subclass, ``name`` is empty or contains
        whitespace, or an entry point already uses ``name``.
    """
    if not (isinstance(cls, type) and issubclass(cls, Plugin)):
        raise PluginError(f"register_plugin({name!r}, ...): {cls!r} is not a fusion.plugin.Plugin")
    if not isinstance(name, str) or not name or name != "".join(name.split()):
        raise PluginError(f"register_plugin: the name {name!r} must be a word without spaces")
    installed = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
    if installed:
        raise PluginError(
            f"register_plugin: {name!r} is already the installed plugin {installed[0].value};"
            " choose another name"
        )
    _registered_at_run_time[name] = cls


def plugin_names() -> list[str]:
    """Names registered in the ``fusion.plugins`` entry-point group (nothing is imported) and
    by :func:`register_plugin`."""
    installed = {ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)}
    return sorted(installed | set(_registered_at_run_time))


def load_plugin_class(kind: str) -> type[Plugin]:
    """The class registered as ``kind``: imported from its entry point (only that one: a broken
    third-party plugin does not stop the others from loading) or as given to
    :func:`register_plugin`."""
    if kind in _registered_at_run_time:
        return _registered_at_run_time[kind]
    matches = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == kind]
    if not matches:
        raise PluginError(f"no plugin {kind!r} is registered (known: {plugin_names()})")
    try:
        cls = matches[0].load()
    except Exception as exc:  # any import failure of third-party code
        raise PluginError(
            f"plugin {kind!r} ({matches[0].value}) cannot be imported: {exc}"
        ) from exc
    if not (isinstance(cls, type) and issubclass(cls, Plugin)):
        raise PluginError(f"plugin {kind!r} ({matches[0].value}) is not a fusion.plugin.Plugin")
    return cls


def validated_options(
    kind: str,
    options: dict[str, Any],
    where: Sequence[str | int],
    source: str = "configuration",
) -> tuple[type[Plugin], PluginOptions]:
    """The class registered as ``kind`` and ``options`` validated by its model; errors name
    ``source`` and ``where`` (the config path)."""
    if kind not in plugin_names():
        raise PluginError(
            f"{source}: key {dotted((*where, 'type'))}: no plugin {kind!r} is registered"
            f" (known: {plugin_names()})"
        )
    cls = load_plugin_class(kind)
    try:
        return cls, cls.Options.model_validate(options)
    except ValidationError as exc:
        raise PluginError("\n".join(error_lines(source, cls.Options, exc, where))) from None


def validate_plugin_options(config: FusionConfig, source: str = "configuration") -> None:
    """Check every plugin block's options against its plugin's model (no recording needed);
    report every problem at once."""
    problems = []
    for i, block in enumerate(config.plugins):
        try:
            validated_options(block.type, block.options, ("plugins", i), source)
        except PluginError as exc:
            problems.append(str(exc))
    if problems:
        raise PluginError("\n".join(problems))


def create_plugin(
    kind: str,
    name: str,
    options: dict[str, Any],
    recording: Recording,
    where: Sequence[str | int],
) -> Plugin:
    """Instantiate plugin ``kind`` with ``options``; errors name ``where`` (the config path),
    and a recording the plugin cannot serve (a missing sensor file or meta.yaml section) is a
    :class:`PluginError` naming the recording (:class:`MissingStream` for a missing stream)."""
    cls, opts = validated_options(kind, options, where)
    try:
        return cls(name, opts, recording)
    except ValueError as exc:
        error = MissingStream if isinstance(exc, MissingStream) else PluginError
        raise error(
            f"configuration: key {dotted(where)} ({kind}): recording {recording.path}: {exc}"
        ) from None
