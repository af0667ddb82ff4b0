"""Three-omniwheel kinematics and torque map (docs/physics.md §3), as matrices built from the geometry.

ω_rel is the ball's angular velocity relative to the body, in the body frame. With the planar
coordinates of this package (small tilt, ball not spinning on the floor):
    ω_rel = [φ̇_x - θ̇_x, φ̇_y - θ̇_y, -ψ̇_yaw]
where (φ_x, θ_x) are the roll-plane ball and body angles (rotations about +x) and (φ_y, θ_y) the pitch-plane
ones (about +y).
"""

from __future__ import annotations

import math

import numpy as np

from plant.params import Drivetrain


def wheel_jacobian(ball_radius: float, drivetrain: Drivetrain) -> np.ndarray:
    """J (3×3): wheel rates (rad/s at the wheel, model sign) = J @ ω_rel.

    Row i: ρ [-cosα cosβ_i, -cosα sinβ_i, sinα], from r_W ψ̇_i = ω_rel · (p_i × d_i).
    """
    rho = ball_radius / drivetrain.wheel_radius
    alpha = math.radians(drivetrain.zenith_deg)
    rows = []
    for i in range(3):
        beta = math.radians(drivetrain.azimuth0_deg) + i * 2.0 * math.pi / 3.0
        rows.append([-math.cos(alpha) * math.cos(beta), -math.cos(alpha) * math.sin(beta), math.sin(alpha)])
    return rho * np.array(rows)


def motor_jacobian(ball_radius: float, drivetrain: Drivetrain) -> np.ndarray:
    """G (3×3): motor-shaft rates = G @ ω_rel, including the gear ratio and each motor's sign.

    By power balance (Σ T_i q̇_i = τ·ω_rel) the torque on the ball from motor-shaft torques T is τ = Gᵀ T.
    """
    signs = np.diag(np.asarray(drivetrain.motor_sign, dtype=float))
    g: np.ndarray = drivetrain.gear_ratio * signs @ wheel_jacobian(ball_radius, drivetrain)
    return g


def wheel_inertia_equivalents(ball_radius: float, drivetrain: Drivetrain) -> tuple[float, float]:
    """Θ_W for the pitch/roll planes and for yaw (docs/physics.md §3.4), kg m², referred to the ball.

    Σ ½ J_act ψ̇_i² with ψ̇ = J ω_rel gives ½ ω_relᵀ (J_act JᵀJ) ω_rel, and JᵀJ = ρ² diag(3/2 cos²α,
    3/2 cos²α, 3 sin²α). Θ_W here is J_act times the diagonal *without* ρ², matching docs/physics.md's
    M11 = ... + Θ_W ρ² convention.
    """
    j_act = drivetrain.wheel_inertia + drivetrain.gear_ratio**2 * drivetrain.rotor_inertia
    alpha = math.radians(drivetrain.zenith_deg)
    return 1.5 * math.cos(alpha) ** 2 * j_act, 3.0 * math.sin(alpha) ** 2 * j_act
