"""The strapdown mechanization against an exact, independent analytic IMU truth.

``analytic_truth`` synthesizes interval-mean IMU samples of a closed-form shearer trajectory
with its own WGS84 model (nothing shared with ``fusion``). The first group of tests validates
the synthesizer itself (rest readings, velocity vs. position, rates vs. attitude, specific
force vs. the navigation-frame equation, quadrature convergence); the second runs
``fusion.strapdown.mechanize`` free-inertial against it.

Run with ``pytest -s tests/test_strapdown_truth.py`` to see the measured errors, and
``-m slow`` for the one-hour acceptance run.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from analytic_truth import (
    WGS84_OMEGA,
    ShearerMotion,
    Synthetic,
    Trajectory,
    c_b_n_from_euler,
    ecef_to_geodetic,
    geodetic_to_ecef,
    harmonic,
    normal_gravity,
    pointwise,
    polynomial,
    radii_of_curvature,
    rotvec_from_dcm,
    static_trajectory,
    synthesize,
)

ORIGIN = (34.25, 108.95, -350.0)
ARCSEC = np.deg2rad(1.0 / 3600.0)


def _cbn(euler: np.ndarray) -> np.ndarray:
    """C_b^n (N, 3, 3) from (N, 3) roll, pitch, yaw with the helper's own rotations."""
    c = c_b_n_from_euler(*(np.asarray(euler, float).T))
    return np.array([[np.asarray(c[i][j], float) for j in range(3)] for i in range(3)]).transpose(
        2, 0, 1
    )


def _local_rates(lat, h, vel):
    """ω_ie^n and ω_en^n (N, 3) in local ENU from latitude, height and local ENU velocity."""
    rm, rn = radii_of_curvature(lat)
    w_ie = np.stack([0.0 * lat, WGS84_OMEGA * np.cos(lat), WGS84_OMEGA * np.sin(lat)], -1)
    w_en = np.stack(
        [-vel[:, 1] / (rm + h), vel[:, 0] / (rn + h), vel[:, 0] * np.tan(lat) / (rn + h)], -1
    )
    return w_ie, w_en


def _fd1(f, t, h):
    """Fourth-order central first derivative of f(t) (array valued, time along axis 0)."""
    return (f(t - 2 * h) - 8 * f(t - h) + 8 * f(t + h) - f(t + 2 * h)) / (12 * h)


# ------------------------------------------------------------------------------------------
# The synthesizer itself
# ------------------------------------------------------------------------------------------
def test_rest_level_reads_gravity_and_earth_rate():
    traj = static_trajectory(ORIGIN)
    syn = synthesize(traj, 1.0)
    lat, h = np.deg2rad(ORIGIN[0]), ORIGIN[2]
    g = normal_gravity(lat, h)
    np.testing.assert_allclose(syn.accel, np.tile([0.0, 0.0, g], (syn.t.size, 1)), atol=1e-12)
    w = [0.0, WGS84_OMEGA * np.cos(lat), WGS84_OMEGA * np.sin(lat)]
    np.testing.assert_allclose(syn.gyro, np.tile(w, (syn.t.size, 1)), atol=1e-18)
    np.testing.assert_allclose(syn.velocity, 0.0, atol=1e-15)
    np.testing.assert_allclose(syn.position_enu, 0.0, atol=1e-9)
    assert abs(g - 9.7977825) < 1e-6  # 34.25° N, −350 m


