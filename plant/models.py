"""The plants a run can simulate, in one table by the sim settings' `plant` (`PlantName`): 3d (MuJoCo,
plant/ballbot3d.py) or planar (plant/ballbot.py). A plant's module, and MuJoCo with the 3-D one, is imported
only when it is asked for.

A plant is a `PlantCore` plus its mechanics, `PlantMechanics` (plant/core.py).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, get_args

from plant.core import PlantCore, PlantMechanics, RiderIntent
from plant.params import PlantName, RiderParams, RobotParams, SimParams

PLANTS: dict[str, str] = {"3d": "plant.ballbot3d:Plant3D", "planar": "plant.ballbot:Plant"}
"""Each plant's class, "module:class", imported when a run asks for it."""
assert set(PLANTS) == set(get_args(PlantName)), "every plant name has its class, and no other"


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
