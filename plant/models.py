"""The plant a run simulates, by the sim settings' `plant`: 3d (MuJoCo, plant/ballbot3d.py) or planar
(plant/ballbot.py). The 3-D plant's module, and MuJoCo with it, is imported only when it is asked for."""

from __future__ import annotations

from plant.ballbot import Plant, PlantCore, RiderIntent
from plant.params import RiderParams, RobotParams, SimParams


def make_plant(
    robot: RobotParams,
    rider: RiderParams | None,
    sim: SimParams,
    intent: RiderIntent | None = None,
    initial_tilt: tuple[float, float] = (0.0, 0.0),
) -> PlantCore:
    if sim.plant == "3d":
        from plant.ballbot3d import Plant3D

        return Plant3D(robot, rider, sim, intent, initial_tilt)
    return Plant(robot, rider, sim, intent, initial_tilt)
