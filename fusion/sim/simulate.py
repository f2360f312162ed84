"""Orchestration: scenario → truth → exact IMU → sensor models → recording directory.

The run is generated in chunks of ``scenario.chunk_s`` seconds (default 600 s) so that an
8-hour shift needs bounded memory: each chunk of truth (:class:`~fusion.sim.trajectory.
TruthChunk`) is passed to the chunk-aware sensor simulators of :mod:`fusion.sim.sensors`
(which carry their own state across chunks) and the rows are appended to the CSV files at once.
The CSV text is produced by the writer of :mod:`fusion.recording` (``repr``-exact floats), one
chunk at a time; ``meta.yaml`` is validated by :class:`fusion.recording.RecordingMeta` and
written last.

Random streams are derived from the seed by fixed keys (``SeedSequence(seed, spawn_key=(k,))``:
trajectory 1, IMU 2, odometer 3, magnetometer 4, UWB 5, support 6, position 7, initial-state
perturbation 8), so switching one sensor off leaves every other realization unchanged, and the
same seed gives byte-identical files.

The trajectory describes the vehicle (its y axis along the track, the odometer's axis); the
IMU is mounted on it with the odometer section's residual mounting angles δα
(``C_b^m = exp(−δα×)``), so that the truth attitude, the IMU and the motion constraint are the
IMU's and the mounting angles are observable, as in seed 000.

A stream file is written whenever the scenario has the sensor, even when no row falls inside
the recording: a support section whose recording ends before the first AFC push gives a
header-only ``support.csv`` (the sensor was logging and saw no push; the reader accepts it as
a stream of zero rows), which is what the presets have always written for short runs.

``meta.yaml`` holds the *perturbed* initial state (truth + a seeded draw from the scenario's
1-σ, unless ``initial.perturb`` is false) with that σ, so that a filter starts with a realistic
error; the true initial state, the injected faults (``{type, t_start, t_end, …}``), the AFC push
events, the realized IMU errors, the scenario name and the seed are under ``extra:``.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from fusion import recording as rec
from fusion.earth import LocalFrame
from fusion.sim.kinematics import ExactImu
from fusion.sim.scenario import (
    Scenario,
    apply_overrides,
    list_presets,
    parse_override,
    scenario_from_mapping,
)
from fusion.sim.scenario import (
    load_scenario as _load_scenario,
)
from fusion.sim.sensors import (
    ImuErrorSimulator,
    MagnetometerSimulator,
    OdometerSimulator,
    PositionFixSimulator,
    SupportSimulator,
    UwbModel,
    UwbSimulator,
    spec_for_meta,
)
from fusion.sim.trajectory import Trajectory, TruthChunk
from fusion.sim.worlds import FAMILIES, family_world

STREAM_KEYS = {
    "trajectory": 1,
    "imu": 2,
    "odometer": 3,
    "magnetometer": 4,
    "uwb": 5,
    "support": 6,
    "position": 7,
    "initial": 8,
}
"""Spawn keys of the independent random streams."""


def stream_rng(seed: int, name: str) -> np.random.Generator:
    """The random generator of one component (see :data:`STREAM_KEYS`)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(STREAM_KEYS[name],)))


def load_scenario(
    name_or_path: str | Path, overrides: Sequence[str] = (), *, seed: int = 0
) -> Scenario:
    """Load a preset by name, a scenario YAML file or the world of a random family (drawn from
    ``seed``, :data:`fusion.sim.worlds.FAMILIES`) and apply ``key.sub=value`` overrides.

    An override of ``duration_s`` on a family is passed to the draw, so that the world plans
    enough cutting cycles for that length.
    """
    if isinstance(name_or_path, str) and name_or_path in FAMILIES:
        duration: float | None = None
        for text in overrides:
            path, value = parse_override(text)
            if path == ["duration_s"] and isinstance(value, int | float):
                duration = float(value)
        world = family_world(name_or_path, seed, duration_s=duration)
        if not overrides:
            return world
        data = world.model_dump(mode="json")
        return scenario_from_mapping(apply_overrides(data, overrides), name_or_path)
    return _load_scenario(name_or_path, overrides)