def test_rest_tilted_displaced_reads_rotated_gravity_and_earth_rate():
    pos, eul = (150.0, -60.0, 25.0), (0.03, -0.05, 1.65)
    syn = synthesize(static_trajectory(ORIGIN, pos, eul), 1.0)
    lat, h = syn.lat[0], syn.height[0]
    # the displaced point is independently on the local ellipsoid normal of its own latitude
    o = [np.deg2rad(ORIGIN[0]), np.deg2rad(ORIGIN[1]), ORIGIN[2]]
    assert abs(lat - o[0]) > 1e-6
    c_n_b = _cbn(np.array([eul]))[0].T
    f_expect = c_n_b @ [0.0, 0.0, normal_gravity(lat, h)]
    w_expect = c_n_b @ [0.0, WGS84_OMEGA * np.cos(lat), WGS84_OMEGA * np.sin(lat)]
    np.testing.assert_allclose(syn.accel, np.tile(f_expect, (syn.t.size, 1)), atol=1e-12)
    np.testing.assert_allclose(syn.gyro, np.tile(w_expect, (syn.t.size, 1)), atol=1e-18)
    np.testing.assert_allclose(syn.position_enu, np.tile(pos, (syn.t.size, 1)), atol=1e-9)
    np.testing.assert_allclose(syn.attitude[:, :2], np.tile(eul[:2], (syn.t.size, 1)))


VIBRATION: dict[str, Any] = {"coning_amp_deg": 0.3, "sculling_amp_deg": 0.2, "sculling_accel": 2.0}
# Finite-difference checks: (motion, time span, step). Steps are powers of two and the times
# multiples of 2⁻¹⁶ s, so that t ± h is exact; the remaining floor is the rounding of the phase
# ω t of each harmonic (≈ ulp(ω t)), which is why the vibration case uses a shorter span.
FD_CASES = {
    "smooth": (ShearerMotion(), 1800.0, 2.0**-10),
    "vibration": (ShearerMotion(**VIBRATION), 300.0, 2.0**-14),
}


def _fd_times(span: float) -> np.ndarray:
    return np.round(np.linspace(-3.0, span, 997) * 2.0**16) / 2.0**16


@pytest.mark.parametrize("case", FD_CASES)
def test_velocity_is_derivative_of_position(case):
    motion, span, h = FD_CASES[case]
    traj = motion.trajectory()
    t = _fd_times(span)
    pw = pointwise(traj, t)
    dp = _fd1(lambda s: pointwise(traj, s)["enu"], t, h)  # origin-ENU axes
    c_n0_e = pointwise(static_trajectory(ORIGIN), np.zeros(1))["c_n_e"][0]
    vel_fd = np.einsum("nji,jk,nk->ni", pw["c_n_e"], c_n0_e, dp)  # to local ENU
    err = np.abs(vel_fd - pw["vel"]).max()
    print(f"\n[{case}] |v - dp/dt| max {err:.2e} m/s")
    assert err < 1e-9


@pytest.mark.parametrize("case", FD_CASES)
def test_specific_force_and_rate_match_navigation_frame_equations(case):
    """f^b and ω_ib^b against finite differences of v^n and C_b^n (local-level n-frame route).

    ``f^n = v̇^n + (2ω_ie^n + ω_en^n) × v^n − g^n`` and ``ω_ib^b = ω_nb^b + C_n^b(ω_ie^n + ω_en^n)``
    with ``ω_nb^b`` from the rotation between C_b^n(t−h) and C_b^n(t+h) (Richardson-extrapolated
    over h and 2h) — a route disjoint from the synthesizer's ECEF Jet computation. The smooth
    tolerances are below the transport-rate terms (v²/R ≈ 3.5e-9 m/s², v/R ≈ 2.3e-8 rad/s),
    so those are checked too.
    """
    motion, span, h = FD_CASES[case]
    traj = motion.trajectory()
    t = _fd_times(span)
    pw = pointwise(traj, t)
    w_ie, w_en = _local_rates(pw["lat"], pw["h"], pw["vel"])
    cbn = _cbn(pw["euler"])

    vdot = _fd1(lambda s: pointwise(traj, s)["vel"], t, h)
    g_n = np.stack([0 * t, 0 * t, -normal_gravity(pw["lat"], pw["h"])], -1)
    f_n = vdot + np.cross(2 * w_ie + w_en, pw["vel"]) - g_n
    f_b = np.einsum("nji,nj->ni", cbn, f_n)
    f_err = np.abs(f_b - pw["f_b"]).max()

    def rate(step):
        c_m = _cbn(pointwise(traj, t - step)["euler"])
        c_p = _cbn(pointwise(traj, t + step)["euler"])
        return rotvec_from_dcm(np.swapaxes(c_m, -1, -2) @ c_p) / (2 * step)

    w_nb_b = (4.0 * rate(h) - rate(2 * h)) / 3.0
    w_ib_b = w_nb_b + np.einsum("nji,nj->ni", cbn, w_ie + w_en)
    w_err = np.abs(w_ib_b - pw["w_ib_b"]).max()
    print(f"\n[{case}] f^b err {f_err:.2e} m/s², ω_ib^b err {w_err:.2e} rad/s")
    assert f_err < (2e-8 if case == "vibration" else 1e-9)
    assert w_err < (2e-9 if case == "vibration" else 1e-10)


