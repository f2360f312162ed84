"""Hand-worked cases of the attitude convention and the WGS84 model."""

import numpy as np
import pytest

from fusion import attitude, earth


def test_yaw_90_maps_body_y_to_east() -> None:
    c = attitude.dcm_from_euler(0.0, 0.0, np.pi / 2)
    np.testing.assert_allclose(c @ [0, 1, 0], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(c @ [1, 0, 0], [0, -1, 0], atol=1e-15)


def test_yaw_is_clockwise_from_north() -> None:
    c = attitude.dcm_from_euler(0.0, 0.0, np.deg2rad(30))
    east, north, _ = c @ [0, 1, 0]
    assert east > 0 and north > 0
    assert np.isclose(np.arctan2(east, north), np.deg2rad(30))


def test_positive_pitch_raises_the_nose() -> None:
    c = attitude.dcm_from_euler(0.0, np.deg2rad(10), 0.0)
    np.testing.assert_allclose(c @ [0, 1, 0], [0, np.cos(0.1745329), np.sin(0.1745329)], atol=1e-7)


def test_positive_roll_lowers_the_right_side() -> None:
    c = attitude.dcm_from_euler(np.deg2rad(5), 0.0, 0.0)
    assert (c @ [1, 0, 0])[2] < 0


def test_matches_the_contract_product_of_elementary_rotations() -> None:
    def rx(a: float) -> np.ndarray:
        return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])

    def ry(a: float) -> np.ndarray:
        return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])

    def rz(a: float) -> np.ndarray:
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])

    r, p, y = 0.3, -0.4, 2.5
    np.testing.assert_allclose(attitude.dcm_from_euler(r, p, y), rz(-y) @ rx(p) @ ry(r), atol=1e-15)


@pytest.mark.parametrize("angles", [(0.1, 0.2, 0.3), (-0.5, 1.2, 6.0), (2.0, -1.0, 0.01)])
def test_euler_dcm_quaternion_round_trips(angles: tuple[float, float, float]) -> None:
    c = attitude.dcm_from_euler(*angles)
    back = attitude.euler_from_dcm(c)
    np.testing.assert_allclose(attitude.wrap_angle(back - angles), 0, atol=1e-12)
    q = attitude.quat_from_dcm(c)
    np.testing.assert_allclose(attitude.dcm_from_quat(q), c, atol=1e-14)


def test_quaternion_product_composes_rotations() -> None:
    a, b = np.array([0.1, -0.2, 0.3]), np.array([-0.05, 0.4, 0.02])
    qa, qb = attitude.quat_from_rotvec(a), attitude.quat_from_rotvec(b)
    c = attitude.dcm_from_quat(attitude.quat_multiply(qa, qb))
    np.testing.assert_allclose(c, attitude.dcm_from_quat(qa) @ attitude.dcm_from_quat(qb))


def test_small_rotation_vector_series_is_continuous() -> None:
    for a in (1e-5, 9.9e-5, 1.01e-4, 1e-3):
        rv = np.array([a, 0.0, 0.0])
        np.testing.assert_allclose(
            attitude.quat_from_rotvec(rv), [np.cos(a / 2), np.sin(a / 2), 0, 0], atol=1e-17
        )


def test_normal_gravity_at_equator_and_pole() -> None:
    assert earth.normal_gravity(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert earth.normal_gravity(np.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-9)
    # Free-air gradient ≈ −3.086e-6 s⁻².
    assert earth.normal_gravity_height_gradient(0.7, 0.0) == pytest.approx(-3.086e-6, rel=2e-3)


def test_radii_at_equator_and_pole() -> None:
    rm, rn = earth.radii(0.0)
    assert rn == pytest.approx(earth.A)
    assert rm == pytest.approx(earth.A * (1 - earth.E2))
    rm, rn = earth.radii(np.pi / 2)
    assert rm == pytest.approx(rn)


def test_enu_round_trip_and_axes() -> None:
    frame = earth.LocalFrame(34.25, 108.95, -350.0)
    enu = np.array([[0.0, 0.0, 0.0], [200.0, -30.0, 5.0], [-1500.0, 800.0, -20.0]])
    lat, lon, h = frame.to_geodetic(enu)
    np.testing.assert_allclose(frame.to_enu(lat, lon, h), enu, atol=1e-8)
    # 100 m north is a latitude step of 100 / (R_M + h).
    lat1, _, _ = frame.to_geodetic([0.0, 100.0, 0.0])
    rm, _ = earth.radii(frame.lat0)
    assert lat1 - frame.lat0 == pytest.approx(100.0 / (rm + frame.height0), rel=1e-6)


def test_a_point_s_enu_bits_do_not_depend_on_the_array_it_is_in() -> None:
    """The smoother holds a kept block at the forward coordinates computed over its window;
    the forward track computes them over the whole run: the same bits either way (a matrix
    product rounded single points differently from rows of a long array)."""
    frame = earth.LocalFrame(35.4, 116.6, -650.0)
    rng = np.random.default_rng(0)
    n = 20_011
    lat = frame.lat0 + rng.normal(0.0, 2e-4, n)
    lon = frame.lon0 + rng.normal(0.0, 2e-4, n)
    height = frame.height0 + rng.normal(0.0, 10.0, n)
    whole = frame.to_enu(lat, lon, height)
    for start, stop in [(0, 1), (3, 10), (17, 4099), (999, 1000), (5, n)]:
        part = slice(start, stop)
        np.testing.assert_array_equal(frame.to_enu(lat[part], lon[part], height[part]), whole[part])
    for i in range(0, n, 997):
        np.testing.assert_array_equal(frame.to_enu(lat[i], lon[i], height[i]), whole[i])


def test_point_memo_matches_the_array_forms_and_hands_out_copies() -> None:
    frame = earth.LocalFrame(35.4, 116.6, -650.0)
    lat, lon, height = np.deg2rad(35.4005), np.deg2rad(116.6007), -648.0
    enu, rotation = frame.point(lat, lon, height)
    np.testing.assert_array_equal(enu, frame.to_enu(lat, lon, height))
    np.testing.assert_array_equal(rotation, frame.rotation_to_local(lat, lon))
    enu[:] = 0.0  # the caller's copy; the memo keeps the point
    np.testing.assert_array_equal(frame.point(lat, lon, height)[0], frame.to_enu(lat, lon, height))
    other = frame.point(lat + 1e-6, lon, height)[0]  # a new point replaces the memo
    np.testing.assert_array_equal(other, frame.to_enu(lat + 1e-6, lon, height))
