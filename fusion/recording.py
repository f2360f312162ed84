"""Reader, validator and writer of recording directories (format ``shearer-recording/1``).

A recording directory holds ``meta.yaml`` and one CSV file per sensor stream, as specified in
``shared/RECORDING_FORMAT.md``.  This module implements that contract:

* :func:`read_recording` parses a directory into a :class:`Recording` (typed numpy arrays per
  stream plus the validated :class:`RecordingMeta`) and raises :class:`RecordingError` listing
  *every* broken rule it found (file, line or key, and the rule), never a silent guess;
* :func:`validate_recording` runs the same checks and returns the list of :class:`Problem`;
* :func:`check_recording` applies the rules that concern arrays to a :class:`Recording` built in
  memory (the engine calls it on every recording it receives);
* :func:`write_recording` writes a :class:`Recording` back, deterministically (byte-identical
  files for identical input, ``repr``-exact floats, optional ``.csv.gz`` with a zero mtime).

Rules checked (each broken one becomes a :class:`Problem`)
---------------------------------------------------------
Every file: a regular file (or a symbolic link to one); a directory, a named pipe, a dangling
link or a link loop in place of a file is a problem of its own, and nothing else is opened.

``meta.yaml``: present, UTF-8, valid YAML within the limits of :mod:`fusion.yaml_limits` (no
duplicate key, bounded nesting and alias expansion), a mapping, every required key present
(reported by its dotted path, e.g. ``initial.sigma.position_m``), no unknown key outside the
free-form ``extra:`` mapping (with the closest valid key suggested), right types, lengths and
ranges (rates > 0, sigmas >= 0, finite numbers), ``format: shearer-recording/1``; the section of
every present CSV file (``uwb`` with a non-empty ``uwb.anchors`` when ``uwb.csv`` is present).

CSV files: ``imu.csv`` present; never both ``x.csv`` and ``x.csv.gz``; text (first bytes that
are not, e.g. a gzip file named ``.csv``, are one short problem); a header line whose first
columns are exactly the required ones in order (extra columns after them are ignored); every
row with as many fields as the header (a decimal comma ``9,81`` adds one); no empty line, empty
cell, non-numeric cell, NaN or infinity; time strictly
increasing (``uwb.csv``: per anchor); ``imu.csv`` with at least two samples; the sample rate
``rate_hz`` of ``imu``, ``odometer`` and ``magnetometer`` within 10 % of
``1 / median(sample interval)``; no gap
in ``imu.csv`` longer than 5 median sample intervals (unless bridged explicitly with
``bridge_imu_gaps=True``); physically possible values: ``|w| <= 50 rad/s`` and
``|f| <= 200 m/s²`` per component, ``range >= 0``, position sigmas ``> 0``; ``anchor`` a key of
``uwb.anchors``; truth ``cycle`` a non-negative integer.

``uwb.rate_hz`` is the ranging system's nominal rate of ranges, all anchors together, and is not
compared with the file: which anchors answer depends on where the tag is (a system that polls
the anchors in range in turn shares its rate among them), and the ranges of one round may share
a time stamp. ``uwb.csv``'s times must increase per anchor; the reader returns its rows in time
order (stable, so rows sharing a time stamp keep their file order).

Warnings (logged on the ``fusion.recording`` logger, not problems: the format allows them): an
optional stream with a header and no rows (support.csv excepted: no row there means no push),
and a stream that begins before, ends after or lies entirely outside the IMU's time span by
more than one IMU sample interval, named with both spans.

Every rule reports at most :data:`MAX_REPORTS_PER_RULE` occurrences per file, followed by one
problem saying how many more lines break it.  Line numbers are 1-based file lines: the header is
line 1, the first data row line 2.

Reading is vectorized: :func:`numpy.loadtxt` over blocks of about 8 MB of whole lines; only a
block where that fast path fails is re-read line by line to pinpoint every bad line (NaN and
infinity are located without it).  A 3-million-row ``imu.csv`` reads in a few seconds.

Two choices the format leaves open: a position sigma of exactly 0 is rejected like a negative one
(a fix cannot be perfect, and a zero variance breaks the filter), and ``bridge_imu_gaps`` bridges
gaps only explicitly, returning them in :attr:`Recording.imu_gaps` and logging a warning.
"""

from __future__ import annotations

import gzip
import io
import itertools
import logging
import math
import os
import re
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, BinaryIO, Literal, NamedTuple

import numpy as np
import numpy.typing as npt
import yaml
from annotated_types import Ge, Gt, Le
from pydantic import (
    AllowInfNan,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    field_validator,
)

from fusion.input_files import regular_file_problem
from fusion.memory import release_freed_memory
from fusion.validation import describe_error, dotted, short_repr, suggest
from fusion.yaml_limits import KeyPath, YamlError, load_yaml

__all__ = [
    "FORMAT",
    "MAX_ANGULAR_RATE_RADPS",
    "MAX_IMU_GAP_INTERVALS",
    "MAX_REPORTS_PER_RULE",
    "MAX_SPECIFIC_FORCE_MPS2",
    "RATE_TOLERANCE",
    "STREAM_COLUMNS",
    "Attitude",
    "FaceMeta",
    "ImuData",
    "ImuMeta",
    "ImuSpec",
    "Initial",
    "InitialSigma",
    "MagnetometerData",
    "MagnetometerMeta",
    "OdometerData",
    "OdometerMeta",
    "Origin",
    "PositionData",
    "PositionMeta",
    "Problem",
    "Recording",
    "RecordingError",
    "RecordingMeta",
    "SupportData",
    "TruthData",
    "UwbData",
    "UwbMeta",
    "check_recording",
    "load_meta",
    "read_recording",
    "validate_recording",
    "write_recording",
]

_log = logging.getLogger(__name__)

FORMAT = "shearer-recording/1"
"""Value of the ``format`` key in ``meta.yaml``."""
MAX_REPORTS_PER_RULE = 20
"""Occurrences of one rule reported per file before a single "and N more" problem."""
RATE_TOLERANCE = 0.10
"""Largest accepted relative difference between ``rate_hz`` and the measured sample rate."""
MAX_IMU_GAP_INTERVALS = 5.0
"""An IMU interval longer than this many median sample intervals is a gap."""
MAX_ANGULAR_RATE_RADPS = 50.0
"""Largest physically possible angular-rate component (rad/s)."""
MAX_SPECIFIC_FORCE_MPS2 = 200.0
"""Largest physically possible specific-force component (m/s²)."""

STREAM_COLUMNS: dict[str, tuple[str, ...]] = {
    "imu": ("t", "wx", "wy", "wz", "fx", "fy", "fz"),
    "odometer": ("t", "speed"),
    "magnetometer": ("t", "mx", "my", "mz"),
    "uwb": ("t", "anchor", "range"),
    "support": ("t", "advance"),
    "position": ("t", "e", "n", "u", "se", "sn", "su"),
    "truth": ("t", "e", "n", "u", "ve", "vn", "vu", "roll", "pitch", "yaw", "cycle"),
}
"""Required leading columns of each CSV file, keyed by the file stem (``imu`` → ``imu.csv``)."""

# Stream stem -> meta.yaml section that must be present when the file is (None: no section).
_SECTION_OF: dict[str, str | None] = {
    "imu": "imu",
    "odometer": "odometer",
    "magnetometer": "magnetometer",
    "uwb": "uwb",
    "support": None,
    "position": "position",
    "truth": None,
}
# Streams whose meta section carries a rate_hz that is checked against the data.
_RATE_CHECKED = ("imu", "odometer", "magnetometer")

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


# --------------------------------------------------------------------------------------------
# Problems
# --------------------------------------------------------------------------------------------


class Problem(NamedTuple):
    """One broken rule of the recording format.

    Attributes
    ----------
    file : str
        File name relative to the recording directory (``"imu.csv"``, ``"meta.yaml"``), or
        ``""`` when the problem concerns the directory itself; for a recording built in memory
        the part concerned (``"Recording.imu"``, ``"Recording.meta"``, ``"ImuData"``).
    where : str
        Location inside the file: ``"line 17"``, ``"line 17, column fz"``,
        ``"key uwb.anchors.A3 (line 12)"``, ``"lines 100-101 (t=0.99..1.8 s)"`` or ``""``; in
        memory a row is ``"sample 17"``, its index in the arrays.
    rule : str
        Sentence naming the rule that is broken and what was found.
    """

    file: str
    where: str
    rule: str

    def __str__(self) -> str:
        """Return ``"file, where: rule"`` (empty parts left out)."""
        prefix = ", ".join(part for part in (self.file, self.where) if part)
        return f"{prefix}: {self.rule}" if prefix else self.rule


class RecordingError(ValueError):
    """A recording (or a solution file) breaks the format; lists every problem found.

    Parameters
    ----------
    problems : list of Problem
        All problems found.
    path : str or Path, optional
        The recording directory (or file) concerned; shown on the first line of the message.

    Attributes
    ----------
    problems : list of Problem
        All problems found, in file order.
    path : Path or None
        The recording directory or file.
    """

    def __init__(self, problems: Sequence[Problem], path: str | Path | None = None) -> None:
        self.problems: list[Problem] = list(problems)
        self.path: Path | None = Path(path) if path is not None else None
        n = len(self.problems)
        head = f"{self.path}: " if self.path is not None else ""
        head += f"{n} problem{'s' if n != 1 else ''} with the recording format"
        super().__init__("\n".join([head, *(f"  {p}" for p in self.problems)]))

    def __reduce__(self) -> tuple[Any, ...]:
        """Support pickling (e.g. across process pools)."""
        return (type(self), (self.problems, self.path))


