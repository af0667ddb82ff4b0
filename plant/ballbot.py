"""PURE + rider: two vertical planes and yaw, drives, sensors and the rider, advanced by fixed-step RK4.

The planes are the heading-frame decomposition of docs/physics.md §2 (pitch: about +y, roll: about +x), each a
three-body model with the rider's torso (plane.py); yaw is a single body on a ball that does not spin on the
floor (§2.5). Drive torques are held over a tick (zero-order hold, first-order current lag inside).
Deterministic for a seed; no clock, no I/O: the caller owns time by calling `step()`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from mypy_extensions import mypyc_attr

from drivers.bounds import G0
from drivers.rotations import quaternion_zyx, rotate
from plant.anthropometry import SeatedRider, composite, robot_body_segment, seat_rider, yaw_inertia
from plant.drives import DriveArray
from plant.omniwheel import motor_jacobian, wheel_inertia_equivalents
from plant.params import RiderParams, RobotParams, SimParams
from plant.plane import STICK_TIME_CONSTANT, HipPolicy, PlaneDynamics, PlaneParams, Wrench
from plant.rider import LeanStyle, Profile, Segment, Step
from plant.sensors import (
    DriveFeedback,
    DriveFeedbackModel,
    ImuModel,
    ImuSample,
    Record,
    TesModel,
    TesSample,
)
from plant.torso import TorsoController, TwistController

PITCH, ROLL = 0, 1
PLANES = ("pitch", "roll")


def plane_params(
    robot: RobotParams, rider: RiderParams | None, plane: str, torso: bool = True
) -> PlaneParams:
    """Parameters of one plane. With torso=False a rider is lumped rigidly (upright) into the chassis."""
    b, f, dt = robot.ball, robot.friction, robot.drivetrain
    theta_w, _ = wheel_inertia_equivalents(b.radius, dt)
    segments = [robot_body_segment(robot)]
    hat_mass = hat_com = hat_inertia = hip_fwd = hip_up = 0.0
    if rider is not None:
        seated = seat_rider(robot, rider)
        segments += list(seated.lower_limbs)
        if torso:
            hat_mass, hat_com = seated.hat.mass, seated.hat.com_distance
            hat_inertia = seated.hat.i_pitch if plane == "pitch" else seated.hat.i_roll
            hip_fwd = seated.hip_x if plane == "pitch" else 0.0
            hip_up = seated.hip_z
        else:
            segments.append(seated.hat_segment())
    return PlaneParams(
        ball_radius=b.radius,
        ball_mass=b.mass,
        ball_inertia=b.inertia,
        rho=b.radius / dt.wheel_radius,
        wheel_inertia=theta_w,
        chassis=composite(segments, plane),
        top_height=robot.body.top_height,
        hat_mass=hat_mass,
        hat_com_distance=hat_com,
        hat_inertia=hat_inertia,
        hip_forward=hip_fwd,
        hip_up=hip_up,
        rolling_viscous=f.rolling_viscous,
        drivetrain_viscous=f.drivetrain_viscous,
        drivetrain_coulomb=f.drivetrain_coulomb,
        drivetrain_stiction=f.drivetrain_stiction,
        stick_velocity=f.stick_velocity,
    )


@dataclass(slots=True)
class RiderIntent:
    """What the rider tries to do: lean profiles per plane (degrees) and a twist profile (Nm)."""

    pitch: list[Segment] = field(default_factory=list)
    roll: list[Segment] = field(default_factory=list)
    twist: list[Segment] = field(default_factory=list)


Pose = tuple[tuple[float, float, float], tuple[float, float, float, float]]
"""A body's frame in the world: position (m) and orientation as a unit quaternion (w, x, y, z)."""