def test_interval_means_converge_and_approach_midpoint_values():
    # vibration up to 22 Hz: 6 Gauss–Legendre nodes are converged to the rounding of the node
    # times (ulp(t) × jerk / angular acceleration)
    motion = ShearerMotion(**VIBRATION)
    a = synthesize(motion.trajectory(), 20.0, nodes=6)
    b = synthesize(motion.trajectory(), 20.0, nodes=10)
    print(
        f"\n6 vs 10 nodes: gyro {np.abs(a.gyro - b.gyro).max():.1e} rad/s, "
        f"accel {np.abs(a.accel - b.accel).max():.1e} m/s²"
    )
    assert np.abs(a.gyro - b.gyro).max() < 1e-12
    assert np.abs(a.accel - b.accel).max() < 1e-11
    # slow motion: sample k is the mean over (t_k - dt, t_k], Simpson's rule on the pointwise
    # values at t_k - dt, t_k - dt/2, t_k agrees to O(dt⁴) (a shifted interval would not)
    traj = ShearerMotion().trajectory()
    s = synthesize(traj, 20.0)
    p0, pm, p1 = (pointwise(traj, s.t - off) for off in (0.01, 0.005, 0.0))
    for key, mean, tol in (("w_ib_b", s.gyro, 2e-9), ("f_b", s.accel, 1e-7)):
        simpson = (p0[key] + 4.0 * pm[key] + p1[key]) / 6.0
        err = np.abs(mean - simpson).max()
        print(
            f"{key}: |mean − Simpson| {err:.1e}, "
            f"|mean − end value| {np.abs(mean - p1[key]).max():.1e}"
        )
        assert err < tol


def test_own_earth_model_agrees_with_fusion_earth():
    """Cross-check only: the two implementations are independent, they must agree."""
    from fusion import earth

    lat = np.deg2rad(np.array([-80.0, -34.0, 0.0, 12.5, 34.25, 60.0, 89.0]))
    lon = np.deg2rad(np.array([-170.0, -60.0, 0.0, 30.0, 108.95, 150.0, 179.0]))
    h = np.array([-1200.0, -350.0, 0.0, 12.0, 500.0, 3000.0, -20.0])
    rm, rn = radii_of_curvature(lat)
    rm2, rn2 = earth.radii(lat)
    np.testing.assert_allclose(np.array([rm, rn]), np.array([rm2, rn2]), rtol=1e-15)
    np.testing.assert_allclose(
        normal_gravity(lat, h), earth.normal_gravity(lat, h), rtol=1e-15, atol=0
    )
    r = np.stack(geodetic_to_ecef(lat, lon, h), -1)
    np.testing.assert_allclose(r, earth.geodetic_to_ecef(lat, lon, h), rtol=0, atol=1e-8)
    back = ecef_to_geodetic(list(r.T))
    np.testing.assert_allclose(back[0], lat, atol=1e-14)
    np.testing.assert_allclose(back[1], lon, atol=1e-14)
    np.testing.assert_allclose(back[2], h, atol=1e-8)
    # the earth and transport rates the mechanization uses, both hemispheres, moving E and N
    from fusion import kernels

    vel = np.array([[3.0, -2.0, 0.5]] * lat.size)
    w_ie, w_en = _local_rates(lat, h, vel)
    for k in range(lat.size):
        _, _, w_ie2, w_en2 = kernels.frame_rates(float(lat[k]), float(h[k]), vel[k])
        np.testing.assert_allclose(w_ie2, w_ie[k], rtol=1e-12, atol=1e-20)
        np.testing.assert_allclose(w_en2, w_en[k], rtol=1e-12, atol=1e-20)


