"""CANopen CiA 402 drives in cyclic synchronous torque (configs/devices/cia402.eds), and the host's side of
them: what a controller or a supervisor sends and reads (docs/devices.md).

The PDO mapping is the EDS's (CiA 301 predefined connection set, COB-ID = function + node id):

- TPDO1 0x180+id, every SYNC: statusword 0x6041 (U16), modes of operation display 0x6061 (I8), error code
  0x603F (U16);
- TPDO2 0x280+id, every SYNC: position actual 0x6064 (I32, encoder increments), velocity actual 0x606C (I32,
  increments/s);
- TPDO3 0x380+id, every 4th SYNC: torque actual 0x6077 (I16, per mille of the rated torque 0x6076 = 1 Nm:
  mNm);
- RPDO1 0x200+id: controlword 0x6040 (U16), target torque 0x6071 (I16, mNm); RPDO2 0x300+id: modes of
  operation 0x6060 (I8).

The host keeps each drive's last statusword and error code (TPDO1) and turns TPDO2 into the contract's
DRIVEn_FEEDBACK, TPDO3 into DRIVEn_TORQUE, and a DRIVEn_COMMAND into RPDO1 frames: the controlword walk to
OPERATION ENABLED when Enable goes 1 (fault reset first where the drive is in FAULT), disable voltage while it
is 0. No SDO in the hot path: the mapping is the EDS's, known to both sides.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum
from importlib.resources import files
from pathlib import Path
from typing import TYPE_CHECKING

import can

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE
from drivers.devices import CANOPEN_FUNCTIONS, Cia402Options, DriveHost, contract_ids
from drivers.devices.profile import PURE, Profile

if TYPE_CHECKING:
    from drivers.devices import Devices, Role

NMT, EMCY, TPDO1, RPDO1, TPDO2, RPDO2, TPDO3, SDO_TX, SDO_RX, HEARTBEAT = (
    0x000, 0x080, 0x180, 0x200, 0x280, 0x300, 0x380, 0x580, 0x600, 0x700,
)  # fmt: skip
CST = 10
"""Modes of operation: cyclic synchronous torque."""
RATED_MNM = 1000
"""0x6076 motor rated torque, mNm: torque objects are per mille of it, so 1 unit = 1 mNm."""
TORQUE_EVERY = 4
"""TPDO3's transmission type: every 4th SYNC (100 Hz at a 400 Hz tick, the contract's DRIVEn_TORQUE rate)."""

TPDO1_FMT = struct.Struct("<HbH")
TPDO2_FMT = struct.Struct("<ii")
TPDO3_FMT = struct.Struct("<h")
RPDO1_FMT = struct.Struct("<Hh")


class State(IntEnum):
    """CiA 402 drive states."""

    NOT_READY_TO_SWITCH_ON = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7


STATUS_BITS = {
    State.NOT_READY_TO_SWITCH_ON: 0x00,
    State.SWITCH_ON_DISABLED: 0x40,
    State.READY_TO_SWITCH_ON: 0x21,
    State.SWITCHED_ON: 0x23,
    State.OPERATION_ENABLED: 0x27,
    State.QUICK_STOP_ACTIVE: 0x07,
    State.FAULT_REACTION_ACTIVE: 0x0F,
    State.FAULT: 0x08,
}
"""The statusword's state bits (0-3, 5, 6) per state."""
VOLTAGE_ENABLED = 0x0010
REMOTE = 0x0200


def state_of(statusword: int) -> State:
    """The state a statusword shows (the masks of CiA 402 / python-canopen's BaseNode402)."""
    for state, bits in STATUS_BITS.items():
        mask = 0x4F if state in _MASK_4F else 0x6F
        if statusword & mask == bits:
            return state
    return State.NOT_READY_TO_SWITCH_ON


_MASK_4F = {
    State.NOT_READY_TO_SWITCH_ON,
    State.SWITCH_ON_DISABLED,
    State.FAULT_REACTION_ACTIVE,
    State.FAULT,
}


class Cw(IntEnum):
    """Controlword commands (CiA 402)."""

    DISABLE_VOLTAGE = 0x00
    QUICK_STOP = 0x02
    SHUTDOWN = 0x06
    SWITCH_ON = 0x07
    ENABLE_OPERATION = 0x0F
    FAULT_RESET = 0x80


class ErrorCode(IntEnum):
    """0x603F / EMCY error codes the emulation raises (CiA 301/402), with the error register bits."""

    NONE = 0x0000
    DC_LINK_UNDER_VOLTAGE = 0x3220
    POWER_SECTION = 0x5400
    COMMUNICATION = 0x8100
    """The drive's command watchdog (no command for its timeout)."""
    POWER_STAGE_OFF = 0xFF01
    """Manufacturer specific: the power stage went off without a controlword (the supervisor's permission
    line, like a safe-torque-off input)."""