class Truth(Record):
    """The plant's true state after a tick, for metrics, recording and the supervisor's referee."""

    t: float
    tilt: tuple[float, float]
    """Chassis tilt (pitch, roll), rad."""
    tilt_rate: tuple[float, float]
    ball_angle: tuple[float, float]
    ball_rate: tuple[float, float]
    lean: tuple[float, float]
    """Torso lean relative to the chassis (pitch, roll), rad; 0 without a torso."""
    velocity: tuple[float, float]
    """Ground speed in the heading frame (forward, left), m/s."""
    position: tuple[float, float]
    """Ball contact point in the world frame (x, y) from the start, m."""
    yaw: float
    yaw_rate: float
    motor_torque: tuple[float, float, float]
    hip_torque: tuple[float, float]
    seat_wrench: tuple[float, float, float, float, float, float]
    """True rider wrench on the seat at P, body axes [Fx, Fy, Fz, Mx, My, Mz]."""
    fallen: str | None
    resting: bool
    """Powered off at standstill and held by the rider's feet or the stand."""
    powered: bool
    """Any drive's power stage is on."""

    def __init__(
        self,
        *,
        t: float,
        tilt: tuple[float, float],
        tilt_rate: tuple[float, float],
        ball_angle: tuple[float, float],
        ball_rate: tuple[float, float],
        lean: tuple[float, float],
        velocity: tuple[float, float],
        position: tuple[float, float],
        yaw: float,
        yaw_rate: float,
        motor_torque: tuple[float, float, float],
        hip_torque: tuple[float, float],
        seat_wrench: tuple[float, float, float, float, float, float],
        fallen: str | None,
        resting: bool = False,
        powered: bool = False,
    ) -> None:
        self.t, self.tilt, self.tilt_rate = t, tilt, tilt_rate
        self.ball_angle, self.ball_rate, self.lean = ball_angle, ball_rate, lean
        self.velocity, self.position, self.yaw, self.yaw_rate = velocity, position, yaw, yaw_rate
        self.motor_torque, self.hip_torque, self.seat_wrench = motor_torque, hip_torque, seat_wrench
        self.fallen, self.resting, self.powered = fallen, resting, powered

    def _values(self) -> tuple[object, ...]:
        return (
            self.t,
            self.tilt,
            self.tilt_rate,
            self.ball_angle,
            self.ball_rate,
            self.lean,
            self.velocity,
            self.position,
            self.yaw,
            self.yaw_rate,
            self.motor_torque,
            self.hip_torque,
            self.seat_wrench,
            self.fallen,
            self.resting,
            self.powered,
        )