def list_scenarios() -> list[tuple[str, str]]:
    """``(name, one-line description)`` of the preset scenarios, then the random families."""
    return list_presets() + list(FAMILIES.items())


class _CsvAppender:
    """Appends chunks to one recording CSV with the writer of :mod:`fusion.recording`."""

    def __init__(self, path: Path, stem: str, kinds: str) -> None:
        self.path = path
        self.header = rec.STREAM_COLUMNS[stem]
        self.kinds = kinds
        self.rows = 0
        self._fh: IO[bytes] = open(path, "wb")
        self._fh.write((",".join(self.header) + "\n").encode())

    def append(self, columns: Sequence[NDArray[Any]]) -> None:
        if len(columns[0]) == 0:
            return
        chunks = rec.csv_text_chunks(self.header, columns, self.kinds)
        next(iter(chunks))  # the header, written once in __init__
        for part in chunks:
            self._fh.write(part)
        self.rows += len(columns[0])

    def close(self) -> None:
        self._fh.close()


def _as_scenario(scenario: Scenario | str | Path, overrides: Sequence[str], seed: int) -> Scenario:
    if isinstance(scenario, Scenario):
        if not overrides:
            return scenario
        data = scenario.model_dump(mode="json")
        return scenario_from_mapping(apply_overrides(data, overrides), scenario.name)
    return load_scenario(scenario, overrides, seed=seed)


def _uwb_model(sc: Scenario, traj: Trajectory) -> UwbModel | None:
    if sc.uwb is None:
        return None
    data = sc.uwb.model_dump()
    frame = data.pop("anchors_frame")
    if frame == "face":
        data["anchors"] = {
            k: tuple(round(float(x), 4) for x in traj.enu_from_face(*v))
            for k, v in sc.uwb.anchors.items()
        }
    return UwbModel(**data)


def _fault_list(sc: Scenario) -> list[dict[str, Any]]:
    out = []
    for f in sc.faults:
        d = f.model_dump(mode="json")
        kind = d.pop("kind")
        out.append({"type": kind, **d})
    return out


