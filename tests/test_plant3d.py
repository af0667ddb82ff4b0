"""The 3-D plant (plant/ballbot3d.py) checked against physics that does not come from its engine: the planar
model where the two must agree (small angles, no yaw), Newton-Euler balances of a steady turn, the
kinematics of body rates, energy, rolling, and the omniwheel map (docs/physics.md §11)."""

from __future__ import annotations

import math

import msgspec
import mujoco
import numpy as np
import pytest
from scipy.optimize import brentq

from drivers.bounds import G0
from drivers.config import ConfigError, load_toml
from drivers.rotations import euler_rates
from hil.run.truth_balancer import TruthBalancer
from plant.anthropometry import (
    TRUNK_EXTENSION_DEG,
    TRUNK_FLEXION_DEG,
    TRUNK_LATERAL_DEG,
    robot_body_segment,
)
from plant.ballbot import Plant
from plant.ballbot3d import Plant3D
from plant.core import RiderIntent
from plant.model3d import drive_inertia
from plant.omniwheel import motor_jacobian
from plant.params import RobotParams, SimParams
from plant.rider import Hold, Ramp, Sine
from tests.helpers import NO_FRICTION, RIDER_75, ROOT, deg, robot, sim

DT = 1.0 / 400.0
DEBUG = False


def plant3d(rob=None, rider=RIDER_75, intent=None, tilt=(0.0, 0.0), cls=Plant3D, **sim_fields):
    return cls(rob or robot(), rider, sim(plant="3d", **sim_fields), intent, tilt)


class MujocoTurnsTheChassis(Plant3D):
    """The positive control of the attitude checks: the chassis turned as MuJoCo composes it (a subclass,
    not a patch: the compiled build's class cannot be patched)."""

    def _turn_chassis_by_its_rate(self) -> None:
        pass


# ------------------------------------------------------------------ agreement with the planar model
def hold_yaw(plant, yaw, rate, kp=2000.0, kd=100.0):
    """A stiff yaw hold through the drives: the planar split assumes yaw decoupled, so compare there."""
    inv = np.linalg.inv(np.array(plant._g).T)
    plant.drives.set_commands(tuple((inv @ [0.0, 0.0, kp * yaw + kd * rate]).tolist()), True, plant.t)


def planar_poles(rider):
    def step(x):
        p = Plant(robot(friction=NO_FRICTION), rider, sim())
        p.x[:] = x
        hold_yaw(p, p.x[12], p.x[13])
        p.step()
        return np.array(p.x)

    eps, n = 1e-6, 14
    jac = np.column_stack([(step(eps * e) - step(-eps * e)) / (2 * eps) for e in np.eye(n)])
    return continuous_poles(jac)


def poles_3d(rider, hold=True):
    """Poles of the 3-D plant's tick by central differences; hold: the yaw held by the drives."""
    base = plant3d(robot(friction=NO_FRICTION), rider)
    m, nv, q0 = base.model, base.model.nv, base.data.qpos.copy()

    def step(dx):
        p = plant3d(robot(friction=NO_FRICTION), rider)
        q = q0.copy()
        mujoco.mj_integratePos(m, q, dx[:nv], 1.0)
        p.data.qpos[:], p.data.qvel[:] = q, dx[nv:]
        mujoco.mj_forward(m, p.data)
        p._state = p._read_state()
        if hold:
            hold_yaw(p, p.yaw, p.truth().yaw_rate)
        p.step()
        out = np.zeros(2 * nv)
        mujoco.mj_differentiatePos(m, out[:nv], 1.0, q0, p.data.qpos)
        out[nv:] = p.data.qvel
        return out

    eps = 1e-6
    jac = np.column_stack([(step(eps * e) - step(-eps * e)) / (2 * eps) for e in np.eye(2 * nv)])
    return continuous_poles(jac)


def continuous_poles(jac):
    mu = np.linalg.eigvals(jac)
    lam = np.log(mu[np.abs(mu) > 1e-9].astype(complex)) / DT
    # The tilt and torso modes (6-9 1/s); not the neutral ones (position, heading), the yaw hold's (above
    # 20 1/s) or the contact's own (above 80 1/s).
    return sorted((z for z in lam if 1.0 < abs(z) < 15.0), key=lambda z: (-z.real, z.imag))


@pytest.mark.parametrize("rider", [None, RIDER_75], ids=["robot", "robot+rider"])
def test_linearised_poles_agree_with_the_planar_plant(rider):
    planar, spatial = planar_poles(rider), poles_3d(rider)
    assert len(planar) == len(spatial), (planar, spatial)
    for a, b in zip(planar, spatial, strict=True):
        assert abs(b - a) <= 0.02 * abs(a), (planar, spatial)
    assert planar[0].real > 5.0, "the upright is unstable in both"


