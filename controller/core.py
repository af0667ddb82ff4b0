"""The reference PURE controller, one SYNC tick at a time: no I/O (the node feeds it frames and samples).

States (CONTROLLER_HEARTBEAT.State): INIT until the sensors have spoken, BALANCING, DISABLED (e-stopped
or never enabled: zero torque, drives disabled), FAULT (a sensor stream went silent: drives disabled).
After an e-stop or a fault the controller stays down until an explicit enable: a reset of the e-stop
permits motion, it never causes it.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from controller.balance import PlaneBalancer, equilibrium
from controller.command import CommandSpeed, YawCommand
from controller.config import ControllerConfig, RiderInfo
from controller.estimator import PITCH, ROLL, Estimate, Estimator
from controller.model import PlaneModel, lqr_gain, motor_jacobian, plane_model, seat_load_height
from drivers.bounds import G0
from drivers.robot import RobotModel
from drivers.schemas import ScCommand
from drivers.vocabulary import ControllerState

PLANES = ("pitch", "roll")
YAW_RATE_GAIN = 20.0
"""Nm of ball yaw torque per rad/s of yaw-rate error."""


class Fault(IntEnum):
    NONE = 0
    SENSOR_TIMEOUT = 1
    ESTOP = 2
    TES_STALE = 3
    """Not fatal: the rider's input is ignored (command speed 0) until the seat speaks again."""
    INTERNAL = 4
    """The controller's own code failed; drives disabled until an explicit enable."""
    DEGRADED = 5
    """Not fatal: balancing with an input stood in for (lost, or named faulty by the supervisor's diagnosis;
    controller/estimator.py)."""


# The per-tick records are plain classes with a typed __init__: compiled (mypyc), a dataclass keeps its
# generated Python __init__, a native one is a C constructor.
class Wrench:
    def __init__(self, force: tuple[float, float, float], moment: tuple[float, float, float]):
        self.force, self.moment = force, moment


class Output:
    def __init__(
        self,
        motor_torque: tuple[float, float, float],
        enable: bool,
        state: ControllerState,
        fault: Fault,
        command_speed: tuple[float, float] = (0.0, 0.0),
        tilt_command: tuple[float, float] = (0.0, 0.0),
        yaw_rate_command: float = 0.0,
        ball_torque: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ):
        self.motor_torque, self.enable, self.state, self.fault = motor_torque, enable, state, fault
        self.command_speed, self.tilt_command = command_speed, tilt_command
        self.yaw_rate_command, self.ball_torque = yaw_rate_command, ball_torque