@mypyc_attr(allow_interpreted_subclasses=True)  # the 3-D plant (plant/ballbot3d.py) is one
class PlantCore:
    """What both plants share: the drives, the sensors' models, the rider's intent and torso control, the
    supervisor's alert, pushes and the outputs' per-tick caches. A plant adds its mechanics: `step()`,
    `truth()`, `imu_truth()`, `motor_angles_and_rates()`, `_compute_seat_wrench()`, `energy()`."""

    def __init__(
        self,
        robot: RobotParams,
        rider: RiderParams | None,
        sim: SimParams,
        intent: RiderIntent | None = None,
    ):
        self.robot, self.rider, self.sim = robot, rider, sim
        self.dt = sim.dt
        self.clamped = sim.fixture == "clamped"
        G = motor_jacobian(robot.ball.radius, robot.drivetrain)
        self._g = tuple(tuple(float(v) for v in row) for row in G)
        intent = intent or RiderIntent()
        self.seated: SeatedRider | None = None
        self.torso: tuple[TorsoController, TorsoController] | None = None
        """The rider's lean (pitch, roll); None without a rider, or a torso left to itself."""
        self.twist: TwistController | None = None
        if rider is not None:
            self.seated = seat_rider(robot, rider)
            hat = self.seated.hat
            self.style = LeanStyle(rider.lean_amplitude_deg, rider.lean_rate_deg)
            self.torso = (
                TorsoController(rider, hat.mass, hat.com_distance, Profile(intent.pitch, style=self.style)),
                TorsoController(rider, hat.mass, hat.com_distance, Profile(intent.roll, style=self.style)),
            )
            self.twist = TwistController(rider, Profile(intent.twist))

        self.drives = DriveArray(robot.drive)
        seeds = np.random.SeedSequence(sim.seed).spawn(3)
        self.feedback_model = DriveFeedbackModel(robot.encoder, robot.drive, np.random.default_rng(seeds[0]))
        self.imu_model = ImuModel(robot.imu, np.random.default_rng(seeds[1]))
        self.tes_model = TesModel(robot.tes, robot.body.seat_height, np.random.default_rng(seeds[2]))

        self.t = 0.0
        self.tick = 0
        self.external: list[Wrench | None] = [None, None]
        """External wrench on the chassis at P per plane (pushes, tests)."""
        self.external_yaw = 0.0
        self.ball_torque = (0.0, 0.0, 0.0)
        self.fallen: str | None = None
        self.heeds_alert = False
        """The rider sits up on the supervisor's alert (`alert`); False: the scripted rider ignores it."""
        self._alerted: float | None = None
        """When the rider acts on the alert (s), once noticed."""
        self.resting = False
        self._powered = False
        """Power off at standstill: the rider's feet (the seat is at chair height) or the parking stand
        hold the robot where it is, as `clamped` does, until a drive is powered again."""
        self._outputs_tick = self._wrench_tick = -1
        self._wrench: tuple[float, float, float, float, float, float] = (0.0,) * 6

    def alert(self, level: int) -> None:
        """The supervisor's alert reaches the rider (0 none, 1 slow down, 2 stop). A rider who heeds it
        (`heeds_alert`) sits up and holds still `alert_reaction_time` after the first alert: the intent
        becomes upright and no twist, at the rider's own rates. One who does not, goes on as scripted."""
        if level > 0 and self.heeds_alert and self._alerted is None and self.rider is not None:
            self._alerted = self.t + self.rider.alert_reaction_time

    def set_intent(self, intent: RiderIntent) -> None:
        """Replace the rider's intent from now on; each profile starts where the rider is."""
        if self.torso is None:
            return
        for controller, segments in zip(self.torso, (intent.pitch, intent.roll), strict=True):
            controller.profile = Profile(
                segments, start=self.t, value=math.degrees(controller.lean_cmd), style=self.style
            )
        if self.twist is not None:
            self.twist.profile = Profile(intent.twist, start=self.t, value=self.twist.torque)

    def _rider_decides(self) -> None:
        """The rider's tick: act on a noticed alert, move the lean commands, update the twist."""
        if self._alerted is not None and self.t >= self._alerted:
            self._alerted = math.inf  # acted on: once
            self.set_intent(RiderIntent(pitch=[Step(to=0.0)], roll=[Step(to=0.0)], twist=[Step(to=0.0)]))
        if self.torso is not None:
            velocity = self.velocity
            for k in (PITCH, ROLL):
                self.torso[k].update(self.t, self.dt, velocity[k])
            if self.twist is not None:
                self.twist.update(self.t)

    @property
    def velocity(self) -> tuple[float, float]:
        """Ground speed in the heading frame (forward, left), m/s."""
        raise NotImplementedError

    def step(self) -> None:
        raise NotImplementedError

    def truth(self) -> Truth:
        raise NotImplementedError

    def energy(self) -> float:
        raise NotImplementedError

    def poses(self) -> dict[str, Pose]:
        """Where the bodies are: ball, chassis, torso (with a rider), world frame (z up from the floor)."""
        raise NotImplementedError

    def motor_angles_and_rates(self) -> tuple[list[float], list[float]]:
        raise NotImplementedError

    def imu_truth(
        self,
    ) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
        raise NotImplementedError

    def _compute_seat_wrench(self) -> tuple[float, float, float, float, float, float]:
        raise NotImplementedError

    def sample_drives(self) -> tuple[DriveFeedback, DriveFeedback, DriveFeedback]:
        angles, rates = self.motor_angles_and_rates()
        return self.feedback_model.sample(angles, rates, self.drives.torques)

    def sample_imu(self) -> ImuSample:
        attitude, rate, accel = self.imu_truth()
        return self.imu_model.sample(attitude, rate, accel)

    def seat_wrench(self) -> tuple[float, float, float, float, float, float]:
        """True wrench of the rider on the seat at P, body axes (once per tick, shared by TES and truth)."""
        if self._wrench_tick != self.tick:
            self._wrench = self._compute_seat_wrench()
            self._wrench_tick = self.tick
        return self._wrench

    def sample_tes(self) -> TesSample:
        return self.tes_model.sample(self.seat_wrench())


