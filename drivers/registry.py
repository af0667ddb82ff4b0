"""The one registry of bench parts: each kind of part is an entry-point group, and a part is found by name in
its group and imported only then, as python-can finds a bus backend. Built-in parts are entry points of this
package (pyproject.toml); a lab's own are entry points of its package, one line each.

    find_plug(DEVICE_PROFILES, "odrive", "device profile")     installed(DEVICE_PROFILES)

A kind of part with a typed start wraps find_plug: drivers.dut.start_dut, drivers.plugs.start_supervisor.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

CONTROLLERS = "pure_hil.controllers"
"""start(DutSpec) -> handle: the controller under test (drivers/dut.py)."""
SUPERVISORS = "pure_hil.supervisors"
"""start(SupervisorSpec, link=None) -> handle: the supervisor (drivers/plugs.py)."""
SUPERVISOR_RULES = "pure_hil.supervisor_rules"
"""The type of a supervisor's rules (a msgspec Struct, by the supervisor's name): the rig checks a bench's
rules file with a scenario's overrides against it before the run (drivers/rules.py). Optional."""
PLANTS = "pure_hil.plants"
"""A plant: a class `cls(robot, rider, sim, intent, initial_tilt)`, a `plant.core.PlantCore` with its
`PlantMechanics`, named by the sim settings' `plant` (hil/run/plants.py)."""
FAULT_FAMILIES = "pure_hil.faults"
"""A fault family: a tuple of fault classes (`hil.faults.base.FaultSpec`), each tagged by its `kind`
(hil/faults/__init__.py)."""
DEVICE_PROFILES = "pure_hil.devices"
"""A DeviceProfile: a device profile's name, kind, settings, host and emulation, one line each
(drivers/devices/profile.py)."""


class PlugNotFound(LookupError):
    pass


class BrokenPlug(PlugNotFound):
    """An entry point that is installed but does not load, or is not the kind of part its group holds."""


def installed(group: str) -> list[str]:
    """The names registered in `group`, sorted."""
    return sorted(ep.name for ep in entry_points(group=group))


def find_plug(group: str, name: str, what: str) -> Callable[..., Any]:
    """The callable registered as `name` in entry-point group `group` (imported only now); PlugNotFound
    names `what`, the group and what is installed."""
    found = {ep.name: ep for ep in entry_points(group=group)}
    if name not in found:
        raise PlugNotFound(f"no {what} {name!r} in entry points {group!r} (have: {', '.join(sorted(found))})")
    try:
        plug: Callable[..., Any] = found[name].load()  # an entry point: whatever it loads is untyped
    except (ImportError, AttributeError) as exc:  # the lab's package is there, its line is wrong
        raise BrokenPlug(f"{what} {name!r}: entry point {found[name].value!r} does not load: {exc}") from None
    return plug
