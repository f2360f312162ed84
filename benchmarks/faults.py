"""Fault windows for the benchmarks, planned on a seed's own trajectory.

An injected fault only tests something when the sensor is in use: odometer slip while the
shearer moves, UWB non-line-of-sight while the tag is within range of an anchor. The window is
therefore placed from the truth trajectory of that seed (:class:`fusion.sim.trajectory.
Trajectory`, which does not depend on the sensors, so planning does not change the recording
otherwise):

* ``t_m`` = first moving instant; the window starts at the first moving instant at or after
  ``t_m + min(300 s, 0.3·(T − t_m))`` (the filter has converged), or for ``uwb_nlos`` at the
  first such instant within ``0.8·max_range_m`` of an anchor;
* lengths: 60 s (1 s for an IMU gap), cut to stay inside the recording and, for NLOS, inside
  the stay in range.

Magnitudes: magnetic interference ``[18, −12, 6]`` µT with 2 s ramps (the
``seed003-brokenline-maginterf`` preset), UWB NLOS biases uniform in 0.3–1.5 m on every anchor,
odometer slip +20 % with 2 s ramps, an odometer dropout, a 1 s IMU logging gap.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from fusion.sim.simulate import load_scenario, stream_rng
from fusion.sim.trajectory import Trajectory

FAULT_KINDS = ("magnetic_interference", "uwb_nlos", "odometer_slip", "dropout", "imu_gap")
"""Fault kinds the ablation injects (one at a time)."""

WINDOW_S = 60.0
CONVERGE_S = 300.0


def plan_fault(scenario: str, seed: int, kind: str, overrides: Sequence[str] = ()) -> str:
    """A ``faults=[...]`` scenario override: the scenario's own faults plus one of ``kind``.

    Parameters
    ----------
    scenario
        Preset name or path.
    seed
        The recording's seed (the trajectory depends on it).
    kind
        One of :data:`FAULT_KINDS`.
    overrides
        The scenario overrides already applied.

    Raises
    ------
    ValueError
        For an unknown kind, or NLOS on a scenario whose tag never comes within UWB range.
    """
    if kind not in FAULT_KINDS:
        raise ValueError(f"unknown fault kind {kind!r} (known: {', '.join(FAULT_KINDS)})")
    sc = load_scenario(scenario, overrides, seed=seed)  # a random family draws its world
    traj = Trajectory(sc, stream_rng(seed, "trajectory"))
    t = np.arange(0.0, traj.duration, 1.0)
    state = traj.evaluate(t)
    moving = np.asarray(state.moving, bool)
    if not moving.any():
        raise ValueError(f"scenario {scenario}: the vehicle never moves, no fault window to plan")
    t_m = float(t[np.argmax(moving)])
    earliest = t_m + min(CONVERGE_S, 0.3 * (traj.duration - t_m))
    usable = moving & (t >= earliest)
    if kind == "uwb_nlos":
        usable &= _near_anchor(sc, traj, state.position)
        if not usable.any():
            raise ValueError(f"scenario {scenario}: the UWB tag never comes within anchor range")
    start_index = int(np.argmax(usable)) if usable.any() else int(np.searchsorted(t, earliest))
    t_start = float(t[min(start_index, t.size - 2)])
    length = 1.0 if kind == "imu_gap" else WINDOW_S
    if kind == "uwb_nlos":
        stay = int(np.argmin(usable[start_index:])) if not usable[start_index:].all() else None
        if stay is not None:
            length = min(length, max(float(stay), 5.0))
    t_end = min(t_start + length, traj.duration - 2.0)
    fault: dict[str, Any] = {"kind": kind, "t_start": t_start, "t_end": t_end}
    if kind == "magnetic_interference":
        fault.update(ramp_s=2.0, field_uT=[18.0, -12.0, 6.0])
    elif kind == "uwb_nlos":
        fault.update(bias_m=[0.3, 1.5])
    elif kind == "odometer_slip":
        fault.update(ramp_s=2.0, slip_ratio=0.2)
    elif kind == "dropout":
        fault.update(sensor="odometer")
    existing = [f.model_dump(mode="json") for f in sc.faults]
    return "faults=" + json.dumps([*existing, fault])


def _near_anchor(sc: Any, traj: Trajectory, position: np.ndarray) -> np.ndarray:
    """Epochs within 0.8 × max range of some anchor (every epoch False without UWB)."""
    if sc.uwb is None:
        return np.zeros(position.shape[0], bool)
    anchors = []
    for xyz in sc.uwb.anchors.values():
        if sc.uwb.anchors_frame == "face":
            anchors.append(traj.enu_from_face(*xyz))
        else:
            anchors.append(np.asarray(xyz, float))
    d = np.linalg.norm(position[:, None, :] - np.asarray(anchors)[None, :, :], axis=2)
    return np.asarray(d.min(axis=1) < 0.8 * sc.uwb.max_range_m)
