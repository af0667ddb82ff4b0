"""The controller's own model: rigid rider lumped onto the robot, the planar linearisation, LQR gains,
and the omniwheel map. Independent of the rig's plant by design (docs/physics.md §2.4, §3;
iHACS paper §III-A).

Seated rider [Winter-derived, simplified]: one rigid body whose COM is 0.104 H above the hip and straight
over the ball axis, radius of gyration 0.19 H; hip 0.09 m above the seat. For 75 kg / 1.75 m on PURE this
gives m_B = 105 kg, l = 0.563 m, Θ_B = 12.9 kg m² (the plant's segment model: 13.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from controller.config import Lqr
from drivers.bounds import G0
from drivers.robot import RobotModel

RIDER_COM_ABOVE_HIP = 0.104  # × height
RIDER_GYRATION = 0.19  # × height
HIP_ABOVE_SEAT = 0.09
SEAT_LOAD_COM_ABOVE_HIP = 0.139  # × height: torso (0.678 M at 0.18 H) and thighs (0.2 M at 0) over the hip


@dataclass(frozen=True, slots=True)
class PlaneModel:
    """Two-body (ball + lumped body) parameters of one plane and its linearisation about upright."""

    ball_radius: float
    mass: float
    """m_B: robot body + rider."""
    com: float
    """l: COM above the ball centre, m."""
    a: np.ndarray
    """4×4, state s = [θ, φ, θ̇, φ̇]."""
    b: np.ndarray
    """4×1, input τ (ball torque)."""
    top_height: float
    rolling_viscous: float
    drivetrain_viscous: float

    @property
    def unstable_pole(self) -> float:
        return math.sqrt(self.a[2, 0])


def plane_model(robot: RobotModel, rider_mass: float, rider_height: float, plane: str) -> PlaneModel:
    b, body, dt = robot.ball, robot.body, robot.drivetrain
    rho = b.radius / dt.wheel_radius
    j_act = dt.wheel_inertia + dt.gear_ratio**2 * dt.rotor_inertia
    theta_w = 1.5 * math.cos(math.radians(dt.zenith_deg)) ** 2 * j_act
    hip = body.top_height + body.seat_height + HIP_ABOVE_SEAT
    z_rider = hip + RIDER_COM_ABOVE_HIP * rider_height
    k_rider = RIDER_GYRATION * rider_height
    i_body = body.inertia_pitch if plane == "pitch" else body.inertia_roll
    m = body.mass + rider_mass
    com = (body.mass * body.com_height + rider_mass * z_rider) / m
    inertia = (
        i_body + body.mass * (body.com_height - com) ** 2 + rider_mass * (k_rider**2 + (z_rider - com) ** 2)
    )

    m11 = b.mass * b.radius**2 + b.inertia + m * b.radius**2 + theta_w * rho**2
    m12 = m * b.radius * com - theta_w * rho * (1 + rho)
    m22 = inertia + m * com**2 + theta_w * (1 + rho) ** 2
    det = m11 * m22 - m12**2
    mgl = m * G0 * com
    a = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [m11 * mgl / det, 0, 0, 0], [-m12 * mgl / det, 0, 0, 0]], float)
    bb = np.array([[0.0], [0.0], [-(m11 + m12) / det], [(m22 + m12) / det]])
    f = robot.friction
    return PlaneModel(b.radius, m, com, a, bb, body.top_height, f.rolling_viscous, f.drivetrain_viscous)


def seat_load_height(robot: RobotModel, rider_height: float) -> float:
    """Height above P of the COM of what the seat carries (torso + thighs, Winter: 0.139 H above the hip)."""
    return robot.body.seat_height + HIP_ABOVE_SEAT + SEAT_LOAD_COM_ABOVE_HIP * rider_height


def lqr_gain(model: PlaneModel, weights: Lqr) -> np.ndarray:
    """K (1×4) on s = [θ, φ, θ̇, φ̇] with no gain on φ: continuous LQR on [θ, θ̇, φ̇], K = R⁻¹ Bᵀ P with P
    from scipy's Riccati solver (what python-control's `lqr` solves; importing python-control pulls in
    scipy.signal and matplotlib, 40 s of start-up on an emulated bench CPU)."""
    idx = [0, 2, 3]
    a, b = model.a[np.ix_(idx, idx)], model.b[idx]
    q = np.diag([weights.q_tilt, weights.q_tilt_rate, weights.q_ball_rate])
    r = np.array([[weights.r_torque]])
    p = scipy.linalg.solve_continuous_are(a, b, q, r)
    k = np.linalg.solve(r, b.T @ p).ravel()
    return np.array([k[0], 0.0, k[1], k[2]])


def motor_jacobian(robot: RobotModel) -> np.ndarray:
    """G: motor-shaft rates = G @ ω_rel, ω_rel = [φ̇_x − θ̇_x, φ̇_y − θ̇_y, −ψ̇] (docs/physics.md §3)."""
    dt = robot.drivetrain
    rho = robot.ball.radius / dt.wheel_radius
    alpha = math.radians(dt.zenith_deg)
    rows = []
    for i in range(3):
        beta = math.radians(dt.azimuth0_deg) + i * 2 * math.pi / 3
        rows.append([-math.cos(alpha) * math.cos(beta), -math.cos(alpha) * math.sin(beta), math.sin(alpha)])
    return dt.gear_ratio * np.diag(np.asarray(dt.motor_sign, float)) @ (rho * np.array(rows))