def balanced_step(make, plane, degrees=2.0, seconds=2.0):
    tilt = (deg(degrees), 0.0) if plane == "pitch" else (0.0, deg(degrees))
    plant = make(tilt)
    balancer = TruthBalancer(plant)
    k = 0 if plane == "pitch" else 1
    out = []
    for _ in range(int(seconds * 400)):
        balancer.drive()
        plant.step()
        out.append(plant.truth().tilt[k])
    return np.array(out)


@pytest.mark.parametrize("plane", ["pitch", "roll"])
def test_tilt_step_response_agrees_with_the_planar_plant(plane):
    planar = balanced_step(lambda t: Plant(robot(), RIDER_75, sim(), initial_tilt=t), plane)
    spatial = balanced_step(lambda t: plant3d(tilt=t), plane)
    assert np.abs(planar).max() > deg(1.9) and abs(planar[-1]) < deg(0.2), "a step the balancer recovers"
    assert np.abs(spatial - planar).max() < 0.02 * deg(2.0)


def test_a_held_tilt_loads_the_seat_with_the_riders_weight():
    # On the stand (clamped) at a tilt, after the torso settles: the seat carries the weight of the torso
    # and the thighs, moved to P, in body axes. The planar plant agrees except about z: it leaves out the
    # moment of the weight's sideways part at the hip's and the thighs' offsets along x.
    tilt = (deg(3.0), deg(-2.0))
    spatial = plant3d(tilt=tilt, fixture="clamped")
    planar = Plant(robot(), RIDER_75, sim(fixture="clamped"), initial_tilt=tilt)
    for _ in range(400):
        spatial.step()
        planar.step()
    (att_p, _, acc_p), (att_s, _, acc_s) = planar.imu_truth(), spatial.imu_truth()
    np.testing.assert_allclose(att_s[:2], att_p[:2], atol=5e-4)  # the stand gives a little
    np.testing.assert_allclose(acc_s, acc_p, atol=0.01)
    seated, top = spatial.seated, spatial.robot.body.top_height
    gravity = (rot_y(tilt[0]) @ rot_x(tilt[1])).T @ [0.0, 0.0, -G0]  # in body axes
    force, moment = np.zeros(3), np.zeros(3)
    for s in (seated.hat_segment(), *seated.thighs):
        f = s.mass * gravity
        force += f
        moment += np.cross([s.x, s.y, s.z - top], f)
    wrench = np.array(spatial.seat_wrench())
    np.testing.assert_allclose(wrench, [*force, *moment], rtol=0.005, atol=0.05)
    np.testing.assert_allclose(wrench[:5], planar.seat_wrench()[:5], rtol=0.005, atol=0.1)
    assert abs(wrench[5]) > 0.5, "the moment the planar plant leaves out"


# ------------------------------------------------------------------------------------- energy
def free_plant(tilt, rates, **sim_fields) -> Plant3D:
    """The robot and a limp rider in free motion, without friction, gravity or the floor: what is left is
    the model's inertias and joints. `rates(nv)`: every joint's rate at the start, rad/s or m/s."""
    plant = plant3d(robot(friction=NO_FRICTION), tilt=tilt, **sim_fields)
    plant.torso = None
    m, d = plant.model, plant.data
    m.opt.gravity[:] = 0.0
    m.geom_conaffinity[:] = 0
    m.jnt_limited[:] = 0  # the trunk's stops are soft constraints, which take energy at each hit
    d.qvel[:] = rates(m.nv)
    mujoco.mj_forward(m, d)
    return plant


def hanging_plant(friction) -> Plant3D:
    """The robot without a rider hanging from its ball through the floor (only the ball touches it),
    swinging from a tilt of 150°, its contact settled under the swinging load."""
    plant = plant3d(robot(friction=friction), rider=None, tilt=(deg(150.0), deg(-20.0)))
    m = plant.model
    m.geom_contype[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "chassis_rim")] = 0
    plant._settle()  # the plant settled the ball with the rim, below the floor here, carrying it
    for _ in range(10):  # the contact finds its depth under the swinging load
        plant.step()
    return plant


def test_energy_is_conserved_without_friction_or_inputs():
    # 10 s of free motion: ball and chassis turning apart about every axis, the limp torso flailing, all of
    # it spinning.
    plant = free_plant((deg(20.0), deg(-20.0)), lambda nv: np.linspace(-1.5, 1.5, nv))
    e0 = plant.energy()
    drift = swing = 0.0
    for _ in range(4000):
        plant.step()
        drift = max(drift, abs(plant.energy() - e0))
        swing = max(swing, abs(plant.truth().lean[0]))
    assert swing > 1.0, "the check covers large motion"
    assert drift < 0.01 * e0, f"energy drift {drift:.3g} J of {e0:.3g} J"


