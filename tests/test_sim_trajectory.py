"""Truth trajectory and exact IMU of the longwall simulator (issue 3).

Acceptance: the error-free IMU fed to the project's mechanization reproduces the truth.

Measured on ``longwall-200m`` (seed 0), mechanization with two-sample coning/sculling:

=====================================  ===========  ==========  ===============
case                                   horiz. max   height max  attitude max
=====================================  ===========  ==========  ===============
1 h, 100 Hz, no vibration              4.5e-6 m     2.4e-5 m    2.4e-10 deg
1 h, 1 kHz, vibration on               1.1e-4 m     2.9e-5 m    4.8e-9 deg
1 h, 100 Hz, vibration on              6.9e-3 m     0.154 m     2.8e-7 deg
10 min, 100 Hz, vibration on           4e-3 m       1.4e-3 m    5e-7 deg
=====================================  ===========  ==========  ===============

At 100 Hz with 5–30 Hz vibration the interval means are exact, but the within-interval coning
and sculling they hide cannot be rebuilt by a two-sample algorithm: the remainder acts as a
vertical specific-force error of ≈ 1.6e-9 m/s² that the unstable free-inertial vertical channel
(time constant √(R/2g) ≈ 570 s) amplifies exponentially (0.3 mm at 10 min, 6 mm at 30 min,
0.15 m at 1 h); :func:`test_vibration_100hz_documented` and the slow 1-hour case pin its size
so that a change is noticed. The truth is not low-passed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.attitude import dcm_from_euler, wrap_angle
from fusion.earth import LocalFrame
from fusion.sim.kinematics import ExactImu, body_rate_from_euler
from fusion.sim.scenario import Scenario
from fusion.sim.simulate import load_scenario, stream_rng
from fusion.sim.trajectory import Trajectory, TruthChunk
from fusion.strapdown import NavState, mechanize


def _build(sc: Scenario, seed: int = 0) -> tuple[Trajectory, LocalFrame]:
    traj = Trajectory(sc, stream_rng(seed, "trajectory"))
    frame = LocalFrame(sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.height_m)
    return traj, frame


def _truth(sc: Scenario, rate: float, chunk_s: float = 600.0) -> list[TruthChunk]:
    traj, frame = _build(sc)
    imu = ExactImu(traj, frame, rate, sc.imu.quadrature_nodes)
    return [imu.chunk(a, b) for a, b in imu.chunks(chunk_s)]


def _mechanize_errors(sc: Scenario, rate: float) -> tuple[float, float, float, float]:
    """Max horizontal, height (m), attitude (deg) and velocity (m/s) error of free inertial."""
    _, frame = _build(sc)
    chunks = _truth(sc, rate)

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(c, name) for c in chunks])

    t, pos, vel, att = cat("t"), cat("position_enu"), cat("velocity_enu"), cat("attitude")
    init = NavState.from_enu(frame, pos[0], vel[0], *att[0])
    res = mechanize(t, cat("gyro"), cat("accel"), init, coning_sculling=True, frame=frame)
    dp = res.position_enu - pos
    return (
        float(np.hypot(dp[:, 0], dp[:, 1]).max()),
        float(np.abs(dp[:, 2]).max()),
        float(np.rad2deg(np.abs(wrap_angle(res.attitude - att))).max()),
        float(np.abs(res.velocity - vel).max()),
    )


def _longwall(*extra: str) -> Scenario:
    return load_scenario("longwall-200m", extra)


# -------------------------------------------------------------------------- derivations


def test_body_rate_matches_dcm_finite_difference() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        e = rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 2 * np.pi])
        ed = rng.uniform(-0.3, 0.3, size=3)
        h = 1e-6
        cp = dcm_from_euler(*(e + h * ed))
        cm = dcm_from_euler(*(e - h * ed))
        c = dcm_from_euler(*e)
        w_skew = c.T @ (cp - cm) / (2 * h)  # Ċ = C (ω×)
        w_fd = np.array([w_skew[2, 1], w_skew[0, 2], w_skew[1, 0]])
        w = body_rate_from_euler(e[None], ed[None])[0]
        np.testing.assert_allclose(w, w_fd, atol=1e-8)
        np.testing.assert_allclose(w_skew + w_skew.T, 0.0, atol=1e-8)


@pytest.mark.parametrize("vibration", [False, True])
def test_trajectory_derivatives_match_finite_differences(vibration: bool) -> None:
    sc = _longwall(f"motion.vibration.enabled={str(vibration).lower()}", "face.length_m=40")
    traj, _ = _build(sc)
    t = np.linspace(50.0, traj.duration - 50.0, 4001)
    h = 1e-5 if vibration else 1e-4
    m0, mp, mm = traj.evaluate(t), traj.evaluate(t + h), traj.evaluate(t - h)
    # tolerances: central differences, error ~ h² x third derivative
    np.testing.assert_allclose((mp.position - mm.position) / (2 * h), m0.velocity, atol=1e-7)
    np.testing.assert_allclose((mp.velocity - mm.velocity) / (2 * h), m0.acceleration, atol=2e-5)
    de = wrap_angle(mp.euler - mm.euler) / (2 * h)
    np.testing.assert_allclose(de, m0.euler_rate, atol=2e-6)


def test_exact_imu_is_chunk_invariant() -> None:
    sc = _longwall("face.length_m=40", "duration_s=300")
    a = _truth(sc, 100.0, chunk_s=600.0)
    b = _truth(sc, 100.0, chunk_s=37.0)
    for name in ("t", "gyro", "accel", "position_enu", "attitude", "odometer_distance"):
        x = np.concatenate([getattr(c, name) for c in a])
        y = np.concatenate([getattr(c, name) for c in b])
        assert np.array_equal(x, y), name


# -------------------------------------------------------------------------- face geometry


def test_face_geometry_and_mining_cycle() -> None:
    sc = _longwall("motion.vibration.enabled=false")
    traj, _ = _build(sc)
    face = sc.face
    assert face is not None
    t = np.arange(0.0, traj.duration, 1.0)
    m = traj.evaluate(t)
    psi0 = math.radians(face.azimuth_deg)
    # the shearer never turns around: heading within a few degrees of the face azimuth
    dpsi = np.rad2deg(np.abs(wrap_angle(m.euler[:, 2] - psi0)))
    assert dpsi.max() < 5.0
    # roll and pitch: a few degrees
    assert np.rad2deg(np.abs(m.euler[:, :2])).max() < 8.0
    # cutting speeds within the configured 3-8 m/min (cruise segments), never above 8 m/min
    seg = traj._seg
    cruise = (seg["dv"] == 0) & (seg["v0"] != 0) & (seg["cycle"] > 0)
    v = np.abs(seg["v0"][cruise]) * 60.0
    assert v.size > 10
    assert v.min() >= face.maneuver_speed_mpm - 1e-9 or v.min() >= sc.motion.speed_mpm[0] - 1e-9
    assert v.max() <= sc.motion.speed_mpm[1] + 1e-9
    assert np.abs(m.s_dot).max() * 60.0 <= sc.motion.speed_mpm[1] + 1e-9
    # the body y velocity has one sign per pass: forward on odd passes, backwards on even
    cycles = np.unique(m.cycle[m.cycle > 0])
    assert list(cycles) == list(range(1, face.cycles + 1))
    for c in cycles:
        sd = m.s_dot[(m.cycle == c) & m.moving]
        assert np.all(sd > 0) if c % 2 == 1 else np.all(sd < 0)
    # the AFC is advanced by d per cycle: mean offset to the right of the face line
    right = np.array([math.cos(psi0), -math.sin(psi0)])
    offs = [float(np.mean(m.position[m.cycle == c, :2] @ right)) for c in cycles]
    np.testing.assert_allclose(np.diff(offs), face.advance_m, atol=0.02)
    # one push event of d per cycle transition, between the passes
    assert len(traj.push_events) == face.cycles - 1
    for ev in traj.push_events:
        assert ev.advance == pytest.approx(face.advance_m)
        assert m.cycle[int(ev.t)] == 0 and not m.moving[int(ev.t)]
    # initial static period of 60 s, cycle 0
    assert not m.moving[: int(sc.static_start_s)].any()
    assert (m.cycle[: int(sc.static_start_s)] == 0).all()


@pytest.mark.parametrize("name", ["longwall-200m", "seed000-carrier", "seed003-brokenline"])
def test_continuity_and_motion_constraint(name: str) -> None:
    """No jump where the AFC configuration changes; body velocity along y only."""
    sc = load_scenario(name, ["motion.vibration=false"])
    traj, frame = _build(sc)
    seg = traj._seg
    switch = seg["t0"][np.flatnonzero(np.diff(seg["leg"]) != 0) + 1]
    if switch.size:
        a, b = traj.evaluate(switch - 1e-9), traj.evaluate(switch + 1e-9)
        np.testing.assert_allclose(a.position, b.position, atol=1e-9)
        np.testing.assert_allclose(a.euler, b.euler, atol=1e-9)
    imu = ExactImu(traj, frame, 5.0, 2)
    c = imu.chunk(0, imu.n_samples)
    speed = np.abs(c.velocity_body[:, 1])
    # non-holonomic: lateral and vertical body velocity only from the meridian convergence
    # between the origin's and the local level frame (≈ 1.6e-7 rad per metre)
    assert np.abs(c.velocity_body[:, [0, 2]]).max() <= 5e-5 * speed.max()
    # odometer distance = integral of the body-y speed (signed)
    np.testing.assert_allclose(
        c.odometer_distance[-1], np.trapezoid(c.velocity_body[:, 1], c.t), rtol=1e-3, atol=1e-3
    )


def test_track_turns_and_laps() -> None:
    sc = load_scenario("seed002-rectangle-718", ["motion.vibration.enabled=false"])
    traj, _ = _build(sc)
    t = np.arange(0.0, traj.duration, 0.05)
    m = traj.evaluate(t)
    yaw = np.unwrap(m.euler[:, 2])
    # four clockwise laps: the heading turns by 4 x 360 degrees
    assert np.rad2deg(yaw[-1] - yaw[0]) == pytest.approx(4 * 360.0, abs=1.0)
    assert set(np.unique(m.cycle)) == {0, 1, 2, 3, 4}
    # back at the start after the laps
    np.testing.assert_allclose(m.position[-1], m.position[0], atol=1e-3)
    # stops happen (ZUPT material)
    starts = np.flatnonzero(np.diff(m.moving.astype(int)) == -1)
    assert starts.size >= 3


# -------------------------------------------------------------------------- acceptance


def test_mechanization_reproduces_truth_quick() -> None:
    """10 min on a short face (pass, terminal oblique cut, push, reverse pass), 100 Hz."""
    sc = _longwall(
        "motion.vibration.enabled=false", "face.length_m=30", "face.cycles=3", "duration_s=600"
    )
    horiz, height, att, vel = _mechanize_errors(sc, 100.0)
    assert horiz < 1e-3
    assert height < 5e-3
    assert att < 1e-5
    assert vel < 1e-5


def test_mechanization_with_vibration_1khz_quick() -> None:
    """5 min with vibration at 1 kHz (pass, end manoeuvre)."""
    sc = _longwall("face.length_m=15", "face.cycles=2", "duration_s=300", "imu.quadrature_nodes=3")
    horiz, height, att, _ = _mechanize_errors(sc, 1000.0)
    assert horiz < 1e-3
    assert height < 5e-3
    assert att < 1e-5


def test_vibration_100hz_documented() -> None:
    """At 100 Hz with vibration the interval means hide coning/sculling: a bounded drift."""
    sc = _longwall("duration_s=600")
    horiz, height, att, _ = _mechanize_errors(sc, 100.0)
    assert horiz < 0.02  # measured 4e-3 m in 10 min
    assert height < 0.01  # measured 1.4e-3 m
    assert att < 1e-4  # measured 5e-7 deg


@pytest.mark.slow
def test_mechanization_reproduces_truth_1h_100hz() -> None:
    sc = _longwall("motion.vibration.enabled=false", "duration_s=3600")
    horiz, height, att, _ = _mechanize_errors(sc, 100.0)
    assert horiz < 0.01
    assert height < 0.05
    assert att < 1e-3


@pytest.mark.slow
def test_vibration_100hz_1h_documented() -> None:
    sc = _longwall("duration_s=3600")
    horiz, height, att, _ = _mechanize_errors(sc, 100.0)
    assert horiz < 0.03  # measured 6.9e-3 m
    assert height < 0.5  # measured 0.154 m (vertical-channel instability)
    assert att < 1e-5  # measured 2.8e-7 deg


@pytest.mark.slow
def test_mechanization_reproduces_truth_20min_1khz_vibration() -> None:
    """20 min of cutting vibration at 1 kHz (several passes, face-end manoeuvres, a push): the
    coning and sculling terms hold. The hour without vibration is the 100-Hz test's."""
    sc = _longwall("duration_s=1200", "imu.quadrature_nodes=3")
    horiz, height, att, _ = _mechanize_errors(sc, 1000.0)
    assert horiz < 0.01
    assert height < 0.05
    assert att < 1e-3
