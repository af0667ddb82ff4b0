"""Three emulated ODrive axes on CAN Simple (firmware 0.6), one per omniwheel motor (docs/devices.md).

Each axis is IDLE until a host asks for CLOSED_LOOP_CONTROL, makes torque only there and only in torque
control, and disarms as the firmware does: on an Estop frame (ESTOP_REQUESTED, and only then), when its
watchdog expires (WATCHDOG_TIMER_EXPIRED), when the DC bus is lost (DC_BUS_UNDER_VOLTAGE) and on a power
stage fault (DRV_FAULT). The supervisor's permission line cuts the power stage outside the firmware, as an
STO input does: the axis's state does not show it. An axis with an error refuses to arm until
Clear_Errors. It sends Heartbeat and Get_Encoder_Estimates at the bench's
rates and Get_Torques at 100 Hz, answers an RTR of every message firmware 0.6.10 answers (the Get_* messages,
Heartbeat, Address: node discovery) at once, and serves the endpoints a lab's configuration reads and
writes at start-up over RxSdo/TxSdo (ENDPOINTS).

Set_Input_Torque reaches the rig as the contract's DRIVEn_COMMAND tagged with the current tick (a CAN
Simple command carries no tick): the rig applies it as it applies any command.
"""

from __future__ import annotations

import json
import logging
import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import can

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MOTOR_OF
from drivers.config import ConfigError
from drivers.devices import Devices, OdriveOptions, Translator
from drivers.devices.odrive import (
    BROADCAST_NODE,
    REQUESTED,
    AxisError,
    AxisState,
    Cmd,
    ControlMode,
    OdriveWire,
    frame_id,
    split_id,
)
from hil.devices.plant_drive import PlantFault, plant_faults

log = logging.getLogger(__name__)

AXIS_ERROR = {
    PlantFault.UNPOWERED: AxisError.DC_BUS_UNDER_VOLTAGE,
    PlantFault.WATCHDOG: AxisError.WATCHDOG_TIMER_EXPIRED,
    PlantFault.POWER_STAGE: AxisError.DRV_FAULT,
}
"""The axis error each fault of the plant's drive state disarms the axis with."""
LATCHED = AxisError.WATCHDOG_TIMER_EXPIRED | AxisError.ESTOP_REQUESTED | AxisError.DRV_FAULT
"""Errors that stay until Clear_Errors (the bus voltage error stays while the bus is down)."""
TEMPERATURE = 25.0
"""deg C, FET and motor alike: the emulation has no thermal model (Get_Temperature)."""
SERIAL = 0x505552450000
"""An axis's serial number is this plus its node id ("PURE" in ASCII, then the node): the emulation's own."""
HARDWARE = (4, 4, 58)
"""Get_Version's board (product line, version, variant) without a lab's endpoints file: an ODrive Pro,
as ODrive's own package (odrive 0.6.10, hw_version.py) names the triplet 4.4.58."""
FIRMWARE = {
    "Fw_Version_Major": 0,
    "Fw_Version_Minor": 6,
    "Fw_Version_Revision": 10,
    "Fw_Version_Unreleased": 0,
    "Protocol_Version": 2,
}


@dataclass(slots=True)
class Axis:
    node_id: int
    control_mode: int
    state: int = AxisState.IDLE
    error: int = 0
    disarm_reason: int = 0
    setpoint: float = 0.0
    pos: float = 0.0
    """rev"""
    vel: float = 0.0
    """rev/s"""
    torque: float = 0.0
    powered: bool = True
    sent: int = 0
    """Feedback calls so far (the cyclic messages' phase)."""
    warned_mode: bool = False
    forced_error: int = 0
    """An error a fault holds active (hil/faults/devices.py): Clear_Errors cannot clear it."""
    mute_heartbeat: bool = False
    """A fault keeps its heartbeat off the bus."""
    config: dict[str, float] = field(default_factory=dict)
    """Endpoint values a host may write (ENDPOINTS' writable ones), by path."""

    @property
    def armed(self) -> bool:
        return self.state == AxisState.CLOSED_LOOP_CONTROL

    def disarm(self, error: int) -> None:
        if self.armed:
            self.disarm_reason = error
        self.state = AxisState.IDLE
        self.error |= error


