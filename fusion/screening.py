"""Physical-plausibility screening of every sensor stream, before any plugin reads it.

RECORDING_FORMAT.md has the reader refuse only what no sensor can output (NaN, |ω| > 50 rad/s,
|f| > 200 m/s², a negative range …): "any other finite value is a sensor's reading, however
implausible: whether to use it is the engine's decision, and the engine says how many readings
it rejected". This module is that decision. One hostile reading inside the format's limits was
enough to wreck a run: an odometer row at 10⁴ m/s left 1.2 km of error under a σ of 6 cm, one
at 10⁶ m/s grew CPOEM's stored points to 20 GB, a 49 rad/s gyro row 11 m.

Rules (limits in :class:`fusion.config.ScreeningOptions`, each justified there)
----------------------------------------------------------------------------------
* IMU: ``|ω| ≤ max_angular_rate`` and ``|f| ≤ max_specific_force`` per axis (the sensor's range,
  or the platform's); and a *step* rule: per axis ``|x_k − x_ref| ≤ floor + rate·(t_k − t_ref)``
  against the last accepted sample ``ref`` (angular acceleration for ω, jerk for f).
* odometer: ``|speed| ≤ max_speed``, and the step rule with the largest acceleration.
* magnetometer: ``min_field ≤ |B| ≤ max_field``.
* UWB: ``range ≤ max_range``.
* position fixes: each σ in ``[min_sigma, max_sigma]``, the fix within
  ``max_distance_from_origin`` of the origin, and within ``max_speed·Δt + k·σ`` of the last
  accepted fix (σ of the two fixes combined).
* support: ``0 ≤ advance ≤ max_advance``.

A sample gets the first rule that rejects it. A step rule has a recovery: after
``recovery_samples`` consecutive rejections by it the next sample is accepted as the new
reference, so a real step (or a first sample that was itself off) never locks the screen out.

Screening is causal: a sample is judged from itself and the accepted samples before it, never
from later ones, so a streaming engine gets the same decisions (appending samples never changes
the verdict on earlier ones).

Rejected rows are removed from their stream. For the IMU, whose samples the SINS integrates
back to back, each run of rejected rows becomes a gap ``(t_before, t_after)`` added to
``Recording.imu_gaps``, which the engine bridges like a logging gap (:mod:`fusion.imu_gaps`: the
mean rates of the window before it, with the process noise of that assumption), whatever its
length. A run at the very start or end has no sample on one side to bridge from or to: the IMU
then starts at its first or ends at its last accepted sample (logged).

The range rules are vectorized; the step rules, which depend on the last accepted sample, are
one compiled pass (numba) with the range rules of the same stream, so an 8-hour shift's 3
million IMU rows are screened without full-size temporaries.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion import kernels
from fusion.config import ConfigError, ScreeningOptions
from fusion.recording import (
    ImuData,
    MagnetometerData,
    OdometerData,
    PositionData,
    Recording,
    SupportData,
    UwbData,
)

_log = logging.getLogger(__name__)

STREAMS = ("imu", "odometer", "magnetometer", "uwb", "position", "support")
"""The screened streams, in report order (the recording's CSV stems)."""

Verdicts = NDArray[np.uint8]
"""Per sample: 0 accepted, otherwise the 1-based number of the rule that rejected it."""


@dataclass(frozen=True)
class StreamScreening:
    """The screening of one stream.

    Attributes
    ----------
    stream
        The stream's CSV stem (``"odometer"``).
    samples
        Samples screened.
    rejected_by_rule
        Rejected samples per rule that rejected them (rule text with its limit); rules that
        rejected nothing are left out.
    """

    stream: str
    samples: int
    rejected_by_rule: dict[str, int] = field(default_factory=dict)

    @property
    def rejected(self) -> int:
        """Samples rejected by any rule."""
        return sum(self.rejected_by_rule.values())

    def describe(self) -> str:
        """``"odometer: 1 of 4000 samples rejected as implausible (|speed| > 5 m/s)"``."""
        rules = ", ".join(
            rule if len(self.rejected_by_rule) == 1 else f"{count} {rule}"
            for rule, count in self.rejected_by_rule.items()
        )
        return (
            f"{self.stream}: {self.rejected} of {self.samples} samples rejected as implausible"
            f" ({rules})"
        )


@dataclass(frozen=True)
class ScreeningReport:
    """What the screening of one recording rejected (:attr:`fusion.engine.RunResult.screening`).

    Attributes
    ----------
    enabled
        Whether the streams were screened.
    streams
        One entry per stream present in the recording (``STREAMS`` order).
    imu_gaps
        The gaps ``(t_before, t_after)`` left by rejected IMU runs (bridged by the engine).
    """

    enabled: bool
    streams: tuple[StreamScreening, ...] = ()
    imu_gaps: tuple[tuple[float, float], ...] = ()

    @property
    def rejected(self) -> int:
        """Samples rejected over all streams."""
        return sum(s.rejected for s in self.streams)

    def stream(self, name: str) -> StreamScreening | None:
        """The entry of stream ``name`` (None when the recording has no such stream)."""
        return next((s for s in self.streams if s.stream == name), None)

    def rejected_in(self, name: str) -> int:
        """Samples rejected in stream ``name`` (0 when absent)."""
        entry = self.stream(name)
        return entry.rejected if entry is not None else 0

    def to_dict(self) -> dict[str, Any]:
        """JSON form (metrics.json's ``"screening"``)."""
        return {
            "enabled": self.enabled,
            "streams": {
                s.stream: {
                    "samples": s.samples,
                    "rejected": s.rejected,
                    "rejected_by_rule": dict(s.rejected_by_rule),
                }
                for s in self.streams
            },
            "imu_gaps": [list(g) for g in self.imu_gaps],
        }


def screen_recording(
    recording: Recording, options: ScreeningOptions
) -> tuple[Recording, ScreeningReport]:
    """The recording with every implausible sample removed, and what was removed.

    Parameters
    ----------
    recording
        As read (``truth`` is never screened).
    options
        The limits; ``options.enabled`` false returns the recording itself.

    Returns
    -------
    Recording
        Rejected rows removed; the gaps left by rejected IMU runs added to ``imu_gaps`` (the
        recording itself when nothing was rejected).
    ScreeningReport
        Counts per stream and rule. A warning is logged for each stream with rejections.

    Raises
    ------
    ConfigError
        When fewer than two IMU samples are accepted (the limits cannot fit this IMU).
    """
    if not options.enabled:
        return recording, ScreeningReport(enabled=False)
    entries = []
    changes: dict[str, Any] = {}
    gaps: list[tuple[float, float]] = []
    for name in STREAMS:
        data = getattr(recording, name)
        if data is None:
            continue
        verdicts, rules = _SCREENS[name](data, options)
        entry = _count(name, verdicts, rules)
        entries.append(entry)
        if entry.rejected == 0:
            continue
        _log.warning("%s: screening: %s", recording.meta.name or "recording", entry.describe())
        keep = verdicts == 0
        if name == "imu":
            changes["imu"], gaps, changes["imu_gaps"] = _imu_without(recording, keep)
        else:
            changes[name] = _rows(data, keep)
    report = ScreeningReport(True, tuple(entries), tuple(gaps))
    return (replace(recording, **changes) if changes else recording), report


def _count(name: str, verdicts: Verdicts, rules: tuple[str, ...]) -> StreamScreening:
    counts = np.bincount(verdicts, minlength=len(rules) + 1)
    by_rule = {rule: int(counts[i + 1]) for i, rule in enumerate(rules) if counts[i + 1]}
    return StreamScreening(name, int(verdicts.size), by_rule)


def _g(x: float) -> str:
    return f"{x:g}"


# --------------------------------------------------------------------------------------------
# Per-stream rules: each returns the verdicts and the rule texts they number (1-based)
# --------------------------------------------------------------------------------------------


def screen_imu(imu: ImuData, options: ScreeningOptions) -> tuple[Verdicts, tuple[str, ...]]:
    """Range of ω and f per axis, then their steps against the last accepted sample."""
    o = options.imu
    verdicts = _range_and_steps(
        imu.t,
        imu.gyro,
        imu.accel,
        np.full(3, o.max_angular_rate_rad_s),
        np.full(3, o.max_specific_force_mps2),
        np.full(3, o.max_angular_acceleration_rad_s2),
        np.full(3, o.max_jerk_mps3),
        np.full(3, o.angular_rate_step_floor_rad_s),
        np.full(3, o.specific_force_step_floor_mps2),
        o.recovery_samples,
    )
    rules = (
        f"|ω| > {_g(o.max_angular_rate_rad_s)} rad/s",
        f"|f| > {_g(o.max_specific_force_mps2)} m/s²",
        f"|Δω| > {_g(o.angular_rate_step_floor_rad_s)} rad/s"
        f" + {_g(o.max_angular_acceleration_rad_s2)} rad/s²·Δt",
        f"|Δf| > {_g(o.specific_force_step_floor_mps2)} m/s² + {_g(o.max_jerk_mps3)} m/s³·Δt",
    )
    return verdicts, rules


def screen_odometer(
    odometer: OdometerData, options: ScreeningOptions
) -> tuple[Verdicts, tuple[str, ...]]:
    """Range of the speed, then its step against the last accepted reading."""
    o = options.odometer
    none = np.empty((odometer.t.size, 0))
    verdicts = _range_and_steps(
        odometer.t,
        odometer.speed.reshape(-1, 1),
        none,
        np.array([o.max_speed_mps]),
        np.empty(0),
        np.array([o.max_acceleration_mps2]),
        np.empty(0),
        np.array([o.speed_step_floor_mps]),
        np.empty(0),
        o.recovery_samples,
    )
    verdicts[verdicts == 3] = 2  # the kernel's rules 2 and 4 are the absent second channel's
    rules = (
        f"|speed| > {_g(o.max_speed_mps)} m/s",
        f"|Δspeed| > {_g(o.speed_step_floor_mps)} m/s + {_g(o.max_acceleration_mps2)} m/s²·Δt",
    )
    return verdicts, rules


def screen_magnetometer(
    magnetometer: MagnetometerData, options: ScreeningOptions
) -> tuple[Verdicts, tuple[str, ...]]:
    """The field norm within the plausible band."""
    o = options.magnetometer
    norm = np.sqrt(np.einsum("ij,ij->i", magnetometer.field, magnetometer.field))
    bad = ~((norm >= o.min_field_uT) & (norm <= o.max_field_uT))
    return _first_rule([bad]), (f"|B| outside [{_g(o.min_field_uT)}, {_g(o.max_field_uT)}] µT",)


def screen_uwb(uwb: UwbData, options: ScreeningOptions) -> tuple[Verdicts, tuple[str, ...]]:
    """Ranges within the anchors' reach."""
    o = options.uwb
    return _first_rule([~(uwb.range <= o.max_range_m)]), (f"range > {_g(o.max_range_m)} m",)


def screen_position(
    position: PositionData, options: ScreeningOptions
) -> tuple[Verdicts, tuple[str, ...]]:
    """σ band, distance from the origin, then the jump from the last accepted fix."""
    o = options.position
    sigma_ok = np.all((position.sigma >= o.min_sigma_m) & (position.sigma <= o.max_sigma_m), 1)
    far = ~(np.linalg.norm(position.enu, axis=1) <= o.max_distance_from_origin_m)
    verdicts = _first_rule([~sigma_ok, far])
    _fix_jumps(
        position.t,
        position.enu,
        position.sigma,
        verdicts,
        o.max_speed_mps,
        o.sigma_multiple,
        o.recovery_samples,
        3,
    )
    rules = (
        f"σ outside [{_g(o.min_sigma_m)}, {_g(o.max_sigma_m)}] m",
        f"more than {_g(o.max_distance_from_origin_m)} m from the origin",
        f"jump > {_g(o.max_speed_mps)} m/s·Δt + {_g(o.sigma_multiple)}σ",
    )
    return verdicts, rules


def screen_support(
    support: SupportData, options: ScreeningOptions
) -> tuple[Verdicts, tuple[str, ...]]:
    """Pushes within ``[0, max_advance]``."""
    o = options.support
    bad = ~((support.advance >= 0.0) & (support.advance <= o.max_advance_m))
    return _first_rule([bad]), (f"advance outside [0, {_g(o.max_advance_m)}] m",)


_SCREENS: dict[str, Callable[[Any, ScreeningOptions], tuple[Verdicts, tuple[str, ...]]]] = {
    "imu": screen_imu,
    "odometer": screen_odometer,
    "magnetometer": screen_magnetometer,
    "uwb": screen_uwb,
    "position": screen_position,
    "support": screen_support,
}


def _first_rule(bad: list[NDArray[np.bool_]]) -> Verdicts:
    """Verdicts numbering, per sample, the first rule whose mask rejects it."""
    verdicts = np.zeros(bad[0].size, np.uint8)
    for rule, mask in enumerate(bad, start=1):
        verdicts[(verdicts == 0) & mask] = rule
    return verdicts


# --------------------------------------------------------------------------------------------
# Compiled causal passes
# --------------------------------------------------------------------------------------------


@kernels.jit
def _range_and_steps(
    t: NDArray[np.float64],
    a: NDArray[np.float64],
    b: NDArray[np.float64],
    limit_a: NDArray[np.float64],
    limit_b: NDArray[np.float64],
    rate_a: NDArray[np.float64],
    rate_b: NDArray[np.float64],
    floor_a: NDArray[np.float64],
    floor_b: NDArray[np.float64],
    recovery: int,
) -> Verdicts:
    """Verdicts of two channels of one stream (e.g. ω and f) in one causal pass.

    Rule 1 (2): some ``|a| > limit_a`` (``b``); rule 3 (4): some
    ``|a_k − a_ref| > floor_a + rate_a·(t_k − t_ref)`` (``b``) with ``ref`` the last accepted
    sample. A sample out of range is never a reference. After ``recovery`` consecutive samples
    rejected by a step rule the next in-range one is accepted whatever its step. Non-finite
    values fail the range rules.
    """
    n = t.size
    verdicts = np.zeros(n, np.uint8)
    ref = -1
    run = 0
    for k in range(n):
        code = 0
        for c in range(a.shape[1]):
            if not abs(a[k, c]) <= limit_a[c]:
                code = 1
                break
        if code == 0:
            for c in range(b.shape[1]):
                if not abs(b[k, c]) <= limit_b[c]:
                    code = 2
                    break
        if code != 0:
            verdicts[k] = code
            continue
        if ref >= 0 and run < recovery:
            dt = t[k] - t[ref]
            for c in range(a.shape[1]):
                if abs(a[k, c] - a[ref, c]) > floor_a[c] + rate_a[c] * dt:
                    code = 3
                    break
            if code == 0:
                for c in range(b.shape[1]):
                    if abs(b[k, c] - b[ref, c]) > floor_b[c] + rate_b[c] * dt:
                        code = 4
                        break
        if code != 0:
            verdicts[k] = code
            run += 1
        else:
            ref = k
            run = 0
    return verdicts


@kernels.jit
def _fix_jumps(
    t: NDArray[np.float64],
    enu: NDArray[np.float64],
    sigma: NDArray[np.float64],
    verdicts: Verdicts,
    max_speed: float,
    sigma_multiple: float,
    recovery: int,
    code: int,
) -> None:
    """Mark (in place, as ``code``) the fixes still accepted in ``verdicts`` that lie farther
    than ``max_speed·Δt + sigma_multiple·√(Σσ_k² + Σσ_ref²)`` from the last accepted fix;
    after ``recovery`` consecutive such fixes the next one is accepted as the new reference."""
    ref = -1
    run = 0
    for k in range(t.size):
        if verdicts[k] != 0:
            continue
        if ref >= 0 and run < recovery:
            d2 = 0.0
            s2 = 0.0
            for c in range(3):
                d2 += (enu[k, c] - enu[ref, c]) ** 2
                s2 += sigma[k, c] ** 2 + sigma[ref, c] ** 2
            if np.sqrt(d2) > max_speed * (t[k] - t[ref]) + sigma_multiple * np.sqrt(s2):
                verdicts[k] = code
                run += 1
                continue
        ref = k
        run = 0


# --------------------------------------------------------------------------------------------
# Removing rejected rows
# --------------------------------------------------------------------------------------------


def _rows(data: Any, keep: NDArray[np.bool_]) -> Any:
    """A stream's data class with only the rows ``keep``."""
    if isinstance(data, UwbData):
        return UwbData(data.t[keep], data.anchor_index[keep], data.range[keep], data.anchor_ids)
    if isinstance(data, OdometerData):
        return OdometerData(data.t[keep], data.speed[keep])
    if isinstance(data, MagnetometerData):
        return MagnetometerData(data.t[keep], data.field[keep])
    if isinstance(data, PositionData):
        return PositionData(data.t[keep], data.enu[keep], data.sigma[keep])
    if isinstance(data, SupportData):
        return SupportData(data.t[keep], data.advance[keep])
    raise TypeError(f"no screening rows for {type(data).__name__}")


def _imu_without(
    recording: Recording, keep: NDArray[np.bool_]
) -> tuple[ImuData, list[tuple[float, float]], list[tuple[float, float]]]:
    """The IMU without the rejected rows, the gaps the interior rejected runs leave (between
    the accepted samples around each run), and those merged with the recording's own bridged
    gaps (a logging gap next to a rejected run becomes part of the run's gap)."""
    imu = recording.imu
    kept = np.flatnonzero(keep)
    if kept.size < 2:
        raise ConfigError(
            f"screening accepted {kept.size} of {imu.t.size} IMU samples: the limits of config"
            " section screening.imu do not fit this IMU (or set screening.enabled: false)"
        )
    name = recording.meta.name or "recording"
    if kept[0] > 0:
        _log.warning(
            "%s: screening: the IMU starts at its first accepted sample, t = %.3f s (the"
            " initial state of meta.yaml is taken there)",
            name,
            imu.t[kept[0]],
        )
    if kept[-1] < imu.t.size - 1:
        _log.warning(
            "%s: screening: the IMU ends at its last accepted sample, t = %.3f s",
            name,
            imu.t[kept[-1]],
        )
    lost = np.flatnonzero(np.diff(kept) > 1)
    gaps = [(float(imu.t[kept[i]]), float(imu.t[kept[i + 1]])) for i in lost]
    logging_gaps = [g for g in recording.imu_gaps if _kept_at(imu.t, keep, g)]
    merged = sorted(gaps + logging_gaps)
    return ImuData(imu.t[kept], imu.gyro[kept], imu.accel[kept]), gaps, merged


def _kept_at(t: NDArray[np.float64], keep: NDArray[np.bool_], times: tuple[float, float]) -> bool:
    """Whether the samples at both ``times`` (sample times of ``t``) are kept."""
    index = np.searchsorted(t, times)
    return bool(np.all(keep[np.minimum(index, t.size - 1)]))
