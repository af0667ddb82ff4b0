"""An Xsens MTi 600-series IMU on its CAN output, and the host's side of it: what a controller or a supervisor
reads (docs/devices.md).

Every output period the device sends one data group: SampleTime (100 us ticks), GroupCounter, StatusWord,
then EulerAngles, RateOfTurn and Acceleration (configs/devices/xsens_mti.dbc, frame id = base_id + XCID).
The host turns them into the contract's IMU_ATTITUDE (rad), IMU_RATE (rad/s) and IMU_ACCEL (m/s^2), with
Valid from the StatusWord (the filter's valid flag for the attitude, the clipping flags for the rates and
the accelerations).

The profile has no E2E protection. What stands in for an alive counter is the group's own: a data frame
is valid only if SampleTime and GroupCounter have both advanced since the last group that data frame was
passed on with. A device whose counter and sample time stop while its values go on (a stuck firmware
pipeline) or a repeated data frame therefore reaches the logic as Valid 0, which to the supervisor is the
IMU going silent.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntFlag
from functools import cache
from importlib.resources import files
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
import cantools

from drivers.can_bus import Received
from drivers.can_codec import MessageName
from drivers.devices import XSENS_XCIDS, Translator, XsensOptions, contract_ids
from drivers.devices.profile import PURE, Profile, find_profile

if TYPE_CHECKING:
    from drivers.devices import Devices, Role

DBC_NAME = "xsens_mti.dbc"
TIME_TICKS_PER_S = 10_000
"""SampleTime counts a 10 kHz clock."""
DATA = {
    "EulerAngles": MessageName.IMU_ATTITUDE,
    "RateOfTurn": MessageName.IMU_RATE,
    "Acceleration": MessageName.IMU_ACCEL,
}
"""The Xsens data message that carries each logical IMU message."""


class Status(IntFlag):
    """XDI_StatusWord bits the profile uses."""

    SELF_TEST = 1 << 0
    FILTER_VALID = 1 << 1
    CLIP_ACC_X = 1 << 8
    CLIP_ACC_Y = 1 << 9
    CLIP_ACC_Z = 1 << 10
    CLIP_GYR_X = 1 << 11
    CLIP_GYR_Y = 1 << 12
    CLIP_GYR_Z = 1 << 13


CLIP_ACC = Status.CLIP_ACC_X | Status.CLIP_ACC_Y | Status.CLIP_ACC_Z
CLIP_GYR = Status.CLIP_GYR_X | Status.CLIP_GYR_Y | Status.CLIP_GYR_Z
INVALID_IF = {
    "EulerAngles": None,  # valid only with FILTER_VALID set
    "RateOfTurn": CLIP_GYR,
    "Acceleration": CLIP_ACC,
}


def dbc_path() -> Path:
    """configs/devices/xsens_mti.dbc, from a checkout or an installed wheel (package `pure_hil_configs`)."""
    here = Path(__file__).resolve().parents[2] / "configs" / "devices" / DBC_NAME
    if here.is_file():
        return here
    return Path(str(files("pure_hil_configs") / "devices" / DBC_NAME))


@cache
def _messages() -> dict[int, Any]:
    """XCID -> the DBC's message (cantools)."""
    db = cantools.database.load_file(str(dbc_path()))
    if not isinstance(db, cantools.database.can.Database):
        raise TypeError(f"{dbc_path()}: not a CAN database")
    return {m.frame_id: m for m in db.messages}


class XsensWire:
    """Encode and decode the MTi's CAN messages with the project's DBC, at the bench's base id."""

    def __init__(self, base_id: int):
        self.base_id = base_id
        self._messages = _messages()
        self.ids = {name: base_id + xcid for name, xcid in XSENS_XCIDS.items()}
        self.names = {i: name for name, i in self.ids.items()}

    def frame(self, name: str, values: Mapping[str, float]) -> can.Message:
        message = self._messages[XSENS_XCIDS[name]]
        data = message.encode(dict(values), scaling=True, strict=False)
        return can.Message(arbitration_id=self.ids[name], data=data, is_extended_id=False)

    def raw(self, name: str, signal: str, value: float) -> int:
        """`value` in raw counts of `signal`, saturated at the signal's range (the device clips)."""
        sig = self._messages[XSENS_XCIDS[name]].get_signal_by_name(signal)
        lo, hi = -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
        return int(min(hi, max(lo, round(value / sig.scale))))

    def scale(self, name: str, signal: str) -> float:
        return float(self._messages[XSENS_XCIDS[name]].get_signal_by_name(signal).scale)

    def decode(self, msg: can.Message) -> tuple[str, dict[str, float]]:
        """(message name, signals). ValueError on an unknown id or a short frame."""
        name = self.names.get(msg.arbitration_id)
        if name is None:
            raise ValueError(f"no Xsens message at 0x{msg.arbitration_id:03X}")
        message = self._messages[XSENS_XCIDS[name]]
        if len(msg.data) < message.length:
            raise ValueError(f"{name}: {len(msg.data)} bytes, expected {message.length}")
        try:
            decoded: dict[str, float] = message.decode(bytes(msg.data[: message.length]))
        except Exception as exc:  # cantools raises its own DecodeError types
            raise ValueError(f"{name}: {exc}") from exc
        return name, decoded