class OdriveAxes(Translator):
    """The device side of three ODrive axes."""

    def __init__(self, devices: Devices, counts_per_rev: int, tick_hz: float):
        super().__init__()
        options = devices.odrive
        self.wire = OdriveWire()
        mode = {"torque": ControlMode.TORQUE_CONTROL, "velocity": ControlMode.VELOCITY_CONTROL}.get(
            options.control_mode, ControlMode.POSITION_CONTROL
        )
        self.axes = [Axis(n, mode, config=_config(options, mode)) for n in options.node_ids]
        self.bus_voltage, self.phase_resistance = options.bus_voltage, options.phase_resistance
        self.endpoints, self.hardware = _endpoints(options.endpoints)
        self._path_of = {ident: path for path, (ident, _) in self.endpoints.items()}
        self._unknown_endpoints: set[int] = set()
        self._axis_of = {n: a for n, a in zip(options.node_ids, range(3), strict=True)}
        self.counts_per_rev = counts_per_rev
        self.encoder_every = _ticks(options.encoder_ms, tick_hz)
        self.heartbeat_every = _ticks(options.heartbeat_ms, tick_hz)
        self.torques = options.torques
        self.names = frozenset((*DRIVE_FEEDBACK, *DRIVE_TORQUE))
        self.frame_ids = self.wire.ids(options.node_ids, range(32)) | {frame_id(BROADCAST_NODE, Cmd.ADDRESS)}
        self.sends = self.wire.ids(options.node_ids, ANSWERS)

    # ------------------------------------------------------------------------------ the drives' output
    def frame_id_as(self, msg: can.Message, name: str) -> int:
        """The same command from the axis that sends `name`."""
        return frame_id(self.axes[MOTOR_OF[name]].node_id, split_id(msg.arbitration_id)[1])

    def outgoing(self, name: str, values: Mapping[str, float]) -> list[can.Message]:
        if name in DRIVE_TORQUE:
            axis = self.axes[MOTOR_OF[name]]
            axis.torque = float(values["Torque"])
            return [self._reply(axis, Cmd.GET_TORQUES)] if self.torques else []
        axis = self.axes[MOTOR_OF[name]]
        self._follow_plant(axis, values)
        frames = []
        if self.encoder_every and axis.sent % self.encoder_every == 0:
            frames.append(self._reply(axis, Cmd.GET_ENCODER_ESTIMATES))
        if self.heartbeat_every and axis.sent % self.heartbeat_every == 0 and not axis.mute_heartbeat:
            frames.append(self._reply(axis, Cmd.HEARTBEAT))
        axis.sent += 1
        return frames

    def _follow_plant(self, axis: Axis, s: Mapping[str, float]) -> None:
        """The plant's drive state this tick -> the axis's state and errors."""
        axis.pos = s["Position"] / self.counts_per_rev
        axis.vel = s["Velocity"] / (2.0 * math.pi)
        axis.powered = bool(s["BusPowered"])
        for fault in plant_faults(s):  # an error bit each
            axis.disarm(AXIS_ERROR[fault])
        # Nothing else of the plant's drive state reaches the axis's state: the firmware's own errors
        # (above) disarm it, and ESTOP_REQUESTED comes only from an Estop frame. The plant's Enabled this
        # tick is not the axis's state: an arming request the rig takes after the controller's heartbeat
        # reaches the power stage with the next setpoint (issue 36), and the supervisor's permission line
        # cuts the stage outside the firmware (an STO input), which the axis cannot see.

    def _reply(self, axis: Axis, cmd: int) -> can.Message:
        values: dict[str, float]
        if cmd == Cmd.HEARTBEAT:
            values = {
                "Axis_Error": axis.error,
                "Axis_State": axis.state,
                "Procedure_Result": 0,
                "Trajectory_Done_Flag": 1,
            }
        elif cmd == Cmd.GET_ENCODER_ESTIMATES:
            values = {"Pos_Estimate": axis.pos, "Vel_Estimate": axis.vel}
        elif cmd == Cmd.GET_TORQUES:
            values = {"Torque_Target": axis.setpoint if axis.armed else 0.0, "Torque_Estimate": axis.torque}
        elif cmd == Cmd.GET_ERROR:
            values = {"Active_Errors": axis.error, "Disarm_Reason": axis.disarm_reason}
        elif cmd == Cmd.GET_BUS_VOLTAGE_CURRENT:
            values = {"Bus_Voltage": self.vbus(axis), "Bus_Current": self.ibus()}
        elif cmd == Cmd.GET_IQ:
            kt = axis.config[TORQUE_CONSTANT]
            target = axis.setpoint if axis.armed else 0.0
            values = {"Iq_Setpoint": target / kt, "Iq_Measured": axis.torque / kt}
        elif cmd == Cmd.GET_TEMPERATURE:
            values = {"FET_Temperature": TEMPERATURE, "Motor_Temperature": TEMPERATURE}
        elif cmd == Cmd.GET_POWERS:
            electrical, mechanical = self.powers(axis)
            values = {"Electrical_Power": electrical, "Mechanical_Power": mechanical}
        elif cmd == Cmd.ADDRESS:
            values = {"Node_ID": axis.node_id, "Serial_Number": SERIAL + axis.node_id}
        else:
            major, minor, variant = self.hardware
            values = {
                **FIRMWARE,
                "Hw_Version_Major": major,
                "Hw_Version_Minor": minor,
                "Hw_Version_Variant": variant,
            }
        return self.wire.frame(axis.node_id, cmd, values)

    # ----------------------------------------------------------------------- the motors as a DC load
    def powers(self, axis: Axis) -> tuple[float, float]:
        """(electrical, mechanical) W of one axis: the shaft's torque x speed, plus the copper loss
        1.5 R Iq^2 (amplitude-invariant Iq, as ODrive's current loop uses it). No inverter loss."""
        mechanical = axis.torque * axis.vel * 2.0 * math.pi
        iq = axis.torque / axis.config[TORQUE_CONSTANT]
        return mechanical + 1.5 * self.phase_resistance * iq * iq, mechanical

    def vbus(self, axis: Axis) -> float:
        return self.bus_voltage if axis.powered else 0.0

    def ibus(self) -> float:
        """A: the three drives' electrical power over the bus voltage (the emulation's one DC bus, so
        each axis reports the whole bus's current; a real ODrive measures its own board's)."""
        if not self.axes[0].powered:
            return 0.0
        return sum(self.powers(axis)[0] for axis in self.axes) / self.bus_voltage

    # ------------------------------------------------------------------------------- the host's input
    def incoming(self, msg: can.Message) -> Received | None:
        node, cmd = split_id(msg.arbitration_id)
        if node == BROADCAST_NODE:  # Address discovery: every axis answers with its node id and serial
            if msg.is_remote_frame:
                for i, axis in enumerate(self.axes):
                    self._answer(i, axis, Cmd.ADDRESS)
            return None  # setting an address by serial number: not emulated (the bench fixes node ids)
        i = self._axis_of[node]
        axis = self.axes[i]
        if msg.is_remote_frame or (cmd in ANSWERS and not msg.data):  # (0.5.5 on: DLC 0 asks as RTR does)
            if cmd in ANSWERS:
                self._answer(i, axis, cmd)
            return None
        if cmd in OWN:  # the same id sent by another node: a bus conflict, not a command
            raise ValueError(f"axis {node}: a frame with this axis's own id 0x{msg.arbitration_id:03X}")
        if cmd == Cmd.ESTOP:
            axis.disarm(AxisError.ESTOP_REQUESTED)
            return self._command(i, 0.0, False, msg)
        if cmd == Cmd.CLEAR_ERRORS:
            axis.error = axis.forced_error | (0 if axis.powered else AxisError.DC_BUS_UNDER_VOLTAGE)
            return None
        if cmd == Cmd.RX_SDO:
            return self._endpoint(i, axis, msg)
        s = self.wire.decode(msg)
        if cmd == Cmd.SET_AXIS_STATE:
            return self._request_state(i, axis, int(s[REQUESTED]), msg)
        if cmd == Cmd.SET_CONTROLLER_MODE:
            axis.control_mode = int(s["Control_Mode"])
            axis.config[INPUT_MODE] = int(s["Input_Mode"])
            return None
        if cmd == Cmd.SET_INPUT_TORQUE:
            axis.setpoint = float(s["Input_Torque"])
            if axis.armed and axis.control_mode != ControlMode.TORQUE_CONTROL and not axis.warned_mode:
                axis.warned_mode = True
                log.warning("axis %d is not in TORQUE_CONTROL: its torque setpoint does nothing", node)
            torque = axis.setpoint if axis.control_mode == ControlMode.TORQUE_CONTROL else 0.0
            return self._command(i, torque, axis.armed, msg)
        return None  # limits, gains, trajectories: accepted, not emulated

    def _answer(self, i: int, axis: Axis, cmd: int) -> None:
        assert self.node is not None
        self.node.reply(DRIVE_FEEDBACK[i], self._reply(axis, cmd))

    def _request_state(self, i: int, axis: Axis, requested: int, msg: can.Message) -> Received | None:
        """Set_Axis_State, or a write of axis0.requested_state."""
        if requested == AxisState.CLOSED_LOOP_CONTROL and not axis.error:
            axis.state, axis.setpoint = AxisState.CLOSED_LOOP_CONTROL, 0.0
            return self._command(i, 0.0, True, msg)
        if requested == AxisState.IDLE:
            axis.state = AxisState.IDLE
            return self._command(i, 0.0, False, msg)
        return None  # refused: an active error, or a state the emulation has not (calibration, ...)

    def _endpoint(self, i: int, axis: Axis, msg: can.Message) -> Received | None:
        """RxSdo: read an endpoint (answered with TxSdo: reserved, endpoint id, reserved, value) or write
        one (firmware 0.6.10 confirms nothing; 0.6.11 does). An id the emulation does not serve gets no
        answer, logged once."""
        if len(msg.data) < 4:
            raise ValueError(f"RxSdo: {len(msg.data)} bytes, expected at least 4")
        opcode, ident = msg.data[0], int.from_bytes(msg.data[1:3], "little")
        path = self._path_of.get(ident)
        if path is None:
            if ident not in self._unknown_endpoints:
                self._unknown_endpoints.add(ident)
                log.warning("axis %d: endpoint id %d is not one the emulation serves", axis.node_id, ident)
            return None
        fmt = "<" + FORMATS[self.endpoints[path][1]]
        if opcode == 0:
            value = self._read_endpoint(axis, path)
            data = struct.pack("<BHB", 0, ident, 0) + struct.pack(fmt, _as(fmt, value))
            assert self.node is not None
            self.node.reply(DRIVE_FEEDBACK[i], self._tx_sdo(axis, data))
            return None
        if path not in WRITABLE:
            return None  # read-only: the firmware ignores the write
        if len(msg.data) < 4 + struct.calcsize(fmt):
            raise ValueError(f"RxSdo write of {path}: {len(msg.data)} bytes")
        (value,) = struct.unpack_from(fmt, bytes(msg.data), 4)
        if path == "axis0.requested_state":
            return self._request_state(i, axis, int(value), msg)
        if path == CONTROL_MODE:
            axis.control_mode = int(value)
        else:
            axis.config[path] = float(value)
        return None

    def _tx_sdo(self, axis: Axis, data: bytes) -> can.Message:
        return can.Message(
            arbitration_id=frame_id(axis.node_id, Cmd.TX_SDO), data=data.ljust(8, b"\0"), is_extended_id=False
        )

    def _read_endpoint(self, axis: Axis, path: str) -> float:
        if path in axis.config:
            return axis.config[path]
        major, minor, variant = self.hardware
        live: dict[str, float] = {
            "vbus_voltage": self.vbus(axis),
            "ibus": self.ibus(),
            "hw_version_major": major,
            "hw_version_minor": minor,
            "hw_version_variant": variant,
            "fw_version_major": FIRMWARE["Fw_Version_Major"],
            "fw_version_minor": FIRMWARE["Fw_Version_Minor"],
            "fw_version_revision": FIRMWARE["Fw_Version_Revision"],
            "fw_version_unreleased": FIRMWARE["Fw_Version_Unreleased"],
            "axis0.active_errors": axis.error,
            "axis0.disarm_reason": axis.disarm_reason,
            "axis0.current_state": axis.state,
            "axis0.requested_state": axis.state,
            "axis0.pos_estimate": axis.pos,
            "axis0.vel_estimate": axis.vel,
            "axis0.config.can.node_id": axis.node_id,
            CONTROL_MODE: axis.control_mode,
        }
        return live[path]

    # ------------------------------------------------------------------ protocol faults (hil/faults)
    profile = "odrive"

    def axis_error(self, motor: int, error: int) -> None:
        """The axis raises `error` and disarms; it stays active, whatever Clear_Errors says, until 0."""
        axis = self.axes[motor]
        axis.forced_error = error
        if error:
            axis.disarm(error)

    def heartbeat_loss(self, motor: int, lost: bool) -> None:
        self.axes[motor].mute_heartbeat = lost

    def disarm(self, motor: int) -> None:
        """The axis drops to IDLE unasked, with no active error (its Disarm_Reason says SYSTEM_LEVEL)."""
        axis = self.axes[motor]
        if axis.armed:
            axis.disarm_reason = AxisError.SYSTEM_LEVEL
        axis.state = AxisState.IDLE

    def _command(self, i: int, torque: float, enable: bool, msg: can.Message) -> Received:
        signals = {"Torque": torque, "Tick": self.tick, "Enable": int(enable)}
        return Received(DRIVE_COMMAND[i], signals, msg.timestamp, None)


