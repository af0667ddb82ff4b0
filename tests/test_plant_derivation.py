"""The plane's runtime equations of motion equal a fresh Lagrangian derivation (sympy), off-axis COMs too."""

from dataclasses import replace

import numpy as np
import pytest

from drivers.bounds import G0
from plant.ballbot import plane_params
from plant.params import RiderParams, RobotParams
from plant.plane import PlaneDynamics, Wrench

sp = pytest.importorskip("sympy")


def lagrangian_model():
    t = sp.symbols("t")
    r, m_k, i_k, rho, i_w = sp.symbols("r m_K Theta_K rho Theta_W", positive=True)
    m_b, l_b, d_b, i_b = sp.symbols("m_B l_B delta_B Theta_B")
    m_h, h_h, d_h, dist, i_h, h_p, g = sp.symbols("m_H h_H delta_H d_H I_H h_P g")
    tau, u, fx, fz, my = sp.symbols("tau u F_x F_z M_y")
    phi, th, ga = (sp.Function(n)(t) for n in ("phi", "theta", "gamma"))
    q = [phi, th, ga]
    dq = [sp.diff(v, t) for v in q]

    def kinetic_point(mass, x, z):
        return sp.Rational(1, 2) * mass * (sp.diff(x, t) ** 2 + sp.diff(z, t) ** 2)

    x_b, z_b = r * phi + l_b * sp.sin(th + d_b), l_b * sp.cos(th + d_b)
    hip_x, hip_z = r * phi + h_h * sp.sin(th + d_h), h_h * sp.cos(th + d_h)
    x_h, z_h = hip_x + dist * sp.sin(ga), hip_z + dist * sp.cos(ga)
    kinetic = (
        sp.Rational(1, 2) * (m_k * r**2 + i_k) * dq[0] ** 2
        + kinetic_point(m_b, x_b, z_b)
        + sp.Rational(1, 2) * i_b * dq[1] ** 2
        + kinetic_point(m_h, x_h, z_h)
        + sp.Rational(1, 2) * i_h * dq[2] ** 2
        + sp.Rational(1, 2) * i_w * (dq[1] - rho * (dq[0] - dq[1])) ** 2
    )
    potential = g * (m_b * z_b + m_h * z_h)
    lag = kinetic - potential
    # Generalised forces by virtual work: drive torque on ψ = φ − θ, hip torque on γ − θ, wrench at P.
    x_p, z_p = r * phi + h_p * sp.sin(th), h_p * sp.cos(th)
    work_rate = (
        tau * (dq[0] - dq[1]) + u * (dq[2] - dq[1]) + fx * sp.diff(x_p, t) + fz * sp.diff(z_p, t) + my * dq[1]
    )
    forces = [sp.diff(work_rate, v) for v in dq]
    ddq = sp.symbols("a0:3")
    eom = []
    for v, dv, f in zip(q, dq, forces, strict=True):
        expr = sp.diff(sp.diff(lag, dv), t) - sp.diff(lag, v) - f
        expr = expr.subs({sp.diff(w, t, 2): a for w, a in zip(q, ddq, strict=True)})
        eom.append(expr)
    states = sp.symbols("th ga dphi dth dga")
    subs = {dq[0]: states[2], dq[1]: states[3], dq[2]: states[4]}
    subs2 = {th: states[0], ga: states[1]}
    eom = [e.subs(subs).subs(subs2) for e in eom]
    mass = sp.Matrix([[sp.diff(e, a) for a in ddq] for e in eom])
    rest = sp.Matrix([e.subs({a: 0 for a in ddq}) for e in eom])
    params = (r, m_k, i_k, rho, i_w, m_b, l_b, d_b, i_b, m_h, h_h, d_h, dist, i_h, h_p, g)
    inputs = (tau, u, fx, fz, my)
    return sp.lambdify((states, params, inputs), (mass, rest), "numpy")


@pytest.fixture(scope="module")
def model():
    return lagrangian_model()


def frictionless(plane):
    p = plane_params(RobotParams(), RiderParams(name="t", mass=75.0, height=1.75), plane)
    return replace(
        p, rolling_viscous=0.0, drivetrain_viscous=0.0, drivetrain_coulomb=0.0, drivetrain_stiction=0.0
    )


@pytest.mark.parametrize("plane", ["pitch", "roll"])
def test_runtime_eom_matches_lagrangian(model, plane):
    p = frictionless(plane)
    dyn = PlaneDynamics(p)
    assert dyn.has_torso and (plane == "roll" or abs(dyn.d_b) > 0.01)  # pitch exercises off-axis COMs
    params = (
        p.ball_radius,
        p.ball_mass,
        p.ball_inertia,
        p.rho,
        p.wheel_inertia,
        p.chassis.mass,
        p.chassis.distance,
        dyn.d_b,
        p.chassis.inertia,
        p.hat_mass,
        dyn.h_h,
        dyn.d_h,
        p.hat_com_distance,
        p.hat_inertia,
        p.top_height,
        G0,
    )
    rng = np.random.default_rng(1)
    for _ in range(50):
        th, ga = rng.uniform(-0.6, 0.6, 2)
        dphi, dth, dga = rng.uniform(-3.0, 3.0, 3)
        tau, u, fx, fz, my = rng.uniform(-40.0, 40.0, 5)
        mass, rest = model((th, ga, dphi, dth, dga), params, (tau, u, fx, fz, my))
        expected = np.linalg.solve(np.array(mass, dtype=float), -np.array(rest, dtype=float).ravel())
        got = dyn.accelerations(th, ga, dphi, dth, dga, tau, u, Wrench(fx, fz, my))
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
