"""A lab's own drive profile, as tests/test_devices_plug.py installs it by one entry-point line: the drives
speak the contract's own DRIVEn_* frames (configs/can/pure.dbc, E2E sealed as the contract seals them),
but `shift` above the contract's ids, as a lab whose bus has other devices at 0x181-0x283 would put them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated

import can
import msgspec

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, Catalog
from drivers.devices import Devices, DriveHost, Role, Translator, contract_ids
from drivers.devices.profile import PURE, Profile

CATALOG = Catalog()
DRIVES = (*DRIVE_FEEDBACK, *DRIVE_TORQUE, *DRIVE_COMMAND)


class ShiftedOptions(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    shift: Annotated[int, msgspec.Meta(ge=1, le=0x7FF - 0x283)] = 0x400
    """Added to each DRIVEn frame's id (0x283, DRIVE3_TORQUE, is the highest)."""


def shift_of(devices: Devices) -> int:
    options = devices.options("shifted")
    assert isinstance(options, ShiftedOptions)
    return options.shift


def shifted(msg: can.Message, by: int) -> can.Message:
    return can.Message(arbitration_id=msg.arbitration_id + by, data=bytes(msg.data), is_extended_id=False)


def ids(names: tuple[str, ...], shift: int) -> frozenset[int]:
    return frozenset(CATALOG[n].frame_id + shift for n in names)


def unshifted(msg: can.Message, shift: int) -> Received:
    """A shifted frame -> the contract message it carries (ValueError, counted by the node, if it does not
    decode)."""
    codec = CATALOG.by_id(msg.arbitration_id - shift)
    if codec is None:
        raise ValueError(f"no contract frame at 0x{msg.arbitration_id - shift:03X}")
    return Received(codec.name, codec.decode(msg.data), msg.timestamp, None)


class ShiftedHost(DriveHost):
    profile = "shifted"

    def __init__(self, devices: Devices, counts_per_rev: int, role: Role):
        super().__init__(role)
        self.shift = shift_of(devices)
        self.frame_ids = ids(DRIVES, self.shift)
        self.sends = ids(DRIVE_COMMAND, self.shift)

    def _command(self, index: int, torque: float, enable: bool) -> list[can.Message]:
        assert self.node is not None
        values = {"Torque": torque, "Enable": int(enable), "Tick": self.tick}
        return [shifted(self.node.contract_frame(DRIVE_COMMAND[index], values), self.shift)]

    def _stop(self, index: int) -> list[can.Message]:
        return []  # the contract's SUPERVISOR_ESTOP is these drives' stop

    def incoming(self, msg: can.Message) -> Received | None:
        return unshifted(msg, self.shift)


class ShiftedDrives(Translator):
    """The rig's side: the plant's drive feedback out on the shifted ids, the host's commands in."""

    profile = "shifted"

    def __init__(self, devices: Devices, counts_per_rev: int, tick_hz: float):
        super().__init__()
        self.shift = shift_of(devices)
        self.names = frozenset((*DRIVE_FEEDBACK, *DRIVE_TORQUE))
        self.frame_ids = ids(DRIVE_COMMAND, self.shift)
        self.sends = ids((*DRIVE_FEEDBACK, *DRIVE_TORQUE), self.shift)

    def outgoing(self, name: str, values: Mapping[str, float]) -> list[can.Message]:
        assert self.node is not None
        return [shifted(self.node.contract_frame(name, values), self.shift)]

    def incoming(self, msg: can.Message) -> Received | None:
        return unshifted(msg, self.shift)


def claims(devices: Devices) -> dict[int, str]:
    return {i: "a shifted drive's frames" for i in ids(DRIVES, shift_of(devices))}


def check(devices: Devices) -> None:
    kept = {i: name for name, i in contract_ids(drives=False, imu=devices.imu == PURE).items()}
    clash = sorted(kept[i] for i in claims(devices) if i in kept)
    if clash:
        raise ValueError(f"settings.shifted.shift: puts a drive frame on the contract's {', '.join(clash)}")


PROFILE = Profile(
    "shifted", "drives", ShiftedOptions, ShiftedHost, "tests.shifted_profile:ShiftedDrives", claims, check
)
