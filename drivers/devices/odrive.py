"""ODrive "CAN Simple" (firmware 0.6) through ODrive's own DBC, as the `odrive-can` package ships it, and the
host's side of it: what a controller or a supervisor sends and reads (docs/devices.md).

Frame id = node_id << 5 | command id; every axis has the same messages, so the codecs are the DBC's
`Axis0_*` definitions with the node id put in. The host keeps each axis's last heartbeat (state, error) and
turns Get_Encoder_Estimates into the contract's DRIVEn_FEEDBACK, Get_Torques into DRIVEn_TORQUE, and a
DRIVEn_COMMAND into Set_Input_Torque with the axis-state requests an enable or a disable needs.
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
import cantools

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE
from drivers.devices import DriveHost, OdriveOptions, contract_ids
from drivers.devices.profile import PURE, Profile

if TYPE_CHECKING:
    from drivers.devices import Devices, Role

DBC_NAME = "odrive-cansimple-0.6.10.dbc"
REQUESTED = "Axis_Requested_State"
POWERED_TORQUE = 0.05
"""Nm: an axis whose measured torque is above this has its power stage on, whatever its state says (a
stage that will not turn off reports IDLE: only its current shows it). 10x the torque sensor's noise."""
HEARTBEATS_MISSED = 3
"""Heartbeat periods without one before a host stops passing the axis's estimates on."""


class Cmd(IntEnum):
    """CAN Simple command ids (the low 5 bits of a frame id) the profile handles (ODrive's 0.6.10 DBC)."""

    GET_VERSION = 0x00
    HEARTBEAT = 0x01
    ESTOP = 0x02
    GET_ERROR = 0x03
    RX_SDO = 0x04
    TX_SDO = 0x05
    ADDRESS = 0x06
    SET_AXIS_STATE = 0x07
    GET_ENCODER_ESTIMATES = 0x09
    SET_CONTROLLER_MODE = 0x0B
    SET_INPUT_TORQUE = 0x0E
    GET_IQ = 0x14
    GET_TEMPERATURE = 0x15
    GET_BUS_VOLTAGE_CURRENT = 0x17
    CLEAR_ERRORS = 0x18
    GET_TORQUES = 0x1C
    GET_POWERS = 0x1D


BROADCAST_NODE = 0x3F
"""The node id every ODrive listens on besides its own (firmware 0.6.9 on): Address discovery's RTR."""


class AxisState(IntEnum):
    IDLE = 1
    CLOSED_LOOP_CONTROL = 8


class ControlMode(IntEnum):
    VOLTAGE_CONTROL = 0
    TORQUE_CONTROL = 1
    VELOCITY_CONTROL = 2
    POSITION_CONTROL = 3


class AxisError(IntFlag):
    """The firmware 0.6 error bits the emulation raises (ODrive.Error)."""

    NONE = 0
    SYSTEM_LEVEL = 0x00000002
    DC_BUS_UNDER_VOLTAGE = 0x00000200
    DRV_FAULT = 0x00000020
    WATCHDOG_TIMER_EXPIRED = 0x01000000
    ESTOP_REQUESTED = 0x02000000


HOST_SENDS = (Cmd.ESTOP, Cmd.SET_AXIS_STATE, Cmd.SET_INPUT_TORQUE, Cmd.CLEAR_ERRORS)
"""What a host of this module sends an axis."""
HOST_READS = (Cmd.HEARTBEAT, Cmd.GET_ENCODER_ESTIMATES, Cmd.GET_TORQUES)
"""The axes' frames a host of this module turns into the contract's messages."""


def frame_id(node_id: int, cmd: int) -> int:
    return node_id << 5 | cmd


def split_id(arbitration_id: int) -> tuple[int, int]:
    """(node id, command id)."""
    return arbitration_id >> 5, arbitration_id & 0x1F


def dbc_path() -> Path:
    """ODrive's DBC as the odrive-can package ships it (found without importing the package, which sets up
    logging and loads the whole DBC at import)."""
    spec = importlib.util.find_spec("odrive_can")
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError("the odrive profile needs the odrive-can package (pip install odrive-can)")
    return Path(next(iter(spec.submodule_search_locations))) / "dbc" / DBC_NAME


