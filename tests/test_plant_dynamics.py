"""Plant physics checked against physics: energy, equilibria, linearisation, instability, friction, limits."""

import math
from dataclasses import replace

import numpy as np
import pytest

from drivers.bounds import G0
from hil.run.truth_balancer import TruthBalancer, linearise_plane
from plant.anthropometry import composite, robot_body_segment, seat_rider
from plant.ballbot import Plant, plane_params
from plant.core import RiderIntent
from plant.params import Drive, RobotParams
from plant.plane import PlaneDynamics, Wrench
from plant.rider import Hold, Profile, Ramp
from plant.torso import TorsoController
from tests.helpers import NO_FRICTION, RIDER_75, deg, robot, sim


# ------------------------------------------------------------------------------------------ energy
@pytest.mark.parametrize("with_rider", [False, True], ids=["robot", "robot+limp-torso"])
def test_energy_is_conserved_without_torque_or_friction(with_rider):
    # 10 s of free motion from a tilt: the robot topples and swings (and a limp torso flails).
    plant = Plant(
        robot(friction=NO_FRICTION),
        RIDER_75 if with_rider else None,
        sim(substeps=8),
        initial_tilt=(deg(5.0), deg(-3.0)),
    )
    plant.torso = None  # no hip torque: the torso is a free pendulum on the hip
    plant.x[13] = 0.7  # and a yaw spin
    e0 = plant.energy()
    scale = abs(e0) + 1.0
    drift = 0.0
    for _ in range(4000):
        plant.step()
        drift = max(drift, abs(plant.energy() - e0))
    swing = max(abs(plant.x[1]), abs(plant.x[7]))
    assert swing > 0.5, "the check must cover large motion"
    assert drift / scale < 1e-6, f"energy drift {drift:.3g} J of {scale:.3g} J"


def test_friction_dissipates_energy():
    plant = Plant(RobotParams(), None, sim(), initial_tilt=(deg(5.0), 0.0))
    e = [plant.energy()]
    for _ in range(800):
        plant.step()
        e.append(plant.energy())
    assert e[-1] < e[0]


# --------------------------------------------------------------------------- linearisation (§2.4)
def closed_form_ab(p):
    """A, B of docs/physics.md §2.4 from the two-body parameters (COM on the axis)."""
    r, c = p.ball_radius, p.chassis
    m11 = p.ball_mass * r**2 + p.ball_inertia + c.mass * r**2 + p.wheel_inertia * p.rho**2
    m12 = c.mass * r * c.distance - p.wheel_inertia * p.rho * (1 + p.rho)
    m22 = c.inertia + c.mass * c.distance**2 + p.wheel_inertia * (1 + p.rho) ** 2
    d = m11 * m22 - m12**2
    mgl = c.mass * G0 * c.distance
    a = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [m11 * mgl / d, 0, 0, 0], [-m12 * mgl / d, 0, 0, 0]])
    b = np.array([[0], [0], [-(m11 + m12) / d], [(m22 + m12) / d]])
    return a, b, math.sqrt(m11 * mgl / d)