def test_on_the_floor_energy_never_grows_and_friction_takes_it():
    # The same robot hanging from its ball through the floor (only the ball touches it), swinging: MuJoCo's
    # soft contact takes a little (docs/physics.md §11.4), friction takes more, nothing adds any.
    def swing(friction):
        plant = hanging_plant(friction)
        e, kinetic = [plant.energy()], 0.0
        for _ in range(2000):
            plant.step()
            e.append(plant.energy())
            kinetic = max(kinetic, float(plant.data.energy[1]))
        return np.array(e), kinetic

    (free, kinetic), (rough, _) = swing(NO_FRICTION), swing(RobotParams().friction)
    assert kinetic > 5.0, "a swing of a few joules"
    assert np.maximum.accumulate(free).max() - free[0] < 0.005 * kinetic, "nothing adds energy"
    assert free[0] - free[-1] < 0.15 * kinetic
    assert rough[0] - rough[-1] > 3.0 * (free[0] - free[-1])


def test_friction_dissipates_energy():
    plant = plant3d(rider=None, tilt=(deg(5.0), 0.0))
    e = [plant.energy()]
    for _ in range(200):
        plant.step()
        e.append(plant.energy())
    assert e[-1] < e[0] - 1.0


# ------------------------------------------------------------------------------- a steady turn
def steady_turn(rider, speed, yaw_rate, seconds=6.0, each=None, cls=Plant3D):
    """Hold a speed and a yaw rate on the true state; the rider (if any) stays upright on a stiff trunk.
    each(plant): called after every tick."""
    if rider is not None:
        rider = msgspec.structs.replace(rider, trunk_stiffness=2.0e4, trunk_damping=400.0)
    plant = plant3d(robot(friction=NO_FRICTION), rider=rider, cls=cls)
    balancer = TruthBalancer(plant, yaw_gains=(60.0, 0.0))
    balancer.yaw_rate_command = yaw_rate
    lateral = 0.0
    rows = []
    for i in range(int(seconds * 400)):
        _, left = plant.truth().velocity
        lateral += 2.0 * left * DT  # integral action: no side slip of the heading in the steady state
        ramp = min(1.0, i / 800)
        balancer.set_velocity(speed * ramp, -lateral)
        balancer.drive()
        plant.step()
        if each is not None:
            each(plant)
        truth = plant.truth()
        rows.append((truth.tilt[1], truth.tilt[0], math.hypot(*truth.velocity), truth.yaw_rate))
    rows = np.array(rows)
    if __debug__ and DEBUG:
        for i in range(0, len(rows), 200):
            print(i / 400, rows[i])
    return plant, rows[-400:].mean(axis=0), rows[-400:].std(axis=0)


def rigid_bodies(plant):
    """Mass, COM and inertia about the COM (chassis frame, from the ball centre) of everything above the
    ball, from the parameters alone: the robot body with the drives' share, the rider's segments."""
    robot_, drives = plant.robot, drive_inertia(plant.robot)
    segs = [robot_body_segment(robot_)]
    if plant.seated is not None:
        segs += [*plant.seated.lower_limbs, plant.seated.hat_segment()]
    mass = sum(s.mass for s in segs)
    com = sum(np.array([s.x, s.y, s.z]) * s.mass for s in segs) / mass
    inertia = np.diag(drives.chassis)
    for s in segs:
        d = np.array([s.x, s.y, s.z]) - com
        inertia = (
            inertia + np.diag([s.i_roll, s.i_pitch, s.i_yaw]) + s.mass * (d @ d * np.eye(3) - np.outer(d, d))
        )
    return mass, com, inertia


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def roll_moment(plant, roll, pitch, speed, yaw_rate):
    """Newton-Euler about the ball's contact point, along the heading's forward axis, for a rigid robot in
    a steady turn: Σ r × m(a − g) + Σ Ḣ (moments of the floor's forces about their point vanish)."""
    mass, com, inertia = rigid_bodies(plant)
    r = plant.robot.ball.radius
    turn_radius = speed / yaw_rate  # of the ball centre; the turn's centre is at +y (a left turn)
    rot = rot_y(pitch) @ rot_x(roll)
    p = rot @ com + np.array([0.0, 0.0, r])  # from the contact point, heading frame
    a = np.array([-(yaw_rate**2) * p[0], yaw_rate**2 * (turn_radius - p[1]), 0.0])  # towards the centre
    force = mass * (a - np.array([0.0, 0.0, -G0]))
    moment = np.cross(p, force)[0]
    w = np.array([0.0, 0.0, yaw_rate])
    moment += np.cross(w, rot @ inertia @ rot.T @ w)[0]
    # The ball: its centre circles at the turn radius; it rolls forward and precesses with the heading.
    ball_mass, ball_inertia = (
        plant.robot.ball.mass,
        plant.robot.ball.inertia + drive_inertia(plant.robot).ball,
    )
    ball_a = np.array([0.0, yaw_rate**2 * turn_radius, 0.0])
    moment += np.cross([0.0, 0.0, r], ball_mass * (ball_a + np.array([0.0, 0.0, G0])))[0]
    moment += np.cross(w, ball_inertia * np.array([0.0, speed / r, 0.0]))[0]
    return moment