ANSWERS = frozenset(
    {
        Cmd.GET_VERSION,
        Cmd.HEARTBEAT,
        Cmd.GET_ERROR,
        Cmd.ADDRESS,
        Cmd.GET_ENCODER_ESTIMATES,
        Cmd.GET_IQ,
        Cmd.GET_TEMPERATURE,
        Cmd.GET_BUS_VOLTAGE_CURRENT,
        Cmd.GET_TORQUES,
        Cmd.GET_POWERS,
    }
)
"""Messages an axis answers on RTR: every one firmware 0.6.10's DBC has an axis send."""
OWN = ANSWERS | {Cmd.TX_SDO}
"""Ids only the axis itself sends as data frames."""

TORQUE_CONSTANT = "axis0.config.motor.torque_constant"
CONTROL_MODE = "axis0.controller.config.control_mode"
INPUT_MODE = "axis0.controller.config.input_mode"
ENDPOINTS: dict[str, str] = {
    "vbus_voltage": "float",
    "ibus": "float",
    "hw_version_major": "uint8",
    "hw_version_minor": "uint8",
    "hw_version_variant": "uint8",
    "fw_version_major": "uint8",
    "fw_version_minor": "uint8",
    "fw_version_revision": "uint8",
    "fw_version_unreleased": "uint8",
    "axis0.active_errors": "uint32",
    "axis0.disarm_reason": "uint32",
    "axis0.current_state": "uint8",
    "axis0.requested_state": "uint8",
    "axis0.pos_estimate": "float",
    "axis0.vel_estimate": "float",
    TORQUE_CONSTANT: "float",
    CONTROL_MODE: "uint8",
    INPUT_MODE: "uint8",
    "axis0.controller.config.vel_limit": "float",
    "axis0.config.motor.current_soft_max": "float",
    "axis0.config.torque_soft_min": "float",
    "axis0.config.torque_soft_max": "float",
    "axis0.config.enable_watchdog": "bool",
    "axis0.config.watchdog_timeout": "float",
    "axis0.config.can.node_id": "uint32",
    "axis0.config.can.heartbeat_msg_rate_ms": "uint32",
    "axis0.config.can.encoder_msg_rate_ms": "uint32",
    "axis0.config.can.torques_msg_rate_ms": "uint32",
}
"""The endpoints served over RxSdo/TxSdo (0.6's names) and their types. Without a lab's flat_endpoints.json
their ids are 1, 2, ... in this order: the emulation's own, since ODrive publishes the file per firmware
and board and no source reachable here holds 0.6.10's (docs/devices.md)."""
WRITABLE = frozenset(
    {
        "axis0.requested_state",
        TORQUE_CONSTANT,
        CONTROL_MODE,
        INPUT_MODE,
        "axis0.controller.config.vel_limit",
        "axis0.config.motor.current_soft_max",
        "axis0.config.torque_soft_min",
        "axis0.config.torque_soft_max",
        "axis0.config.enable_watchdog",
        "axis0.config.watchdog_timeout",
        "axis0.config.can.heartbeat_msg_rate_ms",
        "axis0.config.can.encoder_msg_rate_ms",
        "axis0.config.can.torques_msg_rate_ms",
    }
)
"""Endpoints a host may write: the requested state arms and disarms, the control mode is
Set_Controller_Mode's; the others are stored and read back, not emulated (docs/devices.md)."""
FORMATS = {
    "bool": "?",
    "uint8": "B",
    "int8": "b",
    "uint16": "H",
    "int16": "h",
    "uint32": "I",
    "int32": "i",
    "uint64": "Q",
    "int64": "q",
    "float": "f",
}
"""flat_endpoints.json's types -> struct formats (ODrive's CAN guide packs values so)."""


