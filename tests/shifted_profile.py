"""A lab's own drive profile, as tests/test_devices_plug.py installs it by one entry-point line: the drives
speak the contract's own DRIVEn_* frames (configs/can/pure.dbc, E2E sealed as the contract seals them),
but 0x400 above the contract's ids, as a lab whose bus has other devices at 0x181-0x283 would put them.
"""

from __future__ import annotations

from collections.abc import Mapping

import can
import msgspec

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, Catalog
from drivers.devices import Devices, DriveHost, Role, Translator
from drivers.devices.profile import Profile

SHIFT = 0x400
CATALOG = Catalog()


class ShiftedOptions(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """None to set: the shift is the profile's."""


def shifted(msg: can.Message, by: int = SHIFT) -> can.Message:
    return can.Message(arbitration_id=msg.arbitration_id + by, data=bytes(msg.data), is_extended_id=False)


def ids(names: tuple[str, ...]) -> frozenset[int]:
    return frozenset(CATALOG[n].frame_id + SHIFT for n in names)


def unshifted(msg: can.Message) -> Received:
    """A shifted frame -> the contract message it carries (ValueError, counted by the node, if it does not
    decode)."""
    codec = CATALOG.by_id(msg.arbitration_id - SHIFT)
    if codec is None:
        raise ValueError(f"no contract frame at 0x{msg.arbitration_id - SHIFT:03X}")
    return Received(codec.name, codec.decode(msg.data), msg.timestamp, None)


class ShiftedHost(DriveHost):
    profile = "shifted"

    def __init__(self, devices: Devices, counts_per_rev: int, role: Role):
        super().__init__(role)
        self.frame_ids = ids((*DRIVE_FEEDBACK, *DRIVE_TORQUE, *DRIVE_COMMAND))
        self.sends = ids(DRIVE_COMMAND)

    def _command(self, index: int, torque: float, enable: bool) -> list[can.Message]:
        assert self.node is not None
        values = {"Torque": torque, "Enable": int(enable), "Tick": self.tick}
        return [shifted(self.node.contract_frame(DRIVE_COMMAND[index], values))]

    def _stop(self, index: int) -> list[can.Message]:
        return []  # the contract's SUPERVISOR_ESTOP is these drives' stop

    def incoming(self, msg: can.Message) -> Received | None:
        return unshifted(msg)


class ShiftedDrives(Translator):
    """The rig's side: the plant's drive feedback out on the shifted ids, the host's commands in."""

    profile = "shifted"

    def __init__(self, devices: Devices, counts_per_rev: int, tick_hz: float):
        super().__init__()
        self.names = frozenset((*DRIVE_FEEDBACK, *DRIVE_TORQUE))
        self.frame_ids = ids(DRIVE_COMMAND)
        self.sends = ids((*DRIVE_FEEDBACK, *DRIVE_TORQUE))

    def outgoing(self, name: str, values: Mapping[str, float]) -> list[can.Message]:
        assert self.node is not None
        return [shifted(self.node.contract_frame(name, values))]

    def incoming(self, msg: can.Message) -> Received | None:
        return unshifted(msg)


def claims(devices: Devices) -> dict[int, str]:
    return {i: "a shifted drive" for i in ids((*DRIVE_FEEDBACK, *DRIVE_TORQUE, *DRIVE_COMMAND))}


PROFILE = Profile(
    "shifted", "drives", ShiftedOptions, ShiftedHost, "tests.shifted_profile:ShiftedDrives", claims
)