@pytest.mark.parametrize("rider", [None, RIDER_75], ids=["robot", "robot+rider"])
def test_a_steady_turn_leans_as_newton_euler_says(rider):
    speed, yaw_rate = 1.0, 0.8
    plant, (roll, pitch, v, r), spread = steady_turn(rider, speed, yaw_rate)
    assert spread[0] < deg(0.05) and abs(r - yaw_rate) < 0.05 and abs(v - speed) < 0.05, "a steady turn"
    predicted = brentq(lambda phi: roll_moment(plant, phi, pitch, v, r), -0.5, 0.5)
    assert roll == pytest.approx(predicted, rel=0.02)
    # Into the turn (toward +y: a negative roll), by about atan(v ψ̇ / g) and more: the pivot sits at the
    # ball's centre, above the floor, and the ball's own precession needs a moment too.
    naive = math.atan(v * r / G0)
    assert 1.0 < -roll / naive < 1.6


def test_the_gyro_carries_the_yaw_rate_times_the_tilt():
    # Body rates are not Euler rates: in a steady turn with lean φ the gyro's y axis reads ψ̇ sin φ cos θ.
    plant, (roll, pitch, _, yaw_rate), _ = steady_turn(None, 1.0, 0.8)
    _, gyro, _ = plant.imu_truth()
    expected_y = yaw_rate * math.sin(roll) * math.cos(pitch)
    assert abs(expected_y) > 0.05
    assert gyro[1] == pytest.approx(expected_y, rel=0.02)
    assert gyro[0] == pytest.approx(-yaw_rate * math.sin(pitch), abs=0.01)
    assert gyro[2] == pytest.approx(yaw_rate * math.cos(roll) * math.cos(pitch), rel=0.01)


def attitude_drift(cls=Plant3D):
    """In a steady turn at 1 m/s and 1.5 rad/s (robot alone), over the last second: how fast the gyro's
    rates as Euler rates run from the attitude's own, (roll, pitch, yaw) rad/s."""
    attitude, rates = [], []

    def record(plant):
        (roll, pitch, yaw), gyro, _ = plant.imu_truth()
        attitude.append((roll, pitch, yaw))
        rates.append(euler_rates(gyro, roll, pitch))

    _, (_, _, speed, yaw_rate), _ = steady_turn(None, 1.0, 1.5, seconds=4.0, each=record, cls=cls)
    assert speed == pytest.approx(1.0, abs=0.02) and yaw_rate == pytest.approx(1.5, abs=0.02)
    return drift_rate(attitude[-400:], rates[-400:])


def drift_rate(attitude, rates):
    """How fast the attitude runs from the integral of its rates (rad/s per column): the slope of their
    difference, so whatever the motion does in the window falls out."""
    attitude, rates = np.array(attitude), np.array(rates)
    integral = np.vstack([np.zeros(rates.shape[1]), np.cumsum(0.5 * (rates[1:] + rates[:-1]) * DT, axis=0)])
    t = np.arange(len(attitude)) * DT
    return -np.polyfit(t, attitude - attitude[0] - integral, 1)[0]


def test_the_attitude_turns_at_the_gyros_rate_in_a_fast_turn():
    # The IMU's attitude and its gyro come from one rigid body, so they agree on average. MuJoCo turning
    # the ball and then the chassis on it drifts the attitude by h/2 ω_ball × ω_rel (8 mrad/s here) unless
    # the plant keeps the chassis' turn its own.
    assert np.abs(attitude_drift()).max() < 0.5e-3
    # Positive control: MuJoCo's own composition drifts.
    assert np.abs(attitude_drift(MujocoTurnsTheChassis)).max() > 4e-3


