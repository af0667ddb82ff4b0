"""Actuator and plant faults: the drives misbehave, or the world pushes on the robot and its rider."""

from __future__ import annotations

import math
import typing
from typing import Annotated, ClassVar

from hil.faults.base import Bound, FaultSpec, FaultState, FaultTarget, Motor
from plant.params import RiderParams
from plant.plane import Wrench

HEAVIEST_RIDER = typing.get_type_hints(RiderParams, include_extras=True)["mass"].__metadata__[0].lt
"""kg: the heaviest rider a rider file may describe (plant/params.py)."""
PUSH = round(HEAVIEST_RIDER * 9.81)
"""N: the largest push, the heaviest rider's weight."""
REACH = 0.4
"""m: a hand's distance from the vertical axis through P, at a rider's shoulder."""


Newtons = Annotated[
    float,
    Bound(
        magnitude=True,
        high=PUSH,
        why=f"N, each component; the weight of the heaviest rider a rider file may describe "
        f"({HEAVIEST_RIDER:g} kg): a larger force is a collision, not a push to ride through",
    ),
]
Lean = Annotated[
    float, Bound(magnitude=True, high=90.0, why="deg; past horizontal a torso is no seated rider's")
]


class PlantFault(FaultSpec, frozen=True, kw_only=True):
    """A fault of the robot's drives, or something the world or the rider does to it."""


class DriveFault(PlantFault, frozen=True, kw_only=True):
    """A fault of one drive: the supervisor must see it within 50 ms."""

    motor: Motor
    detect_within: ClassVar[float] = 0.05


class DriveTorque(DriveFault, frozen=True, tag="plant.drive_torque"):
    """Drive `motor` produces `scale` times the torque it is commanded (0: torque lost, the drive still
    reports itself enabled)."""

    scale: Annotated[
        float,
        Bound(
            0.0,
            10.0,
            why="a drive producing more than 10x its command is no drive's torque constant; its torque "
            "limit clamps what it produces anyway",
        ),
    ] = 0.0

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        rig.plant.drives.motors[self.motor - 1].gain = self.scale

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        rig.plant.drives.motors[self.motor - 1].gain = 1.0


class DriveStuckEnabled(DriveFault, frozen=True, tag="plant.drive_stuck_enabled"):
    """Drive `motor`'s power stage cannot be switched off: it ignores disable, its watchdog and the
    supervisor's e-stop, and holds its last setpoint (latent until the drives are told to turn off)."""

    latent: ClassVar[bool] = True

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        rig.plant.drives.motors[self.motor - 1].stuck_enabled = True

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        rig.plant.drives.motors[self.motor - 1].stuck_enabled = False


class Push(PlantFault, frozen=True, tag="plant.push"):
    """A push on the robot for the fault's duration: `force` (N; forward, left) applied `height` metres
    above the chassis top P (0: on the chassis; about 0.4: the rider's chest), and a `twist` about the
    vertical (Nm). The rider is taken as rigid with the chassis for the push: its wrench acts at P."""

    force: tuple[Newtons, Newtons] = (0.0, 0.0)
    height: Annotated[
        float,
        Bound(
            -1.0,
            1.5,
            why="m; a point of the robot or its seated rider: PURE's P is about 0.5 m above the floor, the "
            "tallest rider's head about 1.2 m above P",
        ),
    ] = 0.0
    twist: Annotated[
        float,
        Bound(
            magnitude=True,
            high=PUSH * REACH,
            why=f"Nm; the largest push at a rider's shoulder, {REACH:g} m from the vertical axis",
        ),
    ] = 0.0
    disturbance: ClassVar[bool] = True

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        forward, left = self.force
        # The roll plane's forward is −y; a force above P also turns the plane about P (r × F).
        rig.plant.external = [
            Wrench(forward=forward, moment=self.height * forward),
            Wrench(forward=-left, moment=-self.height * left),
        ]
        rig.plant.external_yaw = self.twist

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        rig.plant.external = [None, None]
        rig.plant.external_yaw = 0.0


class MassShift(PlantFault, frozen=True, tag="plant.mass_shift"):
    """The rider's weight shifts suddenly by a torso lean of `pitch_deg` (forward) and `roll_deg`, on top of
    whatever the rider does (a slip on the seat, a reach for something; in 30 ms, as fast as a body's mass
    moves); lasts the fault's duration."""

    pitch_deg: Lean = 0.0
    roll_deg: Lean = 0.0
    disturbance: ClassVar[bool] = True

    def validate(self, rig: FaultTarget) -> None:
        if rig.plant.torso is None:
            raise ValueError("plant.mass_shift needs a rider")

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        torsos = rig.plant.torso
        assert torsos is not None  # validate() refused a plant without a rider
        for torso, deg in zip(torsos, (self.pitch_deg, self.roll_deg), strict=True):
            torso.shift = math.radians(deg)

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        torsos = rig.plant.torso
        assert torsos is not None  # validate() refused a plant without a rider
        for torso in torsos:
            torso.shift = 0.0


FAULTS: tuple[type[FaultSpec], ...] = (DriveTorque, DriveStuckEnabled, Push, MassShift)