class _Reporter:
    """Collect problems of one file, capping the occurrences reported per rule."""

    def __init__(self, file: str, cap: int = MAX_REPORTS_PER_RULE, unit: str = "line") -> None:
        self.file = file
        self.cap = cap
        self.unit = unit  # what a row number counts: a file's "line", an array's "sample"
        self.problems: list[Problem] = []
        self._counts: Counter[str] = Counter()
        self._summaries: dict[str, str] = {}

    def add(self, key: str, where: str, rule: str, summary: str | None = None) -> None:
        """Record one occurrence of rule ``key``."""
        self._counts[key] += 1
        if self._counts[key] <= self.cap:
            self.problems.append(Problem(self.file, where, rule))
        self._summaries.setdefault(key, summary or rule)

    def add_many(
        self,
        key: str,
        count: int,
        make: Callable[[int], tuple[str, str]],
        summary: str,
    ) -> None:
        """Record ``count`` occurrences; ``make(i)`` gives (where, rule) of the i-th one."""
        if count <= 0:
            return
        room = max(0, self.cap - self._counts[key])
        for i in range(min(room, count)):
            where, rule = make(i)
            self.problems.append(Problem(self.file, where, rule))
        self._counts[key] += count
        self._summaries.setdefault(key, summary)

    def finish(self) -> list[Problem]:
        """Return the problems, with one "and N more" line per rule that hit the cap."""
        out = list(self.problems)
        for key, count in self._counts.items():
            if count > self.cap:
                out.append(
                    Problem(
                        self.file,
                        "",
                        f"and {count - self.cap} more occurrences of: {self._summaries[key]}",
                    )
                )
        return out


# --------------------------------------------------------------------------------------------
# meta.yaml models
# --------------------------------------------------------------------------------------------


def _check_len3(value: Any) -> Any:
    if isinstance(value, list | tuple) and len(value) != 3:
        raise ValueError(f"must be a list of 3 numbers, found {len(value)} items")
    return value


Real = Annotated[float, Strict(), AllowInfNan(False)]
PositiveReal = Annotated[float, Strict(), AllowInfNan(False), Gt(0)]
NonNegReal = Annotated[float, Strict(), AllowInfNan(False), Ge(0)]
Vec3 = Annotated[tuple[Real, Real, Real], BeforeValidator(_check_len3)]
NonNegVec3 = Annotated[tuple[NonNegReal, NonNegReal, NonNegReal], BeforeValidator(_check_len3)]

_ANCHOR_ID = re.compile(r"[^\s,\"']+")


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_default=True)


class Origin(_Section):
    """WGS84 geodetic point that is the origin of the ENU frame."""

    lat_deg: Annotated[Real, Ge(-90), Le(90)]
    lon_deg: Annotated[Real, Ge(-180), Le(180)]
    height_m: Real


class Attitude(_Section):
    """Roll, pitch and yaw in degrees (convention of the format: ψ clockwise from north)."""

    roll: Real
    pitch: Real
    yaw: Real


class InitialSigma(_Section):
    """1-sigma uncertainty of the initial navigation state."""

    position_m: NonNegVec3
    velocity_mps: NonNegVec3
    attitude_deg: NonNegVec3


class Initial(_Section):
    """Navigation state at the first IMU sample (ENU metres / m/s about the origin)."""

    position_enu_m: Vec3
    velocity_enu_mps: Vec3
    attitude_deg: Attitude
    sigma: InitialSigma


class ImuSpec(_Section):
    """Optional datasheet figures of the IMU, used as default tuning."""

    gyro_bias_deg_h: NonNegReal | None = None
    gyro_arw_deg_rth: NonNegReal | None = None
    accel_bias_mg: NonNegReal | None = None
    accel_vrw_mg_rthz: NonNegReal | None = None


class ImuMeta(_Section):
    """``imu`` section: sample rate and optional datasheet figures."""

    rate_hz: PositiveReal
    spec: ImuSpec | None = None


class OdometerMeta(_Section):
    """``odometer`` section."""

    rate_hz: PositiveReal


class MagnetometerMeta(_Section):
    """``magnetometer`` section; the expected earth field figures are optional."""

    rate_hz: PositiveReal
    declination_deg: Real
    field_uT: PositiveReal | None = None
    inclination_deg: Annotated[Real, Ge(-90), Le(90)] | None = None


class UwbMeta(_Section):
    """``uwb`` section.

    ``rate_hz`` is the nominal number of ranges per second, all anchors together (not compared
    with the file); ``anchors`` maps each anchor id (the values of the ``anchor`` column of
    ``uwb.csv``) to its ENU position in metres.
    """

    rate_hz: PositiveReal
    tag_lever_arm_b_m: Vec3 = (0.0, 0.0, 0.0)
    anchors: dict[str, Vec3] = Field(default_factory=dict)

    @field_validator("anchors", mode="before")
    @classmethod
    def _anchor_ids(cls, value: Any) -> Any:
        """Accept numeric YAML keys (``1: [...]``) as ids and reject ids unusable in a CSV."""
        if not isinstance(value, dict):
            return value
        out: dict[Any, Any] = {}
        for key, item in value.items():
            if isinstance(key, bool) or not isinstance(key, str | int):
                raise ValueError(f"anchor id {key!r} must be a string")
            name = str(key)
            if not _ANCHOR_ID.fullmatch(name):
                raise ValueError(
                    f"anchor id {name!r} must be non-empty and contain no comma, quote or space"
                )
            out[name] = item
        return out


class PositionMeta(_Section):
    """``position`` section: lever arm of the fixed point (antenna, prism) in the b-frame."""

    lever_arm_b_m: Vec3 = (0.0, 0.0, 0.0)


class FaceMeta(_Section):
    """``face`` section: longwall geometry known in advance."""

    length_m: PositiveReal | None = None
    advance_m: PositiveReal | None = None
    ends_enu_m: tuple[Vec3, Vec3] | None = None


class RecordingMeta(_Section):
    """Contents of ``meta.yaml``; unknown keys are rejected everywhere except under ``extra``."""

    format: Literal["shearer-recording/1"]
    name: str = ""
    origin: Origin
    initial: Initial
    imu: ImuMeta
    odometer: OdometerMeta | None = None
    magnetometer: MagnetometerMeta | None = None
    uwb: UwbMeta | None = None
    position: PositionMeta | None = None
    face: FaceMeta | None = None
    extra: dict[str, Any] = Field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# Stream data
# --------------------------------------------------------------------------------------------


def _as_float(name: str, value: Any, ndim: int, n: int | None = None) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if ndim == 1 and arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array, got shape {arr.shape}")
    if ndim == 2 and (arr.ndim != 2 or arr.shape[1] != 3):
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise ValueError(f"{name} has {arr.shape[0]} rows but t has {n}")
    return arr


def _as_int(name: str, value: Any, n: int) -> IntArray:
    raw = np.asarray(value)
    arr = raw.astype(np.int64)
    if raw.ndim != 1 or arr.shape[0] != n:
        raise ValueError(f"{name} must be a 1-D array of {n} integers, got shape {raw.shape}")
    if raw.dtype.kind == "f" and not np.array_equal(arr, raw):
        raise ValueError(f"{name} must hold integer values")
    return arr


def _set(obj: object, name: str, value: Any) -> None:
    object.__setattr__(obj, name, value)


class _Stream:
    """Base of the stream classes: their arrays are converted to float64 (int64 for indices)
    and their shapes checked on construction; a bad one raises :class:`RecordingError`."""

    def __post_init__(self) -> None:
        try:
            self._convert()
        except ValueError as exc:
            raise RecordingError([Problem(type(self).__name__, "", str(exc))]) from None

    def _convert(self) -> None:
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class ImuData(_Stream):
    """IMU samples: each the mean over ``(t_prev, t]``.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Time (s), strictly increasing.
    gyro : ndarray, shape (N, 3)
        Angular rate of b relative to inertial space, in b (rad/s).
    accel : ndarray, shape (N, 3)
        Specific force in b (m/s²).
    """

    t: FloatArray
    gyro: FloatArray
    accel: FloatArray

    def _convert(self) -> None:
        t = _as_float("t", self.t, 1)
        _set(self, "t", t)
        _set(self, "gyro", _as_float("gyro", self.gyro, 2, len(t)))
        _set(self, "accel", _as_float("accel", self.accel, 2, len(t)))


@dataclass(frozen=True, eq=False)
class OdometerData(_Stream):
    """Odometer samples: signed speed along the m-frame y axis (m/s)."""

    t: FloatArray
    speed: FloatArray

    def _convert(self) -> None:
        t = _as_float("t", self.t, 1)
        _set(self, "t", t)
        _set(self, "speed", _as_float("speed", self.speed, 1, len(t)))