@pytest.mark.parametrize("rider", [None, RIDER_75], ids=["robot", "rider-lumped"])
def test_linearisation_reproduces_closed_form(rider):
    params = replace(plane_params(robot(friction=NO_FRICTION), rider, "pitch", torso=False))
    a, b = linearise_plane(params)
    a_ref, b_ref, _ = closed_form_ab(params)
    np.testing.assert_allclose(a, a_ref, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(b, b_ref, rtol=1e-6, atol=1e-9)


def test_linearisation_matches_physics_md_numbers():
    # docs/physics.md §6.1, rider 75 kg / 1.75 m: A[2,0] 35.9, A[3,0] −161.6, B = [0, 0, −0.341, 2.204].
    a, b = linearise_plane(plane_params(robot(friction=NO_FRICTION), RIDER_75, "pitch", torso=False))
    assert a[2, 0] == pytest.approx(35.9, abs=0.05)
    assert a[3, 0] == pytest.approx(-161.6, abs=0.1)
    np.testing.assert_allclose(b.ravel()[2:], [-0.341, 2.204], atol=1e-3)


def test_lumping_matches_the_worked_example():
    # docs/physics.md §5.2: lumped body 105 kg, l = 0.563 m, Θ_B = 13.2 kg m² (hip ≈ 0.089 m behind the axis).
    rob = RobotParams()
    seated = seat_rider(rob, RIDER_75)
    body = composite([robot_body_segment(rob), *seated.lower_limbs, seated.hat_segment()], "pitch")
    assert body.mass == pytest.approx(105.0)
    assert body.up == pytest.approx(0.563, abs=0.001)
    assert body.inertia == pytest.approx(13.2, abs=0.1)
    assert body.forward == pytest.approx(0.0, abs=1e-12)
    assert seated.hip_x == pytest.approx(-0.089, abs=0.001)


@pytest.mark.parametrize("plane", ["pitch", "roll"])
def test_locked_torso_equals_lumped_rider(plane):
    # Constraining γ = θ in the three-body model must give the two-body model of the lumped rider:
    # Tᵀ M₃ T = M₂ with q₃ = T q₂, and the same gravity torque.
    rob = robot(friction=NO_FRICTION)
    three = PlaneDynamics(plane_params(rob, RIDER_75, plane))
    two = PlaneDynamics(plane_params(rob, RIDER_75, plane, torso=False))
    t = np.array([[1, 0], [0, 1], [0, 1]])
    for th in (-0.3, 0.0, 0.2):
        m11, m12, m13, m22, m23, m33 = three.mass_matrix(th, th)
        m3 = np.array([[m11, m12, m13], [m12, m22, m23], [m13, m23, m33]])
        a11, a12, _, a22, _, _ = two.mass_matrix(th, th)
        np.testing.assert_allclose(t.T @ m3 @ t, [[a11, a12], [a12, a22]], rtol=1e-12)
        e3 = three.energy((0.0, th, th), (0.0, 0.0, 0.0))
        e2 = two.energy((0.0, th, th), (0.0, 0.0, 0.0))
        assert e3 == pytest.approx(e2, rel=1e-12)


# ------------------------------------------------------------------------------ equilibria (§4.2)
def theta_eq_closed_form(p, fx, fz, my, dphi_c):
    r, c = p.ball_radius, p.chassis
    a_ = c.mass * G0 * c.distance - p.top_height * fz
    b_ = p.top_height * fx
    c_ = r * fx + my - p.rolling_viscous * dphi_c
    theta = math.asin(-c_ / math.hypot(a_, b_)) - math.atan2(b_, a_)
    tau = -r * fx + (p.rolling_viscous + p.drivetrain_viscous) * dphi_c
    return theta, tau


@pytest.mark.parametrize(
    ("wrench", "theta_deg", "tau"),
    [((20.0, 0.0, 0.0), -0.99, -2.29), ((0.0, 0.0, 20.0), -1.98, 0.0), ((-30.0, 0.0, -15.0), 2.97, 3.44)],
)
def test_closed_form_equilibria_match_physics_md_table(wrench, theta_deg, tau):
    p = replace(plane_params(robot(friction=NO_FRICTION), RIDER_75, "pitch", torso=False))
    th, t = theta_eq_closed_form(p, *wrench, 0.0)
    assert math.degrees(th) == pytest.approx(theta_deg, abs=0.01)
    assert t == pytest.approx(tau, abs=0.01)


@pytest.mark.parametrize("dphi_c", [0.0, 4.0, -8.0])
@pytest.mark.parametrize(
    "wrench", [(20.0, 0.0, 0.0), (0.0, 0.0, 20.0), (-30.0, -150.0, -15.0), (15.0, 80.0, 30.0)]
)
def test_plant_rests_at_closed_form_equilibrium(wrench, dphi_c):
    # Viscous friction on (b_φ, b_ψ), Coulomb off: the closed form of §4.2 has no Coulomb term.
    fr = replace_friction(rolling_viscous=0.75, drivetrain_viscous=0.5)
    p = plane_params(robot(friction=fr), RIDER_75, "pitch", torso=False)
    dyn = PlaneDynamics(p)
    th, tau = theta_eq_closed_form(p, *wrench, dphi_c)
    acc = dyn.accelerations(th, th, dphi_c, 0.0, 0.0, tau, 0.0, Wrench(*wrench))
    assert np.abs(acc[:2]).max() < 1e-9
    # Off the equilibrium the same plant accelerates: the check can fail.
    acc_off = dyn.accelerations(th + 0.01, th + 0.01, dphi_c, 0.0, 0.0, tau, 0.0, Wrench(*wrench))
    assert abs(acc_off[1]) > 0.1


def replace_friction(**kw):
    import msgspec

    return msgspec.structs.replace(NO_FRICTION, **kw)


# ----------------------------------------------------------------------------- open-loop instability
@pytest.mark.parametrize(("rider", "pole"), [(None, 8.2), (RIDER_75, 6.0)], ids=["robot", "rider"])
def test_upright_is_unstable_with_the_expected_pole(rider, pole):
    rob = robot(friction=NO_FRICTION)
    _, _, p_closed = closed_form_ab(plane_params(rob, rider, "pitch", torso=False))
    assert p_closed == pytest.approx(pole, abs=0.1)  # docs/physics.md §6.1
    plant = Plant(rob, rider, sim(substeps=4), initial_tilt=(1e-6, 0.0))
    if rider is not None:
        plant.torso = None
        plant.planes = tuple(
            PlaneDynamics(plane_params(rob, rider, n, torso=False)) for n in ("pitch", "roll")
        )
    tilts = []
    for _ in range(int(1.2 * 400)):
        plant.step()
        tilts.append(plant.x[1])
    t = np.arange(1, len(tilts) + 1) / 400.0
    window = (t > 0.6) & (t < 1.2)
    growth = np.polyfit(t[window], np.log(np.abs(np.array(tilts)[window])), 1)[0]
    assert growth == pytest.approx(p_closed, rel=0.02)


def test_rk4_converges():
    # The default one RK4 step per 400 Hz tick agrees with eight steps on a closed-loop lean manoeuvre.
    def run(substeps):
        intent = RiderIntent(pitch=[Hold(duration=0.5), Ramp(to=20.0, duration=1.0), Hold(duration=1.5)])
        plant = Plant(RobotParams(), RIDER_75, sim(substeps=substeps), intent, initial_tilt=(deg(3.0), 0.0))
        bal = TruthBalancer(plant)
        vmax = 0.0
        for _ in range(3 * 400):
            bal.drive()
            plant.step()
            vmax = max(vmax, abs(plant.velocity[0]))
        return np.array([vmax, plant.position[0], plant.x[1], plant.x[2]])

    coarse, fine = run(1), run(8)
    np.testing.assert_allclose(coarse, fine, rtol=1e-4, atol=1e-6)


# ---------------------------------------------------------------------------------- friction
def dyn_with(**friction):
    return PlaneDynamics(plane_params(robot(friction=replace_friction(**friction)), None, "pitch"))


def test_kinetic_friction_is_viscous_plus_coulomb():
    plain = dyn_with()
    rough = dyn_with(drivetrain_viscous=0.5, drivetrain_coulomb=1.5, drivetrain_stiction=2.0)
    th, dphi, dth, tau = 0.05, 3.0, -0.4, 5.0
    a0 = np.array(plain.accelerations(th, th, dphi, dth, dth, tau, 0.0, None)[:2])
    a1 = np.array(rough.accelerations(th, th, dphi, dth, dth, tau, 0.0, None)[:2])
    # Same as the frictionless plant with the friction torque taken off the drive torque.
    f = 0.5 * (dphi - dth) + 1.5
    a_ref = np.array(plain.accelerations(th, th, dphi, dth, dth, tau - f, 0.0, None)[:2])
    np.testing.assert_allclose(a1, a_ref, rtol=1e-12)
    assert not np.allclose(a0, a1)


def test_stiction_holds_below_breakaway_and_slips_above():
    d = dyn_with(drivetrain_viscous=0.5, drivetrain_coulomb=1.5, drivetrain_stiction=4.0)

    # At rest the torque needed to keep ψ stuck grows with the drive torque; find the breakaway torque.
    def psi_acc(tau):
        ddphi, ddth, _ = d.accelerations(0.0, 0.0, 0.0, 0.0, 0.0, tau, 0.0, None)
        return ddphi - ddth

    assert psi_acc(0.5) == pytest.approx(0.0, abs=1e-12)
    assert psi_acc(-0.5) == pytest.approx(0.0, abs=1e-12)
    big = psi_acc(40.0)
    assert big > 1.0
    # Slipping: kinetic friction (1.5 Nm), not the 4 Nm breakaway.
    plain = dyn_with()
    ddphi, ddth, _ = plain.accelerations(0.0, 0.0, 0.0, 0.0, 0.0, 40.0 - 1.5, 0.0, None)
    assert big == pytest.approx(ddphi - ddth, rel=1e-9)


def test_stuck_drivetrain_keeps_encoders_still_while_robot_topples():
    # A motor torque below breakaway: the robot falls over as one rigid body, the wheels do not turn.
    fr = replace_friction(
        drivetrain_viscous=0.5, drivetrain_coulomb=1.5, drivetrain_stiction=3.0, stick_velocity=0.01
    )
    plant = Plant(robot(friction=fr), None, sim(), initial_tilt=(deg(1.0), 0.0))
    for _ in range(200):
        plant.drives.set_commands((0.01, -0.01, 0.0), True, plant.t)
        plant.step()
    angles, _ = plant.motor_angles_and_rates()
    assert abs(plant.x[1]) > deg(2.5)
    assert max(abs(a) for a in angles) < 0.01


def test_yaw_stiction_and_kinetic_friction():
    fr = replace_friction(yaw_viscous=0.5, yaw_coulomb=0.5, yaw_stiction=0.8)
    plant = Plant(robot(friction=fr), None, sim())
    assert plant._yaw_acceleration(0.0, 0.5) == pytest.approx(0.0, abs=1e-12)  # below breakaway
    acc = plant._yaw_acceleration(0.0, 5.0)
    assert acc == pytest.approx((-5.0 + 0.5) / plant.yaw_inertia)
    assert plant._yaw_acceleration(2.0, 0.0) == pytest.approx(-(0.5 * 2.0 + 0.5) / plant.yaw_inertia)


# -------------------------------------------------------------------------------------- drives
def test_torque_limit_and_current_lag():
    drive = Drive(torque_limit=3.0, current_loop_tau=0.001, watchdog_timeout=0.02)
    plant = Plant(robot(drive=drive), None, sim(fixture="clamped"))
    plant.drives.set_commands((10.0, -10.0, 1.0), True, 0.0)
    plant.drives.advance(0.001, 0.001, (0.0, 0.0, 0.0))
    # One time constant: 63 % of the limited setpoint.
    assert plant.drives.torques[0] == pytest.approx(3.0 * (1 - math.exp(-1.0)), rel=1e-9)
    for k in range(2, 11):
        held = plant.drives.advance(0.001, k * 0.001, (0.0, 0.0, 0.0))
    assert plant.drives.torques[0] <= 3.0 and plant.drives.torques[0] == pytest.approx(3.0, rel=1e-3)
    assert held[1] == pytest.approx(-3.0, rel=1e-3) and held[2] == pytest.approx(1.0, rel=1e-3)


def test_watchdog_disables_a_drive_that_stops_hearing_commands():
    plant = Plant(RobotParams(), None, sim(fixture="clamped"))
    timeout = plant.robot.drive.watchdog_timeout
    plant.drives.set_commands((1.0, 1.0, 1.0), True, 0.0)
    for _ in range(int(timeout * 400)):
        plant.step()
    assert all(m.state.name == "ENABLED" for m in plant.drives.motors)
    plant.step()
    plant.step()
    assert all(m.state.name == "WATCHDOG" for m in plant.drives.motors)
    assert plant.drives.torques == (0.0, 0.0, 0.0)
    plant.drives.set_commands((1.0, 1.0, 1.0), True, plant.t)  # a fresh command re-arms
    plant.step()
    assert plant.drives.torques[0] > 0.0


def test_disable_and_garbage_commands_give_zero_torque():
    plant = Plant(RobotParams(), None, sim(fixture="clamped"))
    plant.drives.set_commands((2.0, 2.0, 2.0), False, 0.0)
    plant.step()
    assert plant.drives.torques == (0.0, 0.0, 0.0)
    plant.drives.set_commands((float("nan"), 2.0, 2.0), True, plant.t)
    plant.step()
    assert plant.drives.torques[0] == 0.0 and plant.drives.motors[0].state.name == "DISABLED"
    assert plant.drives.torques[1] > 0.0


def test_motor_torques_reach_the_ball_through_the_omniwheel_map():
    plant = Plant(RobotParams(), None, sim(fixture="clamped"))
    motor = np.array([1.0, -0.5, 0.25])
    for _ in range(40):
        plant.drives.set_commands(tuple(motor), True, plant.t)
        plant.step()
    g = np.array(plant._g)
    np.testing.assert_allclose(plant.ball_torque, g.T @ np.array(plant.drives.torques), rtol=1e-12)
    np.testing.assert_allclose(plant.drives.torques, motor, rtol=1e-6)


# --------------------------------------------------------------------------------------- falls
def test_fall_is_detected_without_a_controller():
    plant = Plant(RobotParams(), RIDER_75, sim(), initial_tilt=(deg(2.0), 0.0))
    for _ in range(4 * 400):
        plant.step()
        if plant.fallen:
            break
    assert plant.fallen and plant.fallen.startswith("tilt beyond 30 deg")
    assert abs(plant.x[1]) > deg(30.0)


def test_leaving_the_floor_envelope_is_a_fall():
    plant = Plant(RobotParams(), None, sim(floor_half_x=0.5))
    bal = TruthBalancer(plant)
    bal.set_velocity(1.0)
    for _ in range(6 * 400):
        bal.drive()
        plant.step()
        if plant.fallen:
            break
    assert plant.fallen and plant.fallen.startswith("left the floor envelope")
    assert abs(plant.x[1]) < deg(30.0)


def test_without_permission_drives_ignore_commands_until_a_fresh_one():
    plant = Plant(RobotParams(), None, sim(fixture="clamped"))
    plant.drives.set_commands((1.0, 1.0, 1.0), True, 0.0)
    plant.step()
    assert plant.drives.powered
    plant.drives.set_permission(False)
    assert not plant.drives.powered and plant.drives.torques == (0.0, 0.0, 0.0), "off at once"
    plant.drives.set_commands((2.0, 2.0, 2.0), True, plant.t)  # queued while not permitted: never applied
    plant.step()
    assert plant.drives.torques == (0.0, 0.0, 0.0)
    plant.drives.set_permission(True)
    plant.step()
    assert not plant.drives.powered, "permission alone starts nothing"
    plant.drives.set_commands((1.0, 1.0, 1.0), True, plant.t)
    plant.step()
    assert plant.drives.powered and plant.drives.torques[0] > 0.0


def _balanced(speed: float) -> tuple[Plant, TruthBalancer]:
    plant = Plant(RobotParams(), RIDER_75, sim())
    bal = TruthBalancer(plant)
    bal.set_velocity(speed)
    for _ in range(4 * 400):
        bal.drive()
        plant.step()
    assert plant.fallen is None and plant.drives.powered
    return plant, bal


def test_power_off_at_standstill_comes_to_rest():
    plant, _ = _balanced(0.0)
    plant.drives.set_permission(False)
    position = plant.position[0]
    for _ in range(3 * 400):
        plant.step()
    assert plant.resting and plant.fallen is None
    assert plant.velocity == (0.0, 0.0) and plant.position[0] == pytest.approx(position, abs=1e-3)


def test_power_off_in_motion_tips_over():
    plant, _ = _balanced(1.0)
    plant.drives.set_permission(False)
    for _ in range(3 * 400):
        plant.step()
        if plant.fallen:
            break
    assert not plant.resting and plant.fallen and "tilt" in plant.fallen


def test_rest_ends_when_a_drive_is_powered_again():
    plant, bal = _balanced(0.0)
    plant.drives.set_permission(False)
    plant.step()
    plant.step()
    assert plant.resting
    plant.drives.set_permission(True)
    for _ in range(2 * 400):
        bal.drive()
        plant.step()
    assert not plant.resting and plant.fallen is None and plant.drives.powered


def test_the_rider_holds_their_torso_against_gravity_within_capability():
    # On its command (upright, at rest) the hip torque is the torso's own gravity compensation; far off it
    # the PD saturates at the rider's capability.
    mass, com = 30.0, 0.3
    torso = TorsoController(RIDER_75, mass, com, Profile())
    assert torso.hip_torque(0.1, 0.0, 0.0) == pytest.approx(-G0 * mass * com * math.sin(0.1))
    assert torso.hip_torque(0.0, -1.0, 0.0) == RIDER_75.max_hip_torque