@cache
def _templates() -> dict[int, Any]:
    """Command id -> the DBC's Axis0 message (cantools)."""
    db = cantools.database.load_file(str(dbc_path()), strict=False)
    if not isinstance(db, cantools.database.can.Database):
        raise TypeError(f"{dbc_path()}: not a CAN database")
    return {m.frame_id: m for m in db.messages if m.frame_id < 32}


class OdriveWire:
    """Encode and decode CAN Simple frames with ODrive's DBC."""

    def __init__(self) -> None:
        self._messages = _templates()

    def frame(self, node_id: int, cmd: int, values: Mapping[str, float] | None = None) -> can.Message:
        message = self._messages[cmd]
        data = b"" if message.length == 0 else message.encode(dict(values or {}), scaling=True, strict=False)
        return can.Message(arbitration_id=frame_id(node_id, cmd), data=data, is_extended_id=False)

    def decode(self, msg: can.Message) -> dict[str, float]:
        """Signals of a data frame, raw numbers (no choice names). ValueError on a bad length."""
        message = self._messages.get(msg.arbitration_id & 0x1F)
        if message is None:
            raise ValueError(f"no CAN Simple command 0x{msg.arbitration_id & 0x1F:02X}")
        if len(msg.data) < message.length:
            raise ValueError(f"{message.name[6:]}: {len(msg.data)} bytes, expected {message.length}")
        try:
            decoded: dict[str, float] = message.decode(bytes(msg.data), decode_choices=False)
        except Exception as exc:  # cantools raises its own DecodeError types
            raise ValueError(f"{message.name[6:]}: {exc}") from exc
        return decoded

    def ids(self, node_ids: Iterable[int], cmds: Iterable[int]) -> frozenset[int]:
        return frozenset(frame_id(n, c) for n in node_ids for c in cmds)


@dataclass(slots=True)
class HostAxis:
    """What a host knows of one axis."""

    node_id: int
    state: int = 0
    """Axis_State of the last heartbeat (0: none yet)."""
    error: int = 0
    want: bool = False
    """This host has asked for closed loop (a controller: its last Enable; a supervisor: the controller's
    last Set_Axis_State it saw)."""
    rearm: bool = False
    """A heartbeat showed the axis disarmed while this host wants it armed: clear and re-arm it once."""
    torque: float = 0.0
    """Get_Torques.Torque_Estimate of the last frame, Nm."""
    since_heartbeat: int = 0
    """Encoder estimates since its last heartbeat (the host's clock for the heartbeat's timeout)."""


