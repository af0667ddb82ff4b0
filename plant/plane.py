"""One vertical plane of the ballbot: ball, chassis (with lumped lower limbs), optionally the rider's torso.

Coordinates q = [φ, θ, γ] (docs/physics.md §5.3, generalised to off-axis COMs):
  φ  ball rotation (rolling: x = r_K φ), θ absolute chassis tilt, γ absolute torso (HAT) angle.
The chassis COM sits at distance l_B and angle δ_B from the body axis, the hip at h_H and δ_H; the HAT COM
is d_H from the hip along the torso. Lagrange's equations give M(q) q̈ + h(q, q̇) + G(q) = Q with

  M11 = m_K r² + Θ_K + (m_B + m_H) r² + Θ_W ρ²
  M12 = r (m_B l_B cos(θ+δ_B) + m_H h_H cos(θ+δ_H)) − Θ_W ρ (1+ρ)
  M13 = m_H d_H r cos γ
  M22 = Θ_B + m_B l_B² + m_H h_H² + Θ_W (1+ρ)²
  M23 = m_H h_H d_H cos(θ + δ_H − γ)
  M33 = I_H + m_H d_H²
  h   = [−r (m_B l_B sin(θ+δ_B) + m_H h_H sin(θ+δ_H)) θ̇² − m_H d_H r sin γ γ̇²,
          m_H h_H d_H sin(θ+δ_H−γ) γ̇²,
         −m_H h_H d_H sin(θ+δ_H−γ) θ̇²]
  G   = [0, −g (m_B l_B sin(θ+δ_B) + m_H h_H sin(θ+δ_H)), −g m_H d_H sin γ]
  Q   = [τ − b_φ φ̇ − f_ψ + r F_x,  −τ − u_h + f_ψ + h_P (F_x cos θ − F_z sin θ) + M_y,  u_h]

τ is the drive torque on the ball (reaction on the chassis), u_h the rider's hip torque on the torso,
f_ψ the drivetrain friction on ψ = φ − θ, (F_x, F_z, M_y) an external wrench on the chassis at P (world
axes). `tests/test_plant_derivation.py` re-derives all of this with sympy. Without a torso the model is the
two-body ballbot of docs/physics.md §2 (rider absent or lumped into the chassis).

The roll plane uses the same equations in (φ_x, θ_x, γ_x), rotations about +x: forward is −y.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from drivers.bounds import G0
from plant.anthropometry import Composite

STICK_TIME_CONSTANT = 0.005
"""While stuck, residual ψ̇ inside the Karnopp band decays with this time constant, s."""


@dataclass(frozen=True, slots=True)
class PlaneParams:
    ball_radius: float
    ball_mass: float
    ball_inertia: float
    rho: float
    wheel_inertia: float
    """Θ_W of this plane (docs/physics.md §3.4)."""
    chassis: Composite
    """Chassis + lower limbs (+ the rigid rider when there is no torso body)."""
    top_height: float
    """h_P, where external wrenches act, m."""
    hat_mass: float
    """m_H; 0 without a torso body."""
    hat_com_distance: float
    """d_H, hip to HAT COM, m."""
    hat_inertia: float
    """I_H about the HAT COM in this plane, kg m²."""
    hip_forward: float
    hip_up: float
    rolling_viscous: float
    drivetrain_viscous: float
    drivetrain_coulomb: float
    drivetrain_stiction: float
    stick_velocity: float


@dataclass(slots=True)
class Wrench:
    """External wrench on the chassis at P, world axes of the plane: force forward and up (N), moment (Nm)."""

    forward: float = 0.0
    up: float = 0.0
    moment: float = 0.0


HipPolicy = Callable[[float, float, float], float]
"""Rider policy: (torso angle γ, lean γ − θ, lean rate) -> hip torque on the torso."""


class PlaneDynamics:
    """Equations of motion of one plane, evaluated on plain floats (the hot path of the plant)."""

    def __init__(self, p: PlaneParams):
        self.p = p
        r = p.ball_radius
        c = p.chassis
        m_h, d_h = p.hat_mass, p.hat_com_distance
        h_h = math.hypot(p.hip_forward, p.hip_up)
        self.has_torso = m_h > 0.0
        self.d_b = c.offset_angle
        self.d_h = math.atan2(p.hip_forward, p.hip_up)
        self.m11 = p.ball_mass * r * r + p.ball_inertia + (c.mass + m_h) * r * r + p.wheel_inertia * p.rho**2
        self.a_b = r * c.mass * c.distance
        self.a_h = r * m_h * h_h
        self.m12_wheel = -p.wheel_inertia * p.rho * (1.0 + p.rho)
        self.k13 = m_h * d_h * r
        self.m22 = c.inertia + c.mass * c.distance**2 + m_h * h_h**2 + p.wheel_inertia * (1.0 + p.rho) ** 2
        self.k23 = m_h * h_h * d_h
        self.m33 = p.hat_inertia + m_h * d_h * d_h
        self.g_b = G0 * c.mass * c.distance
        self.g_h = G0 * m_h * h_h
        self.g_hd = G0 * m_h * d_h
        self.h_h = h_h
        self.r_ball, self.h_top = r, p.top_height
        self.b_phi, self.b_psi = p.rolling_viscous, p.drivetrain_viscous
        self.tau_c, self.tau_s, self.v_stick = p.drivetrain_coulomb, p.drivetrain_stiction, p.stick_velocity

    # -------------------------------------------------------------------------------------------------
    def mass_matrix(self, th: float, ga: float) -> tuple[float, float, float, float, float, float]:
        m12 = self.a_b * math.cos(th + self.d_b) + self.a_h * math.cos(th + self.d_h) + self.m12_wheel
        m13 = self.k13 * math.cos(ga)
        m23 = self.k23 * math.cos(th + self.d_h - ga)
        return self.m11, m12, m13, self.m22, m23, self.m33

    def accelerations(
        self,
        th: float,
        ga: float,
        dphi: float,
        dth: float,
        dga: float,
        tau: float,
        u_hip: float,
        ext: Wrench | None,
    ) -> tuple[float, float, float]:
        """q̈ for the state and inputs, with Karnopp stick-slip friction on ψ = φ − θ."""
        # Hot path: plain floats and locals only (a tick evaluates this ~20 times).
        sin, cos = math.sin, math.cos
        a_b, a_h, k13, k23 = self.a_b, self.a_h, self.k13, self.k23
        tb, th_h, rel = th + self.d_b, th + self.d_h, th + self.d_h - ga
        s_b, s_h, sg, sa = sin(tb), sin(th_h), sin(ga), sin(rel)
        m11, m22, m33 = self.m11, self.m22, self.m33
        m12 = a_b * cos(tb) + a_h * cos(th_h) + self.m12_wheel
        dth2, dga2 = dth * dth, dga * dga

        r1 = tau - self.b_phi * dphi + (a_b * s_b + a_h * s_h) * dth2 + k13 * sg * dga2
        r2 = -tau - u_hip - k23 * sa * dga2 + self.g_b * s_b + self.g_h * s_h
        r3 = u_hip + k23 * sa * dth2 + self.g_hd * sg
        if ext is not None:
            r1 += self.r_ball * ext.forward
            r2 += self.h_top * (ext.forward * cos(th) - ext.up * sin(th)) + ext.moment

        if self.has_torso:
            m13, m23 = k13 * cos(ga), k23 * cos(rel)
            c11 = m22 * m33 - m23 * m23
            c12 = m13 * m23 - m12 * m33
            c13 = m12 * m23 - m13 * m22
            k = 1.0 / (m11 * c11 + m12 * c12 + m13 * c13)
            i11, i12, i13 = c11 * k, c12 * k, c13 * k
            i22, i23, i33 = (
                (m11 * m33 - m13 * m13) * k,
                (m12 * m13 - m11 * m23) * k,
                (m11 * m22 - m12 * m12) * k,
            )
        else:
            k = 1.0 / (m11 * m22 - m12 * m12)
            i11, i12, i13, i22, i23, i33 = m22 * k, -m12 * k, 0.0, m11 * k, 0.0, 0.0

        # Drivetrain friction enters as −f on φ and +f on θ, i.e. r −= d f with d = [1, −1, 0].
        dpsi = dphi - dth
        if -self.v_stick < dpsi < self.v_stick:
            # Torque that keeps ψ stuck (ψ̈ = −ψ̇/T), clamped at breakaway.
            dminv_r = (i11 - i12) * r1 + (i12 - i22) * r2 + (i13 - i23) * r3
            f = (dminv_r + dpsi / STICK_TIME_CONSTANT) / (i11 - 2.0 * i12 + i22)
            if not -self.tau_s <= f <= self.tau_s:
                f = math.copysign(self.tau_c, f) + self.b_psi * dpsi
        else:
            f = self.b_psi * dpsi + math.copysign(self.tau_c, dpsi)
        r1 -= f
        r2 += f

        ddth = i12 * r1 + i22 * r2 + i23 * r3
        return (
            i11 * r1 + i12 * r2 + i13 * r3,
            ddth,
            i13 * r1 + i23 * r2 + i33 * r3 if self.has_torso else ddth,
        )

    def rk4_step(
        self, s: list[float], h: float, tau: float, hip: HipPolicy | None, ext: Wrench | None
    ) -> list[float]:
        """One RK4 step of [φ, θ, γ, φ̇, θ̇, γ̇] under a held drive torque; hip(γ, lean, lean rate) -> u_h."""
        acc = self.accelerations
        phi, th, ga, dphi, dth, dga = s
        hh = 0.5 * h
        u = hip(ga, ga - th, dga - dth) if hip else 0.0
        a1, b1, c1 = acc(th, ga, dphi, dth, dga, tau, u, ext)
        th2, ga2, dphi2, dth2, dga2 = (
            th + hh * dth,
            ga + hh * dga,
            dphi + hh * a1,
            dth + hh * b1,
            dga + hh * c1,
        )
        u = hip(ga2, ga2 - th2, dga2 - dth2) if hip else 0.0
        a2, b2, c2 = acc(th2, ga2, dphi2, dth2, dga2, tau, u, ext)
        th3, ga3, dphi3, dth3, dga3 = (
            th + hh * dth2,
            ga + hh * dga2,
            dphi + hh * a2,
            dth + hh * b2,
            dga + hh * c2,
        )
        u = hip(ga3, ga3 - th3, dga3 - dth3) if hip else 0.0
        a3, b3, c3 = acc(th3, ga3, dphi3, dth3, dga3, tau, u, ext)
        th4, ga4, dphi4, dth4, dga4 = th + h * dth3, ga + h * dga3, dphi + h * a3, dth + h * b3, dga + h * c3
        u = hip(ga4, ga4 - th4, dga4 - dth4) if hip else 0.0
        a4, b4, c4 = acc(th4, ga4, dphi4, dth4, dga4, tau, u, ext)
        h6 = h / 6.0
        return [
            phi + h6 * (dphi + 2.0 * (dphi2 + dphi3) + dphi4),
            th + h6 * (dth + 2.0 * (dth2 + dth3) + dth4),
            ga + h6 * (dga + 2.0 * (dga2 + dga3) + dga4),
            dphi + h6 * (a1 + 2.0 * (a2 + a3) + a4),
            dth + h6 * (b1 + 2.0 * (b2 + b3) + b4),
            dga + h6 * (c1 + 2.0 * (c2 + c3) + c4),
        ]

    def rk4_step_clamped(self, s: list[float], h: float, hip: HipPolicy | None) -> list[float]:
        """RK4 of the torso alone with the chassis held upright and still (the `clamped` fixture)."""
        phi, th, ga, _, _, dga = s
        hh = 0.5 * h

        def f(g: float, dg: float) -> float:
            return self.clamped_torso_acceleration(g, hip(g, g - th, dg) if hip else 0.0)

        c1 = f(ga, dga)
        c2 = f(ga + hh * dga, dga + hh * c1)
        c3 = f(ga + hh * (dga + hh * c1), dga + hh * c2)
        c4 = f(ga + h * (dga + hh * c2), dga + h * c3)
        h6 = h / 6.0
        ga_next = ga + h6 * (dga + 2.0 * ((dga + hh * c1) + (dga + hh * c2)) + (dga + h * c3))
        return [phi, th, ga_next, 0.0, 0.0, dga + h6 * (c1 + 2.0 * (c2 + c3) + c4)]

    def clamped_torso_acceleration(self, ga: float, u_hip: float) -> float:
        """γ̈ with the chassis held upright and still (the `clamped` fixture): only the torso moves."""
        if not self.has_torso:
            return 0.0
        return (u_hip + self.g_hd * math.sin(ga)) / self.m33

    def energy(self, q: tuple[float, float, float], dq: tuple[float, float, float]) -> float:
        """Kinetic + potential energy (zero potential at the ball centre's height), J."""
        _, th, ga = q
        dphi, dth, dga = dq
        m11, m12, m13, m22, m23, m33 = self.mass_matrix(th, ga)
        if not self.has_torso:
            m13 = m23 = m33 = 0.0
        kinetic = 0.5 * (
            m11 * dphi * dphi
            + m22 * dth * dth
            + m33 * dga * dga
            + 2.0 * (m12 * dphi * dth + m13 * dphi * dga + m23 * dth * dga)
        )
        potential = (
            self.g_b * math.cos(th + self.d_b) + self.g_h * math.cos(th + self.d_h) + self.g_hd * math.cos(ga)
        )
        return kinetic + potential

    def torso_load(
        self,
        th: float,
        ga: float,
        dth: float,
        dga: float,
        ddphi: float,
        ddth: float,
        ddga: float,
        u_hip: float,
    ) -> tuple[float, float, float]:
        """Wrench of the torso on the chassis, moved to P, in body axes: (forward N, up N, moment Nm).

        Newton-Euler on the HAT (docs/physics.md §5.3): hip carries F = m_H (g⃗ − a_cH) and the reaction −u_h
        of the hip torque; the moment arm from P to the hip adds r × F.
        """
        if not self.has_torso:
            return 0.0, 0.0, 0.0
        a = th + self.d_h
        sa, ca = math.sin(a), math.cos(a)
        sg, cg = math.sin(ga), math.cos(ga)
        d = self.p.hat_com_distance
        ax = (
            self.p.ball_radius * ddphi
            + self.h_h * (ca * ddth - sa * dth * dth)
            + d * (cg * ddga - sg * dga * dga)
        )
        az = -self.h_h * (sa * ddth + ca * dth * dth) - d * (sg * ddga + cg * dga * dga)
        m = self.p.hat_mass
        fx, fz = -m * ax, -m * (G0 + az)
        st, ct = math.sin(th), math.cos(th)
        f_fwd = fx * ct - fz * st
        f_up = fx * st + fz * ct
        moment = -u_hip + (self.p.hip_up - self.p.top_height) * f_fwd - self.p.hip_forward * f_up
        return f_fwd, f_up, moment