def wire_attitude_drift(cls=Plant3D):
    """attitude_drift's check from the IMU's CAN frames (noise, bias and the DBC's scaling, through
    cantools), roll and pitch over the last two seconds: the gyro's turn-on bias (0.1 mrad/s, 1σ) and its
    1 mrad/s resolution are in it."""
    import cantools

    db = cantools.database.load_file(ROOT / "configs/can/pure.dbc")
    attitude_frame, rate_frame = db.get_message_by_name("IMU_ATTITUDE"), db.get_message_by_name("IMU_RATE")
    attitude, rates = [], []

    def record(plant):
        imu = plant.sample_imu()
        roll, pitch, yaw = imu.attitude
        a = attitude_frame.decode(
            attitude_frame.encode(
                {"Roll": roll, "Pitch": pitch, "Yaw": yaw, "Valid": 1, "Counter": 0, "Crc": 0}
            )
        )
        x, y, z = imu.rate
        r = rate_frame.decode(
            rate_frame.encode({"RateX": x, "RateY": y, "RateZ": z, "Valid": 1, "Counter": 0, "Crc": 0})
        )
        attitude.append((a["Roll"], a["Pitch"]))
        rates.append(euler_rates((r["RateX"], r["RateY"], r["RateZ"]), a["Roll"], a["Pitch"])[:2])

    steady_turn(None, 1.0, 1.5, seconds=5.0, each=record, cls=cls)
    return drift_rate(attitude[-800:], rates[-800:])


def test_the_attitude_on_the_wire_turns_at_the_gyros_rate():
    assert np.abs(wire_attitude_drift()).max() < 0.5e-3
    assert np.abs(wire_attitude_drift(MujocoTurnsTheChassis)).max() > 4e-3  # positive control, as above


# -------------------------------------------------------------------------------------- rolling
MANOEUVRE = RiderIntent(
    pitch=[Hold(duration=0.5), Ramp(to=10.0, duration=1.0), Hold(duration=2.0)],
    roll=[Hold(duration=1.0), Sine(amplitude=8.0, frequency_hz=0.5, duration=3.0)],
)


def ride(plant, speed=1.2, yaw_rate=0.8, seconds=4.0):
    """Speed up over a second to `speed` while turning at `yaw_rate`, the rider leaning as scripted."""
    balancer = TruthBalancer(plant)
    balancer.yaw_rate_command = yaw_rate
    for i in range(int(seconds * 400)):
        balancer.set_velocity(speed * min(1.0, i / 400))
        balancer.drive()
        plant.step()
    return plant


def test_the_ball_rolls_without_slip_in_ordinary_riding():
    plant = ride(plant3d(intent=MANOEUVRE))
    assert plant.fallen is None
    assert plant.max_slip < 1e-3
    assert plant.slip_ticks == 0


def test_the_ball_slips_past_the_friction_limit():
    slippery = robot(ball=msgspec.structs.replace(RobotParams().ball, floor_friction=0.03))
    plant = ride(plant3d(slippery, intent=MANOEUVRE), seconds=2.0)
    assert plant.slip_ticks > 40
    assert plant.max_slip > 0.05


# ---------------------------------------------------------------------------- the floor's contact
@pytest.mark.parametrize("time_constant", [0.005, 0.01])
def test_the_floor_contact_has_the_configured_time_constant(time_constant):
    # MuJoCo mixes the two geoms' solref: the floor's must be the bench's too, or the contact is softer.
    engine = msgspec.structs.replace(sim().mujoco, contact_time_constant=time_constant)
    plant = plant3d(rider=None, mujoco=engine)
    plant.step()
    (contact,) = plant.data.contact
    assert tuple(contact.solref) == (time_constant, 1.0)


# ----------------------------------------------------------------------------- the drives' friction
def spin_in_the_air(friction, torque, seconds=0.5):
    """The chassis held 0.3 m up, the ball free to turn under it: a constant ball-equivalent torque
    (chassis frame) across the drives. Returns the relative rate (chassis frame) every tick."""
    plant = plant3d(robot(friction=msgspec.structs.replace(friction, rolling_viscous=0.0)), rider=None)
    m, d = plant.model, plant.data
    d.qpos[2] += 0.3
    mujoco.mj_forward(m, d)
    plant._hold()
    d.eq_active[plant._holds[0]] = 0  # only the chassis
    motor = np.linalg.solve(np.array(plant._g).T, torque)
    rates = []
    for _ in range(int(seconds * 400)):
        plant.drives.set_commands(tuple(motor.tolist()), True, plant.t)
        plant.step()
        rates.append(-d.qvel[plant._drive_v : plant._drive_v + 3].copy())  # the ball's on the chassis
    return plant, np.array(rates)