@dataclass(frozen=True, eq=False)
class MagnetometerData(_Stream):
    """Magnetometer samples: flux density in b, shape (N, 3), in µT."""

    t: FloatArray
    field: FloatArray

    def _convert(self) -> None:
        t = _as_float("t", self.t, 1)
        _set(self, "t", t)
        _set(self, "field", _as_float("field", self.field, 2, len(t)))


@dataclass(frozen=True, eq=False)
class UwbData(_Stream):
    """UWB ranges, one per row.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Time (s), non-decreasing (strictly increasing per anchor: the ranges of one round may
        share a time stamp).
    anchor_index : ndarray of int64, shape (N,)
        Index into ``anchor_ids`` of the anchor ranged to.
    range : ndarray, shape (N,)
        Measured range (m).
    anchor_ids : tuple of str
        Anchor ids in the order of ``uwb.anchors`` in meta.yaml.
    """

    t: FloatArray
    anchor_index: IntArray
    range: FloatArray
    anchor_ids: tuple[str, ...]

    def _convert(self) -> None:
        t = _as_float("t", self.t, 1)
        _set(self, "t", t)
        idx = _as_int("anchor_index", self.anchor_index, len(t))
        _set(self, "anchor_index", idx)
        _set(self, "range", _as_float("range", self.range, 1, len(t)))
        _set(self, "anchor_ids", tuple(str(a) for a in self.anchor_ids))
        if idx.size and (idx.min() < 0 or idx.max() >= len(self.anchor_ids)):
            raise ValueError("anchor_index out of range of anchor_ids")


@dataclass(frozen=True, eq=False)
class SupportData(_Stream):
    """AFC push events: at ``t`` the AFC advanced by ``advance`` metres."""

    t: FloatArray
    advance: FloatArray

    def _convert(self) -> None:
        t = _as_float("t", self.t, 1)
        _set(self, "t", t)
        _set(self, "advance", _as_float("advance", self.advance, 1, len(t)))


@dataclass(frozen=True, eq=False)
class PositionData(_Stream):
    """External position fixes (ENU m) of the point ``position.lever_arm_b_m``, with 1-sigma."""

    t: FloatArray
    enu: FloatArray
    sigma: FloatArray

    def _convert(self) -> None:
        t = _as_float("t", self.t, 1)
        _set(self, "t", t)
        _set(self, "enu", _as_float("enu", self.enu, 2, len(t)))
        _set(self, "sigma", _as_float("sigma", self.sigma, 2, len(t)))


@dataclass(frozen=True, eq=False)
class TruthData(_Stream):
    """Reference trajectory (scoring only).

    Attributes
    ----------
    t : ndarray, shape (N,)
    position : ndarray, shape (N, 3)
        ENU m about the origin.
    velocity : ndarray, shape (N, 3)
        ENU m/s.
    attitude : ndarray, shape (N, 3)
        Roll, pitch, yaw (rad).
    cycle : ndarray of int64, shape (N,)
        Cutting-cycle index (1, 2, ...; 0 outside any cycle).
    """

    t: FloatArray
    position: FloatArray
    velocity: FloatArray
    attitude: FloatArray
    cycle: IntArray

    def _convert(self) -> None:
        t = _as_float("t", self.t, 1)
        _set(self, "t", t)
        for name in ("position", "velocity", "attitude"):
            _set(self, name, _as_float(name, getattr(self, name), 2, len(t)))
        _set(self, "cycle", _as_int("cycle", self.cycle, len(t)))


