"""Test support for plugins: a measurement context whose SINS state carries a chosen error.

A plugin's H is tested against numerical differentiation of its full nonlinear measurement
function through a perturbed SINS state. :func:`perturbed_context` builds the context the engine
would hand the plugin when the nominal SINS state is the truth plus the error ``dx``:
``ṽ = v + δv``, ``C̃_b^n = (I − φ×) C_b^n`` (exactly, through the rotation vector −φ) and
``p̃ = p + δp`` (local metres, converted through the recording frame). Plugin states in ``dx``
are not applied here — they are parameters of the truth, which each test perturbs itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from fusion import earth
from fusion.attitude import dcm_from_euler, dcm_from_quat, quat_from_rotvec
from fusion.config import FusionConfig
from fusion.earth import LocalFrame
from fusion.engine import Engine, RunResult
from fusion.error_model import G0, ImuNoise, StateBlock, StateLayout, common_blocks
from fusion.metrics import compute_metrics, interpolate_truth
from fusion.plugin import Measurement, MeasurementContext
from fusion.recording import ImuData, Recording, RecordingMeta, read_recording
from fusion.sim.simulate import simulate

FRAME = LocalFrame(34.0, 117.0, 40.0)
SEED002_SPEC = {  # seed 002 Table 1, as the simulator's "seed002-mems" grade writes it to meta.yaml
    "gyro_bias_deg_h": 3.0,
    "gyro_arw_deg_rth": 0.0433,
    "accel_bias_mg": 1.0,
    "accel_vrw_mg_rthz": 0.0144,
}


def recording_meta(
    *, imu: dict[str, Any] | None = None, initial: dict[str, Any] | None = None, **sections: Any
) -> RecordingMeta:
    """meta.yaml of an in-memory test recording at FRAME's origin: level and at rest at the
    origin with 1-unit σ (``initial`` overrides keys), a 100 Hz IMU (``imu`` replaces it), and
    the stream sections given (``odometer={...}``, ``uwb={...}``, …)."""
    start = {
        "position_enu_m": [0, 0, 0],
        "velocity_enu_mps": [0, 0, 0],
        "attitude_deg": {"roll": 0, "pitch": 0, "yaw": 0},
        "sigma": {"position_m": [1] * 3, "velocity_mps": [1] * 3, "attitude_deg": [1] * 3},
    }
    return RecordingMeta.model_validate(
        {
            "format": "shearer-recording/1",
            "origin": {"lat_deg": 34.0, "lon_deg": 117.0, "height_m": 40.0},
            "initial": {**start, **(initial or {})},
            "imu": imu or {"rate_hz": 100.0},
            **sections,
        }
    )


def still_imu(duration_s: float = 1.0, rate_hz: float = 100.0) -> ImuData:
    """An IMU stream of zeros (plugins under test that do not read the IMU)."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    return ImuData(t=t, gyro=np.zeros((t.size, 3)), accel=np.zeros((t.size, 3)))


def layout_with(blocks: tuple[StateBlock, ...]) -> StateLayout:
    """The common 15 states followed by ``blocks``."""
    imu = ImuNoise(1e-4, 1e-3, 1e-5, 1e-3)
    return StateLayout(common_blocks(imu, [1.0] * 3, [0.01] * 3, [1.0] * 3)).extended(blocks)


def perturbed_context(
    layout: StateLayout,
    dx: NDArray[np.float64],
    *,
    t: float = 0.5,
    position_enu: NDArray[np.float64] | None = None,
    velocity: NDArray[np.float64] | None = None,
    c_b_n: NDArray[np.float64] | None = None,
    x: NDArray[np.float64] | None = None,
    covariance: NDArray[np.float64] | None = None,
    frame: LocalFrame = FRAME,
) -> MeasurementContext:
    """Context of a SINS whose state is the truth plus the common-state error ``dx[:9]``.

    The position error is in the local level axes at the true point; at the short distances of
    these tests they coincide with the frame's ENU axes to better than 1e-4 rad.
    """
    p = np.zeros(3) if position_enu is None else np.asarray(position_enu, dtype=float)
    v = np.zeros(3) if velocity is None else np.asarray(velocity, dtype=float)
    c = np.eye(3) if c_b_n is None else np.asarray(c_b_n, dtype=float)
    lat, lon, height = frame.to_geodetic(p + dx[6:9])
    return MeasurementContext(
        t=t,
        lat=float(lat),
        lon=float(lon),
        height=float(height),
        velocity=v + dx[0:3],
        c_b_n=dcm_from_quat(quat_from_rotvec(-dx[3:6])) @ c,
        layout=layout,
        x=np.zeros(layout.dim) if x is None else x,
        covariance=layout.initial_covariance() if covariance is None else covariance,
        frame=frame,
    )


