"""The plants a run can simulate: plugs of the entry-point group `pure_hil.plants` (drivers/registry.py), by
the name the sim settings' `plant` (or a bench's) gives. This package registers its two the same way as a
lab registers its own (pyproject.toml): `3d` (MuJoCo, plant/ballbot3d.py) and `planar` (plant/ballbot.py).
A plant's module, and MuJoCo with the 3-D one, is imported only when a run asks for it.

A plant is a class `cls(robot, rider, sim, intent, initial_tilt)`: a `plant.core.PlantCore` with its
`PlantMechanics` (docs/architecture.md, "Parts: plugs").
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from drivers.config import ConfigError, load_toml
from drivers.registry import PLANTS, BrokenPlug, find_plug, installed
from plant.core import PlantCore, PlantMechanics, RiderIntent
from plant.params import RiderParams, RobotParams, SimParams

if TYPE_CHECKING:
    from plant.ballbot import Plant
    from plant.ballbot3d import Plant3D

    _CHECKED: tuple[type[PlantMechanics], ...] = (Plant, Plant3D)


PlantClass = Callable[
    [RobotParams, RiderParams | None, SimParams, RiderIntent | None, tuple[float, float]], PlantCore
]
"""A plant plug: its class, called with the robot, the rider (None: the robot alone), the sim settings, the
rider's intent and the chassis' initial tilt (pitch, roll), rad."""


def plant_class(name: str) -> PlantClass:
    """The plant registered as `name`; PlugNotFound names the group and what is installed, BrokenPlug an
    entry point that is not a PlantCore."""
    found = find_plug(PLANTS, name, "plant")
    if not (isinstance(found, type) and issubclass(found, PlantCore)):
        raise BrokenPlug(f"plant {name!r}: its entry point is {found!r}, not a plant.core.PlantCore subclass")
    cls: PlantClass = found
    return cls


def load_sim(path: Path | str) -> SimParams:
    """A sim settings file whose `plant` is installed; ConfigError names the file, the field and the plants
    installed."""
    sim = load_toml(path, SimParams)
    have = installed(PLANTS)
    if sim.plant not in have:
        raise ConfigError(path, f"no plant {sim.plant!r} installed (have: {', '.join(have)}) - at `$.plant`")
    return sim


def make_plant(
    robot: RobotParams,
    rider: RiderParams | None,
    sim: SimParams,
    intent: RiderIntent | None = None,
    initial_tilt: tuple[float, float] = (0.0, 0.0),
) -> PlantCore:
    return plant_class(sim.plant)(robot, rider, sim, intent, initial_tilt)