@dataclass(frozen=True, eq=False)
class Recording:
    """A parsed recording directory.

    Attributes
    ----------
    path : Path or None
        Directory it was read from (None when built in memory).
    meta : RecordingMeta
    imu : ImuData
    odometer, magnetometer, uwb, support, position, truth
        Optional streams (None when the file is absent).
    imu_gaps : list of (float, float)
        IMU gaps ``(t_before, t_after)`` longer than 5 sample intervals that were accepted
        because the recording was read with ``bridge_imu_gaps=True`` (empty otherwise).
    """

    path: Path | None
    meta: RecordingMeta
    imu: ImuData
    odometer: OdometerData | None = None
    magnetometer: MagnetometerData | None = None
    uwb: UwbData | None = None
    support: SupportData | None = None
    position: PositionData | None = None
    truth: TruthData | None = None
    imu_gaps: list[tuple[float, float]] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last IMU sample (s)."""
        t = self.imu.t
        return float(t[-1] - t[0]) if t.size else 0.0

    def with_imu_figures(self, figures: Mapping[str, float | None]) -> Recording:
        """This recording with ``figures`` in place of its ``meta.yaml`` ``imu.spec`` figures
        of the same names (the others kept; a spec made of them where there is none)."""
        meta = self.meta
        stated = meta.imu.spec
        update = dict(figures)
        spec = stated.model_copy(update=update) if stated is not None else ImuSpec(**update)
        imu = meta.imu.model_copy(update={"spec": spec})
        return replace(self, meta=meta.model_copy(update={"imu": imu}))


# --------------------------------------------------------------------------------------------
# meta.yaml reading
# --------------------------------------------------------------------------------------------


def _meta_problems_from_validation(
    exc: ValidationError, lines: dict[KeyPath, int], label: str = "meta.yaml"
) -> list[Problem]:
    out: list[Problem] = []
    for err in exc.errors():
        loc = tuple(p for p in err["loc"] if p != "[key]")
        where = f"key {dotted(loc)}" if loc else ""
        line = lines.get(loc)
        if line is not None:
            where += f" (line {line})"
        out.append(Problem(label, where, describe_error(RecordingMeta, err)))
    return out


def load_meta(path: str | Path) -> RecordingMeta:
    """Read and validate ``meta.yaml``.

    Parameters
    ----------
    path : str or Path
        A recording directory or the ``meta.yaml`` file itself.

    Returns
    -------
    RecordingMeta

    Raises
    ------
    RecordingError
        When the file is missing or breaks the format (all problems listed).
    """
    path = Path(path)
    file = path / "meta.yaml" if path.is_dir() else path
    meta, _, _, problems = _load_meta(file)
    if meta is None or problems:
        raise RecordingError(problems, file)
    return meta


def _load_meta(
    file: Path,
) -> tuple[RecordingMeta | None, Any, dict[KeyPath, int], list[Problem]]:
    """Return (model or None, raw data or None, key lines, problems)."""
    if not os.path.lexists(file):
        return None, None, {}, [Problem("meta.yaml", "", "required file is missing")]
    kind = regular_file_problem(file)
    if kind is not None:
        return None, None, {}, [Problem("meta.yaml", "", kind)]
    try:
        document = load_yaml(file.read_bytes())
    except OSError as exc:
        return None, None, {}, [Problem("meta.yaml", "", f"cannot read file: {exc.strerror}")]
    except YamlError as exc:
        where = f"line {exc.line}" if exc.line is not None else ""
        if exc.key is not None:
            where = f"key {dotted(exc.key)} ({where})"
        return None, None, {}, [Problem("meta.yaml", where, exc.rule)]
    raw, lines = document.data, document.key_lines
    if raw is None:
        return None, None, lines, [Problem("meta.yaml", "", "file is empty; expected a mapping")]
    if not isinstance(raw, dict):
        rule = f"must be a mapping of keys to values (found {short_repr(raw)})"
        return None, None, lines, [Problem("meta.yaml", "", rule)]
    try:
        meta = RecordingMeta.model_validate(raw)
    except ValidationError as exc:
        return None, raw, lines, _meta_problems_from_validation(exc, lines)
    return meta, raw, lines, []


# --------------------------------------------------------------------------------------------
# CSV reading
# --------------------------------------------------------------------------------------------

_NUMBER = re.compile(r"\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*")
_NONFINITE = {"nan", "inf", "infinity"}


@dataclass
class _Table:
    """Rows of a CSV file that parsed cleanly."""

    values: FloatArray  # (N, k) numeric columns in order (text column slot holds NaN)
    lines: IntArray  # (N,) 1-based file line of each row
    text: npt.NDArray[np.str_] | None  # the text column, when there is one


def _line_blocks(stream: BinaryIO) -> Iterator[bytes]:
    """The file in blocks of whole lines, about ``_BLOCK_BYTES`` each, read as it streams (an
    8-hour imu.csv is 280 MB: held whole, it doubled the reader's peak memory).

    A block ends at a line with content (the line end after it is dropped); the empty lines
    that follow go to the start of the next block, so an empty line inside the file stays a
    line of its own, while line ends at the very end of the file are dropped. The first block
    starts with the header line; a UTF-8 byte-order mark is removed.
    """
    carry = b""
    first = True
    while True:
        chunk = stream.read(_BLOCK_BYTES)
        buf = carry + chunk
        if first and buf.startswith(b"\xef\xbb\xbf"):
            buf = buf[3:]
        first = False
        if not chunk:
            body = buf.rstrip(b"\r\n")
            if body:
                yield body
            return
        body = buf[: buf.rfind(b"\n") + 1].rstrip(b"\r\n")
        if not body:
            carry = buf
            continue
        rest = len(body) + (2 if buf[len(body) : len(body) + 2] == b"\r\n" else 1)
        carry = buf[rest:]
        yield body


def _open_csv(path: Path) -> BinaryIO:
    """The file as a binary stream (decompressed on the fly for ``.gz``)."""
    if path.name.endswith(".gz"):
        return gzip.open(path, "rb")  # type: ignore[return-value]
    return path.open("rb")


def _check_header(header: str, columns: Sequence[str], rep: _Reporter) -> bool:
    found = header.split(",")
    k = len(columns)
    if found[:k] == list(columns):
        return True
    expected = ",".join(columns)
    missing = [c for c in columns if c not in found]
    if found and _NUMBER.fullmatch(found[0]):
        rule = f"the first line must be the header '{expected}'; found a data row"
    else:
        rule = (
            f"header must start with exactly the columns '{expected}' (found {short_repr(header)})"
        )
        if missing:
            rule += f"; missing column{'s' if len(missing) > 1 else ''} " + ", ".join(
                repr(c) for c in missing
            )
        else:
            rule += "; columns out of order"
        j = next(i for i, c in enumerate(columns) if i >= len(found) or found[i] != c)
        if j < len(found):
            rule += f" (column {j + 1} is {short_repr(found[j])}, expected {columns[j]!r})"
    rep.add("header", "line 1", rule)
    return False


_BLOCK_BYTES = 1 << 23  # the body is parsed in blocks of about 8 MB


def _read_table(
    path: Path, label: str, columns: Sequence[str], rep: _Reporter, text_col: int | None = None
) -> _Table | None:
    """Read one CSV file; None when it is unreadable or its header is wrong.

    The file is read as it streams, in blocks of whole lines (:func:`_line_blocks`), each parsed
    with :func:`numpy.loadtxt`; a block that fails (or whose row count shows skipped blank
    lines) is re-parsed line by line to report each bad line, so one bad cell in a huge file
    costs one slow block, not a slow file. Each block's rows are copied into arrays sized from
    the file's length (:class:`_TableBuilder`).
    """
    size = None if path.name.endswith(".gz") else path.stat().st_size
    try:
        with _open_csv(path) as stream:
            table = _parse_lines(_line_blocks(stream), label, columns, rep, text_col, size)
    except (OSError, EOFError, zlib.error, gzip.BadGzipFile) as exc:
        rep.add("read", "", f"cannot read {label}: {exc}")
        return None
    if table is not None:
        _drop_nonfinite(table, columns, rep, text_col)
    return table


class _TableBuilder:
    """Rows gathered block by block into arrays allocated once, at the size the file's length
    predicts (grown by half when the prediction falls short).

    Keeping each block's parsed array until the end and concatenating them held the table twice,
    and the freed blocks stayed in the allocator's heap: reading an 8-hour recording left the
    process at 800 MB for a 300 MB recording. Here a block's temporaries are freed before the
    next block is parsed, so the heap reuses the same few megabytes.

    Parameters
    ----------
    k
        Number of columns.
    file_bytes
        Length of the file, or None when unknown (compressed).
    """

    def __init__(self, k: int, file_bytes: int | None) -> None:
        self.values = np.empty((0, k))
        self.lines = np.empty(0, dtype=np.int64)
        self.texts: list[npt.NDArray[np.str_]] = []
        self.n = 0
        self._file_bytes = file_bytes
        self._bytes_read = 0

    def add(
        self, values: FloatArray, lines: IntArray, text: npt.NDArray[np.str_], n_bytes: int
    ) -> None:
        """Append one block's rows (``n_bytes`` of the file)."""
        self._bytes_read += n_bytes
        end = self.n + values.shape[0]
        if end > self.values.shape[0]:
            self._grow(end)
        self.values[self.n : end] = values
        self.lines[self.n : end] = lines
        self.texts.append(text)
        self.n = end

    def _grow(self, needed: int) -> None:
        predicted = 0
        if self._file_bytes:
            predicted = int(needed * 1.02 * self._file_bytes / max(self._bytes_read, 1)) + 16
        capacity = max(needed, predicted, int(1.5 * self.values.shape[0]))
        values = np.empty((capacity, self.values.shape[1]))
        values[: self.n] = self.values[: self.n]
        lines = np.empty(capacity, dtype=np.int64)
        lines[: self.n] = self.lines[: self.n]
        self.values, self.lines = values, lines

    def table(self, with_text: bool) -> _Table:
        """The rows gathered (a copy at the exact size when the capacity overshot by a fifth)."""
        values, lines = self.values[: self.n], self.lines[: self.n]
        if self.n < 0.8 * self.values.shape[0]:
            values, lines = values.copy(), lines.copy()
        text = np.concatenate([np.empty(0, dtype=str), *self.texts]) if with_text else None
        return _Table(values, lines, text)


def _parse_lines(
    blocks: Iterator[bytes],
    label: str,
    columns: Sequence[str],
    rep: _Reporter,
    text_col: int | None,
    file_bytes: int | None,
) -> _Table | None:
    """Check the header line and parse the body block by block (see :func:`_read_table`);
    None when the file is empty or its header is wrong."""
    k = len(columns)
    first = next(blocks, b"")
    binary = _binary_problem(first, label)
    if binary is not None:
        rep.add("binary", "", binary)
        return None
    nl = first.find(b"\n")
    header = (first if nl < 0 else first[:nl]).decode("utf-8").rstrip("\r")
    body = b"" if nl < 0 else first[nl + 1 :]
    if not header.strip() and not body.strip():
        following = next(blocks, None)
        if following is None:
            rep.add("header", "", f"file is empty; expected the header line '{','.join(columns)}'")
            return None
        blocks = itertools.chain([following], blocks)
    if not _check_header(header, columns, rep):
        return None
    n_fields = header.count(",") + 1
    builder = _TableBuilder(k, file_bytes)
    first_line = 2
    for block in itertools.chain([body] if nl >= 0 else [], blocks):
        n_lines = block.count(b"\n") + 1
        parsed = _parse_block(block, n_lines, k, n_fields, text_col)
        if parsed is None:
            parsed = _diagnose_block(block, first_line, columns, header, rep, text_col)
            row_lines = parsed[2]
        else:
            row_lines = np.arange(first_line, first_line + n_lines, dtype=np.int64)
        builder.add(parsed[0], row_lines, parsed[1], len(block) + 1)
        first_line += n_lines
    return builder.table(text_col is not None)


def _parse_block(
    block: bytes, n_lines: int, k: int, n_fields: int, text_col: int | None
) -> tuple[FloatArray, npt.NDArray[np.str_], IntArray] | None:
    """Vectorized parse of whole lines; None when any line is malformed (a line without the
    header's ``n_fields`` fields included: loadtxt would read a decimal comma's first half)."""
    if not _fields_match(block, n_fields):
        return None
    num_cols = [j for j in range(k) if j != text_col]
    options: dict[str, Any] = {"delimiter": ",", "comments": None, "encoding": "utf-8"}
    try:
        num = np.loadtxt(io.BytesIO(block), usecols=num_cols, ndmin=2, dtype=np.float64, **options)
        if num.shape[0] != n_lines:  # blank lines were skipped
            return None
        text = np.empty(0, dtype=str)
        if text_col is not None:
            text = np.loadtxt(io.BytesIO(block), usecols=(text_col,), ndmin=1, dtype=str, **options)
            if text.shape[0] != n_lines or np.any(text == ""):
                return None
            num = np.insert(num, text_col, np.nan, axis=1)
    except ValueError:  # includes UnicodeDecodeError
        return None
    return num, text, np.empty(0, dtype=np.int64)


def _fields_match(block: bytes, n_fields: int) -> bool:
    """Whether every line of ``block`` has ``n_fields`` comma-separated fields."""
    chars = np.frombuffer(block, dtype=np.uint8)
    commas = np.flatnonzero(chars == ord(","))
    line_ends = np.append(np.flatnonzero(chars == ord("\n")), chars.size)
    per_line = np.diff(np.searchsorted(commas, line_ends), prepend=0)
    return bool(np.all(per_line == n_fields - 1))


_GZIP_MAGIC = b"\x1f\x8b"


def _binary_problem(first_block: bytes, label: str) -> str | None:
    """A short rule when a file's first bytes are not text (a NUL byte, or a first line that is
    not UTF-8), instead of echoing kilobytes of them; None for text."""
    head = first_block[:4096]
    if head.startswith(_GZIP_MAGIC):
        return f"the first bytes are not text: gzip-compressed data (name it {label}.gz)"
    if b"\x00" in head:
        return "the first bytes are not text (a NUL byte): expected a CSV header line"
    nl = head.find(b"\n")
    try:
        (head if nl < 0 else head[:nl]).decode("utf-8")
    except UnicodeDecodeError as exc:
        if nl >= 0 or exc.start < len(head) - 4:  # not a character cut by the 4096 bytes
            return f"the header line is not UTF-8 text (byte 0x{head[exc.start]:02x})"
    return None


def _drop_nonfinite(
    table: _Table, columns: Sequence[str], rep: _Reporter, text_col: int | None
) -> None:
    """Report NaN / inf cells (numpy parses them) and drop their rows."""
    num_cols = [j for j in range(len(columns)) if j != text_col]
    check = table.values if text_col is None else table.values[:, num_cols]
    finite = np.isfinite(check)
    if finite.all():
        return
    rows, cols = np.nonzero(~finite)
    lines = table.lines
    rep.add_many(
        "nonfinite",
        rows.size,
        lambda i: (
            f"line {lines[rows[i]]}, column {columns[num_cols[cols[i]]]}",
            f"value {_num(check[rows[i], cols[i]])} is not a finite number "
            "(missing samples are absent rows, not NaN or inf)",
        ),
        "a cell is NaN or infinite",
    )
    keep = finite.all(axis=1)
    table.values, table.lines = table.values[keep], table.lines[keep]
    if table.text is not None:
        table.text = np.asarray(table.text)[keep]


def _diagnose_block(
    block: bytes,
    first_line: int,
    columns: Sequence[str],
    header: str,
    rep: _Reporter,
    text_col: int | None,
) -> tuple[FloatArray, npt.NDArray[np.str_], IntArray]:
    """Line-by-line pass that reports every malformed line and keeps the good rows."""
    k = len(columns)
    n_fields = header.count(",") + 1
    rows: list[list[float]] = []
    line_numbers: list[int] = []
    texts: list[str] = []
    for offset, raw_line in enumerate(block.decode("utf-8", errors="replace").split("\n")):
        number = first_line + offset
        line = raw_line[:-1] if raw_line.endswith("\r") else raw_line
        if not line.strip():
            rep.add(
                "empty_line",
                f"line {number}",
                "empty line (missing samples are absent rows, not empty lines)",
                "empty line",
            )
            continue
        parts = line.split(",")
        if len(parts) != n_fields:
            rule = (
                f"found {len(parts)} comma-separated fields, the header has {n_fields} "
                f"({short_repr(header)})"
            )
            if len(parts) > n_fields:
                rule += "; a decimal comma? The format's decimal point is '.'"
            rep.add("fields", f"line {number}", rule, "number of fields differs from the header")
            continue
        row: list[float] = []
        ok = True
        for j in range(k):
            cell = parts[j]
            where = f"line {number}, column {columns[j]}"
            if j == text_col:
                if not cell:
                    rep.add("empty", where, "empty cell", "empty cell")
                    ok = False
                row.append(math.nan)
                continue
            if _NUMBER.fullmatch(cell):
                row.append(float(cell))
                continue
            ok = False
            stripped = cell.strip()
            if not stripped:
                rep.add(
                    "empty",
                    where,
                    "empty cell (missing samples are absent rows, not empty cells)",
                    "empty cell",
                )
            elif stripped.lower().lstrip("+-") in _NONFINITE:
                rep.add(
                    "nonfinite",
                    where,
                    f"value {stripped!r} is not a finite number "
                    "(missing samples are absent rows, not NaN or inf)",
                    "a cell is NaN or infinite",
                )
            else:
                rep.add(
                    "nonnumeric",
                    where,
                    f"non-numeric value {short_repr(cell)}"
                    " (a number with '.' decimal point expected)",
                    "non-numeric cell",
                )
        if ok:
            rows.append(row)
            line_numbers.append(number)
            if text_col is not None:
                texts.append(parts[text_col])
    return (
        np.array(rows, dtype=np.float64).reshape(len(rows), k),
        np.array(texts, dtype=str),
        np.array(line_numbers, dtype=np.int64),
    )


# --------------------------------------------------------------------------------------------
# Value checks (shared by the reader and the writer)
# --------------------------------------------------------------------------------------------


def _num(x: Any) -> str:
    return repr(float(x))


def _check_time(
    t: FloatArray, lines: IntArray, rep: _Reporter, keys: npt.NDArray[Any] | None = None
) -> None:
    """Time strictly increasing down the file, or per key (``uwb.csv``: per anchor, since the
    ranges of one round may share a time stamp)."""
    if t.size < 2:
        return
    if keys is None:
        rows = np.arange(t.size)
        what = ""
    else:
        rows = np.lexsort((lines, keys))  # each key's rows in file order, keys one after another
        what = " per anchor"
    earlier, later = rows[:-1], rows[1:]
    same_key = np.ones(earlier.size, dtype=bool) if keys is None else keys[earlier] == keys[later]
    bad = np.flatnonzero(same_key & (t[later] <= t[earlier]))
    bad = bad[np.argsort(lines[later[bad]], kind="stable")]
    rep.add_many(
        "time",
        bad.size,
        lambda i: (
            f"{rep.unit} {lines[later[bad[i]]]}",
            f"time must be strictly increasing{what} (t={_num(t[later[bad[i]]])} after "
            f"t={_num(t[earlier[bad[i]]])} on {rep.unit} {lines[earlier[bad[i]]]})",
        ),
        f"time not strictly increasing{what}",
    )


def _median_interval(t: FloatArray) -> float | None:
    d = np.diff(t)
    d = d[d > 0]
    return float(np.median(d)) if d.size else None


def long_intervals(t: FloatArray, multiple: float) -> tuple[npt.NDArray[np.bool_], float | None]:
    """Per interval ``t[i] → t[i+1]``, whether it is longer than ``multiple`` median sample
    intervals (rows missing before ``t[i+1]``: an IMU gap, an odometer dropout), and that
    median (None, and nothing long, when no interval is positive)."""
    median = _median_interval(t)
    if median is None:
        return np.zeros(max(t.size - 1, 0), dtype=bool), None
    return np.diff(t) > multiple * median, median


def _check_limit(
    values: FloatArray,
    lines: IntArray,
    names: Sequence[str],
    limit: float,
    unit: str,
    what: str,
    rep: _Reporter,
) -> None:
    rows, cols = np.nonzero(np.isfinite(values) & (np.abs(values) > limit))
    rep.add_many(
        f"limit_{what}",
        rows.size,
        lambda i: (
            f"{rep.unit} {lines[rows[i]]}, column {names[cols[i]]}",
            f"|{names[cols[i]]}| = {abs(values[rows[i], cols[i]]):.6g} {unit} exceeds the "
            f"physical limit of {limit:g} {unit} for {what}",
        ),
        f"{what} beyond {limit:g} {unit}",
    )


def _check_positive(
    values: FloatArray,
    lines: IntArray,
    names: Sequence[str],
    rep: _Reporter,
    *,
    strict: bool,
    what: str,
) -> None:
    bad_mask = values <= 0 if strict else values < 0
    rows, cols = np.nonzero(bad_mask)
    need = "positive" if strict else "non-negative"
    rep.add_many(
        f"sign_{what}",
        rows.size,
        lambda i: (
            f"{rep.unit} {lines[rows[i]]}, column {names[cols[i]]}",
            f"{what} must be {need} (found {_num(values[rows[i], cols[i]])})",
        ),
        f"{what} not {need}",
    )


def _check_cycle(cycle: FloatArray, lines: IntArray, rep: _Reporter) -> None:
    bad = np.flatnonzero((cycle < 0) | (cycle != np.floor(cycle)))
    rep.add_many(
        "cycle",
        bad.size,
        lambda i: (
            f"{rep.unit} {lines[bad[i]]}, column cycle",
            f"cycle must be a non-negative integer (found {_num(cycle[bad[i]])})",
        ),
        "cycle not a non-negative integer",
    )


def _rate_problem(
    section: str,
    rate: float,
    median: float,
    label: str,
    lines: dict[KeyPath, int],
    meta_label: str = "meta.yaml",
) -> Problem | None:
    measured = 1.0 / median
    if abs(measured - rate) <= RATE_TOLERANCE * rate:
        return None
    line = lines.get((section, "rate_hz"))
    where = f"key {section}.rate_hz" + (f" (line {line})" if line else "")
    return Problem(
        meta_label,
        where,
        f"rate_hz = {rate:g} Hz disagrees by more than {RATE_TOLERANCE:.0%} with {label}"
        f", whose median sample interval is {median:.6g} s ({measured:.6g} Hz)",
    )


GAP_TOLERANCE = 1e-3
"""Share of a sample interval by which a gap may exceed :data:`MAX_IMU_GAP_INTERVALS` and still
be that many intervals: time stamps are rounded decimals (a 4-sample gap at t = 30 s, 29.99 to
30.04, is 5.0000000000001 median intervals of 100 Hz), and at Unix times a double resolves
2.4·10⁻⁷ s, 2·10⁻⁵ of a 100-Hz interval."""


def _imu_gaps(t: FloatArray) -> tuple[IntArray, float]:
    """Indices i with t[i+1] - t[i] longer than the gap threshold, and that threshold."""
    longer, median = long_intervals(t, MAX_IMU_GAP_INTERVALS + GAP_TOLERANCE)
    if median is None:
        return np.empty(0, dtype=np.int64), math.inf
    return np.flatnonzero(longer).astype(np.int64), MAX_IMU_GAP_INTERVALS * median


# --------------------------------------------------------------------------------------------
# Recording reading
# --------------------------------------------------------------------------------------------


def _positive_number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) and value > 0 else None