# ------------------------------------------------------------------------------------------
# The mechanization
# ------------------------------------------------------------------------------------------
def _errors(syn: Synthetic, coning_sculling: bool = True) -> dict[str, np.ndarray]:
    strapdown = pytest.importorskip("fusion.strapdown")
    from fusion.earth import LocalFrame

    frame = LocalFrame(*syn.origin_deg)
    initial = strapdown.NavState.from_enu(
        frame, syn.position_enu[0], syn.velocity[0], *syn.attitude[0]
    )
    res = strapdown.mechanize(
        syn.t, syn.gyro, syn.accel, initial, coning_sculling=coning_sculling, frame=frame
    )
    assert res.t.shape == syn.t.shape and np.array_equal(res.t, syn.t)
    dp = res.position_enu - syn.position_enu
    dv = res.velocity - syn.velocity
    # attitude error as the n-frame rotation vector φ with C_est = R(φ) C_true
    phi = rotvec_from_dcm(_cbn(res.attitude) @ np.swapaxes(_cbn(syn.attitude), -1, -2))
    return {"t": syn.t, "dp": dp, "dv": dv, "phi": phi}


def _report(label: str, e: dict[str, np.ndarray]) -> tuple[float, float, float, float]:
    horiz = np.hypot(e["dp"][:, 0], e["dp"][:, 1]).max()
    up = np.abs(e["dp"][:, 2]).max()
    vel = np.linalg.norm(e["dv"], axis=1).max()
    att = np.linalg.norm(e["phi"], axis=1).max()
    last = e["t"][-1] - e["t"][0]
    print(
        f"\n[{label}] over {last:.0f} s: max horizontal {horiz * 1e3:.4f} mm, "
        f"max |up| {up * 1e3:.4f} mm, max |δv| {vel * 1e3:.5f} mm/s, "
        f"max attitude {np.rad2deg(att):.3e}° ({att / ARCSEC:.3e}″)"
        f"\n    final δp ENU {e['dp'][-1] * 1e3} mm, δv ENU {e['dv'][-1] * 1e6} µm/s, "
        f"φ ENU {e['phi'][-1] / ARCSEC}″"
    )
    return horiz, up, vel, att


@pytest.fixture(scope="module")
def smooth_10min() -> Synthetic:
    return synthesize(ShearerMotion().trajectory(), 600.0)


def test_free_inertial_10_minutes(smooth_10min):
    """Default-run variant of the one-hour acceptance, with the thresholds scaled to 10 min.

    Scaling from the 1 h figures (1 cm horizontal, 5 cm height, 0.001°) by the growth law of a
    constant algorithmic error: horizontal ∝ t² (accelerometer-like; Schuler period 84 min,
    so still quadratic at 1 h to within a factor ~2) → 1 cm × (10/60)² ≈ 0.3 mm; height in the
    unstable vertical channel (τ = √(R/2g) ≈ 570 s) ∝ cosh(t/τ) − 1, a factor ≈ 450 between
    1 h and 10 min → 5 cm / 450 ≈ 0.1 mm; attitude ∝ t → 0.001° / 6 ≈ 1.7e-4°.
    """
    horiz, up, _, att = _report("smooth 10 min", _errors(smooth_10min))
    assert horiz < 0.3e-3, f"horizontal {horiz * 1e3:.3f} mm after 10 min"
    assert up < 0.1e-3, f"height {up * 1e3:.3f} mm after 10 min"
    assert np.rad2deg(att) < 1.7e-4, f"attitude {np.rad2deg(att):.2e}° after 10 min"