def air_inertia(plant):
    """The ball's inertia about its centre with the chassis held, the drives' share with it (model3d)."""
    drives = drive_inertia(plant.robot)
    return plant.robot.ball.inertia + drives.ball + np.array(drives.armature)


STICKY = msgspec.structs.replace(
    RobotParams().friction, drivetrain_coulomb=1.0, drivetrain_stiction=2.0, yaw_coulomb=0.5, yaw_stiction=0.8
)


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0)], ids=["tilt", "yaw"])
def test_a_torque_below_breakaway_holds_the_drives_and_one_above_turns_them(axis):
    axis = np.array(axis)
    tilt = axis[2] == 0.0
    breakaway = STICKY.drivetrain_stiction if tilt else STICKY.yaw_stiction
    stick = STICKY.stick_velocity
    _, held = spin_in_the_air(STICKY, 0.8 * breakaway * axis)
    assert np.abs(held).max() < stick, "stuck: it creeps within the stick band"
    # Positive control: the same torque with the breakaway lowered under it turns the ball.
    lower = {"drivetrain_stiction": 0.7 * breakaway} if tilt else {"yaw_stiction": 0.7 * breakaway}
    lower |= {"drivetrain_coulomb": 0.5 * breakaway} if tilt else {"yaw_coulomb": 0.5 * breakaway}
    _, moved = spin_in_the_air(msgspec.structs.replace(STICKY, **lower), 0.8 * breakaway * axis)
    assert np.abs(moved[-1]).max() > 20 * stick


@pytest.mark.parametrize("direction", [0.0, 45.0, 120.0])
def test_sliding_drives_take_the_kinetic_torque_in_every_direction(direction):
    # Past breakaway the ball speeds up at (T − τ_c − b ω) / I along the torque, whatever its direction in
    # the tilt plane (MuJoCo's per-axis frictionloss would take √2 τ_c on a diagonal).
    a = math.radians(direction)
    u = np.array([math.cos(a), math.sin(a), 0.0])
    torque = 3.0
    plant, rates = spin_in_the_air(STICKY, torque * u)
    f = STICKY
    inertia = air_inertia(plant)[0]
    along = rates @ u
    assert np.abs(rates - np.outer(along, u)).max() < 1e-6 * along[-1]
    # From 0.25 s (the current loop has settled): the rate of change against the torque balance.
    t0, t1 = 100, 199
    mean_rate = along[t0 : t1 + 1].mean()
    slope = (along[t1] - along[t0]) / ((t1 - t0) * DT)
    expected = (torque - f.drivetrain_coulomb - f.drivetrain_viscous * mean_rate) / inertia
    assert slope == pytest.approx(expected, rel=0.02)


# ------------------------------------------------------------------------------- the omniwheels
def test_encoders_count_the_3d_omniwheel_map():
    plant = plant3d(rider=None)
    w_rel = np.array([0.3, -0.7, 1.1])  # the ball relative to the chassis, chassis frame
    plant.data.qvel[plant._drive_v : plant._drive_v + 3] = -w_rel  # the joint's is the chassis' on the ball
    mujoco.mj_forward(plant.model, plant.data)
    plant._state = plant._read_state()
    _, rates = plant.motor_angles_and_rates()
    np.testing.assert_allclose(rates, motor_jacobian(plant.robot.ball.radius, plant.robot.drivetrain) @ w_rel)


def test_a_motor_torque_turns_the_ball_about_its_axis():
    # Gravity and the floor off: motor 1 alone turns ball and chassis apart about G_1, and its power
    # T ω equals the rate of the kinetic energy.
    plant = plant3d(robot(friction=NO_FRICTION), rider=None)
    plant.model.opt.gravity[:] = 0.0
    plant.model.geom_conaffinity[:] = 0
    mujoco.mj_forward(plant.model, plant.data)
    e0 = plant.energy()
    for _ in range(40):
        plant.drives.set_commands((1.0, 0.0, 0.0), True, plant.t)
        plant.step()
    angles, _ = plant.motor_angles_and_rates()
    assert angles[0] > 0.0
    g = motor_jacobian(plant.robot.ball.radius, plant.robot.drivetrain)
    w_rel = -plant.data.qvel[plant._drive_v : plant._drive_v + 3]
    assert np.dot(w_rel, g[0]) > 0.0
    work = 1.0 * angles[0]  # the current loop's lag makes the torque a little less than 1 Nm at first
    assert plant.energy() - e0 == pytest.approx(work, rel=0.05)