def _raw_section(raw: Any, name: str) -> Any:
    return raw.get(name) if isinstance(raw, dict) else None


def _inspect(path: str | Path, *, bridge_imu_gaps: bool) -> tuple[Recording | None, list[Problem]]:
    """Run every check; return the recording (None when any problem was found) and problems."""
    root = Path(path)
    if not root.is_dir():
        found = "is not a directory" if os.path.lexists(root) else "does not exist"
        return None, [Problem("", "", f"recording directory {str(root)!r} {found}")]
    meta, raw, key_lines, problems = _load_meta(root / "meta.yaml")

    # Locate the CSV files (plain or gzip-compressed, never both; regular files only).
    files: dict[str, Path] = {}
    for stem in STREAM_COLUMNS:
        entries = [root / f"{stem}.csv", root / f"{stem}.csv.gz"]
        present = [entry for entry in entries if os.path.lexists(entry)]
        if len(present) == 2:
            problems.append(
                Problem(
                    f"{stem}.csv",
                    "",
                    f"both {stem}.csv and {stem}.csv.gz are present (ambiguous); keep one",
                )
            )
        elif present:
            kind = regular_file_problem(present[0])
            if kind is None:
                files[stem] = present[0]
            else:
                problems.append(Problem(present[0].name, "", kind))
        elif stem == "imu":
            problems.append(Problem("imu.csv", "", "required file is missing"))

    # Sections required by the files present (checked on the raw YAML, so that they are
    # reported even when another part of meta.yaml is invalid).
    anchor_ids: list[str] | None = None
    if raw is not None:
        for stem in files:
            section = _SECTION_OF[stem]
            if section is None or stem == "imu":
                continue
            if _raw_section(raw, section) is None:
                problems.append(
                    Problem(
                        "meta.yaml",
                        f"key {section}",
                        f"section {section!r} is required because {files[stem].name} is present",
                    )
                )
        uwb_raw = _raw_section(raw, "uwb")
        if "uwb" in files and isinstance(uwb_raw, dict):
            anchors = uwb_raw.get("anchors")
            if anchors is None or anchors == {}:
                line = key_lines.get(("uwb", "anchors")) or key_lines.get(("uwb",))
                problems.append(
                    Problem(
                        "meta.yaml",
                        "key uwb.anchors" + (f" (line {line})" if line else ""),
                        "a non-empty 'anchors' mapping is required because uwb.csv is present",
                    )
                )
            elif isinstance(anchors, dict):
                anchor_ids = [str(a) for a in anchors]
    if meta is not None and meta.uwb is not None:
        anchor_ids = list(meta.uwb.anchors)

    def rate_of(section: str) -> float | None:
        if meta is not None:
            sec = getattr(meta, section)
            return float(sec.rate_hz) if sec is not None else None
        sec_raw = _raw_section(raw, section)
        return _positive_number(sec_raw.get("rate_hz")) if isinstance(sec_raw, dict) else None

    # Read and check every CSV file.
    tables: dict[str, _Table] = {}
    gaps: list[tuple[float, float]] = []
    for stem, file in files.items():
        rep = _Reporter(file.name)
        table = _read_table(
            file, file.name, STREAM_COLUMNS[stem], rep, 1 if stem == "uwb" else None
        )
        if table is not None:
            _check_table(stem, table, rep, anchor_ids)
            rate = rate_of(stem) if stem in _RATE_CHECKED else None
            if rate is not None:
                problems.extend(_check_rate(stem, file.name, table, rate, key_lines))
            if stem == "imu":
                gaps = _check_imu_gaps(
                    table.values[:, 0], table.lines, rep, report=not bridge_imu_gaps
                )
            tables[stem] = table
        problems.extend(rep.finish())
    times = {stem: table.values[:, 0] for stem, table in tables.items()}
    problems.extend(_truth_overlap(times, lambda stem: files[stem].name))
    if "imu" in tables:
        for warning in _stream_warnings(times, lambda stem: files[stem].name, "no rows"):
            _log.warning("%s: %s", root, warning)
    if problems or meta is None:
        return None, problems
    if bridge_imu_gaps and gaps:
        _log.warning(
            "%s: bridging %d IMU gap(s) longer than %g sample intervals: %s",
            root,
            len(gaps),
            MAX_IMU_GAP_INTERVALS,
            ", ".join(f"{a:.6g}..{b:.6g} s" for a, b in gaps[:5])
            + (" ..." if len(gaps) > 5 else ""),
        )
    return _build(root, meta, tables, gaps if bridge_imu_gaps else []), []


