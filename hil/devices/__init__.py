"""The rig's emulated devices: the drives and the IMU as the bench's device profile puts them on the wire
(docs/devices.md). A profile's emulation is a plug found by name in the entry-point group
`pure_hil.devices` (drivers/registry.py; imported only when a bench names it); `pure`, the contract's own
frames, needs none.
"""

from __future__ import annotations

from collections.abc import Callable

import can

from drivers.can_bus import CanNode
from drivers.devices import Devices, ProfileNode, Translator
from drivers.registry import DEVICE_EMULATIONS, find_plug

Emulation = Callable[[Devices, int, float], Translator]
"""(the bench's devices, the plant encoders' counts per revolution, the tick rate in Hz) -> the device-side
translator."""


def emulation(profile: str) -> Emulation:
    factory: Emulation = find_plug(DEVICE_EMULATIONS, profile, "device profile")
    return factory


def rig_node(bus: can.BusABC, devices: Devices, counts_per_rev: int, tick_hz: float) -> CanNode:
    """The rig's node: the devices' frames as the bench's profile speaks them."""
    if devices.pure:
        return CanNode(bus, name="rig")
    emulations = [emulation(profile)(devices, counts_per_rev, tick_hz) for profile in devices.profiles]
    return ProfileNode(bus, emulations, name="rig")
