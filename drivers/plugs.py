"""Bench parts as plugs (docs/architecture.md, "Parts"): the controller under test (drivers/dut.py) and the
supervisor are found by name in an entry-point group, as python-can finds a bus backend, and started from a
spec that says where everything is. The same plug runs in the rig's process (embedded) or, from its spec
serialised to JSON, in a child process the rig starts (`pure-hil part KIND PLUGIN SPEC.json`).

    start(spec) -> handle      handle.stop(); handle.poll() for a part the rig drives in lockstep

The device profiles' emulations are plugs of the same kind on the rig's side (hil/devices/).
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

import msgspec

from drivers.bus_config import BusConfig
from drivers.devices import Devices
from drivers.zenoh_access import ZenohAccess

SUPERVISORS = "pure_hil.supervisors"


class PlugNotFound(LookupError):
    pass


def find_plug(group: str, name: str, what: str) -> Callable[..., Any]:
    """The start function registered as `name` in entry-point group `group` (imported only now)."""
    found = {ep.name: ep for ep in entry_points(group=group)}
    if name not in found:
        raise PlugNotFound(f"no {what} {name!r} in entry points {group!r} (have: {', '.join(sorted(found))})")
    start: Callable[..., Any] = found[name].load()  # an entry point: whatever it loads is untyped
    return start


class SupervisorSpec(msgspec.Struct, frozen=True, kw_only=True):
    """Where a supervisor plug finds its bus and zenoh, and what it enforces."""

    can: BusConfig
    zenoh: ZenohAccess = ZenohAccess()
    devices: Devices = Devices()
    robot: str
    """Robot TOML of its geometry (drive limits, encoders, wheels)."""
    rules: dict[str, Any] = {}
    """Its rules as a SupervisorConfig's fields (the bench's file with the scenario's `[safety]`)."""
    tick_hz: float = 400.0
    lockstep: bool = True
    """It decides once per SYNC (lockstep) or on its own timer (real time)."""
    driven: bool = False
    """The rig updates it from its own tick (embedded): no thread of its own, and the rig hands it the zenoh
    link whose puts the lockstep fence counts."""