def _stream_warnings(
    times: dict[str, FloatArray], label: Callable[[str], str], empty: str
) -> list[Problem]:
    """Streams that hold no samples, and streams that begin before, end after or lie outside
    the IMU's time span: legal (missing samples are absent rows), but worth a warning, since the
    engine can use none of those samples.

    Parameters
    ----------
    times
        Time column of each stream present, keyed by stem; ``"imu"`` must be among them.
    label
        Name of a stream in the warnings (``odometer.csv``, ``Recording.odometer``).
    empty
        What an empty stream has, for its warning (``"no rows"``).

    Notes
    -----
    A support.csv without rows is not mentioned: it says that no push happened. A stream
    reaching less than one IMU sample interval beyond the IMU is inside its span, since the
    first IMU sample is the mean over the interval before it.
    """
    imu = times["imu"]
    if imu.size == 0:
        return []
    start, end = float(imu[0]), float(imu[-1])
    slack = _median_interval(imu) or 0.0
    imu_span = f"{label('imu')} t={start:.6g}..{end:.6g} s"
    warnings: list[Problem] = []
    for stem, t in times.items():
        if stem == "imu" or (stem == "support" and t.size == 0):
            continue
        if t.size == 0:
            warnings.append(Problem(label(stem), "", f"the stream has {empty}: no samples"))
            continue
        first, last = float(t.min()), float(t.max())
        if stem == "truth" and (last < start or first > end):
            continue  # a problem, not a warning (_truth_overlap)
        spans = f"({label(stem)} t={first:.6g}..{last:.6g} s, {imu_span})"
        if last < start - slack or first > end + slack:
            rule = f"lies entirely outside the IMU's time span {spans}: none of it can be used"
        else:
            ends = []
            if first < start - slack:
                ends.append(f"begins {start - first:.6g} s before")
            if last > end + slack:
                ends.append(f"ends {last - end:.6g} s after")
            if not ends:
                continue
            rule = f"{' and '.join(ends)} the IMU {spans}"
        warnings.append(Problem(label(stem), "", rule))
    return warnings


def _truth_overlap(times: dict[str, FloatArray], label: Callable[[str], str]) -> list[Problem]:
    """A truth whose time span misses the IMU's entirely scores nothing (and scoring it would
    fail): one problem naming both spans."""
    if "truth" not in times or "imu" not in times:
        return []
    t_imu, t_truth = times["imu"], times["truth"]
    if t_imu.size == 0 or t_truth.size == 0:
        return []
    if t_truth[-1] >= t_imu[0] and t_truth[0] <= t_imu[-1]:
        return []
    return [
        Problem(
            label("truth"),
            "",
            f"its time span {_num(t_truth[0])}..{_num(t_truth[-1])} s does not overlap"
            f" {label('imu')}'s {_num(t_imu[0])}..{_num(t_imu[-1])} s: the recording's"
            " clock lies outside its truth, so nothing can be scored",
        )
    ]


def _check_rate(
    stem: str, label: str, table: _Table, rate: float, key_lines: dict[KeyPath, int]
) -> list[Problem]:
    """Compare ``rate_hz`` with the median sample interval."""
    median = _median_interval(table.values[:, 0])
    found = _rate_problem(stem, rate, median, label, key_lines) if median is not None else None
    return [found] if found is not None else []


_BRIDGE_BY_READER = "read with bridge_imu_gaps=True to bridge it explicitly"


def _check_imu_gaps(
    t: FloatArray,
    lines: IntArray,
    rep: _Reporter,
    *,
    report: bool,
    known: Sequence[tuple[float, float]] = (),
    hint: str = _BRIDGE_BY_READER,
) -> list[tuple[float, float]]:
    """Report (or just return) the IMU gaps longer than 5 median sample intervals; ``known``
    gaps (already accepted for bridging) are not reported."""
    if t.size < 2 and not rep.problems:
        rep.add("count", "", f"at least 2 samples are required (found {t.size})")
    idx, limit = _imu_gaps(t)
    if report:
        accepted = set(known)
        idx = np.array(
            [i for i in idx if (float(t[i]), float(t[i + 1])) not in accepted], dtype=np.int64
        )
        rep.add_many(
            "gap",
            idx.size,
            lambda i: (
                f"{rep.unit}s {lines[idx[i]]}-{lines[idx[i] + 1]} "
                f"(t={_num(t[idx[i]])}..{_num(t[idx[i] + 1])} s)",
                f"gap of {t[idx[i] + 1] - t[idx[i]]:.6g} s is longer than "
                f"{MAX_IMU_GAP_INTERVALS:g} sample intervals ({limit:.6g} s); {hint}",
            ),
            "IMU gap longer than 5 sample intervals",
        )
    return [(float(t[i]), float(t[i + 1])) for i in idx]


