"""The supervisor's vocabulary on the wire, declared once: its states and causes (SUPERVISOR_ESTOP.State and
.Reason) and the controller's heartbeat states it acts on (CONTROLLER_HEARTBEAT.State): the CAN database's
value tables that every controller and tool reads (tests/test_vocabulary.py checks they are exactly the
DBC's); the names a SafetyState payload carries, the operator's stops and actions, and the events a
supervisor reports. Any supervisor, the controller and the rig speak it; safety/ is one supervisor that
does."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Literal


class State(IntEnum):
    """SUPERVISOR_ESTOP.State."""

    NORMAL = 0
    LIMITING = 1
    STOPPING = 2
    ESTOP = 3
    RECOVERY = 4
    """The supervisor's own recovery law holds the drives (Takeover) and brings the robot to rest; then
    ESTOP at rest. Latched: the controller gets the drives back only through ESTOP and a reset."""


class ControllerState(IntEnum):
    """CONTROLLER_HEARTBEAT.State: what the controller says it is doing (docs/contract.md)."""

    INIT = 0
    DISABLED = 1
    PARKED = 2
    BALANCING = 3
    FAULT = 4


class Cause(IntEnum):
    """SUPERVISOR_ESTOP.Reason: why the supervisor is in its state."""

    NONE = 0
    OPERATOR_ESTOP = 1
    BUTTON_ESTOP = 2
    """The OPERATOR_ESTOP CAN frame (a wired e-stop button)."""
    OVER_CAP = 3
    SC_SILENT = 4
    OVERPOWERED = 5
    HARD_SPEED = 6
    RIDER_ABSENT = 7
    E2E_ERRORS = 8
    WRENCH_SILENT = 9
    TILT = 10
    TORQUE_RANGE = 11
    TORQUE_SATURATED = 12
    HEARTBEAT_LOST = 13
    CONTROLLER_FAULT = 14
    DRIVES_SILENT = 15
    IMU_SILENT = 16
    STOP_TIMEOUT = 17
    MOTION_AFTER_STANDSTILL = 18
    STOP_INEFFECTIVE = 19
    RESET = 20
    SENSOR_STUCK = 21
    """A sensor channel holds one value while other evidence says it must move."""
    SENSOR_DISAGREE = 22
    """Two independent measurements of one quantity disagree (encoders vs gyro yaw, position vs velocity,
    attitude vs integrated rates, speed trend vs accelerometer)."""
    WRENCH_IMPLAUSIBLE = 23
    """The seat's wrench is not what a seated rider can produce (weight band, COP, rate of change, frozen)."""
    DRIVE_FAULT = 24
    """A drive reports its command watchdog tripped or a fault, or stays disabled while permitted and told
    to enable."""
    ACTUATOR_MISMATCH = 25
    """A drive's measured torque does not follow its command."""
    DRIVE_NOT_DISABLED = 26
    """In ESTOP a drive did not confirm it is off: the main contactor opened."""
    CONTACTOR_FAULT = 27
    """The main contactor was told to open and a drive still reports its DC bus live."""
    OPERATOR_CUT = 28
    """The operator's explicit category-0 request (`cut_power`): power off at once, even in motion."""


ReactionStateName = Literal["LIMITING", "STOPPING", "ESTOP", "RECOVERY"]
"""The states a supervisor's reaction leads to (all but NORMAL): what a fault or a run can expect."""
StateName = Literal["NORMAL", ReactionStateName]
RUNNING_STATES = frozenset({"NORMAL", "LIMITING"})
"""The states the robot runs in: a stop starts from one of them (the others are a stop under way)."""
"""State's names, as SafetyState.state carries them (tests/test_vocabulary.py checks they are State's)."""

OperatorCommand = Literal["estop", "cut_power", "reset"]
STOP_COMMANDS: frozenset[OperatorCommand] = frozenset({"estop", "cut_power"})
"""The operator's commands that stop the robot (a reset permits motion again; it stops nothing)."""
"""What an operator asks of the supervisor (pure/safety/estop's `action`): stop, stop with power cut at once
(category 0), or reset. A wired button's press is an `estop`."""

OPERATOR_STOPS = frozenset({Cause.OPERATOR_ESTOP, Cause.BUTTON_ESTOP, Cause.OPERATOR_CUT})
"""The causes an operator's e-stop gives (the zenoh e-stop, a wired button, the category-0 request)."""


OPERATOR_ACTIONS_KEPT = 1000
"""Operator actions a run's record keeps (a flood of e-stops is counted beyond it, not kept)."""


@dataclass(frozen=True, slots=True)
class OperatorRecord:
    """An operator's command as the supervisor took it in: when (s), what (`estop`, `cut_power`, `reset`; a
    wired button's press is an `estop` from `button`), whose (the command's `source`), and the state the
    supervisor was in when it came (before it acted on it)."""

    t: float
    action: OperatorCommand
    source: str
    supervisor_state: str


EventKind = Literal["transition", "reset_refused", "contactor_opened"]
"""What a supervisor's event is: a change of state, a refused reset, or the main contactor opened by the rule
for drives that cannot confirm their power stage off (opened by DRIVE_NOT_DISABLED it is a transition)."""


@dataclass(frozen=True, slots=True)
class Event:
    """A transition or a refused reset, with the values that decided it."""

    t: float
    kind: EventKind
    from_state: str
    to_state: str
    cause: str
    detail: str = ""
    values: dict[str, float | None] = field(default_factory=dict)
