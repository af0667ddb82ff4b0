"""The rig's emulated devices: the drives and the IMU as the bench's device profile puts them on the wire
(docs/devices.md). A profile's emulation is a plug found by name in the entry-point group
`pure_hil.devices` (imported only when a bench names it); `pure`, the contract's own frames, needs none.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import entry_points

import can

from drivers.can_bus import CanNode
from drivers.devices import Devices, ProfileNode, Translator

GROUP = "pure_hil.devices"

Emulation = Callable[[Devices, int, float], Translator]
"""(the bench's devices, the plant encoders' counts per revolution, the tick rate in Hz) -> the device-side
translator."""


class DeviceProfileNotFound(LookupError):
    pass


def emulation(profile: str) -> Emulation:
    found = {ep.name: ep for ep in entry_points(group=GROUP)}
    if profile not in found:
        raise DeviceProfileNotFound(
            f"no device profile {profile!r} in entry points {GROUP!r} (have: {', '.join(sorted(found))})"
        )
    factory: Emulation = found[profile].load()
    return factory


def rig_node(bus: can.BusABC, devices: Devices, counts_per_rev: int, tick_hz: float) -> CanNode:
    """The rig's node: the devices' frames as the bench's profile speaks them."""
    if devices.pure:
        return CanNode(bus, name="rig")
    emulations = [emulation(profile)(devices, counts_per_rev, tick_hz) for profile in devices.profiles]
    return ProfileNode(bus, emulations, name="rig")