def simulate(
    scenario: Scenario | str | Path,
    out_dir: str | Path,
    *,
    seed: int = 0,
    overrides: Sequence[str] = (),
    progress: Callable[[float], None] | None = None,
) -> Path:
    """Simulate a scenario into a recording directory.

    Parameters
    ----------
    scenario
        A :class:`Scenario`, a preset name, a YAML path or a random family
        (``longwall-random``…, :data:`fusion.sim.worlds.FAMILIES`: the world drawn from
        ``seed``).
    out_dir
        Output recording directory (created; files of this run are overwritten).
    seed
        Seed of every random draw; the same seed gives byte-identical files.
    overrides
        ``key.sub=value`` overrides applied before validation.
    progress
        Called after each chunk with the fraction of the scenario's duration written.

    Returns
    -------
    Path
        The recording directory.
    """
    sc = _as_scenario(scenario, overrides, seed)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for stem in rec.STREAM_COLUMNS:  # stale stream files of an earlier run
        for old in (out / f"{stem}.csv", out / f"{stem}.csv.gz"):
            old.unlink(missing_ok=True)
    frame = LocalFrame(sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.height_m)
    traj = Trajectory(sc, stream_rng(seed, "trajectory"))
    # the IMU is mounted on the vehicle with the odometer's residual mounting angles
    mounting = sc.odometer.c_b_m if sc.odometer is not None else None
    if mounting is not None and np.allclose(mounting, np.eye(3), rtol=0.0, atol=0.0):
        mounting = None
    exact = ExactImu(traj, frame, sc.imu.rate_hz, sc.imu.quadrature_nodes, c_b_m=mounting)
    imu_model = sc.imu.error_model
    imu_sim = ImuErrorSimulator(imu_model, sc.imu.rate_hz, stream_rng(seed, "imu"), sc.faults)
    uwb_model = _uwb_model(sc, traj)
    aiding = _aiding_streams(sc, seed, traj, uwb_model)
    truth_step = 1
    if sc.imu.truth_rate_hz is not None:
        truth_step = round(sc.imu.rate_hz / sc.imu.truth_rate_hz)

    files: dict[str, _CsvAppender] = {
        "imu": _CsvAppender(out / "imu.csv", "imu", "fffffff"),
        "truth": _CsvAppender(out / "truth.csv", "truth", "ffffffffffi"),
    }
    for name, (formats, _) in aiding.items():
        files[name] = _CsvAppender(out / f"{name}.csv", name, formats)

    first: TruthChunk | None = None
    t_prev = -math.inf
    try:
        for k0, k1 in exact.chunks(sc.chunk_s):
            tc = exact.chunk(k0, k1)
            if first is None:
                first = tc
            t, gyro, accel = imu_sim.apply_rows(tc.t, tc.gyro, tc.accel)
            files["imu"].append([t, *gyro.T, *accel.T])
            sel = np.arange(k0, k1) % truth_step == 0
            files["truth"].append(
                [
                    tc.t[sel],
                    *tc.position_enu[sel].T,
                    *tc.velocity_enu[sel].T,
                    *tc.attitude[sel].T,
                    tc.cycle[sel],
                ]
            )
            for name, (_, columns) in aiding.items():
                files[name].append(columns(tc, t_prev))
            t_prev = float(tc.t[-1])
            if progress is not None:
                progress(min(t_prev / traj.duration, 1.0) if traj.duration > 0 else 1.0)
    finally:
        for f in files.values():
            f.close()
    assert first is not None
    meta = _meta(sc, seed, traj, first, imu_sim, uwb_model)
    (out / "meta.yaml").write_text(rec.meta_yaml_text(meta), encoding="utf-8")
    return out


StreamColumns = Callable[[TruthChunk, float], list[Any]]
"""The CSV columns of one aiding stream for a truth chunk (and the end of the previous one)."""


def _aiding_streams(
    sc: Scenario, seed: int, traj: Trajectory, uwb_model: UwbModel | None
) -> dict[str, tuple[str, StreamColumns]]:
    """The optional sensors the scenario has: file stem → (column formats, columns of a chunk),
    each simulator with its own random stream."""
    streams: dict[str, tuple[str, StreamColumns]] = {}
    if sc.odometer is not None:
        odo = OdometerSimulator(sc.odometer, stream_rng(seed, "odometer"), sc.faults)
        streams["odometer"] = ("ff", lambda tc, _: list(odo.apply(tc)))
    if sc.magnetometer is not None:
        mag = MagnetometerSimulator(sc.magnetometer, stream_rng(seed, "magnetometer"), sc.faults)

        def magnetometer(tc: TruthChunk, _: float) -> list[Any]:
            t, field = mag.apply(tc)
            return [t, *field.T]

        streams["magnetometer"] = ("ffff", magnetometer)
    if uwb_model is not None:
        uwb = UwbSimulator(uwb_model, stream_rng(seed, "uwb"), sc.faults)
        anchor_ids = np.asarray(uwb_model.anchor_ids, dtype=object)

        def ranges(tc: TruthChunk, _: float) -> list[Any]:
            t, anchor, range_m = uwb.apply(tc)
            return [t, anchor_ids[anchor], range_m]

        streams["uwb"] = ("fsf", ranges)
    if sc.support is not None:
        support = SupportSimulator(sc.support, stream_rng(seed, "support"), sc.faults)
        push_t = np.array([e.t for e in traj.push_events])
        push_d = np.array([e.advance for e in traj.push_events])

        def pushes(tc: TruthChunk, t_prev: float) -> list[Any]:
            in_chunk = (push_t > t_prev) & (push_t <= tc.t[-1])
            return list(support.apply(push_t[in_chunk], push_d[in_chunk]))

        streams["support"] = ("ff", pushes)
    if sc.position is not None:
        fixes = PositionFixSimulator(sc.position, stream_rng(seed, "position"), sc.faults)

        def positions(tc: TruthChunk, _: float) -> list[Any]:
            t, enu, sigma = fixes.apply(tc)
            return [t, *enu.T, *sigma.T]

        streams["position"] = ("fffffff", positions)
    return streams


