"""Three emulated ODrive axes on CAN Simple (firmware 0.6), one per omniwheel motor (docs/devices.md).

Each axis is IDLE until a host asks for CLOSED_LOOP_CONTROL, makes torque only there and only in torque
control, and disarms as the firmware does: on an Estop frame (ESTOP_REQUESTED, and only then), when its
watchdog expires (WATCHDOG_TIMER_EXPIRED), when the DC bus is lost (DC_BUS_UNDER_VOLTAGE) and on a power
stage fault (DRV_FAULT). The supervisor's permission line cuts the power stage outside the firmware, as an
STO input does: the axis's state does not show it. An axis with an error refuses to arm until
Clear_Errors. It sends Heartbeat and Get_Encoder_Estimates at the bench's
rates and Get_Torques at 100 Hz, and answers an RTR of any Get_* message at once.

Set_Input_Torque reaches the rig as the contract's DRIVEn_COMMAND tagged with the current tick (a CAN
Simple command carries no tick): the rig applies it as it applies any command.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

import can

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MOTOR_OF
from drivers.devices import Devices, Translator
from drivers.devices.odrive import (
    REQUESTED,
    AxisError,
    AxisState,
    Cmd,
    ControlMode,
    OdriveWire,
    frame_id,
    split_id,
)

log = logging.getLogger(__name__)

LATCHED = AxisError.WATCHDOG_TIMER_EXPIRED | AxisError.ESTOP_REQUESTED | AxisError.DRV_FAULT
"""Errors that stay until Clear_Errors (the bus voltage error stays while the bus is down)."""
BUS_VOLTS = 48.0
"""What Get_Bus_Voltage_Current reports with the bus live (the emulation has no electrical model)."""
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
        self.axes = [Axis(n, mode) for n in options.node_ids]
        self._axis_of = {n: a for n, a in zip(options.node_ids, range(3), strict=True)}
        self.counts_per_rev = counts_per_rev
        self.encoder_every = _ticks(options.encoder_ms, tick_hz)
        self.heartbeat_every = _ticks(options.heartbeat_ms, tick_hz)
        self.torques = options.torques
        self.names = frozenset((*DRIVE_FEEDBACK, *DRIVE_TORQUE))
        self.frame_ids = self.wire.ids(options.node_ids, range(32))
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
        if not axis.powered:
            axis.disarm(AxisError.DC_BUS_UNDER_VOLTAGE)
        if s["WatchdogTripped"]:
            axis.disarm(AxisError.WATCHDOG_TIMER_EXPIRED)
        if s.get("Fault", 0):
            axis.disarm(AxisError.DRV_FAULT)
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
            values = {"Bus_Voltage": BUS_VOLTS if axis.powered else 0.0, "Bus_Current": 0.0}
        else:
            values = {**FIRMWARE, "Hw_Version_Major": 0, "Hw_Version_Minor": 0, "Hw_Version_Variant": 0}
        return self.wire.frame(axis.node_id, cmd, values)

    # ------------------------------------------------------------------------------- the host's input
    def incoming(self, msg: can.Message) -> Received | None:
        node, cmd = split_id(msg.arbitration_id)
        i = self._axis_of[node]
        axis = self.axes[i]
        if msg.is_remote_frame:
            if cmd in ANSWERS:
                assert self.node is not None
                self.node.reply(DRIVE_FEEDBACK[i], self._reply(axis, cmd))
            return None
        if cmd in OWN:  # the same id sent by another node: a bus conflict, not a command
            raise ValueError(f"axis {node}: a frame with this axis's own id 0x{msg.arbitration_id:03X}")
        if cmd == Cmd.ESTOP:
            axis.disarm(AxisError.ESTOP_REQUESTED)
            return self._command(i, 0.0, False, msg)
        if cmd == Cmd.CLEAR_ERRORS:
            axis.error = axis.forced_error | (0 if axis.powered else AxisError.DC_BUS_UNDER_VOLTAGE)
            return None
        s = self.wire.decode(msg)
        if cmd == Cmd.SET_AXIS_STATE:
            requested = int(s[REQUESTED])
            if requested == AxisState.CLOSED_LOOP_CONTROL and not axis.error:
                axis.state, axis.setpoint = AxisState.CLOSED_LOOP_CONTROL, 0.0
                return self._command(i, 0.0, True, msg)
            if requested == AxisState.IDLE:
                axis.state = AxisState.IDLE
                return self._command(i, 0.0, False, msg)
            return None  # refused: an active error, or a state the emulation has not (calibration, ...)
        if cmd == Cmd.SET_CONTROLLER_MODE:
            axis.control_mode = int(s["Control_Mode"])
            return None
        if cmd == Cmd.SET_INPUT_TORQUE:
            axis.setpoint = float(s["Input_Torque"])
            if axis.armed and axis.control_mode != ControlMode.TORQUE_CONTROL and not axis.warned_mode:
                axis.warned_mode = True
                log.warning("axis %d is not in TORQUE_CONTROL: its torque setpoint does nothing", node)
            torque = axis.setpoint if axis.control_mode == ControlMode.TORQUE_CONTROL else 0.0
            return self._command(i, torque, axis.armed, msg)
        return None  # limits, gains, trajectories: accepted, not emulated

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
        Cmd.GET_ENCODER_ESTIMATES,
        Cmd.GET_BUS_VOLTAGE_CURRENT,
        Cmd.GET_TORQUES,
    }
)
"""Messages an axis answers on RTR."""
OWN = ANSWERS
"""Ids only the axis itself sends as data frames."""


def _ticks(period_ms: float, tick_hz: float) -> int:
    """A period in whole ticks (0: never)."""
    return 0 if period_ms <= 0 else max(1, round(period_ms * 1e-3 * tick_hz))


def emulate(devices: Devices, counts_per_rev: int, tick_hz: float) -> OdriveAxes:
    return OdriveAxes(devices, counts_per_rev, tick_hz)