def numerical_jacobian(
    residual: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    dim: int,
    steps: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Central-difference Jacobian of ``residual(dx)`` at zero, column j with step ``steps[j]``
    (a zero step leaves the column zero)."""
    columns = []
    for j in range(dim):
        dx = np.zeros(dim)
        if steps[j] == 0.0:
            columns.append(np.zeros_like(residual(dx)))
            continue
        dx[j] = steps[j]
        zp = residual(dx)
        dx[j] = -steps[j]
        zm = residual(dx)
        columns.append((zp - zm) / (2 * steps[j]))
    return np.stack(columns, axis=-1)


def group_rms(ratios: NDArray[np.float64]) -> dict[str, float]:
    """RMS of err/σ rows (velocity, attitude, position: 9 columns, as :func:`normalized_errors`
    returns them) per state group."""
    groups = {"velocity": slice(0, 3), "attitude": slice(3, 6), "position": slice(6, 9)}
    return {g: float(np.sqrt(np.mean(ratios[:, cols] ** 2))) for g, cols in groups.items()}


def normalized_errors(
    config: FusionConfig,
    recording: Recording,
    take: Callable[[int, float], bool],
    plugin: int = 0,
) -> tuple[RunResult, NDArray[np.float64]]:
    """Run the engine; at the epochs of plugin number ``plugin`` that ``take(index, t)``
    selects, the error of the filter's estimate (the nominal SINS state in the context,
    corrected by the estimate ``x`` it holds) over its σ, for velocity, attitude φ and
    position, against truth.csv: rows of 9 ratios, ≈ N(0, 1) when the filter is consistent.
    """
    assert recording.truth is not None
    engine = Engine(config, recording)
    probed = engine.plugins[plugin]
    measure = probed.measure
    samples: list[
        tuple[
            float,
            NDArray[np.float64],
            NDArray[np.float64],
            NDArray[np.float64],
            NDArray[np.float64],
            NDArray[np.float64],
        ]
    ] = []

    def probe(index: int, ctx: MeasurementContext) -> Measurement | None:
        if take(index, ctx.t):
            sigma = np.sqrt(np.diag(ctx.covariance)[:9])
            state = (ctx.velocity.copy(), ctx.c_b_n.copy(), ctx.position_enu.copy())
            samples.append((ctx.t, *state, ctx.x[:9].copy(), sigma))
        return measure(index, ctx)

    probed.measure = probe  # type: ignore[method-assign]
    result = engine.run()
    t = np.array([sample[0] for sample in samples])
    inside, position, velocity, attitude, _ = interpolate_truth(recording.truth, t)
    assert inside.all()
    ratios = []
    for k, (_, v, c_b_n, p, x, sigma) in enumerate(samples):
        phi = -Rotation.from_matrix(c_b_n @ dcm_from_euler(*attitude[k]).T).as_rotvec()
        nominal_error = np.concatenate([v - velocity[k], phi, p - position[k]])
        ratios.append((nominal_error - x) / sigma)
    return result, np.array(ratios)


def static_recording(
    gyro_bias_rps: float = 0.0,
    accel_bias_mps2: float = 0.0,
    spec: dict[str, float] | None = SEED002_SPEC,
    seed: int = 0,
) -> Recording:
    """30 s of a level IMU at rest at 34°N sampled at 100 Hz: gravity and earth rate, the
    datasheet white noise of ``SEED002_SPEC``, a constant gyro bias along x and accelerometer bias
    along z (the axis that shifts ‖f‖)."""
    lat, rate = math.radians(34.0), 100.0
    meta = recording_meta(imu={"rate_hz": rate, **({"spec": spec} if spec is not None else {})})
    n = 3000
    rng = np.random.default_rng(seed)
    w_ie = earth.OMEGA_IE * np.array([0.0, math.cos(lat), math.sin(lat)])
    gyro = w_ie + np.array([gyro_bias_rps, 0.0, 0.0])
    gyro = gyro + math.radians(SEED002_SPEC["gyro_arw_deg_rth"]) / 60.0 * math.sqrt(rate) * (
        rng.standard_normal((n, 3))
    )
    f = [0.0, 0.0, float(earth.normal_gravity(lat, 40.0)) + accel_bias_mps2]
    accel = f + SEED002_SPEC["accel_vrw_mg_rthz"] * 1e-3 * G0 * math.sqrt(rate) * (
        rng.standard_normal((n, 3))
    )
    t = np.arange(1, n + 1) / rate
    return Recording(path=None, meta=meta, imu=ImuData(t=t, gyro=gyro, accel=accel))


@dataclass
class MonteCarlo:
    """A plugin alone with the SINS over seeded simulator runs."""

    rms: dict[str, float]
    """RMS(err/σ) per state group over every run (:func:`group_rms`)."""
    whitened: NDArray[np.float64]
    """The plugin's whitened-innovation RMS, per run."""
    aided: NDArray[np.float64]
    """Horizontal RMS error, per run (m)."""
    unaided: NDArray[np.float64]
    """Horizontal RMS error of the free SINS (``free``) on the same run (m)."""

    def report(self) -> None:
        """Print the figures (``pytest -s``)."""
        print("whitened RMS per run:", np.round(self.whitened, 3))
        print("RMS(err/σ):", {g: round(v, 3) for g, v in self.rms.items()})
        print(f"horizontal RMS: {self.aided.mean():.3f} m aided, {self.unaided.mean():.0f} m free")


def monte_carlo(
    config: FusionConfig,
    free: FusionConfig,
    scenario: str,
    root: Path,
    seeds: int,
    overrides: Sequence[str] = (),
) -> MonteCarlo:
    """Run ``config`` (its first plugin the one under test) and ``free`` on ``seeds`` seeded
    simulations of ``scenario``; err/σ taken at every tenth epoch of the plugin."""
    ratios, whitened, aided, unaided = [], [], [], []
    name = config.plugins[0].instance_name
    for seed in range(seeds):
        rec = read_recording(
            simulate(scenario, root / f"seed{seed}", seed=seed, overrides=overrides)
        )
        assert rec.truth is not None
        result, r = normalized_errors(config, rec, lambda index, _: index % 10 == 0)
        ratios.append(r)
        whitened.append(result.innovations[name].whitened_rms())
        aided.append(compute_metrics(result.solution, rec.truth)["horizontal_rms"])
        free_run = Engine(free, rec).run()
        unaided.append(compute_metrics(free_run.solution, rec.truth)["horizontal_rms"])
    return MonteCarlo(
        group_rms(np.concatenate(ratios)), np.array(whitened), np.array(aided), np.array(unaided)
    )
