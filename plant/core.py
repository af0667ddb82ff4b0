"""What every plant is: `PlantCore`, the part all plants share (the drives, the sensors' models, the rider's
intent and torso control, the supervisor's alert, pushes), and `PlantMechanics`, what a plant adds to it (its
bodies' motion, truth, energy, poses and what the sensors read). The planar plant (plant/ballbot.py), the 3-D
plant (plant/ballbot3d.py) and a lab's own plant (an entry point of `pure_hil.plants`, hil/run/plants.py) are
each a `PlantCore` subclass with `PlantMechanics`.

The rig holds a plant as a `PlantCore`, not as the Protocol: the compiled build's tick reads its attributes
natively (a Protocol is an `object` to mypyc, every attribute a dictionary lookup).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from mypy_extensions import mypyc_attr

from plant.anthropometry import SeatedRider, seat_rider
from plant.drives import DriveArray
from plant.omniwheel import motor_jacobian
from plant.params import RiderParams, RobotParams, SimParams
from plant.plane import Wrench
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
"""The two vertical planes' indices (tilt, lean and the planar plant's state are (pitch, roll) pairs)."""


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


@mypyc_attr(allow_interpreted_subclasses=True)  # a lab's own plant (hil/run/plants.py) may be one
class PlantCore:
    """What both plants share: the drives, the sensors' models, the rider's intent and torso control, the
    supervisor's alert, pushes and the outputs' per-tick caches. A plant adds its mechanics:
    `_build_mechanics()`, `step()`, `truth()`, `imu_truth()`, `motor_angles_and_rates()`,
    `_compute_seat_wrench()`, `energy()`."""

    def __init__(
        self,
        robot: RobotParams,
        rider: RiderParams | None,
        sim: SimParams,
        intent: RiderIntent | None = None,
        initial_tilt: tuple[float, float] = (0.0, 0.0),
    ):
        """The plant plug's call (hil/run/plants.py): what every plant shares, then its own mechanics."""
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
        self._build_mechanics(initial_tilt)

    def _build_mechanics(self, initial_tilt: tuple[float, float]) -> None:
        """Build this plant's bodies on the shared parts above, at rest, tilted `initial_tilt` (pitch,
        roll), rad."""
        raise NotImplementedError

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

    def body_model(self) -> object:
        """The compiled MuJoCo model (`mujoco.MjModel`) whose bodies `poses()` places, for the outputs that
        draw them (hil/outputs/bodies.py): the 3-D model of this robot and rider (plant/model3d.py),
        compiled now; a plant that simulates on one returns its own."""
        import mujoco

        from plant.model3d import build_model

        sim = self.sim
        return mujoco.MjModel.from_xml_string(build_model(self.robot, self.rider, sim.mujoco, sim.dt).xml)

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


class PlantMechanics(Protocol):
    """What a plant adds to PlantCore: its bodies' motion, and what the shared sensors and outputs read of
    it. Both plants are checked against it (mypy, below)."""

    @property
    def velocity(self) -> tuple[float, float]:
        """Ground speed in the heading frame (forward, left), m/s."""
        ...

    def step(self) -> None:
        """Advance one tick (`dt`) under the drives' torques, the rider and any push; set `fallen`."""
        ...

    def truth(self) -> Truth: ...

    def energy(self) -> float:
        """Kinetic + potential energy, J (the physics checks' conserved quantity)."""
        ...

    def poses(self) -> dict[str, Pose]: ...

    def motor_angles_and_rates(self) -> tuple[list[float], list[float]]:
        """Each motor's shaft angle (rad) and rate (rad/s): what the drives' encoders measure."""
        ...

    def imu_truth(
        self,
    ) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
        """The chassis' attitude (roll, pitch, yaw), body rates and the IMU's specific force, before noise."""
        ...