@pytest.mark.slow
def test_free_inertial_one_hour_acceptance():
    """Issue acceptance: 1 h at 100 Hz, smooth shearer motion with slopes, gentle heading
    changes and 0.2–2 Hz oscillations: horizontal < 1 cm, height < 5 cm, attitude < 0.001°."""
    syn = synthesize(ShearerMotion().trajectory(), 3600.0)
    horiz, up, _, att = _report("smooth 1 h", _errors(syn))
    assert horiz < 0.01, f"horizontal {horiz * 1e3:.2f} mm after 1 h"
    assert up < 0.05, f"height {up * 1e3:.2f} mm after 1 h"
    assert np.rad2deg(att) < 0.001, f"attitude {np.rad2deg(att):.2e}° after 1 h"


def test_rocking_at_rest_creates_no_vertical_velocity():
    """Diagnostic for the vertical channel: the IMU stands still and only rocks in pitch
    (0.1° at 1.5 Hz, 100 s). The true specific force is constant in n, so any mean vertical
    δv̇ is algorithmic. Dropping the second-order velocity rotation term
    ``(1/6) Δθ × (Δθ × Δv)`` (Savage's ``(1 − sin φ/φ)/φ² φ×(φ×Δv)``) leaves
    ``+(1/6) h² g ⟨ω_⊥²⟩`` (ω_⊥ the rate across f): here 2.2e-8 m/s², 2.2 µm/s in 100 s —
    harmless per step, but the unstable vertical channel (τ = √(R/2g) ≈ 570 s) turns a
    constant bias b into height error b τ² (cosh(t/τ) − 1) ≈ b × 9e7 s² after one hour (≈ 2 m
    here, ≈ 1.2 m for the shearer motion above). A complete second-order update leaves < 1 %.
    """
    amp, hz = np.deg2rad(0.1), 1.5

    def pos(t):
        return [polynomial(t, [0.0]) for _ in range(3)]

    def eul(t):
        return [polynomial(t, [0.01]), harmonic(t, amp, hz, 0.3) + 0.02, polynomial(t, [1.6])]

    syn = synthesize(Trajectory(ORIGIN, pos, eul, "rocking"), 100.0)
    e = _errors(syn)
    _report("rocking at rest", e)
    w2 = 0.5 * (amp * 2 * np.pi * hz) ** 2
    predicted = (0.01**2) * 9.8 * w2 / 6.0  # m/s² of the truncated term
    rate = np.polyfit(e["t"], e["dv"][:, 2], 1)[0]
    print(f"    vertical δv̇ {rate:.2e} m/s² (a missing (1/6)Δθ×(Δθ×Δv) gives {predicted:.2e})")
    assert abs(rate) < 0.01 * predicted, (
        f"vertical velocity drifts at {rate:.2e} m/s² under pure rocking "
        f"({rate / predicted:.2f} × (1/6)h²g⟨ω⊥²⟩)"
    )


def _two_sample_residual(x: float) -> tuple[float, float]:
    """Uncompensated and two-sample-compensated coning (or sculling) error, as fractions of
    the true rectified rate, for a vibration of x = 2π f_vib / f_sample rad per interval."""
    sinc = np.sin(x) / x
    plain = 1.0 - sinc
    return plain, plain - (1.0 - np.cos(x)) * sinc / 3.0


CONING: dict[str, Any] = {"coning_amp_deg": 0.3, "coning_hz": 15.0}
SCULLING: dict[str, Any] = {"sculling_amp_deg": 0.2, "sculling_hz": 22.0, "sculling_accel": 2.0}


