"""The plants a run can simulate, in one table by the sim settings' `plant` (`PlantName`): 3d (MuJoCo,
plant/ballbot3d.py) or planar (plant/ballbot.py). A plant's module, and MuJoCo with the 3-D one, is imported
only when it is asked for.

A plant is a `PlantCore` (plant/ballbot.py: the drives, the sensors' models, the rider, the supervisor's
alert, pushes, shared by every plant) plus its mechanics, `PlantMechanics` below. The rig holds a plant as
a `PlantCore`, not as a Protocol: the compiled build's tick reads its attributes natively (a Protocol is an
`object` to mypyc, every attribute a dictionary lookup).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Protocol, get_args

from plant.ballbot import PlantCore, Pose, RiderIntent, Truth
from plant.params import PlantName, RiderParams, RobotParams, SimParams

PLANTS: dict[str, str] = {"3d": "plant.ballbot3d:Plant3D", "planar": "plant.ballbot:Plant"}
"""Each plant's class, "module:class", imported when a run asks for it."""
assert set(PLANTS) == set(get_args(PlantName)), "every plant name has its class, and no other"


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


if TYPE_CHECKING:
    from plant.ballbot import Plant
    from plant.ballbot3d import Plant3D

    _CHECKED: tuple[type[PlantMechanics], ...] = (Plant, Plant3D)


def make_plant(
    robot: RobotParams,
    rider: RiderParams | None,
    sim: SimParams,
    intent: RiderIntent | None = None,
    initial_tilt: tuple[float, float] = (0.0, 0.0),
) -> PlantCore:
    module, name = PLANTS[sim.plant].split(":")
    plant: PlantCore = getattr(importlib.import_module(module), name)(robot, rider, sim, intent, initial_tilt)
    return plant
