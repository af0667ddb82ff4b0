"""The CiA 402 profile's state machine (CiA 402-2), pure: the next state a controlword asks for, the
statusword a state shows, and whether the drive makes torque. No I/O and no drive: drive.py keeps the
state, applies these and sends the EMCY a fault reset causes (python-canopen's p402 is the master's side).
"""

from __future__ import annotations

from drivers.devices.cia402 import CST, REMOTE, STATUS_BITS, VOLTAGE_ENABLED, State

INTERNAL_LIMIT = 0x0800
"""Statusword bit 11: internal limit active (the target torque is clipped to 0x6072 / 0x6073)."""
HALT = 0x0100
"""Controlword bit 8."""
FAULTS = (State.FAULT, State.FAULT_REACTION_ACTIVE)
"""The states only a fault reset leaves."""
VOLTAGE_STATES = (
    State.READY_TO_SWITCH_ON,
    State.SWITCHED_ON,
    State.OPERATION_ENABLED,
    State.QUICK_STOP_ACTIVE,
)
"""The states whose statusword shows the DC bus's voltage (bit 4), when it is up."""


def next_state(s: State, cw: int, *, fault_reset: bool, quick_stop_stays: bool) -> State:
    """The state controlword `cw` takes a drive in state `s` to. `fault_reset`: a fault reset clears a fault
    now (the caller's rising edge of bit 7, and its conditions: the DC bus up, no error held);
    `quick_stop_stays`: the quick stop option code (0x605A) keeps QUICK STOP ACTIVE."""
    if s in FAULTS:
        return State.SWITCH_ON_DISABLED if fault_reset else s
    if not cw & 0x02:  # disable voltage (transitions 7, 9, 10, 12)
        return State.SWITCH_ON_DISABLED
    if not cw & 0x04:  # quick stop (7, 10, 11)
        if s is State.OPERATION_ENABLED:
            # 0x605A -1 (manufacturer's): torque off at once, stay in QUICK STOP ACTIVE; 0: disable the
            # drive function, the motor free, and on to SWITCH ON DISABLED (transition 12) at once.
            return State.QUICK_STOP_ACTIVE if quick_stop_stays else State.SWITCH_ON_DISABLED
        if s in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON):
            return State.SWITCH_ON_DISABLED
        return s
    if cw & 0x87 == 0x06:  # shutdown (2, 6, 8)
        if s in (State.SWITCH_ON_DISABLED, State.SWITCHED_ON, State.OPERATION_ENABLED):
            return State.READY_TO_SWITCH_ON
        return s
    if cw & 0x8F == 0x07:  # switch on (3) / disable operation (5)
        if s in (State.READY_TO_SWITCH_ON, State.OPERATION_ENABLED):
            return State.SWITCHED_ON
        return s
    if cw & 0x8F == 0x0F and s in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.QUICK_STOP_ACTIVE):
        return State.OPERATION_ENABLED  # switch on + enable operation (3+4), enable operation (4, 16)
    return s


def status_word(s: State, powered: bool, internal_limit: bool) -> int:
    """0x6041 in state `s`: the state's bits, remote, voltage enabled while the DC bus is `powered`, and the
    internal limit when the target torque is clipped."""
    word = STATUS_BITS[s] | REMOTE
    if powered and s in VOLTAGE_STATES:
        word |= VOLTAGE_ENABLED
    if internal_limit:
        word |= INTERNAL_LIMIT
    return word


def makes_torque(s: State, mode: int, controlword: int) -> bool:
    """The torque loop follows the target: OPERATION ENABLED, in cyclic synchronous torque, not halted."""
    return s is State.OPERATION_ENABLED and mode == CST and not controlword & HALT