def test_coning_correction_under_vibration():
    """Coning: roll and pitch oscillating 0.3° at 15 Hz, 90° apart, on the shearer motion, 60 s.

    What interval means at 100 Hz hold: the IMU gives only Δθ_k per 10 ms; the true coning
    drift ½a²Ω = 1.29e-3 rad/s (a = 0.3°, Ω = 2π·15) is about the z axis. Integrating the
    increments without correction leaves the fraction 1 − sin x / x of it (x = Ωh = 0.94 rad):
    0.142, i.e. 1.83e-4 rad/s ≈ 0.63° (≈ 2265″) of heading in 60 s, and a tilt that drives
    ≈ 0.2 m/s of velocity error. The two-sample term (1/12)Δθ_{k-1}×Δθ_k recovers
    (1/3)(1 − cos x) sin x / x = 0.118 of it; the rest, 0.024 (≈ x⁴/30 for small x), is the
    information a 10 ms mean cannot carry, so the correction gains a factor ≈ 6 at 15 Hz,
    ≈ 3 at 22 Hz, ≈ 2.4 at 25 Hz, ≈ 1.8 at 30 Hz and nothing at 50 Hz (Nyquist).
    """
    syn = synthesize(ShearerMotion(**CONING).trajectory(), 60.0)
    off = _errors(syn, coning_sculling=False)
    on = _errors(syn, coning_sculling=True)
    _, _, v_off, a_off = _report("coning, no correction", off)
    _, _, v_on, a_on = _report("coning, two-sample correction", on)
    print(f"    improvement: attitude ×{a_off / a_on:.2f}, velocity ×{v_off / v_on:.2f}")
    assert a_off / a_on >= 2.0
    assert v_off / v_on >= 2.0

    a, w = np.deg2rad(CONING["coning_amp_deg"]), 2 * np.pi * CONING["coning_hz"]
    plain, resid = _two_sample_residual(w / 100.0)
    drift = 0.5 * a * a * w * 60.0  # rad of true coning drift in 60 s
    heading_off, heading_on = abs(off["phi"][-1, 2]), abs(on["phi"][-1, 2])
    print(
        f"    heading error: {heading_off / ARCSEC:.1f}″ (theory {plain * drift / ARCSEC:.1f}″)"
        f" / {heading_on / ARCSEC:.1f}″ (theory {resid * drift / ARCSEC:.1f}″)"
    )
    assert heading_off == pytest.approx(plain * drift, rel=0.1)
    assert heading_on < 1.1 * resid * drift


def test_sculling_correction_under_vibration():
    """Sculling: pitch (about body x) oscillating 0.2° at 22 Hz in phase with a 2 m/s²
    acceleration along the face (≈ body y), on the shearer motion, 60 s.

    The body sees a rectified vertical specific force ½Ab = 3.5e-3 m/s² (A = 2 m/s²,
    b = 0.2°) which the rotation of the body turns back into zero mean in n. From 10 ms means
    the uncompensated algorithm misses the fraction 1 − sin x / x = 0.29 of it (x = 1.38 rad):
    ≈ 61 mm/s of vertical velocity error in 60 s; the two-sample sculling term
    (1/12)(Δθ_{k-1}×Δv_k + Δv_{k-1}×Δθ_k) has the same structure as the coning term and leaves
    0.097, ≈ 20 mm/s: a factor ≈ 3 at 22 Hz, with the same frequency dependence as coning.
    """
    syn = synthesize(ShearerMotion(**SCULLING).trajectory(), 60.0)
    off = _errors(syn, coning_sculling=False)
    on = _errors(syn, coning_sculling=True)
    _, _, v_off, a_off = _report("sculling, no correction", off)
    _, _, v_on, a_on = _report("sculling, two-sample correction", on)
    print(f"    improvement: velocity ×{v_off / v_on:.2f}, attitude ×{a_off / a_on:.2f}")
    assert v_off / v_on >= 2.0

    b, w = np.deg2rad(SCULLING["sculling_amp_deg"]), 2 * np.pi * SCULLING["sculling_hz"]
    plain, resid = _two_sample_residual(w / 100.0)
    rect = 0.5 * SCULLING["sculling_accel"] * b * 60.0  # m/s of rectified Δv in 60 s
    up_off, up_on = abs(off["dv"][-1, 2]), abs(on["dv"][-1, 2])
    print(
        f"    vertical δv: {up_off * 1e3:.2f} mm/s (theory {plain * rect * 1e3:.2f})"
        f" / {up_on * 1e3:.2f} mm/s (theory {resid * rect * 1e3:.2f})"
    )
    assert up_off == pytest.approx(plain * rect, rel=0.1)
    assert up_on < 1.1 * resid * rect