def _check_table(stem: str, table: _Table, rep: _Reporter, anchor_ids: list[str] | None) -> None:
    v, lines = table.values, table.lines
    columns = STREAM_COLUMNS[stem]
    _check_time(v[:, 0], lines, rep, np.asarray(table.text) if stem == "uwb" else None)
    if stem == "imu":
        _check_limit(v[:, 1:4], lines, columns[1:4], MAX_ANGULAR_RATE_RADPS, "rad/s", "gyro", rep)
        _check_limit(
            v[:, 4:7], lines, columns[4:7], MAX_SPECIFIC_FORCE_MPS2, "m/s²", "accelerometer", rep
        )
    elif stem == "uwb":
        _check_positive(v[:, 2:3], lines, columns[2:3], rep, strict=False, what="range")
        if anchor_ids and table.text is not None:
            ids = np.asarray(table.text)
            unknown = np.flatnonzero(~np.isin(ids, np.asarray(anchor_ids)))
            known = ", ".join(anchor_ids)

            def make(i: int) -> tuple[str, str]:
                bad = str(ids[unknown[i]])
                hint = suggest(bad, anchor_ids)
                rule = f"unknown anchor id {bad!r} (meta.yaml uwb.anchors has {known})"
                if hint:
                    rule += f"; did you mean {hint!r}?"
                return f"{rep.unit} {lines[unknown[i]]}, column anchor", rule

            rep.add_many("anchor", unknown.size, make, "unknown anchor id")
    elif stem == "position":
        _check_positive(v[:, 4:7], lines, columns[4:7], rep, strict=True, what="sigma")
    elif stem == "truth":
        _check_cycle(v[:, 10], lines, rep)


def _build(
    root: Path | None,
    meta: RecordingMeta,
    tables: dict[str, _Table],
    gaps: list[tuple[float, float]],
) -> Recording:
    def get(stem: str) -> FloatArray | None:
        table = tables.get(stem)
        return table.values if table is not None else None

    imu = get("imu")
    assert imu is not None
    odo, mag, sup = get("odometer"), get("magnetometer"), get("support")
    pos, tru = get("position"), get("truth")
    uwb: UwbData | None = None
    uwb_table = tables.get("uwb")
    if uwb_table is not None:
        assert meta.uwb is not None and uwb_table.text is not None
        anchor_ids = tuple(meta.uwb.anchors)
        lookup = {a: i for i, a in enumerate(anchor_ids)}
        ids = np.asarray(uwb_table.text, dtype=str)
        uniq, inverse = np.unique(ids, return_inverse=True)
        index = np.array([lookup[str(u)] for u in uniq], dtype=np.int64)[inverse.reshape(-1)]
        v = uwb_table.values
        order = np.argsort(v[:, 0], kind="stable")  # time order; a round's shared stamps stay
        uwb = UwbData(
            t=v[order, 0], anchor_index=index[order], range=v[order, 2], anchor_ids=anchor_ids
        )
    return Recording(
        path=root,
        meta=meta,
        imu=ImuData(  # contiguous copies, so the strapdown loop needs none and the table goes
            t=np.ascontiguousarray(imu[:, 0]),
            gyro=np.ascontiguousarray(imu[:, 1:4]),
            accel=np.ascontiguousarray(imu[:, 4:7]),
        ),
        odometer=OdometerData(t=odo[:, 0], speed=odo[:, 1]) if odo is not None else None,
        magnetometer=MagnetometerData(t=mag[:, 0], field=mag[:, 1:4]) if mag is not None else None,
        uwb=uwb,
        support=SupportData(t=sup[:, 0], advance=sup[:, 1]) if sup is not None else None,
        position=PositionData(t=pos[:, 0], enu=pos[:, 1:4], sigma=pos[:, 4:7])
        if pos is not None
        else None,
        truth=TruthData(
            t=tru[:, 0],
            position=tru[:, 1:4],
            velocity=tru[:, 4:7],
            attitude=tru[:, 7:10],
            cycle=tru[:, 10].astype(np.int64),
        )
        if tru is not None
        else None,
        imu_gaps=gaps,
    )


def read_recording(path: str | Path, *, bridge_imu_gaps: bool = False) -> Recording:
    """Read and validate a recording directory.

    Parameters
    ----------
    path : str or Path
        The recording directory.
    bridge_imu_gaps : bool, default False
        Accept gaps in ``imu.csv`` longer than 5 sample intervals instead of rejecting the
        recording; they are returned in :attr:`Recording.imu_gaps` (and logged as a warning) so
        that the engine can report them.

    Returns
    -------
    Recording

    Raises
    ------
    RecordingError
        Listing every problem found (file, line or key, rule), when the recording breaks the
        format.
    """
    recording, problems = _inspect(path, bridge_imu_gaps=bridge_imu_gaps)
    release_freed_memory()  # the parse's temporaries
    if problems or recording is None:
        raise RecordingError(problems, path)
    return recording


def validate_recording(path: str | Path, *, bridge_imu_gaps: bool = False) -> list[Problem]:
    """Check a recording directory against the format without raising for bad content.

    Parameters
    ----------
    path : str or Path
        The recording directory.
    bridge_imu_gaps : bool, default False
        Do not report IMU gaps (as with :func:`read_recording`).

    Returns
    -------
    list of Problem
        Every broken rule found; empty when the recording is valid.
    """
    return _inspect(path, bridge_imu_gaps=bridge_imu_gaps)[1]


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------

_CHUNK_ROWS = 16384  # rows formatted at once: about 20 MB of Python objects for a 13-column file


def csv_text_chunks(
    header: Sequence[str], columns: Sequence[npt.NDArray[Any]], kinds: str
) -> Iterable[bytes]:
    """Yield a CSV file's bytes in chunks: floats as ``repr`` (exact; kind ``f``) or to 7
    significant digits (kind ``g``, float32's precision), ints as ``%d``, text as is.

    Public so that writers working in chunks (the simulator) produce exactly this format.
    """
    yield (",".join(header) + "\n").encode()
    n = len(columns[0]) if columns else 0
    fmt = ",".join({"f": "%r", "g": "%.7g", "i": "%d", "s": "%s"}[k] for k in kinds) + "\n"
    for start in range(0, n, _CHUNK_ROWS):
        stop = min(n, start + _CHUNK_ROWS)
        parts = [c[start:stop].tolist() for c in columns]
        yield "".join(map(fmt.__mod__, zip(*parts, strict=True))).encode()


def _write_csv(
    path: Path,
    header: Sequence[str],
    columns: Sequence[npt.NDArray[Any]],
    kinds: str,
    *,
    compress: bool,
) -> None:
    """Write a CSV file (``path`` without ``.gz``); with ``compress`` write ``path.gz``."""
    chunks = csv_text_chunks(header, columns, kinds)
    if compress:
        with (
            open(path.with_name(path.name + ".gz"), "wb") as raw,
            gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0, compresslevel=6) as gz,
        ):
            for chunk in chunks:
                gz.write(chunk)
    else:
        with open(path, "wb") as fh:
            for chunk in chunks:
                fh.write(chunk)


def meta_yaml_text(meta: RecordingMeta) -> str:
    """The meta.yaml text of ``meta`` (``extra`` last, absent sections left out)."""
    data = meta.model_dump(mode="json", exclude_none=True, exclude={"extra"})
    if meta.extra:
        data["extra"] = meta.extra
    return yaml.safe_dump(
        data, sort_keys=False, default_flow_style=None, allow_unicode=True, width=100
    )


def _stream_columns(
    recording: Recording,
) -> dict[str, tuple[list[npt.NDArray[Any]], str] | None]:
    r = recording
    out: dict[str, tuple[list[npt.NDArray[Any]], str] | None] = {}
    out["imu"] = ([r.imu.t, *r.imu.gyro.T, *r.imu.accel.T], "fffffff")
    out["odometer"] = ([r.odometer.t, r.odometer.speed], "ff") if r.odometer else None
    out["magnetometer"] = (
        ([r.magnetometer.t, *r.magnetometer.field.T], "ffff") if r.magnetometer else None
    )
    if r.uwb is not None:
        names = np.asarray(r.uwb.anchor_ids, dtype=object)[r.uwb.anchor_index]
        out["uwb"] = ([r.uwb.t, names, r.uwb.range], "fsf")
    else:
        out["uwb"] = None
    out["support"] = ([r.support.t, r.support.advance], "ff") if r.support else None
    out["position"] = (
        ([r.position.t, *r.position.enu.T, *r.position.sigma.T], "fffffff") if r.position else None
    )
    if r.truth is not None:
        tr = r.truth
        out["truth"] = (
            [tr.t, *tr.position.T, *tr.velocity.T, *tr.attitude.T, tr.cycle],
            "ffffffffffi",
        )
    else:
        out["truth"] = None
    return out


def _report_nonfinite(rep: _Reporter, lines: IntArray, bad: IntArray, name: str) -> None:
    rep.add_many(
        "nonfinite",
        bad.size,
        lambda i: (f"{rep.unit} {lines[bad[i]]}, column {name}", "value is not a finite number"),
        "a value is NaN or infinite",
    )


class _Naming(NamedTuple):
    """How problems name the parts of a recording: its files, or its arrays in memory."""

    stream: Callable[[str], str]  # stem -> label
    meta: str
    first_row: int  # number of the first row (a file's line 2, an array's sample 0)
    unit: str


_FILE_NAMING = _Naming(lambda stem: f"{stem}.csv", "meta.yaml", 2, "line")
_MEMORY_NAMING = _Naming(lambda stem: f"Recording.{stem}", "Recording.meta", 0, "sample")