def advanced(new: int, old: int | None, bits: int) -> bool:
    """A wrapping counter moved forward (by less than half its range) since `old` (None: never seen)."""
    if old is None:
        return True
    step = (new - old) % (1 << bits)
    return 0 < step < 1 << (bits - 1)


@dataclass(slots=True)
class Group:
    """What the host knows of the device's current data group."""

    sample_time: int | None = None
    counter: int | None = None
    status: int = 0
    errors: int = 0
    passed: dict[str, tuple[int, int]] = field(default_factory=dict)
    """Data message -> the (sample time, counter) of the group it was last passed on with."""


class XsensHost(Translator):
    """The host side of an Xsens MTi on CAN, for a controller or a supervisor."""

    def __init__(self, devices: Devices, counts_per_rev: int, role: Role):
        super().__init__()
        self.options, self.role = devices.xsens, role
        self.wire = XsensWire(self.options.base_id)
        self.frame_ids = frozenset(self.wire.ids.values())
        self.group = Group()
        self.stale = 0
        """Data frames held back as not valid because the group's counter or time had not advanced."""
        self.error_codes: list[int] = []

    def incoming(self, msg: can.Message) -> Received | None:
        if msg.is_remote_frame:
            return None
        name, s = self.wire.decode(msg)
        group = self.group
        if name == "SampleTime":
            group.sample_time = int(s["SampleTime"])
        elif name == "GroupCounter":
            group.counter = int(s["GroupCounter"])
        elif name == "StatusWord":
            group.status = int(s["StatusWord"])
        elif name == "Error":
            group.errors += 1
            self.error_codes.append(int(s["ErrorCode"]))
        else:
            return self._data(name, s, msg.timestamp)
        return None

    def _data(self, name: str, s: Mapping[str, float], timestamp: float) -> Received:
        group = self.group
        fresh = group.sample_time is not None and group.counter is not None
        if fresh:
            assert group.sample_time is not None and group.counter is not None
            last = group.passed.get(name)
            fresh = advanced(group.sample_time, None if last is None else last[0], 32) and advanced(
                group.counter, None if last is None else last[1], 16
            )
            if fresh:
                group.passed[name] = (group.sample_time, group.counter)
        if not fresh:
            self.stale += 1
        bad = INVALID_IF[name]
        ok = bool(group.status & Status.FILTER_VALID) if bad is None else not group.status & bad
        valid = int(fresh and ok)
        logical = DATA[name]
        if name == "EulerAngles":
            signals = {k: math.radians(s[k]) for k in ("Roll", "Pitch", "Yaw")}
        elif name == "RateOfTurn":
            signals = {"RateX": s["gyrX"], "RateY": s["gyrY"], "RateZ": s["gyrZ"]}
        else:
            signals = {"AccX": s["accX"], "AccY": s["accY"], "AccZ": s["accZ"]}
        return Received(logical, {**signals, "Valid": valid}, timestamp, None)


def host(devices: Devices, counts_per_rev: int, role: Role) -> XsensHost:
    return XsensHost(devices, counts_per_rev, role)


def check(devices: Devices) -> None:
    """The Xsens ids own no contract frame that stays on the bus and no frame of the drives' profile."""
    owner = {i: name for name, i in contract_ids(drives=devices.drives == PURE, imu=False).items()}
    if devices.drives != PURE:
        owner.update(find_profile(devices.drives).claims(devices))
    base = devices.xsens.base_id
    clash = sorted(
        f"{name} 0x{base + xcid:03X} on {owner[base + xcid]}"
        for name, xcid in XSENS_XCIDS.items()
        if base + xcid in owner
    )
    if clash:
        raise ValueError(
            f"xsens.base_id: 0x{base:03X} puts the Xsens {', '.join(clash)}: pick another base_id"
        )


PROFILE = Profile("xsens", "imu", XsensOptions, host, "hil.devices.xsens:emulate", check=check)
"""The `xsens` device profile (entry point `pure_hil.devices`)."""
