"""The rig's emulated devices: the drives and the IMU as the bench's device profile puts them on the wire
(docs/devices.md). A profile's emulation is named by its profile, found by name in the entry-point group
`pure_hil.devices` (drivers/devices/profile.py; imported only when a bench names it); `pure`, the
contract's own frames, needs none.
"""

from __future__ import annotations

import can

from drivers.can_bus import CanNode
from drivers.devices import Devices, ProfileNode
from drivers.devices.profile import Emulate, find_profile


def emulation(profile: str) -> Emulate:
    """The rig's side of an installed profile."""
    return find_profile(profile).emulation()


def rig_node(bus: can.BusABC, devices: Devices, counts_per_rev: int, tick_hz: float) -> CanNode:
    """The rig's node: the devices' frames as the bench's profile speaks them."""
    if devices.pure:
        return CanNode(bus, name="rig")
    emulations = [emulation(profile)(devices, counts_per_rev, tick_hz) for profile in devices.profiles]
    return ProfileNode(bus, emulations, name="rig")
