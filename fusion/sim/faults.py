"""Fault injection for the sensor simulators.

A scenario lists faults as plain mappings with a ``kind`` key; :data:`FaultSpec` is the pydantic
discriminated union that validates them:

=========================  ==================================================================
``magnetic_interference``  an additive body-frame field ``field_uT`` (µT, 3-vector) on the
                           magnetometer, e.g. machinery switched on near the sensor
``uwb_nlos``               non-line-of-sight on the listed anchors (all when empty): every range
                           gets a positive bias drawn uniformly in ``bias_m = [lo, hi]`` m
``odometer_slip``          the wheel over-reads by ``slip_ratio`` (``+0.2`` = 20 % too much
                           travel, negative values under-read); multiplicative on the increment
``dropout``                rows of ``sensor`` are absent in the window
``imu_gap``                IMU rows are absent in the window (a logging gap; the IMU's own error
                           processes keep running underneath)
=========================  ==================================================================

Every fault has a window ``[t_start, t_end]`` (seconds on the recording clock) and a ramp time
``ramp_s`` (default 0). Its *weight* at time t is the trapezoid

    w(t) = clip(min(t − t_start, t_end − t) / ramp_s, 0, 1)      (ramp_s > 0)
    w(t) = 1 if t_start ≤ t ≤ t_end else 0                         (ramp_s = 0),

i.e. the ramps lie inside the window: the effect grows linearly from 0 at ``t_start`` to full at
``t_start + ramp_s`` and decays back to 0 at ``t_end``. Additive and multiplicative effects are
scaled by w (interference ``w·field``, slip ``1 + w·slip_ratio``). Row-removing faults
(``dropout``, ``imu_gap``) and ``uwb_nlos`` are on/off: active where w > 0, which with a ramp is
the open window, and with ``ramp_s = 0`` the closed window.

All helpers are vectorized over the time array and stateless, so they are trivially chunk-aware.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Annotated, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator

SensorName = Literal["imu", "odometer", "magnetometer", "uwb", "support", "position"]
"""Sensor names a ``dropout`` fault can target (the recording's CSV file stems)."""

FaultKind = Literal["magnetic_interference", "uwb_nlos", "odometer_slip", "dropout", "imu_gap"]


class _Window(BaseModel):
    """Common fields: the time window and the linear ramp inside it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    t_start: float = Field(description="start of the window (s, recording clock)")
    t_end: float = Field(description="end of the window (s), > t_start")
    ramp_s: float = Field(default=0.0, ge=0.0, description="linear ramp-in/-out time (s)")

    @model_validator(mode="after")
    def _check_window(self) -> _Window:
        if not self.t_end > self.t_start:
            raise ValueError(f"t_end ({self.t_end}) must be greater than t_start ({self.t_start})")
        if 2.0 * self.ramp_s > self.t_end - self.t_start:
            raise ValueError(
                f"ramp_s ({self.ramp_s}) too long: two ramps must fit in the window "
                f"[{self.t_start}, {self.t_end}]"
            )
        return self


class MagneticInterference(_Window):
    """Additive magnetic field in the body frame (µT)."""

    kind: Literal["magnetic_interference"] = "magnetic_interference"
    field_uT: tuple[float, float, float] = Field(description="additive b-frame field (µT)")


class UwbNlos(_Window):
    """Non-line-of-sight window on some anchors: positive range bias uniform in ``bias_m``."""

    kind: Literal["uwb_nlos"] = "uwb_nlos"
    anchors: list[str] = Field(default_factory=list, description="anchor ids; empty = all")
    bias_m: tuple[float, float] = Field(default=(0.3, 1.5), description="[lo, hi] bias (m)")

    @model_validator(mode="after")
    def _check_bias(self) -> UwbNlos:
        lo, hi = self.bias_m
        if not 0.0 <= lo <= hi:
            raise ValueError(f"bias_m must satisfy 0 <= lo <= hi, got {self.bias_m}")
        return self


class OdometerSlip(_Window):
    """Wheel slip: the odometer increment is multiplied by ``1 + w(t)·slip_ratio``."""

    kind: Literal["odometer_slip"] = "odometer_slip"
    slip_ratio: float = Field(default=0.2, gt=-1.0, description="relative over-read, +0.2 = +20 %")


class Dropout(_Window):
    """Rows of one sensor absent in the window."""

    kind: Literal["dropout"] = "dropout"
    sensor: SensorName


class ImuGap(_Window):
    """IMU rows absent in the window."""

    kind: Literal["imu_gap"] = "imu_gap"


FaultSpec = Annotated[
    MagneticInterference | UwbNlos | OdometerSlip | Dropout | ImuGap,
    Field(discriminator="kind"),
]
"""One fault of any kind, discriminated by its ``kind`` key."""

_FAULT_LIST: TypeAdapter[list[FaultSpec]] = TypeAdapter(list[FaultSpec])


def parse_faults(data: Iterable[Any] | None) -> list[FaultSpec]:
    """Validate a list of fault mappings (or models) into :data:`FaultSpec` objects.

    Parameters
    ----------
    data
        Mappings with a ``kind`` key (e.g. from a scenario YAML) or already-built fault models;
        ``None`` means no faults.

    Returns
    -------
    list of FaultSpec
        Validated faults, in the given order.
    """
    if data is None:
        return []
    return _FAULT_LIST.validate_python(
        [d.model_dump() if isinstance(d, BaseModel) else d for d in data]
    )


def fault_weight(fault: FaultSpec, t: ArrayLike) -> NDArray[np.float64]:
    """Weight in [0, 1] of one fault at times ``t`` (trapezoid with ramps inside the window).

    Parameters
    ----------
    fault
        The fault.
    t
        Times (s), any shape.

    Returns
    -------
    numpy.ndarray
        Same shape as ``t``.
    """
    tt = np.asarray(t, dtype=float)
    if fault.ramp_s > 0.0:
        edge = np.minimum(tt - fault.t_start, fault.t_end - tt) / fault.ramp_s
        return np.clip(edge, 0.0, 1.0)
    return ((tt >= fault.t_start) & (tt <= fault.t_end)).astype(float)


def faults_of_kind(faults: Sequence[FaultSpec], kind: FaultKind) -> list[FaultSpec]:
    """The faults of one ``kind``, in order."""
    return [f for f in faults if f.kind == kind]


def active_weight(
    faults: Sequence[FaultSpec],
    kind: FaultKind,
    t: ArrayLike,
    *,
    sensor: str | None = None,
    anchor: str | None = None,
) -> NDArray[np.float64]:
    """Combined activity in [0, 1] of the faults of one kind at times ``t``.

    Overlapping faults of the same kind combine by the maximum of their weights.

    Parameters
    ----------
    faults
        All faults of the run.
    kind
        Fault kind to look at.
    t
        (N,) times (s).
    sensor
        For ``dropout``: only faults on this sensor.
    anchor
        For ``uwb_nlos``: only faults that affect this anchor id (an empty anchor list affects
        every anchor).

    Returns
    -------
    numpy.ndarray
        (N,) weights.
    """
    tt = np.asarray(t, dtype=float)
    w = np.zeros(tt.shape)
    for f in faults_of_kind(faults, kind):
        if sensor is not None and isinstance(f, Dropout) and f.sensor != sensor:
            continue
        if anchor is not None and isinstance(f, UwbNlos) and f.anchors and anchor not in f.anchors:
            continue
        w = np.maximum(w, fault_weight(f, tt))
    return w


def present_mask(
    faults: Sequence[FaultSpec], sensor: SensorName, t: ArrayLike
) -> NDArray[np.bool_]:
    """Rows of ``sensor`` at times ``t`` that survive ``dropout`` (and, for the IMU, ``imu_gap``).

    Parameters
    ----------
    faults
        All faults of the run.
    sensor
        Sensor name (CSV file stem).
    t
        (N,) row times (s).

    Returns
    -------
    numpy.ndarray of bool
        (N,) True where the row is kept.
    """
    gone = active_weight(faults, "dropout", t, sensor=sensor) > 0.0
    if sensor == "imu":
        gone |= active_weight(faults, "imu_gap", t) > 0.0
    return ~gone


def magnetic_interference_field(faults: Sequence[FaultSpec], t: ArrayLike) -> NDArray[np.float64]:
    """Sum of the ramped interference fields ``Σ w_f(t)·field_f`` (µT), shape (N, 3)."""
    tt = np.asarray(t, dtype=float)
    out = np.zeros((tt.size, 3))
    for f in faults_of_kind(faults, "magnetic_interference"):
        assert isinstance(f, MagneticInterference)
        out += fault_weight(f, tt)[:, None] * np.asarray(f.field_uT, dtype=float)
    return out


def odometer_slip_factor(faults: Sequence[FaultSpec], t: ArrayLike) -> NDArray[np.float64]:
    """Multiplicative odometer factor ``1 + Σ w_f(t)·slip_ratio_f``, shape (N,)."""
    tt = np.asarray(t, dtype=float)
    out = np.ones(tt.shape)
    for f in faults_of_kind(faults, "odometer_slip"):
        assert isinstance(f, OdometerSlip)
        out = out + fault_weight(f, tt) * f.slip_ratio
    return out


def uwb_nlos_bias_range(
    faults: Sequence[FaultSpec], anchor: str, t: ArrayLike
) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64]]:
    """Where an ``uwb_nlos`` fault affects ``anchor`` and its bias interval there.

    Parameters
    ----------
    faults
        All faults of the run.
    anchor
        Anchor id.
    t
        (N,) range times (s).

    Returns
    -------
    active, lo, hi
        (N,) bool mask, and the lower/upper bias bounds (m) of the first fault active at each
        time (0 where none is).
    """
    tt = np.asarray(t, dtype=float)
    active = np.zeros(tt.shape, dtype=bool)
    lo = np.zeros(tt.shape)
    hi = np.zeros(tt.shape)
    for f in faults_of_kind(faults, "uwb_nlos"):
        assert isinstance(f, UwbNlos)
        if f.anchors and anchor not in f.anchors:
            continue
        new = (fault_weight(f, tt) > 0.0) & ~active
        lo[new], hi[new] = f.bias_m
        active |= new
    return active, lo, hi


def faults_to_meta(faults: Sequence[FaultSpec]) -> list[dict[str, Any]]:
    """Plain (YAML-safe) mappings of the faults for the recording's ``extra:`` section.

    Tuples become lists; the result round-trips through :func:`parse_faults`.
    """
    return [f.model_dump(mode="json") for f in faults]
