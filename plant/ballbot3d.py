"""PURE + rider in 3-D: rigid bodies simulated by MuJoCo (docs/physics.md §11, the model: plant/model3d.py).

The ball rolls on the floor with finite friction, the chassis rides on it with three rotational degrees of
freedom, the omniwheel motors act through the exact 3-D map, and the rider's torso leans forward and
sideways on the seat. Drives, sensors' noise and the rider's control are the planar plant's (plant/drives.py,
plant/sensors.py, plant/torso.py): what changes is the mechanics underneath. Deterministic for a seed; no
clock, no I/O: the caller owns time by calling `step()`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco
import numpy as np
from mypy_extensions import mypyc_attr

from drivers.rotations import euler_rates, euler_zyx, quaternion_zyx
from plant.core import PITCH, ROLL, PlantCore, Pose, Truth
from plant.model3d import (
    BALL,
    CHASSIS,
    DRIVE_JOINT,
    FALL_GEOMS,
    FLOOR,
    HIPS,
    HOLDS,
    LEAN_JOINTS,
    MAX_SINK,
    MOTORS,
    P_SITE,
    TORSO,
    apply_dof_parameters,
    build_model,
)
from plant.params import RobotParams

SLIP_SPEED = 0.01
"""m/s of the ball's contact point over the floor beyond which a tick counts as slipping."""

Pair = tuple[float, float]
Triple = tuple[float, float, float]


class Motion(NamedTuple):
    """What a tick's outputs read of MuJoCo's state, read once per tick (pairs are (pitch, roll) or
    (forward, left) in the heading frame)."""

    attitude: Triple
    """ZYX (roll, pitch, yaw) of the chassis, yaw within ±π."""
    tilt_rate: Pair
    """Euler rates of pitch and roll, rad/s."""
    yaw_rate: float
    velocity: Pair
    """Ball centre, heading frame, m/s."""
    ball_rate: Pair
    """The ball's rotation rate about the heading's y (pitch) and x (roll) axes, rad/s."""
    position: Pair
    """Ball centre in the world (x, y) from the start, m."""
    gyro: Triple
    accel: Triple
    lean: Pair
    lean_rate: Pair
    slip: float
    """Speed of the ball's contact point over the floor, m/s."""

    @property
    def tilt(self) -> Pair:
        return self.attitude[1], self.attitude[0]


class StickSlip(NamedTuple):
    """Dry and viscous friction across the drive joint about one direction, ball-equivalent (the robot
    file's values, as the planar plant reads them), as the damping MuJoCo integrates implicitly.

    Stuck (rate below `stick`): a damping of breakaway / stick, so the torque that holds the joint reaches
    the breakaway torque at the band's edge and a torque T below it leaves a creep of T/breakaway × stick at
    most. Sliding: viscous + kinetic / rate, the kinetic torque exactly, and, implicit, it can slow the joint
    to rest within a step but never turn it back (an explicit Coulomb torque chatters about zero)."""

    viscous: float
    kinetic: float
    breakaway: float
    stick: float

    def damping(self, rate: float) -> float:
        """Nm s/rad at |rate| (rad/s)."""
        if rate < self.stick:
            return self.viscous + self.breakaway / self.stick
        return self.viscous + self.kinetic / rate


class DriveFriction(NamedTuple):
    """The drives' friction (docs/physics.md §11.2): in the tilt plane on the relative rate's magnitude, so
    the same in every direction (MuJoCo's per-axis `frictionloss` is a box, √2 times as strong on a
    diagonal), and about yaw."""

    tilt: StickSlip
    yaw: StickSlip

    @staticmethod
    def of(robot: RobotParams) -> DriveFriction:
        f = robot.friction
        return DriveFriction(
            StickSlip(f.drivetrain_viscous, f.drivetrain_coulomb, f.drivetrain_stiction, f.stick_velocity),
            StickSlip(f.yaw_viscous, f.yaw_coulomb, f.yaw_stiction, f.stick_velocity),
        )


