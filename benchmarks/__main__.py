"""Run a benchmark suite and print its table: ``python -m benchmarks SUITE``.

Suites: ``strapdown`` (mechanization cost per IMU sample, compiled vs interpreted, and the
engine's real-time factor for free inertial navigation).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"


def strapdown() -> None:
    """Cost of the mechanization per IMU sample."""
    from fusion.attitude import dcm_from_euler
    from fusion.earth import LocalFrame
    from fusion.strapdown import HIST_SIZE, NavState, Strapdown, _step, mechanize

    frame = LocalFrame(34.25, 108.95, -350.0)
    initial = NavState.from_enu(frame, [0, 0, 0], [0, 0.05, 0], 0.01, -0.02, 1.6)
    n = 360_001
    t = np.arange(n) / 100.0
    rng = np.random.default_rng(0)
    c = dcm_from_euler(0.01, -0.02, 1.6)
    gyro = 1e-3 * rng.standard_normal((n, 3))
    accel = (c.T @ [0, 0, 9.79])[None, :] + 1e-2 * rng.standard_normal((n, 3))
    mechanize(t[:10], gyro[:10], accel[:10], initial)  # compile / load the cache
    rows = []
    t0 = time.perf_counter()
    mechanize(t, gyro, accel, initial)
    rows.append(("mechanize(), whole record", (time.perf_counter() - t0) / (n - 1)))
    sins = Strapdown(t, gyro, accel, initial)
    t0 = time.perf_counter()
    for te in np.arange(0.1, t[-1] + 1e-9, 0.1):
        sins.advance_to(te)
        sins.take_velocity_increment()
    rows.append(("Strapdown.advance_to, 0.1 s steps", (time.perf_counter() - t0) / (n - 1)))
    nav, hist = initial.to_array(), np.zeros(HIST_SIZE)
    m = 20_000
    t0 = time.perf_counter()
    for k in range(1, m):
        _step.py_func(nav, hist, gyro[k] * 0.01, accel[k] * 0.01, 0.01, True)
    rows.append(("same step interpreted (no numba)", (time.perf_counter() - t0) / (m - 1)))
    print(f"machine: {_machine()}; one process, one core")
    print("| mechanization | µs per IMU sample | budget |")
    print("|---|---:|---:|")
    for name, sec in rows:
        print(f"| {name} | {sec * 1e6:.2f} | 10 |")


SUITES = {"strapdown": strapdown}


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    parser.add_argument("suite", choices=sorted(SUITES))
    args = parser.parse_args()
    SUITES[args.suite]()


if __name__ == "__main__":
    main()
