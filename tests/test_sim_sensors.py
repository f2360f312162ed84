"""Acceptance tests of the sensor simulators (fusion.sim.sensors), faults and Allan utility."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pydantic
import pytest

from fusion.attitude import dcm_from_euler
from fusion.sim.allan import (
    GM_ALLAN_PEAK_RATIO,
    GM_ALLAN_PEAK_TAU_RATIO,
    allan_deviation,
    allan_variance_gauss_markov,
    allan_variance_white,
)
from fusion.sim.faults import (
    active_weight,
    faults_to_meta,
    parse_faults,
    present_mask,
)
from fusion.sim.sensors import (
    DEG_PER_H,
    G0,
    IMU_GRADES,
    MG,
    SEED004_GROUND_ANCHORS,
    ImuErrorModel,
    ImuErrorSimulator,
    MagnetometerModel,
    MagnetometerSimulator,
    OdometerModel,
    OdometerSimulator,
    PositionFixModel,
    PositionFixSimulator,
    SupportModel,
    SupportSimulator,
    UwbModel,
    UwbSimulator,
    spec_for_meta,
)

try:  # the trajectory developer's dataclass, when it exists
    from fusion.sim.trajectory import TruthChunk
except ImportError:  # pragma: no cover - local test double with the same fields

    @dataclass(frozen=True)
    class TruthChunk:  # type: ignore[no-redef]
        t: np.ndarray
        position_enu: np.ndarray
        velocity_enu: np.ndarray
        attitude: np.ndarray
        c_b_n: np.ndarray
        velocity_body: np.ndarray
        gyro: np.ndarray
        accel: np.ndarray
        cycle: np.ndarray
        moving: np.ndarray
        odometer_distance: np.ndarray
        lat: np.ndarray
        lon: np.ndarray
        height: np.ndarray


RATE = 100.0
EARTH_RATE_B = np.array([0.0, 7.292115e-5 * math.cos(0.6), 7.292115e-5 * math.sin(0.6)])


def make_truth(
    t: np.ndarray,
    position: np.ndarray,
    velocity_enu: np.ndarray,
    attitude: np.ndarray,
    odometer_distance: np.ndarray | None = None,
    velocity_body: np.ndarray | None = None,
) -> Any:
    """A TruthChunk from positions, ENU velocities and (roll, pitch, yaw) rows."""
    n = t.size
    c = dcm_from_euler(attitude[:, 0], attitude[:, 1], attitude[:, 2])
    vb = np.einsum("kji,kj->ki", c, velocity_enu) if velocity_body is None else velocity_body
    if odometer_distance is None:
        odometer_distance = np.concatenate(
            [[0.0], np.cumsum(0.5 * (vb[1:, 1] + vb[:-1, 1]) * np.diff(t))]
        )
    z = np.zeros(n)
    return TruthChunk(
        t=t,
        position_enu=position,
        velocity_enu=velocity_enu,
        attitude=attitude,
        c_b_n=c,
        velocity_body=vb,
        gyro=np.tile(EARTH_RATE_B, (n, 1)),
        accel=np.tile([0.0, 0.0, G0], (n, 1)),
        cycle=np.ones(n, dtype=int),
        moving=np.ones(n, dtype=bool),
        odometer_distance=odometer_distance,
        lat=z + 0.6,
        lon=z + 1.9,
        height=z - 350.0,
    )


def split_truth(truth: Any, sizes: list[int]) -> list[Any]:
    """Consecutive chunks of the given sizes (the last takes the rest)."""
    out = []
    start = 0
    n = truth.t.size
    for s in [*sizes, n]:
        stop = min(start + s, n)
        if stop > start:
            out.append(
                dataclasses.replace(
                    truth,
                    **{
                        f.name: getattr(truth, f.name)[start:stop]
                        for f in dataclasses.fields(truth)
                    },
                )
            )
        start = stop
    return out


def moving_truth(duration: float = 120.0, rate: float = RATE, lateral: float = 0.03) -> Any:
    """A shearer-like drive along a 20° heading: varying speed, small attitude wobble."""
    t = np.arange(int(duration * rate) + 1) / rate
    yaw = math.radians(20.0) + 0.05 * np.sin(2 * np.pi * t / 50.0)
    roll = 0.03 * np.sin(2 * np.pi * t / 41.0)
    pitch = 0.02 * np.cos(2 * np.pi * t / 29.0)
    att = np.stack([roll, pitch, yaw], axis=1)
    speed = 0.25 + 0.1 * np.sin(2 * np.pi * t / 30.0)
    c = dcm_from_euler(roll, pitch, yaw)
    vb = np.stack(
        [lateral * np.sin(2 * np.pi * t / 37.0), speed, lateral * np.cos(2 * np.pi * t / 23.0)],
        axis=1,
    )
    vn = np.einsum("kij,kj->ki", c, vb)
    pos = np.concatenate([[np.zeros(3)], np.cumsum(0.5 * (vn[1:] + vn[:-1]) / rate, axis=0)])
    pos = pos + np.array([2.0, 1.0, 0.5])
    return make_truth(t, pos, vn, att, velocity_body=vb)


def assert_identical(a: Any, b: Any) -> None:
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert a.tobytes() == b.tobytes()


# ---------------------------------------------------------------------------------------------
# IMU


def stationary_imu(
    model: ImuErrorModel, hours: float, seed: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    n = int(hours * 3600 * RATE)
    t = np.arange(1, n + 1) / RATE
    sim = ImuErrorSimulator(model, RATE, np.random.default_rng(seed))
    g, f = sim.apply(t, np.tile(EARTH_RATE_B, (n, 1)), np.tile([0.0, 0.0, G0], (n, 1)))
    return g, f


def test_allan_white_noise_at_one_second_matches_arw_vrw() -> None:
    model = IMU_GRADES["mti-g-700"]
    g, f = stationary_imu(model, hours=1.0)
    _, adev_g = allan_deviation(g, RATE, [1.0])
    _, adev_f = allan_deviation(f, RATE, [1.0])
    arw = model.gyro_arw_si  # rad/s at τ = 1 s
    vrw = model.accel_vrw_si
    assert np.all(np.abs(adev_g[0] / arw - 1.0) < 0.10), adev_g[0] / arw
    assert np.all(np.abs(adev_f[0] / vrw - 1.0) < 0.10), adev_f[0] / vrw


def test_allan_bias_instability_gauss_markov() -> None:
    # Short correlation time so that 2 h hold ~700 correlation times.
    model = ImuErrorModel(
        gyro_arw_deg_rth=0.6,
        gyro_bias_instability_deg_h=50.0,
        gyro_bias_corr_time_s=10.0,
        accel_vrw_mg_rthz=0.08,
        accel_bias_instability_mg=0.5,
        accel_bias_corr_time_s=10.0,
    )
    g, f = stationary_imu(model, hours=2.0, seed=7)
    taus = np.array([10.0, 10.0 * GM_ALLAN_PEAK_TAU_RATIO, 50.0])
    for y, dens, sig in (
        (g, model.gyro_arw_si, model.gyro_gm_sigma_si),
        (f, model.accel_vrw_si, model.accel_gm_sigma_si),
    ):
        tau, adev = allan_deviation(y, RATE, taus)
        expected = np.sqrt(
            allan_variance_white(dens, tau) + allan_variance_gauss_markov(sig, 10.0, tau)
        )
        ratio = np.sqrt(np.mean(adev**2, axis=1)) / expected
        assert np.all(np.abs(ratio - 1.0) < 0.10), ratio


def test_allan_peak_equals_bias_instability_without_white_noise() -> None:
    model = ImuErrorModel(gyro_bias_instability_deg_h=10.0, gyro_bias_corr_time_s=5.0)
    g, _ = stationary_imu(model, hours=1.0, seed=3)
    _, adev = allan_deviation(g - EARTH_RATE_B, RATE, [5.0 * GM_ALLAN_PEAK_TAU_RATIO])
    floor = float(np.sqrt(np.mean(adev[0] ** 2))) / DEG_PER_H
    assert abs(floor / 10.0 - 1.0) < 0.10, floor
    # and the analytic curve peaks where the constants say
    taus = np.linspace(1.0, 20.0, 2001)
    curve = np.sqrt(allan_variance_gauss_markov(1.0, 5.0, taus))
    assert curve.max() == pytest.approx(GM_ALLAN_PEAK_RATIO, rel=1e-6)
    assert taus[curve.argmax()] == pytest.approx(5.0 * GM_ALLAN_PEAK_TAU_RATIO, rel=1e-3)


def test_allan_mti_g_700_three_hours() -> None:
    # 3 h at 100 Hz (~1 s): white noise at 1 s and the Gauss–Markov floor at τ_c and 1.89 τ_c;
    # with only ~100 correlation times in the record the floor's estimate scatters ~5-10 %.
    model = IMU_GRADES["mti-g-700"]
    g, f = stationary_imu(model, hours=3.0, seed=11)
    taus = np.array([1.0, 100.0, 189.0])
    for y, dens, sig, tc in (
        (g, model.gyro_arw_si, model.gyro_gm_sigma_si, model.gyro_bias_corr_time_s),
        (f, model.accel_vrw_si, model.accel_gm_sigma_si, model.accel_bias_corr_time_s),
    ):
        tau, adev = allan_deviation(y, RATE, taus)
        expected = np.sqrt(
            allan_variance_white(dens, tau) + allan_variance_gauss_markov(sig, tc, tau)
        )
        ratio = np.sqrt(np.mean(adev**2, axis=1)) / expected
        assert np.all(np.abs(ratio - 1.0) < 0.15), ratio


def test_allan_deviation_white_noise_exact_formula() -> None:
    rng = np.random.default_rng(0)
    y = rng.standard_normal((200_000, 2)) * 0.1  # density 0.1/sqrt(100) = 0.01
    tau, adev = allan_deviation(y, 100.0)
    assert tau[0] == pytest.approx(0.01)
    ratio = adev / (0.01 / np.sqrt(tau))[:, None]
    assert np.all(np.abs(ratio[tau < 10] - 1) < 0.1)


def test_imu_constants_bias_scale_misalignment() -> None:
    model = ImuErrorModel(
        gyro_bias_deg_h=100.0,
        gyro_scale_factor_ppm=1000.0,
        gyro_misalignment_mrad=1.0,
        accel_bias_mg=2.0,
        accel_bias_offset_mg=(1.0, 2.0, 3.0),
        accel_scale_factor_ppm=500.0,
        accel_misalignment_mrad=0.5,
    )
    sim = ImuErrorSimulator(model, RATE, np.random.default_rng(4))
    w = np.array([[0.1, -0.2, 0.3], [0.0, 0.0, 0.0]])
    f = np.array([[1.0, 2.0, 9.8], [0.0, 0.0, 0.0]])
    g_out, f_out = sim.apply(np.array([0.01, 0.02]), w, f)
    np.testing.assert_allclose(g_out, w @ sim.gyro_matrix.T + sim.gyro_bias, rtol=0, atol=1e-15)
    np.testing.assert_allclose(f_out[1], sim.accel_bias, rtol=0, atol=1e-15)
    assert np.all(np.abs(sim.gyro_bias) < 5 * 100 * DEG_PER_H)
    assert np.all(np.diag(sim.gyro_matrix) != 1.0)
    np.testing.assert_array_equal(
        np.diag(sim.gyro_matrix - np.eye(3) - np.diag(np.diag(sim.gyro_matrix - np.eye(3)))), 0.0
    )
    r = sim.realized()
    assert len(r["gyro_misalignment_mrad"]) == 9


def test_imu_ideal_is_identity_and_gap_rows() -> None:
    t = np.arange(1, 501) / RATE
    w = np.random.default_rng(0).standard_normal((500, 3))
    f = np.random.default_rng(1).standard_normal((500, 3))
    faults = parse_faults([{"kind": "imu_gap", "t_start": 1.0, "t_end": 2.0}])
    sim = ImuErrorSimulator(IMU_GRADES["ideal"], RATE, np.random.default_rng(0), faults)
    tk, g, a = sim.apply_rows(t, w, f)
    assert tk.size == 500 - 101
    assert not np.any((tk >= 1.0) & (tk <= 2.0))
    keep = present_mask(faults, "imu", t)
    assert_identical(g, w[keep])
    assert_identical(a, f[keep])
    with pytest.raises(ValueError, match="consecutive"):
        sim.apply(np.array([10.0]), w[:1], f[:1])


def test_imu_chunked_equals_whole_and_seeded() -> None:
    model = IMU_GRADES["mti-g-700"].combined_with(
        ImuErrorModel(
            gyro_scale_factor_ppm=300, gyro_misalignment_mrad=1, accel_scale_factor_ppm=200
        )
    )
    n = 5000
    t = np.arange(1, n + 1) / RATE
    rng = np.random.default_rng(9)
    w = rng.standard_normal((n, 3)) * 0.01
    f = rng.standard_normal((n, 3)) + np.array([0.0, 0.0, G0])
    whole = ImuErrorSimulator(model, RATE, np.random.default_rng(42)).apply(t, w, f)
    sim = ImuErrorSimulator(model, RATE, np.random.default_rng(42))
    parts = [
        sim.apply(t[a:b], w[a:b], f[a:b]) for a, b in ((0, 1), (1, 1234), (1234, 3000), (3000, n))
    ]
    assert_identical(np.concatenate([p[0] for p in parts]), whole[0])
    assert_identical(np.concatenate([p[1] for p in parts]), whole[1])
    other = ImuErrorSimulator(model, RATE, np.random.default_rng(43)).apply(t, w, f)
    assert not np.array_equal(other[0], whole[0])


def test_presets_and_spec_for_meta() -> None:
    names = {"ideal", "mti-g-700", "mti-30", "seed002-mems"} | {f"par{k}" for k in range(1, 13)}
    assert names <= set(IMU_GRADES)
    assert spec_for_meta(IMU_GRADES["mti-g-700"]) == {
        "gyro_bias_deg_h": 720.0,
        "gyro_arw_deg_rth": 0.6,
        "accel_bias_mg": 3.0,
        "accel_vrw_mg_rthz": 0.08,
    }
    assert spec_for_meta(IMU_GRADES["par2"])["gyro_bias_deg_h"] == pytest.approx(200.0)
    assert IMU_GRADES["par5"].gyro_arw_deg_rth == 2.0
    assert IMU_GRADES["par9"].accel_bias_offset_mg == (3.0, 3.0, 3.0)
    assert IMU_GRADES["par10"].accel_vrw_mg_rthz == 1.0
    assert IMU_GRADES["mti-30"].gyro_arw_deg_rth == pytest.approx(6.0)
    assert IMU_GRADES["ideal"].is_ideal()
    both = IMU_GRADES["mti-g-700"].combined_with(IMU_GRADES["par2"])
    assert both.gyro_bias_offset_deg_h == (200.0, 200.0, 200.0)
    assert both.gyro_bias_deg_h == 720.0 and both.gyro_bias_instability_deg_h == 10.0
    both = IMU_GRADES["mti-g-700"].combined_with(IMU_GRADES["par5"])
    assert both.gyro_arw_deg_rth == pytest.approx(math.hypot(0.6, 2.0))
    assert MG == pytest.approx(9.80665e-3)
    with pytest.raises(pydantic.ValidationError):
        ImuErrorModel(gyro_arw=1.0)  # type: ignore[call-arg]


# ---------------------------------------------------------------------------------------------
# odometer


def test_odometer_scale_and_mounting_recovered_by_least_squares() -> None:
    truth = moving_truth(duration=1800.0, lateral=0.05)
    model = OdometerModel(
        scale_factor_error=0.015,
        mounting_angles_deg=(1.0, 0.7, -1.5),
        noise_sigma_mps=0.001,
        counts_per_m=10000.0,
    )
    t, speed = OdometerSimulator(model, np.random.default_rng(5)).apply(truth)
    assert t[0] == pytest.approx(0.1) and np.all(np.diff(t) > 0)
    # regressors: interval means of the true body velocity over (t_j - 0.1, t_j]
    tt, vb = truth.t, truth.velocity_body
    cum = np.concatenate(
        [[np.zeros(3)], np.cumsum(0.5 * (vb[1:] + vb[:-1]) * np.diff(tt)[:, None], axis=0)]
    )
    cj = np.stack([np.interp(t, tt, cum[:, i]) for i in range(3)], axis=1)
    cprev = np.stack([np.interp(t - 0.1, tt, cum[:, i]) for i in range(3)], axis=1)
    vmean = (cj - cprev) / 0.1
    coef, *_ = np.linalg.lstsq(vmean, speed, rcond=None)
    k = coef[1] - 1.0
    # speed = (1 + k) [exp(−δα×) v^b]_y = (1 + k)(v_y − δα_z v_x + δα_x v_z)
    a_z = -coef[0] / coef[1]
    a_x = coef[2] / coef[1]
    assert k == pytest.approx(0.015, rel=0.05)
    assert math.degrees(a_z) == pytest.approx(-1.5, rel=0.05)
    assert math.degrees(a_x) == pytest.approx(1.0, rel=0.05)


def test_odometer_quantization_slip_dropout_and_chunking() -> None:
    truth = moving_truth(duration=60.0)
    faults = [
        {"kind": "odometer_slip", "t_start": 10.0, "t_end": 20.0, "slip_ratio": 0.2},
        {"kind": "dropout", "sensor": "odometer", "t_start": 30.0, "t_end": 31.0},
    ]
    model = OdometerModel(scale_factor_error=0.0, counts_per_m=100.0, noise_sigma_mps=0.001)
    t, s = OdometerSimulator(model, np.random.default_rng(1), parse_faults(faults)).apply(truth)
    sim = OdometerSimulator(model, np.random.default_rng(1), parse_faults(faults))
    parts = [sim.apply(c) for c in split_truth(truth, [1, 3, 777, 1500, 2])]
    assert_identical(np.concatenate([p[0] for p in parts]), t)
    assert_identical(np.concatenate([p[1] for p in parts]), s)
    assert not np.any((t >= 30.0) & (t <= 31.0))
    assert np.allclose(np.diff(t)[np.diff(t) < 0.15], 0.1)
    # slip: exactly +20 % on every interval inside the window, nothing outside
    clean = OdometerModel(scale_factor_error=0.0)
    t0, s0 = OdometerSimulator(clean, np.random.default_rng(1)).apply(truth)
    t1, s1 = OdometerSimulator(clean, np.random.default_rng(1), parse_faults(faults)).apply(truth)
    ratio = s1 / s0[np.isin(t0, t1)]
    inside = (t1 > 10.05) & (t1 <= 20.0)
    np.testing.assert_allclose(ratio[inside], 1.2, rtol=1e-9)
    np.testing.assert_allclose(ratio[(t1 < 9.95) | (t1 > 20.05)], 1.0, rtol=1e-9)
    # quantized distance: travel summed over the rows is a whole number of counts
    _, s_full = OdometerSimulator(
        OdometerModel(scale_factor_error=0.0, counts_per_m=100.0), np.random.default_rng(1)
    ).apply(truth)
    counts = np.cumsum(s_full * 0.1) * 100.0
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)


# ---------------------------------------------------------------------------------------------
# magnetometer


def tilt_compensated_heading(field_b: np.ndarray, roll: float, pitch: float) -> np.ndarray:
    """Magnetic heading ψ − D from the body field, removing roll and pitch (recording convention).

    ``R_z(ψ) B^n = R_x(θ) R_y(γ) B^b =: B_h`` and ``B_h = F cos I [sin(D − ψ), cos(D − ψ), ·]``.
    """
    c_level = dcm_from_euler(roll, pitch, 0.0)  # R_x(θ) R_y(γ)
    bh = field_b @ c_level.T
    return np.arctan2(-bh[:, 0], bh[:, 1])


@pytest.mark.parametrize("yaw_deg", [0.0, 70.0, 200.0, 315.0])
def test_magnetometer_heading_at_rest(yaw_deg: float) -> None:
    n = 1001
    t = np.arange(n) / RATE
    att = np.tile([math.radians(3.0), math.radians(-2.0), math.radians(yaw_deg)], (n, 1))
    truth = make_truth(t, np.zeros((n, 3)), np.zeros((n, 3)), att)
    model = MagnetometerModel(declination_deg=-4.2, noise_sigma_uT=0.1)
    tm, field = MagnetometerSimulator(model, np.random.default_rng(2)).apply(truth)
    assert tm.size == 501  # 50 Hz over [0, 10] s
    heading = tilt_compensated_heading(field, att[0, 0], att[0, 1])
    yaw = heading + math.radians(model.declination_deg)
    err = (yaw - math.radians(yaw_deg) + np.pi) % (2 * np.pi) - np.pi
    per_sample = 0.1 / (50.0 * math.cos(math.radians(55.0)))
    assert abs(err.mean()) < 4 * per_sample / math.sqrt(err.size)
    assert err.std() == pytest.approx(per_sample, rel=0.2)


def test_magnetometer_interference_ramp_iron_and_chunking() -> None:
    truth = moving_truth(duration=40.0)
    faults = parse_faults(
        [
            {
                "kind": "magnetic_interference",
                "t_start": 10.0,
                "t_end": 20.0,
                "ramp_s": 2.0,
                "field_uT": [5.0, -3.0, 1.0],
            }
        ]
    )
    hard = (1.0, 2.0, -3.0)
    soft = ((1.02, 0.01, 0.0), (0.01, 0.98, 0.0), (0.0, 0.0, 1.01))
    model = MagnetometerModel(hard_iron_uT=hard, soft_iron=soft, noise_sigma_uT=0.0)
    t, f_int = MagnetometerSimulator(model, np.random.default_rng(0), faults).apply(truth)
    _, f_clean = MagnetometerSimulator(model, np.random.default_rng(0)).apply(truth)
    w = np.clip(np.minimum(t - 10.0, 20.0 - t) / 2.0, 0.0, 1.0)
    np.testing.assert_allclose(f_int - f_clean, w[:, None] * [5.0, -3.0, 1.0], atol=1e-12)
    # clean field = S C_n^b B^n + h at sample times that coincide with IMU samples
    c = truth.c_b_n[::2]
    expected = np.einsum("kji,j->ki", c, model.field_n) @ np.asarray(soft).T + hard
    np.testing.assert_allclose(f_clean, expected, atol=1e-12)
    noisy = MagnetometerModel(noise_sigma_uT=0.2)
    whole = MagnetometerSimulator(noisy, np.random.default_rng(8), faults).apply(truth)
    sim = MagnetometerSimulator(noisy, np.random.default_rng(8), faults)
    parts = [sim.apply(ch) for ch in split_truth(truth, [1, 2, 1001, 5])]
    assert_identical(np.concatenate([p[0] for p in parts]), whole[0])
    assert_identical(np.concatenate([p[1] for p in parts]), whole[1])


# ---------------------------------------------------------------------------------------------
# UWB


def uwb_model(**kw: Any) -> UwbModel:
    anchors = dict(SEED004_GROUND_ANCHORS)
    anchors["FAR"] = (500.0, 500.0, 0.0)
    base: dict[str, Any] = dict(
        anchors=anchors, tag_lever_arm_b_m=(0.3, 0.8, 0.4), max_range_m=30.0, noise_sigma_m=0.02
    )
    base.update(kw)
    return UwbModel(**base)


def test_uwb_ranges_geometry_nlos_windows_and_range_limit() -> None:
    truth = moving_truth(duration=120.0)  # drives ~30 m away from the anchors
    faults = parse_faults(
        [
            {
                "kind": "uwb_nlos",
                "t_start": 20.0,
                "t_end": 40.0,
                "anchors": ["A2"],
                "bias_m": [0.3, 1.5],
            }
        ]
    )
    model = uwb_model()
    sim = UwbSimulator(model, np.random.default_rng(3), faults)
    t, idx, r = sim.apply(truth)
    assert np.all(np.diff(t) > 0)
    assert np.all(r >= 0)
    ids = np.array(model.anchor_ids)
    assert "FAR" not in set(ids[idx])
    # geometric distance recomputed independently
    pos = np.stack([np.interp(t, truth.t, truth.position_enu[:, i]) for i in range(3)], axis=1)
    c = np.stack(
        [np.interp(t, truth.t, truth.c_b_n[:, i, j]) for i in range(3) for j in range(3)], axis=1
    )
    tag = pos + c.reshape(-1, 3, 3) @ np.array([0.3, 0.8, 0.4])
    geo = np.linalg.norm(tag - np.array([model.anchors[a] for a in ids[idx]]), axis=1)
    assert np.all(geo <= 30.0)
    assert t.max() < 119.0  # the anchors drop out once the shearer is beyond 30 m
    res = r - geo
    inside = (t >= 20.0) & (t <= 40.0) & (ids[idx] == "A2")
    assert np.all(np.abs(res[~inside]) < 5 * 0.02)
    assert abs(res[~inside].mean()) < 0.002 and res[~inside].std() == pytest.approx(0.02, rel=0.1)
    assert np.all(res[inside] > 0.3 - 5 * 0.02) and np.all(res[inside] < 1.5 + 5 * 0.02)
    assert np.all(sim.last_nlos_bias[~inside] == 0.0) and np.all(sim.last_nlos_bias[inside] >= 0.3)
    with pytest.raises(ValueError, match="unknown anchors"):
        UwbSimulator(
            model,
            np.random.default_rng(0),
            parse_faults([{"kind": "uwb_nlos", "t_start": 0, "t_end": 1, "anchors": ["B7"]}]),
        )
    # staggered rounds: 40 Hz rounds of 5 anchors
    assert np.min(np.diff(t)) == pytest.approx(1 / 200.0)


def test_uwb_random_nlos_dropout_and_chunking() -> None:
    truth = moving_truth(duration=30.0)
    faults = parse_faults(
        [
            {"kind": "uwb_nlos", "t_start": 5.0, "t_end": 8.0, "bias_m": [0.5, 0.6]},
            {"kind": "dropout", "sensor": "uwb", "t_start": 10.0, "t_end": 11.0},
        ]
    )
    model = uwb_model(
        nlos_probability={"A1": 0.3},
        nlos_bias_distribution="exponential",
        dropout_probability=0.1,
    )
    whole_sim = UwbSimulator(model, np.random.default_rng(12), faults)
    whole = whole_sim.apply(truth)
    sim = UwbSimulator(model, np.random.default_rng(12), faults)
    parts = [sim.apply(ch) for ch in split_truth(truth, [1, 1, 999, 3])]
    for k in range(3):
        assert_identical(np.concatenate([p[k] for p in parts]), whole[k])
    t, idx, _ = whole
    assert not np.any((t >= 10.0) & (t <= 11.0))
    n_slots = 4 * 40 * 30  # FAR never in range
    assert 0.85 < t.size / (n_slots - 4 * 40) < 0.95
    bias = whole_sim.last_nlos_bias
    outside = (t < 5.0) | (t > 8.0)
    assert np.all(bias >= 0)
    assert np.all(bias[outside & (idx != 0)] == 0.0)
    frac = np.mean(bias[outside & (idx == 0)] > 0)
    assert 0.2 < frac < 0.4
    assert np.all((bias[~outside] >= 0.5) & (bias[~outside] <= 0.6))


# ---------------------------------------------------------------------------------------------
# support, position fixes


def test_support_and_position_fix() -> None:
    times = np.array([100.0, 200.0, 300.0, 400.0])
    adv = np.array([0.8, 0.8, 0.75, 0.8])
    faults = parse_faults([{"kind": "dropout", "sensor": "support", "t_start": 250, "t_end": 350}])
    model = SupportModel(noise_sigma_m=0.007, bias_m=0.01)
    t, a = SupportSimulator(model, np.random.default_rng(0), faults).apply(times, adv)
    assert_identical(t, np.array([100.0, 200.0, 400.0]))
    assert np.all(np.abs(a - 0.81) < 5 * 0.007)
    sim = SupportSimulator(model, np.random.default_rng(0), faults)
    _, a1 = sim.apply(times[:1], adv[:1])
    _, a2 = sim.apply(times[1:], adv[1:])
    assert_identical(np.concatenate([a1, a2]), a)

    truth = moving_truth(duration=20.0)
    pm = PositionFixModel(rate_hz=2.0, sigma_m=(0.01, 0.01, 0.02), lever_arm_b_m=(0.0, 0.0, 0.5))
    tp, enu, sig = PositionFixSimulator(pm, np.random.default_rng(1)).apply(truth)
    assert tp.size == 41 and sig.shape == (41, 3) and np.all(sig[:, 2] == 0.02)
    k = np.searchsorted(truth.t, tp)
    expected = truth.position_enu[k] + truth.c_b_n[k] @ np.array([0.0, 0.0, 0.5])
    assert np.all(np.abs(enu - expected) < 5 * sig)
    sim2 = PositionFixSimulator(pm, np.random.default_rng(1))
    parts = [sim2.apply(ch) for ch in split_truth(truth, [50, 51, 1])]
    for i in range(3):
        assert_identical(np.concatenate([p[i] for p in parts]), (tp, enu, sig)[i])


# ---------------------------------------------------------------------------------------------
# faults


def test_fault_specs_weights_and_meta() -> None:
    raw = [
        {
            "kind": "magnetic_interference",
            "t_start": 0,
            "t_end": 10,
            "ramp_s": 2,
            "field_uT": [1, 2, 3],
        },
        {"kind": "uwb_nlos", "t_start": 5, "t_end": 6, "anchors": ["A1"]},
        {"kind": "odometer_slip", "t_start": 1, "t_end": 2, "slip_ratio": 0.2},
        {"kind": "dropout", "sensor": "magnetometer", "t_start": 3, "t_end": 4},
        {"kind": "imu_gap", "t_start": 7, "t_end": 8},
    ]
    faults = parse_faults(raw)
    assert [f.kind for f in faults] == [r["kind"] for r in raw]
    w = active_weight(faults, "magnetic_interference", [-1, 0, 1, 2, 5, 9, 10, 11])
    np.testing.assert_allclose(w, [0, 0, 0.5, 1, 1, 0.5, 0, 0])
    assert np.array_equal(active_weight(faults, "uwb_nlos", [5.5], anchor="A2"), [0.0])
    assert np.array_equal(active_weight(faults, "uwb_nlos", [5.5], anchor="A1"), [1.0])
    assert np.array_equal(
        present_mask(faults, "magnetometer", [2.9, 3.5, 4.1]), [True, False, True]
    )
    assert np.array_equal(
        present_mask(faults, "imu", [6.9, 7.0, 8.0, 8.1]), [True, False, False, True]
    )
    meta = faults_to_meta(faults)
    assert meta[0]["field_uT"] == [1.0, 2.0, 3.0]
    assert parse_faults(meta) == faults
    for bad in (
        {"kind": "imu_gap", "t_start": 5, "t_end": 5},
        {"kind": "imu_gap", "t_start": 0, "t_end": 1, "ramp_s": 0.6},
        {"kind": "dropout", "sensor": "gps", "t_start": 0, "t_end": 1},
        {"kind": "uwb_nlos", "t_start": 0, "t_end": 1, "bias_m": [-0.1, 1.0]},
        {"kind": "nope", "t_start": 0, "t_end": 1},
        {"kind": "imu_gap", "t_start": 0, "t_end": 1, "extra": 1},
    ):
        with pytest.raises(pydantic.ValidationError):
            parse_faults([bad])


@pytest.mark.parametrize(
    "sizes",
    [[10, 990, 1000, 1], [1, 1, 1, 2000, 7], [333, 334, 335, 2000], [4000]],
    ids=["grid-aligned", "tiny", "odd", "two"],
)
def test_every_simulator_chunk_invariant(sizes: list[int]) -> None:
    """Chunk boundaries on and off the sensor grids, sensor rates that do not divide 100 Hz."""
    truth = moving_truth(duration=50.0)
    faults = parse_faults(
        [
            {"kind": "odometer_slip", "t_start": 5.0, "t_end": 25.0, "ramp_s": 3.0},
            {
                "kind": "magnetic_interference",
                "t_start": 9.0,
                "t_end": 30.0,
                "ramp_s": 5.0,
                "field_uT": [3.0, 0.0, -2.0],
            },
            {"kind": "uwb_nlos", "t_start": 9.995, "t_end": 20.0, "anchors": ["A3"]},
            {"kind": "dropout", "sensor": "magnetometer", "t_start": 12.0, "t_end": 13.0},
        ]
    )

    def run(make: Any, chunks: list[Any]) -> list[np.ndarray]:
        sim = make()
        outs = [sim.apply(c) for c in chunks]
        return [np.concatenate([o[k] for o in outs]) for k in range(len(outs[0]))]

    makers = [
        lambda: OdometerSimulator(
            OdometerModel(
                rate_hz=7.0, mounting_angles_deg=(1, 2, 3), counts_per_m=500.0, noise_sigma_mps=0.01
            ),
            np.random.default_rng(1),
            faults,
        ),
        lambda: MagnetometerSimulator(
            MagnetometerModel(rate_hz=33.0, hard_iron_uT=(1, 2, 3)),
            np.random.default_rng(2),
            faults,
        ),
        lambda: UwbSimulator(
            uwb_model(rate_hz=17.0, nlos_probability=0.2, dropout_probability=0.1),
            np.random.default_rng(3),
            faults,
        ),
        lambda: UwbSimulator(
            uwb_model(nlos_probability={"A2": 0.5, "A4": 0.1}, nlos_mean_duration_s=0.7),
            np.random.default_rng(5),
            faults,
        ),
        lambda: PositionFixSimulator(
            PositionFixModel(rate_hz=3.0, lever_arm_b_m=(0.1, 0.2, 0.3)), np.random.default_rng(4)
        ),
    ]
    chunks = split_truth(truth, sizes)
    for make in makers:
        whole = run(make, [truth])
        parts = run(make, chunks)
        assert whole[0].size > 10
        for w, p in zip(whole, parts, strict=True):
            assert_identical(p, w)


def test_uwb_nlos_episodes() -> None:
    n = 600 * 100 + 1
    t = np.arange(n) / RATE
    att = np.tile([0.0, 0.0, 0.3], (n, 1))
    truth = make_truth(t, np.tile([3.0, 4.0, 0.0], (n, 1)), np.zeros((n, 3)), att)
    model = UwbModel(
        anchors={"A": (0.0, 0.0, 0.0), "B": (1.0, 0.0, 0.0)},
        rate_hz=10.0,
        noise_sigma_m=0.0,
        nlos_probability={"A": 0.3},
        nlos_mean_duration_s=2.0,
    )
    sim = UwbSimulator(model, np.random.default_rng(21))
    _, idx, _ = sim.apply(truth)
    nlos = sim.last_nlos_bias[idx == 0] > 0
    assert np.all(sim.last_nlos_bias[idx == 1] == 0.0)
    assert 0.2 < nlos.mean() < 0.4
    starts = np.flatnonzero(np.diff(nlos.astype(int)) == 1)
    mean_len = nlos.sum() / 10.0 / max(starts.size, 1)  # s, 10 ranges per second
    assert 1.5 < mean_len < 2.6, mean_len
    with pytest.raises(pydantic.ValidationError):
        UwbModel(anchors={"A": (0.0, 0.0, 0.0)}, nlos_probability={"Z": 0.1})
    with pytest.raises(pydantic.ValidationError):
        UwbModel(anchors={"A": (0.0, 0.0, 0.0)}, nlos_probability=1.5)