ERROR_REGISTER = {
    ErrorCode.NONE: 0x00,
    ErrorCode.DC_LINK_UNDER_VOLTAGE: 0x05,
    ErrorCode.POWER_SECTION: 0x03,
    ErrorCode.COMMUNICATION: 0x11,
    ErrorCode.POWER_STAGE_OFF: 0x81,
}


class Nmt(IntEnum):
    """NMT states as a heartbeat carries them."""

    BOOT_UP = 0x00
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


NMT_START = 0x01


def eds_path() -> Path:
    """configs/devices/cia402.eds, from a checkout or an installed wheel (package `pure_hil_configs`)."""
    here = Path(__file__).resolve().parents[2] / "configs" / "devices" / "cia402.eds"
    if here.is_file():
        return here
    return Path(str(files("pure_hil_configs") / "devices" / "cia402.eds"))


def rpdo1(node_id: int, controlword: int, torque: float) -> can.Message:
    """RPDO1: controlword and target torque (Nm, sent in mNm)."""
    mnm = max(-32768, min(32767, round(torque * 1000.0 * 1000.0 / RATED_MNM)))
    data = RPDO1_FMT.pack(controlword & 0xFFFF, mnm)
    return can.Message(arbitration_id=RPDO1 + node_id, data=data, is_extended_id=False)


def nmt(command: int, node_id: int) -> can.Message:
    return can.Message(arbitration_id=NMT, data=bytes((command, node_id)), is_extended_id=False)


def _unpack(fmt: struct.Struct, msg: can.Message, what: str) -> tuple[int, ...]:
    if len(msg.data) < fmt.size:
        raise ValueError(f"{what}: {len(msg.data)} bytes, expected {fmt.size}")
    return fmt.unpack_from(bytes(msg.data))


@dataclass(slots=True)
class HostDrive:
    """What a host knows of one drive."""

    node_id: int
    statusword: int = -1
    """Of the last TPDO1 (-1: none yet)."""
    error: int = 0
    nmt: int = -1
    """NMT state of the last heartbeat or boot-up (-1: none yet)."""
    start: bool = False
    """A boot-up or a pre-operational heartbeat was seen: send NMT start (controller) with the next burst."""
    restart: bool = False
    """A STOPPED heartbeat was seen: the supervisor under its takeover starts it again (the recovery law
    needs every wheel; nobody else asked it to stop)."""
    want: bool = False
    """This host has asked for OPERATION ENABLED (a controller: its last Enable; a supervisor: the last
    controlword it saw)."""

    @property
    def state(self) -> State | None:
        return None if self.statusword < 0 else state_of(self.statusword)