class Controller:
    def __init__(self, config: ControllerConfig, robot: RobotModel, rider: RiderInfo):
        self.config, self.robot, self.rider = config, robot, rider
        self.dt = 1.0 / config.timing.tick_hz
        g = motor_jacobian(robot)
        self.torque_to_motor = np.linalg.inv(g.T)
        # Its rows as floats: numpy's per-call overhead dominates a 3-vector product at 400 Hz.
        self._motor_rows = tuple(tuple(float(x) for x in row) for row in self.torque_to_motor)
        self.estimator = Estimator(g, robot.encoder.counts_per_rev, config.timing.sensor_hold)
        self.motor_limit = robot.drive.torque_limit
        # Largest ball torque in one plane alone that keeps every motor within its limit.
        self.plane_limit = tuple(
            self.motor_limit / np.abs(self.torque_to_motor[:, axis]).max() for axis in (1, 0)
        )
        models = self._models(config.reference_rider_mass, config.reference_rider_height)
        self.balancers = tuple(
            PlaneBalancer(m, lqr_gain(m, config.lqr), config.pi, self.dt, lim)
            for m, lim in zip(models, self.plane_limit, strict=True)
        )
        hacs = config.hacs_for(rider.name)
        self.commands = (CommandSpeed(hacs, self.dt), CommandSpeed(hacs, self.dt))
        self.yaw = YawCommand(hacs, self.dt)
        self.state = ControllerState.INIT
        self.fault = Fault.NONE
        self.enable_requested = False
        self.ever_stopped = False
        self.balancing_since = -math.inf
        """When the controller last started balancing (−inf: never)."""
        self._tare_sum = [0.0] * 6
        self._tare_n = 0
        self.tare: tuple[float, ...] | None = None
        """The seat wrench [Fx, Fy, Fz, Mx, My, Mz] averaged while taring (None until taring has finished)."""
        self.rider_mass: float | None = None
        self._moment_filtered = [0.0, 0.0, 0.0]
        self.seat_load_height = seat_load_height(robot, rider.height)
        self._alpha = 1.0 - math.exp(-2.0 * math.pi * hacs.filter_hz * self.dt)
        # What step reads every tick, read once (a compiled look-up into a config Struct is a dict's).
        timing = config.timing
        self._tare_time, self._tes_hold = timing.tare_time, timing.tes_hold
        self._sc_max_age = timing.sc_max_age
        self._ball_radius = robot.ball.radius
        self._compensated = tuple(config.mode == "ihacs" and p in config.ihacs.planes for p in PLANES)
        """Per plane (PITCH, ROLL): iHACS' interaction compensation applies."""

    def _models(self, mass: float, height: float) -> tuple[PlaneModel, ...]:
        return tuple(plane_model(self.robot, mass, height, p) for p in PLANES)

    # ---------------------------------------------------------------------------------------- control
    def request_enable(self) -> None:
        self.enable_requested = True

    def step(
        self, t: float, wrench: Wrench | None, wrench_age: float, sc: ScCommand | None, estop: bool
    ) -> Output:
        if estop:
            if self.state is ControllerState.BALANCING:
                self.ever_stopped = True
            self.state, self.fault, self.enable_requested = ControllerState.DISABLED, Fault.ESTOP, False
            return self._off()
        estimate = self.estimator.estimate(t)
        if estimate.fault is not None:
            if self.state is ControllerState.BALANCING:
                self.ever_stopped = True
                self.state, self.fault = ControllerState.FAULT, Fault.SENSOR_TIMEOUT
            return self._off()
        if self.state is not ControllerState.BALANCING:
            if not (self.enable_requested or (self.config.auto_enable and not self.ever_stopped)):
                if self.state is ControllerState.INIT:
                    self.state = ControllerState.DISABLED
                return self._off()
            self._start(t, estimate)

        planes = estimate.planes
        taring = t - self.balancing_since < self._tare_time
        moment = self._rider_moment(wrench, wrench_age, taring)
        cap = 0.0 if taring else self._cap(t, sc)
        stale = wrench is None or wrench_age > self._tes_hold
        self.fault = Fault.DEGRADED if estimate.degraded else Fault.TES_STALE if stale else Fault.NONE

        # Command speeds: pitch forward from My, roll "forward" (−y) from Mx.
        v = [
            self.commands[PITCH].update(moment[1], cap),
            self.commands[ROLL].update(moment[0], cap),
        ]
        norm = math.hypot(v[0], v[1])
        if norm > cap:  # the cap bounds the speed vector, not each plane
            v = [x * cap / norm for x in v]
            for c, x in zip(self.commands, v, strict=True):
                c.speed = x
        r = self._ball_radius
        yaw_cmd = 0.0 if taring else self.yaw.update(moment[2])

        tilt_cmd, tau = [0.0, 0.0], [0.0, 0.0]
        for k in (PITCH, ROLL):
            rate_cmd = v[k] / r
            feedforward = 0.0
            if self._compensated[k] and self.tare is not None:
                tilt_cmd[k], feedforward = self._compensation(k, moment, self.tare, planes[k].tilt, rate_cmd)
            tau[k] = self.balancers[k].torque(planes[k], rate_cmd, tilt_cmd[k], feedforward)
        tau_z = YAW_RATE_GAIN * (estimate.yaw_rate - yaw_cmd)
        ball = (tau[ROLL], tau[PITCH], tau_z)
        motor = [r[0] * ball[0] + r[1] * ball[1] + r[2] * ball[2] for r in self._motor_rows]
        peak = max(abs(motor[0]), abs(motor[1]), abs(motor[2]))
        if peak > self.motor_limit:
            motor = [m * self.motor_limit / peak for m in motor]
        return Output(
            (motor[0], motor[1], motor[2]),
            True,
            self.state,
            self.fault,
            (v[0], v[1]),
            (tilt_cmd[0], tilt_cmd[1]),
            yaw_cmd,
            ball,
        )

    def _off(self) -> Output:
        return Output((0.0, 0.0, 0.0), False, self.state, self.fault)

    def _start(self, t: float, estimate: Estimate) -> None:
        self.state, self.fault, self.enable_requested = ControllerState.BALANCING, Fault.NONE, False
        self.balancing_since = t
        for b, plane in zip(self.balancers, estimate.planes, strict=True):
            b.reset(plane.ball_rate)
        for c in self.commands:
            c.reset()

    def _cap(self, t: float, sc: ScCommand | None) -> float:
        if sc is None or t - sc.stamp > self._sc_max_age:
            return 0.0
        return sc.speed_limit()

    # ------------------------------------------------------------------------------------ rider input
    def _rider_moment(self, wrench: Wrench | None, age: float, taring: bool) -> list[float]:
        """Tared, low-passed seat moment [Mx, My, Mz] in body axes; zero while taring or stale. In scalars:
        numpy's per-call overhead dominates 3-vectors at 400 Hz (the same operations, in the same order)."""
        filtered = self._moment_filtered
        if wrench is None or age > self._tes_hold:
            filtered[0] = filtered[1] = filtered[2] = 0.0
            return filtered
        if taring:
            tare_sum = self._tare_sum
            for i, x in enumerate((*wrench.force, *wrench.moment)):
                tare_sum[i] += x
            self._tare_n += 1
            return [0.0, 0.0, 0.0]
        tare = self.tare
        if tare is None:
            tare = self._finish_tare()
            filtered[0] = filtered[1] = filtered[2] = 0.0
        alpha = self._alpha
        for i in range(3):
            filtered[i] += alpha * (wrench.moment[i] - tare[3 + i] - filtered[i])
        return filtered

    def _finish_tare(self) -> tuple[float, ...]:
        n = max(self._tare_n, 1)
        self.tare = tare = tuple(x / n for x in self._tare_sum)
        weight = -tare[2]
        if weight > 20.0:
            self.rider_mass = weight / (G0 * self.config.ihacs.seat_mass_fraction)
        if (
            self.config.mode == "ihacs"
            and self.config.ihacs.personalise_gains
            and self.rider_mass is not None
        ):
            for b, m in zip(self.balancers, self._models(self.rider_mass, self.rider.height), strict=True):
                b.set_model(m, lqr_gain(m, self.config.lqr))
        return tare

    def _compensation(
        self, plane: int, moment: list[float], tare: tuple[float, ...], tilt: float, ball_rate: float
    ) -> tuple[float, float]:
        """θ_EQ, τ_EQ for one plane from the rider's interaction moment at P.

        Convention (a) of docs/physics.md §4.3: the model's body includes the upright rider, so the
        interaction is the seat moment beyond that of a rigid upright rider at the current chassis tilt
        (tilting rotates that rider's weight in the seat frame: moment W (x_c cos θ + z_c sin θ) about P,
        with x_c from the tare and z_c the seat load's COM height from the rider model). The seat *forces*
        are left out: at a steady lean they are only the rider's weight, and their dynamic part is the
        inertia of a rider moving with the chassis, which the lumped model already has; feeding it back
        closes a loop from the chassis motion into θ_EQ (the stability pitfall of docs/physics.md §10).
        `moment`: the tared seat moment [Mx, My, Mz]; `tare`: the seat wrench averaged while taring
        (self.tare, set once taring has finished).
        """
        weight = -tare[2]
        axis = 1 if plane == PITCH else 0
        moment0 = tare[3 + axis]
        seat_moment = moment[axis] + moment0
        c, s = math.cos(tilt), math.sin(tilt)
        interaction = seat_moment - (moment0 * c + weight * self.seat_load_height * s)
        return equilibrium(self.balancers[plane].model, 0.0, 0.0, interaction, ball_rate)