# ----------------------------------------------------------------------------------- falls, holds
def test_a_fall_is_the_first_contact_with_the_floor():
    plant = plant3d(tilt=(deg(1.0), 0.0))
    while plant.fallen is None and plant.t < 3.0:
        plant.step()
    assert plant.fallen is not None and "foot" in plant.fallen
    tilt = plant.truth().tilt[0]
    # Where the toe meets the floor, from the seated rider's geometry (docs/physics.md §11.3).
    seated, r = plant.seated, plant.robot.ball.radius
    leg = seated.legs[0]
    from plant.model3d import FOOT_LENGTH, FOOT_RADIUS

    knee = seated.hip_z - leg.z
    toe = np.array([leg.x + 0.75 * FOOT_LENGTH, leg.z + knee - knee / 0.606])
    touch = brentq(lambda a: toe[1] * math.cos(a) - toe[0] * math.sin(a) - FOOT_RADIUS + r, 0.0, 1.0)
    assert tilt == pytest.approx(touch, abs=deg(1.5))
    assert tilt < plant.sim.fall_tilt


def test_the_clamped_fixture_holds_the_chassis_while_the_torso_leans():
    intent = RiderIntent(pitch=[Ramp(to=20.0, duration=1.0), Hold(duration=1.0)])
    spatial = plant3d(intent=intent, fixture="clamped")
    planar = Plant(robot(), RIDER_75, sim(fixture="clamped"), intent)
    for _ in range(800):
        spatial.step()
        planar.step()
    truth = spatial.truth()
    assert max(abs(a) for a in truth.tilt) < deg(0.05)
    assert truth.lean[0] == pytest.approx(deg(20.0), abs=deg(0.3))
    np.testing.assert_allclose(spatial.seat_wrench(), planar.seat_wrench(), rtol=0.02, atol=1.0)


def limp_lean(joint, start, limited=True):
    """The torso limp on the clamped fixture, let go from `start` rad at hinge `joint` (0: forward, 1:
    sideways): where it ends after 2 s, and its farthest, deg."""
    plant = plant3d(fixture="clamped")
    plant.torso = None
    m, d = plant.model, plant.data
    if not limited:
        m.jnt_limited[:] = 0
    q = plant._lean_q[joint]
    d.qpos[q] = start
    mujoco.mj_forward(m, d)
    peak = 0.0
    for _ in range(800):
        plant.step()
        peak = max(peak, abs(float(d.qpos[q])))
    return math.degrees(float(d.qpos[q])), math.degrees(peak)


@pytest.mark.parametrize(
    ("joint", "start", "stop"),
    [(0, 0.1, TRUNK_FLEXION_DEG), (0, -0.1, -TRUNK_EXTENSION_DEG), (1, 0.1, TRUNK_LATERAL_DEG)],
    ids=["forward", "back", "sideways"],
)
def test_a_limp_torso_stops_where_a_seated_trunk_stops_bending(joint, start, stop):
    end, peak = limp_lean(joint, start)
    assert end == pytest.approx(stop, abs=1.0)
    assert peak < abs(stop) + 3.0
    # Positive control: without the stops it folds over past the seat.
    _, peak = limp_lean(joint, start, limited=False)
    assert peak > 90.0


def test_power_off_at_standstill_rests_and_power_on_releases():
    plant = plant3d()
    balancer = TruthBalancer(plant)
    for _ in range(200):
        balancer.drive()
        plant.step()
    plant.drives.set_permission(False)
    for _ in range(400):
        plant.step()
    assert plant.resting and plant.fallen is None
    assert max(abs(a) for a in plant.truth().tilt) < deg(1.0)
    plant.drives.set_permission(True)
    for _ in range(200):
        balancer.drive()
        plant.step()
    assert not plant.resting and plant.fallen is None


def test_runs_are_deterministic():
    def run():
        plant = ride(plant3d(intent=MANOEUVRE), seconds=1.0)
        return [plant.truth(), plant.sample_imu(), plant.sample_drives(), plant.sample_tes()]

    assert repr(run()) == repr(run())


# ------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("[body]\ninertia_pitch = 0.1\ninertia_roll = 0.1\ninertia_yaw = 0.5\n", "$.body"),
        ("[drivetrain]\nwheel_radius = 0.2\n[ball]\nradius = 0.05\n", "ball.radius"),
        ("[friction]\nrolling_viscous = -1.0\n", "$.friction.rolling_viscous"),
        ("[ball]\nfloor_friction = 0.0\n", "$.ball.floor_friction"),
        ("[drive]\nstall_torque = 2.0\n", "$.drive"),  # below the current limit: never reached
        ("[drive]\nno_load_speed = 400.0\n", "$.drive.no_load_speed"),  # beyond the wire's ±327.67
    ],
)
def test_an_impossible_robot_is_refused_naming_the_field(tmp_path, text, field):
    path = tmp_path / "robot.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_toml(path, RobotParams)
    assert str(path) in str(err.value) and field in str(err.value)