class Cia402Host(DriveHost):
    """The host side of three CiA 402 drives for a controller or a supervisor."""

    def __init__(self, devices: Devices, counts_per_rev: int, role: Role):
        super().__init__(role)
        self.options, self.counts_per_rev = devices.cia402, counts_per_rev
        nodes = self.options.node_ids
        self.drives = [HostDrive(n) for n in nodes]
        self._drive_of: dict[int, tuple[int, int]] = {}
        reads = [TPDO1, TPDO2, TPDO3, HEARTBEAT, EMCY, SDO_TX, SDO_RX]  # SDO: another master's, not used
        if role == "supervisor":  # it checks the controller's commands against what the drives do
            reads.append(RPDO1)
        else:
            reads.append(RPDO1)  # the supervisor's own (its takeover, its quick stop): seen, not used
        for i, n in enumerate(nodes):
            for f in reads:
                self._drive_of[f + n] = (i, f)
        self.frame_ids = frozenset(self._drive_of) | ({NMT} if role == "supervisor" else frozenset())
        self.sends = frozenset(RPDO1 + n for n in nodes) | ({NMT} if role == "controller" else frozenset())

    # ------------------------------------------------------------------------------------------ out
    def _command(self, index: int, torque: float, enable: bool) -> list[can.Message]:
        drive, frames = self.drives[index], []
        if drive.start:  # the master's NMT start, for a drive that booted (or was reset to pre-operational)
            frames.append(nmt(NMT_START, drive.node_id))
            drive.start = False
        return frames + self._walk(drive, torque, enable)

    def _recovery(self, index: int, torque: float) -> list[can.Message]:
        drive, frames = self.drives[index], []
        if drive.restart:  # stopped unasked: the recovery law needs every wheel (once per STOPPED heartbeat)
            frames.append(nmt(NMT_START, drive.node_id))
            drive.restart = False
        return frames + self._walk(drive, torque, True)

    def _walk(self, drive: HostDrive, torque: float, enable: bool) -> list[can.Message]:
        n, state = drive.node_id, drive.state
        if not enable:
            drive.want = False
            return [rpdo1(n, Cw.DISABLE_VOLTAGE, 0.0)]
        frames = []
        if not drive.want or state is not State.OPERATION_ENABLED:
            # The walk: each step is one transition from where the drive may be (the drive takes a step it
            # cannot make as no transition, so the whole walk is safe from any state).
            if state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                frames.append(rpdo1(n, Cw.FAULT_RESET, 0.0))
            elif state is State.QUICK_STOP_ACTIVE:
                frames.append(rpdo1(n, Cw.DISABLE_VOLTAGE, 0.0))
            frames += [rpdo1(n, Cw.SHUTDOWN, 0.0), rpdo1(n, Cw.SWITCH_ON, 0.0)]
        drive.want = True
        frames.append(rpdo1(n, Cw.ENABLE_OPERATION, torque))
        return frames

    def _stop(self, index: int) -> list[can.Message]:
        """Quick stop (OPERATION ENABLED -> QUICK STOP ACTIVE: no torque)."""
        drive = self.drives[index]
        drive.want = False
        return [rpdo1(drive.node_id, Cw.QUICK_STOP, 0.0)]

    # ------------------------------------------------------------------------------------------- in
    def incoming(self, msg: can.Message) -> Received | None:
        if msg.is_remote_frame or msg.arbitration_id == NMT:
            return None  # the controller's NMT start, as the supervisor sees it
        i, function = self._drive_of[msg.arbitration_id]
        if function in (SDO_TX, SDO_RX) or (function == RPDO1 and self.role == "controller"):
            return None  # another master's traffic (examples/cia402_controller.py's SDO, the supervisor's)
        drive = self.drives[i]
        if function == HEARTBEAT:
            if not msg.data:
                raise ValueError("heartbeat without its state byte")
            drive.nmt = msg.data[0] & 0x7F
            drive.start = drive.nmt in (Nmt.BOOT_UP, Nmt.PRE_OPERATIONAL)
            drive.restart = drive.nmt == Nmt.STOPPED and self.role == "supervisor"
            return None
        if function == EMCY:
            return None  # the error code rides in TPDO1 every SYNC as well
        if function == TPDO1:
            drive.statusword, _mode, drive.error = _unpack(TPDO1_FMT, msg, "TPDO1")
            return None
        if function == TPDO2:
            position, velocity = _unpack(TPDO2_FMT, msg, "TPDO2")
            state, error = drive.state, drive.error
            fault = state in (State.FAULT, State.FAULT_REACTION_ACTIVE)
            signals: dict[str, float | int] = {
                "Position": position,
                "Velocity": velocity * 2.0 * math.pi / self.counts_per_rev,
                "Enabled": int(state is State.OPERATION_ENABLED),
                "WatchdogTripped": int(fault and error == ErrorCode.COMMUNICATION),
                "Fault": int(fault and error == ErrorCode.POWER_SECTION),
                "BusPowered": int(not (fault and error == ErrorCode.DC_LINK_UNDER_VOLTAGE)),
            }
            return Received(DRIVE_FEEDBACK[i], signals, msg.timestamp, None)
        if function == TPDO3:
            (torque,) = _unpack(TPDO3_FMT, msg, "TPDO3")
            return Received(DRIVE_TORQUE[i], {"Torque": torque * RATED_MNM * 1e-6}, msg.timestamp, None)
        # RPDO1, as the supervisor sees the controller's command: a step of the walk is no command.
        controlword, torque = _unpack(RPDO1_FMT, msg, "RPDO1")
        if controlword & Cw.FAULT_RESET:
            return None  # fault reset (its other bits clear: not a disable voltage), a step of the walk
        if controlword & 0x8F == Cw.ENABLE_OPERATION:
            enable = True
        elif controlword & 0x02 == 0 or controlword & 0x06 == Cw.QUICK_STOP:
            enable = False  # disable voltage, quick stop
        else:
            return None  # shutdown, switch on, fault reset: steps of the walk
        drive.want = enable
        signals = {
            "Torque": torque * RATED_MNM * 1e-6 if enable else 0.0,
            "Tick": self.tick,
            "Enable": int(enable),
        }
        return Received(DRIVE_COMMAND[i], signals, msg.timestamp, None)


def host(devices: Devices, counts_per_rev: int, role: Role) -> Cia402Host:
    return Cia402Host(devices, counts_per_rev, role)


def claims(devices: Devices) -> dict[int, str]:
    """CiA 301's predefined connection set of each node."""
    return {
        f + node: f"CANopen node {node}'s COB-IDs"
        for node in devices.cia402.node_ids
        for f in CANOPEN_FUNCTIONS
    }


def check(devices: Devices) -> None:
    """No node's COB-ID is a contract frame that stays on the bus."""
    owner = {i: name for name, i in contract_ids(drives=False, imu=devices.imu == PURE).items()}
    for node in devices.cia402.node_ids:
        clash = sorted(
            f"{owner[f + node]} (0x{f + node:03X})" for f in CANOPEN_FUNCTIONS if f + node in owner
        )
        if clash:
            raise ValueError(
                f"cia402.node_ids: node {node}'s CANopen COB-IDs include the contract's "
                f"{', '.join(clash)}: pick another node id"
            )


PROFILE = Profile("cia402", "drives", Cia402Options, host, "hil.devices.cia402:emulate", claims, check)
"""The `cia402` device profile (entry point `pure_hil.devices`)."""
