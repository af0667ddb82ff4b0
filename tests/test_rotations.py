"""drivers/rotations.py against an independent reference: scipy's Rotation for the ZYX convention, the
quaternions and the frames, and a finite difference of the rotation for the Euler rates."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.rotations import (
    body_frame,
    body_up,
    chassis_axis,
    euler_rates,
    euler_zyx,
    heading_frame,
    matrix_zyx,
    multiply,
    quaternion_zyx,
    rotate,
)


def angles(n: int = 30, seed: int = 3) -> np.ndarray:
    """(roll, pitch, yaw) rows, pitch kept off ±π/2 (where ZYX has no unique roll and yaw)."""
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(-np.pi, np.pi, n), rng.uniform(-1.4, 1.4, n), rng.uniform(-np.pi, np.pi, n)]
    )


def reference(roll: float, pitch: float, yaw: float) -> Rotation:
    """Rz(yaw) Ry(pitch) Rx(roll): scipy's intrinsic Z, Y', X''."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll])


def scipy_quat(q) -> Rotation:
    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w])  # scipy's order is scalar last


def test_quaternion_and_matrix_are_scipys_zyx():
    for roll, pitch, yaw in angles():
        r = reference(roll, pitch, yaw)
        assert np.allclose(
            scipy_quat(quaternion_zyx(roll, pitch, yaw)).as_matrix(), r.as_matrix(), atol=1e-12
        )
        assert np.allclose(np.array(matrix_zyx(roll, pitch, yaw)), r.as_matrix(), atol=1e-12)
        assert np.linalg.norm(quaternion_zyx(roll, pitch, yaw)) == pytest.approx(1.0, abs=1e-12)


def test_positive_control_another_order_is_another_rotation():
    roll, pitch, yaw = 0.3, -0.5, 1.1
    xyz = Rotation.from_euler("XYZ", [roll, pitch, yaw]).as_matrix()
    assert not np.allclose(np.array(matrix_zyx(roll, pitch, yaw)), xyz, atol=1e-3)
    assert not np.allclose(
        np.array(matrix_zyx(yaw, pitch, roll)), reference(roll, pitch, yaw).as_matrix(), atol=1e-3
    )


def test_euler_zyx_reads_back_the_angles_of_any_quaternion():
    for roll, pitch, yaw in angles():
        w, x, y, z = quaternion_zyx(roll, pitch, yaw)
        for q in ((w, x, y, z), (-w, -x, -y, -z)):  # both signs are the same rotation
            assert euler_zyx(q) == pytest.approx((roll, pitch, yaw), abs=1e-9)
        yaw_s, pitch_s, roll_s = reference(roll, pitch, yaw).as_euler("ZYX")
        assert euler_zyx(quaternion_zyx(roll, pitch, yaw)) == pytest.approx(
            (roll_s, pitch_s, yaw_s), abs=1e-9
        )


def test_euler_rates_are_the_angles_finite_difference_under_body_rates():
    # Body rates ω turn the body: R(t + h) = R(t) exp(h [ω]×). The angles' central difference over ±h.
    rng = np.random.default_rng(5)
    h = 1e-6
    for roll, pitch, yaw in angles(20):
        rate = rng.normal(scale=2.0, size=3)
        r = reference(roll, pitch, yaw)
        ahead = (r * Rotation.from_rotvec(rate * h)).as_euler("ZYX")[::-1]
        behind = (r * Rotation.from_rotvec(-rate * h)).as_euler("ZYX")[::-1]
        step = (ahead - behind + np.pi) % (2 * np.pi) - np.pi  # yaw and roll wrap at ±π
        assert euler_rates(tuple(rate), roll, pitch) == pytest.approx(step / (2 * h), rel=1e-5, abs=1e-5)
    # A known case: a turn about the body's z on a rolled chassis shows as a pitch rate of −sin(roll).
    assert euler_rates((0.0, 0.0, 1.0), 0.2, 0.3)[1] == pytest.approx(-np.sin(0.2), abs=1e-12)


def test_rotate_and_multiply_are_scipys():
    rng = np.random.default_rng(7)
    for _ in range(30):
        a, b = Rotation.random(random_state=rng), Rotation.random(random_state=rng)
        qa, qb = (tuple(np.roll(r.as_quat(), 1)) for r in (a, b))  # (w, x, y, z)
        v = tuple(rng.normal(size=3))
        assert rotate(v, qa) == pytest.approx(a.apply(v), abs=1e-12)
        # multiply(a, b): b first, then a; the same quaternion as scipy's up to the sign of both.
        product = np.array(multiply(qa, qb))
        expected = np.roll((a * b).as_quat(), 1)
        assert min(np.abs(product - expected).max(), np.abs(product + expected).max()) < 1e-12
        assert not np.allclose(scipy_quat(multiply(qb, qa)).as_matrix(), (a * b).as_matrix(), atol=1e-6)


def test_the_heading_frame_is_the_world_turned_to_the_heading():
    for roll, pitch, _ in angles():
        tilt = Rotation.from_euler("YX", [pitch, roll])  # heading = Ry(pitch) Rx(roll) body
        v = np.array([0.3, -1.2, 0.7])
        assert heading_frame(v, roll, pitch) == pytest.approx(tilt.apply(v), abs=1e-12)
        assert body_frame(v, roll, pitch) == pytest.approx(tilt.inv().apply(v), abs=1e-12)
        assert body_up(roll, pitch) == pytest.approx(tilt.inv().apply([0.0, 0.0, 1.0]), abs=1e-12)
        assert chassis_axis(roll, pitch) == pytest.approx(tilt.apply([0.0, 0.0, 1.0]), abs=1e-12)
