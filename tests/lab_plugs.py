"""A lab's own plant and fault family, as a lab's package holds them: tests/test_plant_fault_plugs.py
registers them through a dist-info of their own, one entry-point line each, as `pip install` leaves it."""

from __future__ import annotations

from typing import Annotated, ClassVar

from hil.faults.base import Bound, FaultSpec, FaultState, FaultTarget
from plant.ballbot import Plant


class LabPlant(Plant):
    """The planar plant under a lab's name: the run shows which class it built."""


class Twist(FaultSpec, frozen=True, tag="lab.twist"):
    """A yaw torque on the robot for the fault's duration (a hand turning the chassis)."""

    torque: Annotated[float, Bound(magnitude=True, high=20.0, why="Nm; a hand on the chassis")] = 10.0
    disturbance: ClassVar[bool] = True

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        rig.plant.external_yaw = self.torque

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        rig.plant.external_yaw = 0.0


FAULTS: tuple[type[FaultSpec], ...] = (Twist,)
"""The family's fault classes: what its entry point names."""

ENTRY_POINTS = (
    "[pure_hil.plants]\nlab = tests.lab_plugs:LabPlant\n\n[pure_hil.faults]\nlab = tests.lab_plugs:FAULTS\n"
)
"""The lab's package's entry points: one line for the plant, one for the fault family."""