def test_an_integrator_the_plant_cannot_honour_is_refused(tmp_path):
    # RK4 integrates damping explicitly (the drives' stuck band needs it implicit) and MuJoCo's RK4 cannot
    # start from the plant's reused forward pass: refused, not silently an Euler step.
    path = tmp_path / "sim.toml"
    path.write_text('[mujoco]\nintegrator = "RK4"\n')
    with pytest.raises(ConfigError) as err:
        load_toml(path, SimParams)
    assert str(path) in str(err.value) and "$.mujoco.integrator" in str(err.value)


def test_both_plants_place_the_bodies_alike():
    # The poses the recordings draw: the planar plant's from its angles, the 3-D plant's from its engine.
    tilt = (deg(6.0), deg(-3.0))
    spatial, planar = plant3d(tilt=tilt), Plant(robot(), RIDER_75, sim(), initial_tilt=tilt)
    a, b = spatial.poses(), planar.poses()
    for body in ("chassis", "torso"):
        np.testing.assert_allclose(a[body][0], b[body][0], atol=1e-3)  # the soft contact's sink
        np.testing.assert_allclose(a[body][1], b[body][1], atol=1e-9)
    assert {"ball", "chassis", "torso", "thigh_left", "shank_right"} <= set(a)


# ------------------------------------------------------------------------------- the drives' top speed
def spin_up(drive, seconds=3.0):
    """The chassis held in the air, no friction anywhere, every drive told its whole current limit one way:
    the three motor speeds every tick. With nothing to turn against, a motor stops accelerating only where
    its back-EMF takes the whole bus voltage: at its no-load speed, from below."""
    plant = plant3d(robot(friction=NO_FRICTION, drive=drive), rider=None)
    m, d = plant.model, plant.data
    d.qpos[2] += 0.3
    mujoco.mj_forward(m, d)
    plant._hold()
    d.eq_active[plant._holds[0]] = 0  # only the chassis
    speeds = []
    for _ in range(int(seconds * 400)):
        plant.drives.set_commands((drive.torque_limit,) * 3, True, plant.t)
        plant.step()
        speeds.append(plant.motor_angles_and_rates()[1])
    return np.array(speeds)


def test_a_motor_with_nothing_to_turn_against_stops_at_its_no_load_speed():
    drive = RobotParams().drive
    top = drive.no_load_speed
    speeds = spin_up(drive)
    assert speeds.max() <= top * (1 + 1e-3), "past the speed its back-EMF allows only by a tick's step"
    assert np.all(np.abs(speeds[-1] / top - 1.0) < 1e-3), speeds[-1]
    # Below the corner the current limit rules (the stall torque is above it): the speed rises by equal
    # steps; past it by ever smaller ones (the line), the last of them nothing.
    corner = top * (1.0 - drive.torque_limit / drive.stall_torque)
    steps = np.diff(speeds[:, 0])
    below = steps[1 : int(np.argmax(speeds[:, 0] > corner)) - 1]
    assert len(below) >= 3 and np.ptp(below) < 0.01 * below.mean(), below
    assert np.ptp(speeds[-40:, 0]) < 1e-3 * top
    # Positive control: a motor whose line lies beyond the wire's range keeps accelerating past it.
    fast = msgspec.structs.replace(drive, stall_torque=1000.0, no_load_speed=327.0)
    assert spin_up(fast, seconds=3.0)[-1].min() > 1.05 * top


def test_braking_keeps_the_whole_current_limit_at_the_top_speed():
    from plant.drives import MotorDrive

    drive = MotorDrive(RobotParams().drive)
    top, limit = drive.params.no_load_speed, drive.params.torque_limit
    assert 0.0 < drive.available(limit, 0.999 * top) < 0.01 * limit, "driving: almost nothing left"
    assert drive.available(limit, 1.01 * top) < 0.0, "past the top speed the current reverses: a brake"
    assert drive.available(limit, 2.0 * top) == -limit, "within the current limit"
    assert drive.available(-limit, 0.999 * top) == -limit, "braking: the back-EMF helps the bus"
    assert drive.available(limit, -top) == limit and drive.available(-limit, -0.5 * top) == -limit
    assert drive.available(-limit, -0.9 * top) == pytest.approx(-0.1 * drive.params.stall_torque)