def _meta(
    sc: Scenario,
    seed: int,
    traj: Trajectory,
    first: TruthChunk,
    imu_sim: ImuErrorSimulator,
    uwb_model: UwbModel | None,
) -> rec.RecordingMeta:
    """meta.yaml contents (validated by :class:`fusion.recording.RecordingMeta`)."""
    sig = sc.initial.sigma
    pos = first.position_enu[0].copy()
    vel = first.velocity_enu[0].copy()
    att = np.rad2deg(first.attitude[0])
    true_init = {
        "position_enu_m": [float(x) for x in pos],
        "velocity_enu_mps": [float(x) for x in vel],
        "attitude_deg": {"roll": float(att[0]), "pitch": float(att[1]), "yaw": float(att[2])},
    }
    if sc.initial.perturb:
        z = stream_rng(seed, "initial").standard_normal(9)
        pos = pos + np.asarray(sig.position_m) * z[0:3]
        vel = vel + np.asarray(sig.velocity_mps) * z[3:6]
        att = att + np.asarray(sig.attitude_deg) * z[6:9]
        att[2] = att[2] % 360.0
    data: dict[str, Any] = {
        "format": rec.FORMAT,
        "name": sc.name,
        "origin": sc.origin.model_dump(),
        "initial": {
            "position_enu_m": [float(x) for x in pos],
            "velocity_enu_mps": [float(x) for x in vel],
            "attitude_deg": {"roll": float(att[0]), "pitch": float(att[1]), "yaw": float(att[2])},
            "sigma": {
                "position_m": list(sig.position_m),
                "velocity_mps": list(sig.velocity_mps),
                "attitude_deg": list(sig.attitude_deg),
            },
        },
        "imu": {
            "rate_hz": sc.imu.rate_hz,
            "spec": (
                spec_for_meta(sc.imu.error_model)
                if sc.imu.meta_spec is None
                else sc.imu.meta_spec.model_dump()
            ),
        },
    }
    if sc.odometer is not None:
        data["odometer"] = sc.odometer.meta()
    if sc.magnetometer is not None:
        data["magnetometer"] = sc.magnetometer.meta()
    if uwb_model is not None:
        data["uwb"] = uwb_model.meta()
    if sc.position is not None:
        data["position"] = sc.position.meta()
    if sc.face is not None:
        data["face"] = {
            "length_m": sc.face.length_m,
            "advance_m": sc.face.advance_m,
            "ends_enu_m": [[round(x, 4) for x in e] for e in traj.face_ends_enu()],
        }
    data["extra"] = {
        "simulator": "fusion.sim",
        "scenario": sc.name,
        "description": sc.description,
        "seed": seed,
        "duration_s": traj.duration,
        "initial_perturbed": sc.initial.perturb,
        "true_initial": true_init,
        "imu_grade": sc.imu.grade if sc.imu.errors is None else "explicit",
        "imu_errors_realized": imu_sim.realized(),
        "vibration": sc.motion.vibration.enabled,
        "faults": _fault_list(sc),
        "push_events": [
            {"t": round(e.t, 6), "advance_m": e.advance, "cycle": e.cycle} for e in traj.push_events
        ],
    }
    if sc.extra:
        data["extra"].update(copy.deepcopy(sc.extra))
        if "world" in sc.extra:  # a drawn world: the whole scenario, to reproduce the run
            data["extra"]["world"]["scenario"] = sc.model_dump(mode="json", exclude={"extra"})
    return rec.RecordingMeta.model_validate(data)