class OdriveHost(DriveHost):
    """The host side of three ODrive axes for a controller or a supervisor."""

    def __init__(self, devices: Devices, counts_per_rev: int, role: Role):
        super().__init__(role)
        self.options, self.counts_per_rev = devices.odrive, counts_per_rev
        self.wire = OdriveWire()
        nodes = self.options.node_ids
        self.axes = [HostAxis(n) for n in nodes]
        self._axis_of = {n: i for i, n in enumerate(nodes)}
        # Every frame of the axes' protocol is known: a supervisor checks the controller's commands against
        # what the drives do; the rest (another host's Set_Controller_Mode, Set_Limits, RTRs and their
        # answers, endpoint access, Address discovery) is ordinary CAN Simple traffic, read and let be.
        self.frame_ids = self.wire.ids(nodes, _templates()) | {frame_id(BROADCAST_NODE, Cmd.ADDRESS)}
        options = self.options
        self.heartbeat_patience = (
            HEARTBEATS_MISSED * max(1, round(options.heartbeat_ms / options.encoder_ms))
            if options.heartbeat_ms > 0 and options.encoder_ms > 0
            else 0
        )
        """Encoder estimates without a heartbeat after which the axis's state is unknown and its estimates
        are not passed on (0: no heartbeat to expect)."""
        self.sends = self.wire.ids(nodes, HOST_SENDS)

    # ------------------------------------------------------------------------------------------ out
    def _command(self, index: int, torque: float, enable: bool) -> list[can.Message]:
        axis = self.axes[index]
        wire, node, frames = self.wire, axis.node_id, []
        if enable and (not axis.want or axis.rearm):
            if axis.error:
                frames.append(wire.frame(node, Cmd.CLEAR_ERRORS, {"Identify": 0}))
            frames.append(wire.frame(node, Cmd.SET_AXIS_STATE, {REQUESTED: AxisState.CLOSED_LOOP_CONTROL}))
            axis.rearm = False
        elif not enable and axis.want:
            frames.append(wire.frame(node, Cmd.SET_AXIS_STATE, {REQUESTED: AxisState.IDLE}))
        axis.want = enable
        frames.append(wire.frame(node, Cmd.SET_INPUT_TORQUE, {"Input_Torque": torque if enable else 0.0}))
        return frames

    def _stop(self, index: int) -> list[can.Message]:
        """CAN Simple's Estop: it disarms the axis with ESTOP_REQUESTED."""
        return [self.wire.frame(self.axes[index].node_id, Cmd.ESTOP)]

    # ------------------------------------------------------------------------------------------- in
    def incoming(self, msg: can.Message) -> Received | None:
        node, cmd = split_id(msg.arbitration_id)
        if msg.is_remote_frame or node not in self._axis_of:
            return None  # another host's request (its answer is what counts) or Address discovery
        if cmd not in HOST_READS and cmd not in HOST_SENDS:
            return None  # CAN Simple this host does not act on
        i = self._axis_of[node]
        axis = self.axes[i]
        if (self.role == "controller" and cmd in HOST_SENDS) or cmd == Cmd.CLEAR_ERRORS:
            return None  # a clear shows in the axis's next heartbeat
        if cmd == Cmd.ESTOP:
            axis.want = False
            return None
        s = self.wire.decode(msg)
        if cmd == Cmd.HEARTBEAT:
            axis.since_heartbeat = 0
            axis.state, axis.error = int(s["Axis_State"]), int(s["Axis_Error"])
            armed = axis.state == AxisState.CLOSED_LOOP_CONTROL
            axis.rearm = axis.want and not armed
            return None
        if cmd == Cmd.GET_ENCODER_ESTIMATES:
            axis.since_heartbeat += 1
            if self.heartbeat_patience and axis.since_heartbeat > self.heartbeat_patience:
                return None  # its heartbeat is lost: what state the axis is in is unknown, so is its data
            error = axis.error
            signals: dict[str, float | int] = {
                "Position": round(s["Pos_Estimate"] * self.counts_per_rev),
                "Velocity": s["Vel_Estimate"] * 2.0 * math.pi,
                "Enabled": int(
                    axis.state == AxisState.CLOSED_LOOP_CONTROL or abs(axis.torque) > POWERED_TORQUE
                ),
                "WatchdogTripped": int(bool(error & AxisError.WATCHDOG_TIMER_EXPIRED)),
                "Fault": int(bool(error & AxisError.DRV_FAULT)),
                "BusPowered": int(not error & AxisError.DC_BUS_UNDER_VOLTAGE),
            }
            return Received(DRIVE_FEEDBACK[i], signals, msg.timestamp, None)
        if cmd == Cmd.GET_TORQUES:
            axis.torque = float(s["Torque_Estimate"])
            return Received(DRIVE_TORQUE[i], {"Torque": axis.torque}, msg.timestamp, None)
        if cmd == Cmd.SET_AXIS_STATE:
            axis.want = int(s["Axis_Requested_State"]) == AxisState.CLOSED_LOOP_CONTROL
            return None
        # Set_Input_Torque, as the supervisor sees the controller's command.
        signals = {"Torque": s["Input_Torque"], "Tick": self.tick, "Enable": int(axis.want)}
        return Received(DRIVE_COMMAND[i], signals, msg.timestamp, None)


def host(devices: Devices, counts_per_rev: int, role: Role) -> OdriveHost:
    return OdriveHost(devices, counts_per_rev, role)


def claims(devices: Devices) -> dict[int, str]:
    """Each axis owns the 32 ids from node_id << 5."""
    return {
        (node << 5) + c: f"ODrive node {node}'s frames" for node in devices.odrive.node_ids for c in range(32)
    }


def check(devices: Devices) -> None:
    """No axis owns a contract frame that stays on the bus."""
    kept = contract_ids(drives=False, imu=devices.imu == PURE)
    for node in devices.odrive.node_ids:
        clash = sorted(name for name, i in kept.items() if i >> 5 == node)
        if clash:
            raise ValueError(
                f"odrive.node_ids: node {node} owns ids 0x{node << 5:03X}-0x{(node << 5) + 31:03X}, "
                f"which holds the contract's {', '.join(clash)}: pick another node id"
            )


PROFILE = Profile("odrive", "drives", OdriveOptions, host, "hil.devices.odrive:emulate", claims, check)
"""The `odrive` device profile (entry point `pure_hil.devices`)."""