@mypyc_attr(allow_interpreted_subclasses=True)  # benchmarks/lockstep.py times its step in a subclass
class Plant(PlantCore):
    """PURE ballbot + rider in two vertical planes and yaw. Per tick: `drives.set_commands(...)`, `step()`,
    then sample or read `truth()`."""

    def __init__(
        self,
        robot: RobotParams,
        rider: RiderParams | None,
        sim: SimParams,
        intent: RiderIntent | None = None,
        initial_tilt: tuple[float, float] = (0.0, 0.0),
    ):
        super().__init__(robot, rider, sim, intent)
        self.h = sim.dt / sim.substeps
        self.planes = tuple(PlaneDynamics(plane_params(robot, rider, name)) for name in PLANES)
        _, theta_w_yaw = wheel_inertia_equivalents(robot.ball.radius, robot.drivetrain)
        rho = robot.ball.radius / robot.drivetrain.wheel_radius
        segments = [robot_body_segment(robot)]
        if self.seated is not None:
            segments += [*self.seated.lower_limbs, self.seated.hat_segment()]
        self.yaw_inertia = yaw_inertia(segments) + theta_w_yaw * rho * rho

        # State: per plane [φ, θ, γ, φ̇, θ̇, γ̇]; yaw [ψ, ψ̇]. The torso starts upright relative to the chassis
        # and φ = θ, so the ball-body angle (what the encoders count from power-up) starts at zero.
        tp, tr = initial_tilt
        self.x = [tp, tp, tp, 0.0, 0.0, 0.0, tr, tr, tr, 0.0, 0.0, 0.0, 0.0, 0.0]
        self.position = [0.0, 0.0]
        self._accel_cache: tuple[tuple[float, ...], tuple[float, float]] = ((0.0,) * 6, (0.0, 0.0))

    # ------------------------------------------------------------------------------------------ dynamics
    def _yaw_acceleration(self, rate: float, tau_z: float) -> float:
        """I_z ψ̈ = −τ_z − f_z + M_ext, Karnopp stick-slip on the ball-body relative yaw."""
        f = self.robot.friction
        drive = -tau_z + self.external_yaw
        if abs(rate) < f.stick_velocity:
            f_stick = drive + self.yaw_inertia * rate / STICK_TIME_CONSTANT
            fz = f_stick if abs(f_stick) <= f.yaw_stiction else math.copysign(f.yaw_coulomb, f_stick)
        else:
            fz = f.yaw_viscous * rate + math.copysign(f.yaw_coulomb, rate)
        return (drive - fz) / self.yaw_inertia

    def _yaw_rk4(self, yaw: float, rate: float, h: float, tau_z: float) -> tuple[float, float]:
        f = self._yaw_acceleration
        hh = 0.5 * h
        k1 = f(rate, tau_z)
        k2 = f(rate + hh * k1, tau_z)
        k3 = f(rate + hh * k2, tau_z)
        k4 = f(rate + h * k3, tau_z)
        yaw += h / 6.0 * (rate + 2.0 * (rate + hh * k1) + 2.0 * (rate + hh * k2) + (rate + h * k3))
        return yaw, rate + h / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)

    def _hip_policies(self) -> tuple[HipPolicy | None, HipPolicy | None]:
        if self.torso is None:
            return None, None
        return self.torso[PITCH].hip_torque, self.torso[ROLL].hip_torque

    # ------------------------------------------------------------------------------------------ one tick
    def step(self) -> None:
        """Advance one tick: the rider decides, drives act (ZOH + current lag), RK4 substeps, fall check."""
        self._rider_decides()
        hip_pitch, hip_roll = self._hip_policies()
        self._update_rest()
        held = self.clamped or self.resting
        pitch, roll = self.planes
        g, h, x = self._g, self.h, self.x
        _, speeds = self.motor_angles_and_rates()  # as the tick starts: the drives' torque-speed line
        for i in range(self.sim.substeps):
            motor = self.drives.advance(h, self.t + (i + 1) * h, speeds)
            self.ball_torque = tau = (
                g[0][0] * motor[0] + g[1][0] * motor[1] + g[2][0] * motor[2],
                g[0][1] * motor[0] + g[1][1] * motor[1] + g[2][1] * motor[2],
                g[0][2] * motor[0] + g[1][2] * motor[1] + g[2][2] * motor[2],
            )
            v0, yaw0 = self.velocity, x[12]
            if held:
                x[0:6] = pitch.rk4_step_clamped(x[0:6], h, hip_pitch)
                x[6:12] = roll.rk4_step_clamped(x[6:12], h, hip_roll)
            else:
                # Pitch plane turns about +y (τ_y), roll plane about +x (τ_x).
                x[0:6] = pitch.rk4_step(x[0:6], h, tau[1], hip_pitch, self.external[PITCH])
                x[6:12] = roll.rk4_step(x[6:12], h, tau[0], hip_roll, self.external[ROLL])
                x[12], x[13] = self._yaw_rk4(x[12], x[13], h, tau[2])
            v1, yaw = self.velocity, 0.5 * (yaw0 + x[12])
            vf, vl = 0.5 * (v0[0] + v1[0]), 0.5 * (v0[1] + v1[1])
            self.position[0] += h * (vf * math.cos(yaw) - vl * math.sin(yaw))
            self.position[1] += h * (vf * math.sin(yaw) + vl * math.cos(yaw))
        self.tick += 1
        self.t = self.tick * self.dt
        self._outputs_tick = self._wrench_tick = -1
        self._check_fall()

    def _update_rest(self) -> None:
        """Power removed at standstill: caught (resting) until powered again; removed in motion: it tips."""
        powered, was_powered = self.drives.powered, self._powered
        self._powered = powered
        if self.resting:
            self.resting = not powered
        elif was_powered and not powered and not self.clamped and self.fallen is None:
            sim, x = self.sim, self.x
            if (
                max(abs(v) for v in self.velocity) < sim.rest_speed
                and max(abs(x[1]), abs(x[7])) < sim.rest_tilt
            ):
                self.resting = True
                x[3] = x[4] = x[9] = x[10] = x[13] = 0.0  # caught: the chassis and the ball stop

    def _outputs(self) -> tuple[tuple[float, ...], tuple[float, float]]:
        """Accelerations (pitch φ̈ θ̈ γ̈, roll φ̈ θ̈ γ̈) and hip torques at the current state, once per tick."""
        if self._outputs_tick != self.tick:
            accel, hips = [], []
            for k, policy in zip((PITCH, ROLL), self._hip_policies(), strict=True):
                _, th, ga, dphi, dth, dga = self.x[6 * k : 6 * k + 6]
                u = policy(ga, ga - th, dga - dth) if policy else 0.0
                if self.clamped or self.resting:
                    accel += [0.0, 0.0, self.planes[k].clamped_torso_acceleration(ga, u)]
                else:
                    tau = self.ball_torque[1 - k]
                    accel += self.planes[k].accelerations(th, ga, dphi, dth, dga, tau, u, self.external[k])
                hips.append(u)
            self._accel_cache = (tuple(accel), (hips[0], hips[1]))
            self._outputs_tick = self.tick
        return self._accel_cache

    @property
    def velocity(self) -> tuple[float, float]:
        """Ground speed in the heading frame (forward, left): the roll plane's forward is −y."""
        r = self.robot.ball.radius
        return r * self.x[3], -r * self.x[9]

    def _check_fall(self) -> None:
        if self.fallen is not None:
            return
        if max(abs(self.x[1]), abs(self.x[7])) > self.sim.fall_tilt:
            self.fallen = f"tilt beyond {self.sim.fall_tilt_deg:g} deg at t={self.t:.3f} s"
        elif abs(self.position[0]) > self.sim.floor_half_x or abs(self.position[1]) > self.sim.floor_half_y:
            self.fallen = f"left the floor envelope at t={self.t:.3f} s"

    # ------------------------------------------------------------------------------------------- outputs
    def relative_ball_rotation(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(angle, rate) of the ball relative to the body, body frame: [φ_x − θ_x, φ_y − θ_y, −ψ]."""
        x = self.x
        angle = (x[6] - x[7], x[0] - x[1], -x[12])
        rate = (x[9] - x[10], x[3] - x[4], -x[13])
        return angle, rate

    def motor_angles_and_rates(self) -> tuple[list[float], list[float]]:
        angle, rate = self.relative_ball_rotation()
        g = self._g
        return (
            [g[i][0] * angle[0] + g[i][1] * angle[1] + g[i][2] * angle[2] for i in range(3)],
            [g[i][0] * rate[0] + g[i][1] * rate[1] + g[i][2] * rate[2] for i in range(3)],
        )

    def imu_truth(
        self,
    ) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
        """True (attitude, body rate, body specific force) at the IMU (docs/physics.md §7.1, per plane)."""
        x, r, h = self.x, self.robot.ball.radius, self.robot.body.imu_height
        a, _ = self._outputs()
        acc = []
        for k in (PITCH, ROLL):
            th, dth = x[6 * k + 1], x[6 * k + 4]
            ddphi, ddth = a[3 * k], a[3 * k + 1]
            st, ct = math.sin(th), math.cos(th)
            acc.append((r * ddphi + h * (ct * ddth - st * dth * dth), -h * (st * ddth + ct * dth * dth)))
        fx, fy, fz = acc[PITCH][0], -acc[ROLL][0], acc[PITCH][1] + acc[ROLL][1] + G0
        pitch, roll = x[1], x[7]
        # Body = (Ry(pitch) Rx(roll))ᵀ world.
        sp, cp, sr, cr = math.sin(pitch), math.cos(pitch), math.sin(roll), math.cos(roll)
        wx, wy, wz = cp * fx - sp * fz, fy, sp * fx + cp * fz
        body = (wx, cr * wy + sr * wz, -sr * wy + cr * wz)
        return (roll, pitch, x[12]), (x[10], x[4], x[13]), body

    def _compute_seat_wrench(self) -> tuple[float, float, float, float, float, float]:
        """Torso load of both planes + the thighs' weight."""
        if self.seated is None:
            return (0.0,) * 6
        accel, hips = self._outputs()
        loads = []
        for k in (PITCH, ROLL):
            _, th, ga, _, dth, dga = self.x[6 * k : 6 * k + 6]
            ddphi, ddth, ddga = accel[3 * k : 3 * k + 3]
            loads.append(self.planes[k].torso_load(th, ga, dth, dga, ddphi, ddth, ddga, hips[k]))
        (fp, up_p, mp), (fr, up_r, mr) = loads
        # Both planes carry the torso's weight; the roll plane adds only its departure from it.
        fx, fy, fz = fp, -fr, up_p + up_r + self.seated.hat.mass * G0
        mx, my = mr, mp
        pitch, roll = self.x[1], self.x[7]
        sp, cp, sr, cr = math.sin(pitch), math.cos(pitch), math.sin(roll), math.cos(roll)
        gx, gy, gz = G0 * sp, -G0 * cp * sr, -G0 * cp * cr  # (Ry Rx)ᵀ (0, 0, −g)
        h_p = self.robot.body.top_height
        for s in self.seated.thighs:
            f = (s.mass * gx, s.mass * gy, s.mass * gz)
            rx, ry, rz = s.x, s.y, s.z - h_p
            fx, fy, fz = fx + f[0], fy + f[1], fz + f[2]
            mx += ry * f[2] - rz * f[1]
            my += rz * f[0] - rx * f[2]
        mz = self.twist.torque if self.twist else 0.0
        return fx, fy, fz, mx, my, mz

    def truth(self) -> Truth:
        x = self.x
        return Truth(
            t=self.t,
            tilt=(x[1], x[7]),
            tilt_rate=(x[4], x[10]),
            ball_angle=(x[0], x[6]),
            ball_rate=(x[3], x[9]),
            lean=((x[2] - x[1], x[8] - x[7]) if self.seated else (0.0, 0.0)),
            velocity=self.velocity,
            position=(self.position[0], self.position[1]),
            yaw=x[12],
            yaw_rate=x[13],
            motor_torque=self.drives.torques,
            hip_torque=self._outputs()[1],
            seat_wrench=self.seat_wrench(),
            fallen=self.fallen,
            resting=self.resting,
            powered=self.drives.powered,
        )

    def poses(self) -> dict[str, Pose]:
        """The planar state drawn in 3-D: the chassis at the ball's centre turned by yaw, pitch and roll, the
        torso at the hip leaning by its two angles relative to it, the ball turned by its two rolling
        angles (the planar plant has no ball spin)."""
        x, r = self.x, self.robot.ball.radius
        centre = (self.position[0], self.position[1], r)
        chassis = quaternion_zyx(x[7], x[1], x[12])
        poses = {"ball": (centre, quaternion_zyx(x[6], x[0], 0.0)), "chassis": (centre, chassis)}
        if self.seated is not None:
            hip = rotate((self.seated.hip_x, 0.0, self.seated.hip_z), chassis)
            torso = quaternion_zyx(x[8], x[2], x[12])
            poses["torso"] = ((centre[0] + hip[0], centre[1] + hip[1], centre[2] + hip[2]), torso)
        return poses

    def energy(self) -> float:
        """Mechanical energy of both planes and yaw (J); conserved without torques and friction."""
        x = self.x
        e = 0.0
        for k in (PITCH, ROLL):
            q, dq = x[6 * k : 6 * k + 3], x[6 * k + 3 : 6 * k + 6]
            e += self.planes[k].energy((q[0], q[1], q[2]), (dq[0], dq[1], dq[2]))
        return e + 0.5 * self.yaw_inertia * x[13] ** 2
