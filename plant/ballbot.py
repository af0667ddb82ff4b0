"""PURE + rider: two vertical planes and yaw, drives, sensors and the rider, advanced by fixed-step RK4.

The planes are the heading-frame decomposition of docs/physics.md §2 (pitch: about +y, roll: about +x), each a
three-body model with the rider's torso (plane.py); yaw is a single body on a ball that does not spin on the
floor (§2.5). Drive torques are held over a tick (zero-order hold, first-order current lag inside).
Deterministic for a seed; no clock, no I/O: the caller owns time by calling `step()`.
"""

from __future__ import annotations

import math

from mypy_extensions import mypyc_attr

from drivers.bounds import G0
from drivers.rotations import quaternion_zyx, rotate
from plant.anthropometry import composite, robot_body_segment, seat_rider, yaw_inertia
from plant.core import PITCH, ROLL, PlantCore, Pose, Truth
from plant.omniwheel import wheel_inertia_equivalents
from plant.params import RiderParams, RobotParams
from plant.plane import STICK_TIME_CONSTANT, HipPolicy, PlaneDynamics, PlaneParams

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


@mypyc_attr(allow_interpreted_subclasses=True)  # benchmarks/lockstep.py times its step in a subclass
class Plant(PlantCore):
    """PURE ballbot + rider in two vertical planes and yaw. Per tick: `drives.set_commands(...)`, `step()`,
    then sample or read `truth()`."""

    def _build_mechanics(self, initial_tilt: tuple[float, float]) -> None:
        robot, rider, sim = self.robot, self.rider, self.sim
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