def _array_problems(
    recording: Recording,
    streams: dict[str, tuple[list[npt.NDArray[Any]], str] | None],
    naming: _Naming,
) -> list[Problem]:
    """Format-level checks of arrays: finite values, increasing time, sections, ids."""
    problems: list[Problem] = []
    meta = recording.meta
    for stem, item in streams.items():
        if item is None:
            continue
        section = _SECTION_OF[stem]
        if section is not None and getattr(meta, section) is None:
            problems.append(
                Problem(naming.meta, f"key {section}", f"section {section!r} is required")
            )
        cols, kinds = item
        rep = _Reporter(naming.stream(stem), unit=naming.unit)
        lines = np.arange(naming.first_row, len(cols[0]) + naming.first_row, dtype=np.int64)
        names = STREAM_COLUMNS[stem]
        for col, kind, name in zip(cols, kinds, names, strict=True):
            if kind == "f":
                _report_nonfinite(rep, lines, np.flatnonzero(~np.isfinite(col)), name)
        keys = np.asarray(cols[1]) if stem == "uwb" else None
        _check_time(np.asarray(cols[0], dtype=np.float64), lines, rep, keys)
        if stem == "truth":
            _check_cycle(np.asarray(cols[-1], dtype=np.float64), lines, rep)
        if stem == "imu" and len(cols[0]) < 2:
            rep.add("count", "", "at least 2 samples are required")
        problems.extend(rep.finish())
    if recording.uwb is not None and meta.uwb is not None:
        unknown = sorted(set(recording.uwb.anchor_ids) - set(meta.uwb.anchors))
        if unknown:
            problems.append(
                Problem(naming.meta, "key uwb.anchors", f"anchor ids {unknown} are not defined")
            )
    return problems


_STREAM_TYPES: dict[str, type] = {
    "imu": ImuData,
    "odometer": OdometerData,
    "magnetometer": MagnetometerData,
    "uwb": UwbData,
    "support": SupportData,
    "position": PositionData,
    "truth": TruthData,
}


def _type_problems(recording: Recording) -> list[Problem]:
    """The parts of a recording of the wrong type (the dataclasses do not check them)."""
    problems = []
    if not isinstance(recording.meta, RecordingMeta):
        found = type(recording.meta).__name__
        problems.append(Problem("Recording.meta", "", f"must be a RecordingMeta (found {found})"))
    for stem, kind in _STREAM_TYPES.items():
        value = getattr(recording, stem)
        if not isinstance(value, kind) and (value is not None or stem == "imu"):
            allowed = kind.__name__ if stem == "imu" else f"{kind.__name__} or None"
            problems.append(
                Problem(
                    f"Recording.{stem}", "", f"must be {allowed} (found {type(value).__name__})"
                )
            )
    return problems


def _physical_problems(
    recording: Recording, *, bridge_imu_gaps: bool
) -> tuple[list[Problem], list[tuple[float, float]]]:
    """The reader's rules that :func:`_array_problems` leaves out: physical limits, rates, IMU
    gaps (those not in ``recording.imu_gaps``; all are accepted with ``bridge_imu_gaps``).
    Returns the problems and the IMU gaps to bridge."""
    naming = _MEMORY_NAMING
    problems: list[Problem] = []
    r = recording

    def rows(n: int) -> IntArray:
        return np.arange(n, dtype=np.int64)

    imu = _Reporter(naming.stream("imu"), unit=naming.unit)
    imu_rows = rows(r.imu.t.size)
    names = STREAM_COLUMNS["imu"]
    _check_limit(r.imu.gyro, imu_rows, names[1:4], MAX_ANGULAR_RATE_RADPS, "rad/s", "gyro", imu)
    _check_limit(
        r.imu.accel, imu_rows, names[4:7], MAX_SPECIFIC_FORCE_MPS2, "m/s²", "accelerometer", imu
    )
    gaps = _check_imu_gaps(
        r.imu.t,
        imu_rows,
        imu,
        report=not bridge_imu_gaps,
        known=r.imu_gaps,
        hint="set bridge_imu_gaps: true in the configuration to bridge it explicitly",
    )
    problems.extend(imu.finish())
    if r.uwb is not None:
        rep = _Reporter(naming.stream("uwb"), unit=naming.unit)
        ranges = r.uwb.range[:, None]
        _check_positive(ranges, rows(r.uwb.t.size), ("range",), rep, strict=False, what="range")
        problems.extend(rep.finish())
    if r.position is not None:
        rep = _Reporter(naming.stream("position"), unit=naming.unit)
        sigma_names = STREAM_COLUMNS["position"][4:7]
        n_fixes = r.position.t.size
        _check_positive(
            r.position.sigma, rows(n_fixes), sigma_names, rep, strict=True, what="sigma"
        )
        problems.extend(rep.finish())
    for stem in _RATE_CHECKED:
        data, section = getattr(r, stem), getattr(r.meta, stem)
        median = _median_interval(data.t) if data is not None else None
        if median is not None and section is not None:
            found = _rate_problem(
                stem, section.rate_hz, median, naming.stream(stem), {}, naming.meta
            )
            problems.extend([found] if found is not None else [])
    if r.truth is not None:
        times = {"imu": r.imu.t, "truth": r.truth.t}
        problems.extend(_truth_overlap(times, naming.stream))
    known = sorted(set(r.imu_gaps) | set(gaps)) if bridge_imu_gaps else list(r.imu_gaps)
    return problems, known


def check_recording(recording: Recording, *, bridge_imu_gaps: bool = False) -> Recording:
    """Check a :class:`Recording` built in memory against the rules of the format.

    The rules of :func:`read_recording` that apply to arrays: the types of the parts, ``meta``
    valid (re-validated, so a value assigned after construction is checked too), every value
    finite, time strictly increasing (``uwb``: per anchor), at least 2 IMU samples, physically
    possible values, the meta section of each stream present, the anchor ids defined, the
    checked rates within 10 %, no IMU gap longer than 5 sample intervals unless it is in
    ``recording.imu_gaps`` or ``bridge_imu_gaps`` is set, a truth that overlaps the IMU's span.
    A problem names the part as ``Recording.imu`` and a row as ``sample i`` (its index in the
    arrays). A recording built in memory (``path`` None) also gets the reader's warnings
    (logged): streams without samples, streams outside the IMU's time span.

    Parameters
    ----------
    recording : Recording
        The recording, e.g. built by a user's script.
    bridge_imu_gaps : bool, default False
        Accept IMU gaps longer than 5 sample intervals and list them in ``imu_gaps``.

    Returns
    -------
    Recording
        ``recording`` itself, or a copy whose ``imu_gaps`` lists the gaps to bridge.

    Raises
    ------
    RecordingError
        Listing every problem found.
    """
    problems = _type_problems(recording)
    if problems:
        raise RecordingError(problems)
    try:
        RecordingMeta.model_validate(recording.meta.model_dump())
    except ValidationError as exc:
        raise RecordingError(_meta_problems_from_validation(exc, {}, "Recording.meta")) from None
    problems = _array_problems(recording, _stream_columns(recording), _MEMORY_NAMING)
    found, gaps = _physical_problems(recording, bridge_imu_gaps=bridge_imu_gaps)
    problems.extend(found)
    if problems:
        raise RecordingError(problems)
    if recording.path is None:
        times = {stem: getattr(recording, stem) for stem in _STREAM_TYPES}
        present = {stem: data.t for stem, data in times.items() if data is not None}
        for warning in _stream_warnings(present, _MEMORY_NAMING.stream, "no samples"):
            _log.warning("in-memory recording: %s", warning)
    if gaps == list(recording.imu_gaps):
        return recording
    return replace(recording, imu_gaps=gaps)


def write_recording(recording: Recording, path: str | Path, *, compress: bool = False) -> None:
    """Write a recording directory.

    The output is deterministic: identical input gives byte-identical files.  Floats are
    written with ``repr`` (the shortest string that reads back to the same float64), so a
    written recording reads back with bit-identical arrays.  Stale recording files of streams
    that are absent (or in the other compression variant) are removed, so that the directory
    holds exactly this recording.

    Parameters
    ----------
    recording : Recording
        The recording to write; ``recording.path`` and ``imu_gaps`` are not written.
    path : str or Path
        Output directory (created when missing).
    compress : bool, default False
        Write ``*.csv.gz`` (gzip with a zero mtime in its header) instead of ``*.csv``.

    Raises
    ------
    RecordingError
        When the recording cannot be written as a valid file set (non-finite values, time not
        strictly increasing, a stream without its meta.yaml section, an undefined anchor id).
    """
    root = Path(path)
    streams = _stream_columns(recording)
    problems = _array_problems(recording, streams, _FILE_NAMING)
    if problems:
        raise RecordingError(problems, root)
    root.mkdir(parents=True, exist_ok=True)
    (root / "meta.yaml").write_text(meta_yaml_text(recording.meta), encoding="utf-8")
    for stem, item in streams.items():
        plain, packed = root / f"{stem}.csv", root / f"{stem}.csv.gz"
        stale = [plain, packed] if item is None else [plain if compress else packed]
        for old in stale:
            old.unlink(missing_ok=True)
        if item is not None:
            cols, kinds = item
            _write_csv(plain, STREAM_COLUMNS[stem], cols, kinds, compress=compress)
