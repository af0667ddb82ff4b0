"""Omniwheel maps (docs/physics.md §3): JᵀJ identity, power balance, the expanded torque map, signs, gears."""

import math

import msgspec
import numpy as np
import pytest

from plant.ballbot import Plant
from plant.omniwheel import motor_jacobian, wheel_inertia_equivalents, wheel_jacobian
from plant.params import Drivetrain, RobotParams
from tests.helpers import sim

R_K = 0.1145


@pytest.mark.parametrize(("alpha", "beta0"), [(45.0, 0.0), (56.0, 30.0), (65.5, -90.0)])
def test_jtj_identity(alpha, beta0):
    dt = Drivetrain(zenith_deg=alpha, azimuth0_deg=beta0)
    j = wheel_jacobian(R_K, dt)
    rho, a = R_K / dt.wheel_radius, math.radians(alpha)
    expected = rho**2 * np.diag([1.5 * math.cos(a) ** 2, 1.5 * math.cos(a) ** 2, 3 * math.sin(a) ** 2])
    np.testing.assert_allclose(j.T @ j, expected, atol=1e-12)


def test_jacobian_matches_physics_md_example():
    j = wheel_jacobian(R_K, Drivetrain())
    expected = [[-1.295, 0, 1.295], [0.648, -1.122, 1.295], [0.648, 1.122, 1.295]]
    np.testing.assert_allclose(j, expected, atol=1e-3)
    # 2.4 m/s forward: wheel rates [0, −23.5, +23.5] rad/s (§3.5).
    rates = j @ np.array([0.0, 2.4 / R_K, 0.0])
    np.testing.assert_allclose(rates, [0.0, -23.5, 23.5], atol=0.05)


@pytest.mark.parametrize("signs", [(1, 1, 1), (1, -1, 1), (-1, -1, 1)])
def test_power_balance_through_gears_and_signs(signs):
    dt = Drivetrain(motor_sign=signs, gear_ratio=6.5)
    g = motor_jacobian(R_K, dt)
    rng = np.random.default_rng(3)
    for _ in range(20):
        torque, omega = rng.normal(size=3), rng.normal(size=3)
        motor_rates = g @ omega
        ball_torque = g.T @ torque
        assert torque @ motor_rates == pytest.approx(ball_torque @ omega, rel=1e-12)
    # A sign flip mirrors exactly that motor; the gear ratio scales rates.
    base = wheel_jacobian(R_K, dt)
    for i, s in enumerate(signs):
        np.testing.assert_allclose(g[i], 6.5 * s * base[i])


@pytest.mark.parametrize(("alpha", "beta0"), [(45.0, 0.0), (60.0, 17.0)])
def test_expanded_torque_formula_is_the_inverse_map(alpha, beta0):
    # T_i = r_W/(3 r_K) [τ_z/sinα − (2/cosα)(τ_x cosβ_i + τ_y sinβ_i)] solves τ = Jᵀ T (§3.2).
    dt = Drivetrain(zenith_deg=alpha, azimuth0_deg=beta0)
    j = wheel_jacobian(R_K, dt)
    a = math.radians(alpha)
    tau = np.array([4.0, -7.0, 2.5])
    betas = [math.radians(beta0) + i * 2 * math.pi / 3 for i in range(3)]
    wheel = [
        dt.wheel_radius
        / (3 * R_K)
        * (tau[2] / math.sin(a) - 2 / math.cos(a) * (tau[0] * math.cos(b) + tau[1] * math.sin(b)))
        for b in betas
    ]
    np.testing.assert_allclose(j.T @ np.array(wheel), tau, atol=1e-12)


def test_actuator_inertia_equivalent():
    # §6.1: J_act ≈ 0.009 kg m² with N = 8 gives Θ_W ≈ 0.0069 for pitch/roll.
    pitch, yaw = wheel_inertia_equivalents(R_K, Drivetrain())
    assert pitch == pytest.approx(0.0069, abs=1e-4)
    assert yaw == pytest.approx(2 * pitch * math.tan(math.radians(45)) ** 2)


def test_encoders_follow_ball_and_yaw_motion():
    # Pure pitch-plane ball rotation leaves wheel 1 (on body +x) still; pure yaw turns all three equally.
    plant = Plant(RobotParams(), None, sim(fixture="clamped"))
    plant.x[0] = 1.0  # φ_y: ball rolled one radian relative to the body
    angles, _ = plant.motor_angles_and_rates()
    assert angles[0] == pytest.approx(0.0, abs=1e-12)
    assert angles[1] == pytest.approx(-angles[2]) and abs(angles[1]) > 1.0
    plant.x[0], plant.x[12] = 0.0, 0.3
    angles, _ = plant.motor_angles_and_rates()
    assert angles[0] == pytest.approx(angles[1]) == pytest.approx(angles[2])
    rho = RobotParams().ball.radius / RobotParams().drivetrain.wheel_radius
    assert angles[0] == pytest.approx(-0.3 * 8 * rho * math.sin(math.radians(45)))


def test_motor_sign_flips_that_encoder():
    flipped = msgspec.structs.replace(RobotParams().drivetrain, motor_sign=(1, -1, 1))
    a = Plant(RobotParams(), None, sim(fixture="clamped"))
    b = Plant(msgspec.structs.replace(RobotParams(), drivetrain=flipped), None, sim(fixture="clamped"))
    for p in (a, b):
        p.x[0], p.x[6] = 0.4, -0.2
    (aa, _), (bb, _) = a.motor_angles_and_rates(), b.motor_angles_and_rates()
    assert bb == pytest.approx([aa[0], -aa[1], aa[2]])