def _config(options: OdriveOptions, mode: int) -> dict[str, float]:
    """An axis's writable endpoints at power-up (the bench's, else the emulation's own defaults)."""
    return {
        TORQUE_CONSTANT: options.torque_constant,
        INPUT_MODE: 1,  # PASSTHROUGH
        "axis0.controller.config.vel_limit": 2.0,
        "axis0.config.motor.current_soft_max": 10.0,
        "axis0.config.torque_soft_min": -math.inf,
        "axis0.config.torque_soft_max": math.inf,
        "axis0.config.enable_watchdog": 1,
        "axis0.config.watchdog_timeout": 0.02,
        "axis0.config.can.heartbeat_msg_rate_ms": options.heartbeat_ms,
        "axis0.config.can.encoder_msg_rate_ms": options.encoder_ms,
        "axis0.config.can.torques_msg_rate_ms": 10.0 if options.torques else 0.0,
    }


def _endpoints(path: str) -> tuple[dict[str, tuple[int, str]], tuple[int, int, int]]:
    """(path -> (id, type) of the endpoints served, the board's hardware version): from a lab's
    flat_endpoints.json, else the emulation's own ids and HARDWARE."""
    if not path:
        return {p: (i, t) for i, (p, t) in enumerate(ENDPOINTS.items(), start=1)}, HARDWARE
    where = f"[devices.odrive] endpoints = {path!r}"
    try:
        data = json.loads(Path(path).read_text())
        fw, hw, table = data["fw_version"], data["hw_version"], data["endpoints"]
        hardware = tuple(int(x) for x in hw.split("."))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ConfigError(
            where, f"not a flat_endpoints.json (fw_version, hw_version, endpoints): {exc}"
        ) from exc
    if fw.partition("-")[0] != "0.6.10" or len(hardware) != 3:
        raise ConfigError(
            where, f"fw_version {fw!r}, hw_version {hw!r}: the profile emulates firmware 0.6.10"
        )
    served = {p: (int(table[p]["id"]), str(table[p]["type"])) for p in ENDPOINTS if p in table}
    odd = sorted(p for p, (_, t) in served.items() if t not in FORMATS)
    if odd:
        raise ConfigError(where, f"endpoint types the CAN guide cannot pack: {odd}")
    return served, (hardware[0], hardware[1], hardware[2])


def _as(fmt: str, value: float) -> float | int | bool:
    """A value as struct packs it under `fmt`."""
    if fmt.endswith("f"):
        return float(value)
    if fmt.endswith("?"):
        return bool(value)
    return int(value)


def _ticks(period_ms: float, tick_hz: float) -> int:
    """A period in whole ticks (0: never)."""
    return 0 if period_ms <= 0 else max(1, round(period_ms * 1e-3 * tick_hz))


def emulate(devices: Devices, counts_per_rev: int, tick_hz: float) -> OdriveAxes:
    return OdriveAxes(devices, counts_per_rev, tick_hz)