@mypyc_attr(allow_interpreted_subclasses=True)  # benchmarks/lockstep.py times its step in a subclass
class Plant3D(PlantCore):
    """PURE ballbot + rider in 3-D. Per tick: `drives.set_commands(...)`, `step()`, then sample or read
    `truth()`, as the planar plant."""

    def _build_mechanics(self, initial_tilt: tuple[float, float]) -> None:
        robot, rider, sim = self.robot, self.rider, self.sim
        info = build_model(robot, rider, sim.mujoco, sim.dt)
        self.model_xml = info.xml
        self.model = m = mujoco.MjModel.from_xml_string(info.xml)
        apply_dof_parameters(m, robot)
        # No tick reads the energy: `energy()` computes it when asked, and MuJoCo's steps skip it.
        m.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_ENERGY)
        self.data = d = mujoco.MjData(m)
        self._steps = sim.mujoco.steps_per_tick

        def obj(kind: mujoco.mjtObj, name: str) -> int:
            return int(mujoco.mj_name2id(m, kind, name))

        joint = mujoco.mjtObj.mjOBJ_JOINT
        self._ball_body = obj(mujoco.mjtObj.mjOBJ_BODY, BALL)
        self._chassis_body = obj(mujoco.mjtObj.mjOBJ_BODY, CHASSIS)
        self._drive_q = int(m.jnt_qposadr[obj(joint, DRIVE_JOINT)])
        self._drive_v = int(m.jnt_dofadr[obj(joint, DRIVE_JOINT)])
        self._motors = [obj(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in MOTORS]
        self._holds = [obj(mujoco.mjtObj.mjOBJ_EQUALITY, n) for n in HOLDS]
        self._p_site = obj(mujoco.mjtObj.mjOBJ_SITE, P_SITE)
        self._floor = obj(mujoco.mjtObj.mjOBJ_GEOM, FLOOR)
        self._fall_geoms = {obj(mujoco.mjtObj.mjOBJ_GEOM, n): n for n in FALL_GEOMS if n in info.xml}
        self._body_names = [(b, mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)) for b in range(1, m.nbody)]
        # Views of MuJoCo's arrays, made once: its buffers never move, and an attribute of MjData builds a
        # new array object on every access (the tick reads a dozen).
        self._qpos, self._qvel, self._ctrl = d.qpos, d.qvel, d.ctrl
        self._sensordata = d.sensordata
        self._xmat = d.xmat.reshape(-1)  # flat: row b of MuJoCo's (nbody, 9) at 9 b
        self._actuator_velocity, self._actuator_force = d.actuator_velocity, d.actuator_force
        self._cfrc_int = d.cfrc_int.reshape(-1)
        self._site_xpos, self._subtree_com = d.site_xpos.reshape(-1), d.subtree_com.reshape(-1)
        self._radius = robot.ball.radius
        self._floor_z = float(m.geom_pos[self._floor][2])
        motors = self._motors
        self._motor_1, self._motor_2, self._motor_3 = motors[0], motors[1], motors[2]
        self._friction = DriveFriction.of(robot)
        self._drive_damping = m.dof_damping[self._drive_v : self._drive_v + 3]
        self._chassis_quat = d.xquat[self._chassis_body]
        self._h = float(m.opt.timestep)
        self._torso_body = -1
        self._lean_q: list[int] = []
        self._lean_v: list[int] = []
        self._hips: list[int] = []
        self._rider_bodies: list[int] = []
        if rider is not None:
            self._torso_body = obj(mujoco.mjtObj.mjOBJ_BODY, TORSO)
            self._lean_q = [int(m.jnt_qposadr[obj(joint, n)]) for n in LEAN_JOINTS]
            self._lean_v = [int(m.jnt_dofadr[obj(joint, n)]) for n in LEAN_JOINTS]
            self._hips = [obj(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in HIPS]
            thighs = [obj(mujoco.mjtObj.mjOBJ_BODY, f"thigh_{s}") for s in ("left", "right")]
            self._rider_bodies = [self._torso_body, *thighs]
        self._ball_xmat = 9 * self._ball_body
        self._chassis_xmat = 9 * self._chassis_body
        self._torso_xmat = 9 * self._torso_body

        self._yaw = self._last_yaw = 0.0
        """The heading, unwrapped (MuJoCo's orientation gives it within ±π)."""
        pitch, roll = initial_tilt
        d.qpos[3:7] = quaternion_zyx(roll, pitch, 0.0)  # the ball turned with the chassis: encoders read zero
        mujoco.mj_kinematics(m, d)
        self._set_drive_friction()  # at rest: stuck
        self._set_hip_controls()  # the rider holds their torso from the start
        self._settle()
        self._forward_current = True
        self.motor_angles = [0.0, 0.0, 0.0]
        """Motor-shaft angles from power-up (the encoders' counts), rad."""
        self._motor_rates = [0.0, 0.0, 0.0]
        self.ball_angle = [0.0, 0.0]
        """The ball's rotation in the heading frame (pitch: about heading y, roll: about heading x), rad."""
        self.slip_ticks = 0
        """Ticks whose contact point slid faster than SLIP_SPEED over the floor."""
        self.max_slip = 0.0
        """The fastest slide of the ball's contact point over the floor so far, m/s."""
        self._state = self._read_state()
        if self.clamped:
            self._hold()

    def _settle(self) -> None:
        """Sink the ball into the floor's soft contact until it carries the robot's weight (the vertical
        acceleration at rest is zero), so the first tick starts at rest, not dropping."""
        m, d = self.model, self.data
        r = self.robot.ball.radius
        low, high = r - MAX_SINK, r
        for _ in range(60):
            d.qpos[2] = 0.5 * (low + high)
            mujoco.mj_forward(m, d)
            if d.qacc[2] > 0.0:
                low = d.qpos[2]
            else:
                high = d.qpos[2]
        d.qpos[2] = 0.5 * (low + high)
        mujoco.mj_forward(m, d)

    # ------------------------------------------------------------------------------------------ one tick
    def step(self) -> None:
        """Advance one tick: the rider decides, drives act (ZOH + current lag), MuJoCo steps, fall check."""
        self._rider_decides()
        self._update_rest()
        m, d = self.model, self.data
        motor = self.drives.advance(self.dt, self.t + self.dt, self._motor_rates)
        ctrl = self._ctrl
        ctrl[self._motor_1] = motor[0]
        ctrl[self._motor_2] = motor[1]
        ctrl[self._motor_3] = motor[2]
        self.ball_torque = self._ball_torque(motor)
        self._set_hip_controls()
        self._apply_external()
        before = self._motor_rates
        if self._forward_current:  # the last tick's closing forward pass holds this state's forces
            mujoco.mj_step2(m, d)
            self._after_step()
            steps = self._steps - 1
        else:
            steps = self._steps
        for _ in range(steps):
            mujoco.mj_step(m, d)
            self._after_step()
        mujoco.mj_forward(m, d)
        self._forward_current = True
        self.tick += 1
        self.t = self.tick * self.dt
        self._outputs_tick = self._wrench_tick = -1
        self._state = self._read_state()
        after = self._motor_rates
        half = 0.5 * self.dt
        for i in range(3):
            self.motor_angles[i] += half * (before[i] + after[i])
        self._check_fall()

    def _after_step(self) -> None:
        """After each MuJoCo step: the chassis turned by its own rate, and the drives' friction for the next
        step."""
        self._turn_chassis_by_its_rate()
        self._set_drive_friction()

    def _set_drive_friction(self) -> None:
        """The drives' friction for the next step, from the drive joint's rates now (DriveFriction)."""
        f, rates = self._friction, self._qvel[self._drive_v : self._drive_v + 3].tolist()
        damping = self._drive_damping
        damping[0] = damping[1] = f.tilt.damping(math.hypot(rates[0], rates[1]))
        damping[2] = f.yaw.damping(abs(rates[2]))

    def _turn_chassis_by_its_rate(self) -> None:
        """Make the step's turn of the chassis exp(h ω_c), ω_c its own rate at the step's end (the gyro's).

        MuJoCo turns the ball by its rate and the chassis on it by the drive joint's, one after the other;
        the chassis' turn then differs from its own rate's by h/2 ω_ball × ω_rel, a drift of its attitude
        against its gyro that grows with speed times yaw rate (2.6 mrad/s at 0.64 m/s and 0.96 rad/s, above
        the gyro's modelled bias). The joint's angle is seen by nothing (a sphere, the encoders count rates),
        so it takes the difference."""
        q, v, dq, dv = self._qpos, self._qvel, self._drive_q, self._drive_v
        # Python floats: a third of the time of MuJoCo's quaternion functions on numpy views.
        rw, rx, ry, rz = q[dq : dq + 4].tolist()  # the chassis on the ball
        bw, bx, by, bz = q[3:7].tolist()  # the ball in the world
        ax, ay, az = v[3:6].tolist()  # the ball's rate, its frame
        # The chassis' rate, its frame: the ball's turned by the joint's inverse, plus the joint's.
        tx, ty, tz = 2.0 * (rz * ay - ry * az), 2.0 * (rx * az - rz * ax), 2.0 * (ry * ax - rx * ay)
        ux, uy, uz = v[dv : dv + 3].tolist()
        wx = ax + rw * tx + rz * ty - ry * tz + ux
        wy = ay + rw * ty + rx * tz - rz * tx + uy
        wz = az + rw * tz + ry * tx - rx * ty + uz
        # The chassis before the step (the step's kinematics) turned by exp(h ω_c).
        cw, cx, cy, cz = self._chassis_quat.tolist()
        rate = math.sqrt(wx * wx + wy * wy + wz * wz)
        if rate > 0.0:
            half = 0.5 * self._h * rate
            k = math.sin(half) / rate
            ew, ex, ey, ez = math.cos(half), wx * k, wy * k, wz * k
            cw, cx, cy, cz = (
                cw * ew - cx * ex - cy * ey - cz * ez,
                cw * ex + cx * ew + cy * ez - cz * ey,
                cw * ey - cx * ez + cy * ew + cz * ex,
                cw * ez + cx * ey - cy * ex + cz * ew,
            )
        # The joint: the ball's inverse times the chassis.
        q[dq : dq + 4] = (
            bw * cw + bx * cx + by * cy + bz * cz,
            bw * cx - bx * cw - by * cz + bz * cy,
            bw * cy + bx * cz - by * cw - bz * cx,
            bw * cz - bx * cy + by * cx - bz * cw,
        )

    def _set_hip_controls(self) -> None:
        """The rider's hip torques for this tick: the engine adds the PD's terms in the lean's state."""
        m, ctrl = self.model, self._ctrl
        if self.torso is not None:
            gammas = self._torso_angles()
            for k in (PITCH, ROLL):
                ctrl[self._hips[k]] = self.torso[k].hip_feedforward(gammas[k])
        elif self._hips and not self._limp:
            # No torso control (tests set torso to None): the hips go limp, no stiffness, no damping.
            for a in self._hips:
                m.actuator_biasprm[a, :3] = 0.0
                ctrl[a] = 0.0
            self._limp = True

    def _ball_torque(self, motor: tuple[float, float, float]) -> tuple[float, float, float]:
        g = self._g
        return (
            g[0][0] * motor[0] + g[1][0] * motor[1] + g[2][0] * motor[2],
            g[0][1] * motor[0] + g[1][1] * motor[1] + g[2][1] * motor[2],
            g[0][2] * motor[0] + g[1][2] * motor[1] + g[2][2] * motor[2],
        )

    def _torso_angles(self) -> tuple[float, float]:
        """The torso's absolute angle from vertical in each plane of the heading frame (pitch, roll), rad."""
        k, xmat = self._torso_xmat, self._xmat
        zx, zy, zz = xmat.item(k + 2), xmat.item(k + 5), xmat.item(k + 8)  # the torso's z axis in the world
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        forward, left = c * zx + s * zy, -s * zx + c * zy
        return math.atan2(forward, zz), math.atan2(-left, zz)

    def _apply_external(self) -> None:
        """A push (external wrench per plane at P, heading axes) as a force and torque on the chassis."""
        d = self.data
        xfrc = d.xfrc_applied[self._chassis_body]
        pitch, roll = self.external
        if pitch is None and roll is None and self.external_yaw == 0.0:
            if self._pushed:
                xfrc[:] = 0.0
                self._pushed = False
            return
        self._pushed = True
        fwd = pitch.forward if pitch else 0.0
        left = -roll.forward if roll else 0.0
        up = (pitch.up if pitch else 0.0) + (roll.up if roll else 0.0)
        my = pitch.moment if pitch else 0.0
        mx = roll.moment if roll else 0.0
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        f = np.array([c * fwd - s * left, s * fwd + c * left, up])
        moment = np.array([c * mx - s * my, s * mx + c * my, self.external_yaw])
        arm = d.site_xpos[self._p_site] - d.xipos[self._chassis_body]
        xfrc[0:3] = f
        xfrc[3:6] = moment + np.cross(arm, f)

    # ------------------------------------------------------------------------------------------- holding
    def _hold(self) -> None:
        """Hold the ball and the chassis where they are (the stand, or the rider's feet at rest): each is
        welded to the world at its present pose, and stops."""
        m, d = self.model, self.data
        d.qvel[0 : self._drive_v + 3] = 0.0
        mujoco.mj_kinematics(m, d)
        for eq, body in zip(self._holds, (self._ball_body, self._chassis_body), strict=True):
            # A weld's relpose is the world's pose in the body's frame.
            inverse = np.zeros(4)
            mujoco.mju_negQuat(inverse, d.xquat[body])
            pos = np.zeros(3)
            mujoco.mju_rotVecQuat(pos, -d.xpos[body], inverse)
            m.eq_data[eq][3:6] = pos
            m.eq_data[eq][6:10] = inverse
            d.eq_active[eq] = 1
        self._forward_current = False

    def _release(self) -> None:
        for eq in self._holds:
            self.data.eq_active[eq] = 0
        self._forward_current = False

    def _update_rest(self) -> None:
        """Power removed at standstill: caught (resting) until powered again; removed in motion: it tips."""
        powered, was_powered = self.drives.powered, self._powered
        self._powered = powered
        if self.resting:
            if powered:
                self.resting = False
                if not self.clamped:
                    self._release()
        elif was_powered and not powered and not self.clamped and self.fallen is None:
            sim = self.sim
            tilt = max(abs(a) for a in self._state.tilt)
            if max(abs(v) for v in self.velocity) < sim.rest_speed and tilt < sim.rest_tilt:
                self.resting = True
                self._hold()

    # ------------------------------------------------------------------------------------------ the state
    def _read_state(self) -> Motion:
        """Everything a tick's outputs read, from MuJoCo's data once per tick: one list per array."""
        sens = self._sensordata.tolist()
        gyro, accel = (sens[0], sens[1], sens[2]), (sens[3], sens[4], sens[5])
        roll, pitch, yaw = euler_zyx((sens[6], sens[7], sens[8], sens[9]))
        self._yaw += (yaw - self._last_yaw + math.pi) % (2.0 * math.pi) - math.pi
        self._last_yaw = yaw
        droll, dpitch, dyaw = euler_rates(gyro, roll, pitch)
        qpos, qvel = self._qpos.tolist(), self._qvel.tolist()
        vx, vy = qvel[0], qvel[1]
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        # The ball's angular velocity in the world (its free joint's rates are in its own frame).
        k = self._ball_xmat
        rb = self._xmat[k : k + 6].tolist()
        wl0, wl1, wl2 = qvel[3], qvel[4], qvel[5]
        wx = rb[0] * wl0 + rb[1] * wl1 + rb[2] * wl2
        wy = rb[3] * wl0 + rb[4] * wl1 + rb[5] * wl2
        # The contact point's velocity over the floor: v + ω × (−z ẑ) = (vx − z ωy, vy + z ωx). The soft
        # contact lets the ball sink by δ (under a millimetre); MuJoCo's contact point is halfway into it.
        z = 0.5 * (qpos[2] + self._radius)
        rates = self._actuator_velocity.tolist()
        self._motor_rates = [rates[self._motor_1], rates[self._motor_2], rates[self._motor_3]]
        lean = lean_rate = (0.0, 0.0)
        if self._lean_q:
            lean = (qpos[self._lean_q[0]], qpos[self._lean_q[1]])
            lean_rate = (qvel[self._lean_v[0]], qvel[self._lean_v[1]])
        return Motion(
            attitude=(roll, pitch, yaw),
            tilt_rate=(dpitch, droll),
            yaw_rate=dyaw,
            velocity=(c * vx + s * vy, -s * vx + c * vy),
            ball_rate=(-s * wx + c * wy, c * wx + s * wy),
            position=(qpos[0], qpos[1]),
            gyro=gyro,
            accel=accel,
            lean=lean,
            lean_rate=lean_rate,
            slip=math.hypot(vx - z * wy, vy + z * wx),
        )

    @property
    def velocity(self) -> tuple[float, float]:
        """Ground speed in the heading frame (forward, left), m/s."""
        return self._state.velocity

    @property
    def position(self) -> tuple[float, float]:
        return self._state.position

    @property
    def yaw(self) -> float:
        return self._yaw

    def _check_fall(self) -> None:
        """Count slip, integrate the ball's rolling, and keep the first fall: a contact of anything but the
        ball with the floor, a tilt beyond the bound, or the floor's edge."""
        state, sim = self._state, self.sim
        if state.slip > SLIP_SPEED:
            self.slip_ticks += 1
        self.max_slip = max(self.max_slip, state.slip)
        self.ball_angle[0] += self.dt * state.ball_rate[0]
        self.ball_angle[1] += self.dt * state.ball_rate[1]
        if self.fallen is not None:
            return
        d = self.data
        ncon = d.ncon
        # Only the floor collides (model3d's contact bits), and a sphere sunk into a plane always makes one
        # contact: with the ball sunk, a lone contact is the ball's, and MuJoCo's contact list (dear to
        # read from Python) needs reading only when there is more.
        if ncon > 1 or (ncon == 1 and self._qpos.item(2) - self._floor_z >= self._radius):
            for g1, g2 in d.contact.geom.tolist():
                name = self._fall_geoms.get(g2 if g1 == self._floor else g1)
                if name is not None:
                    self.fallen = f"{name.replace('_', ' ')} touched the floor at t={self.t:.3f} s"
                    return
        # The tilt from vertical, any direction.
        tilt = math.acos(min(1.0, self._xmat.item(self._chassis_xmat + 8)))
        if tilt > sim.fall_tilt:
            self.fallen = f"tilt beyond {sim.fall_tilt_deg:g} deg at t={self.t:.3f} s"
        elif abs(state.position[0]) > sim.floor_half_x or abs(state.position[1]) > sim.floor_half_y:
            self.fallen = f"left the floor envelope at t={self.t:.3f} s"

    # ------------------------------------------------------------------------------------------- outputs
    def motor_angles_and_rates(self) -> tuple[list[float], list[float]]:
        return list(self.motor_angles), list(self._motor_rates)

    def imu_truth(
        self,
    ) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
        """True (attitude, body rate, body specific force) at the IMU: MuJoCo's sensors at its site."""
        state = self._state
        roll, pitch, _ = state.attitude
        return (roll, pitch, self._yaw), state.gyro, state.accel

    def hip_torques(self) -> tuple[float, float]:
        if not self._hips:
            return 0.0, 0.0
        f = self._actuator_force
        return f.item(self._hips[0]), f.item(self._hips[1])

    def _compute_seat_wrench(self) -> tuple[float, float, float, float, float, float]:
        """What the torso and the thighs put on the seat at P, body axes: minus the force and moment their
        bodies get from the chassis (MuJoCo's cfrc_int: the hip's constraint force and the hip torques,
        gravity and inertia included), moved to P. Plus the rider's twisting moment."""
        if self.seated is None:
            return (0.0,) * 6
        k, kc = 3 * self._p_site, 3 * self._ball_body
        px, py, pz = self._site_xpos[k : k + 3].tolist()
        cx, cy, cz = self._subtree_com[kc : kc + 3].tolist()  # cfrc_int's point: the root's subtree com
        ax, ay, az = cx - px, cy - py, cz - pz
        fx = fy = fz = mx = my = mz = 0.0
        cfrc = self._cfrc_int
        for b in self._rider_bodies:
            tx, ty, tz, gx, gy, gz = cfrc[6 * b : 6 * b + 6].tolist()
            # Minus the body's wrench from the chassis, its moment taken about P.
            fx -= gx
            fy -= gy
            fz -= gz
            mx -= tx + ay * gz - az * gy
            my -= ty + az * gx - ax * gz
            mz -= tz + ax * gy - ay * gx
        k = self._chassis_xmat
        r = self._xmat[k : k + 9].tolist()  # body axes in the world: columns
        twist = self.twist.torque if self.twist else 0.0
        return (
            r[0] * fx + r[3] * fy + r[6] * fz,
            r[1] * fx + r[4] * fy + r[7] * fz,
            r[2] * fx + r[5] * fy + r[8] * fz,
            r[0] * mx + r[3] * my + r[6] * mz,
            r[1] * mx + r[4] * my + r[7] * mz,
            r[2] * mx + r[5] * my + r[8] * mz + twist,
        )

    def truth(self) -> Truth:
        s = self._state
        return Truth(
            t=self.t,
            tilt=s.tilt,
            tilt_rate=s.tilt_rate,
            ball_angle=(self.ball_angle[0], self.ball_angle[1]),
            ball_rate=s.ball_rate,
            lean=s.lean,
            velocity=s.velocity,
            position=s.position,
            yaw=self._yaw,
            yaw_rate=s.yaw_rate,
            motor_torque=self.drives.torques,
            hip_torque=self.hip_torques(),
            seat_wrench=self.seat_wrench(),
            fallen=self.fallen,
            resting=self.resting,
            powered=self.drives.powered,
        )

    def poses(self) -> dict[str, Pose]:
        """Every body of the model by name (ball, chassis, torso, thigh_left, ...), MuJoCo's frames."""
        d, names = self.data, self._body_names
        pos, quat = d.xpos.tolist(), d.xquat.tolist()
        return {name: (tuple(pos[b]), tuple(quat[b])) for b, name in names}

    def body_model(self) -> object:
        """The model it simulates on."""
        return self.model

    def energy(self) -> float:
        """Kinetic + gravitational energy (J), MuJoCo's account at the current state (also left in
        `data.energy`: potential, kinetic)."""
        m, d = self.model, self.data
        mujoco.mj_energyPos(m, d)
        mujoco.mj_energyVel(m, d)
        e = d.energy
        return float(e[0] + e[1])

    _pushed = False
    _limp = False
