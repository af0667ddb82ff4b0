"""Which reaction each cause gets (IEC 60204-1 §9.2.2's stop categories; docs/safety.md): braked to
standstill through the controller, taken over by the recovery law, or power cut at once. Declared apart from
the state machine (safety/machine.py) that acts on them, so a reader finds a cause's reaction in one place."""

from __future__ import annotations

from drivers.vocabulary import Cause

CONTROLLED = frozenset(
    {
        Cause.OPERATOR_ESTOP,
        Cause.BUTTON_ESTOP,
        Cause.OVERPOWERED,
        Cause.HARD_SPEED,
        Cause.RIDER_ABSENT,
        Cause.E2E_ERRORS,
        Cause.WRENCH_SILENT,
        Cause.SENSOR_STUCK,
        Cause.SENSOR_DISAGREE,
        Cause.WRENCH_IMPLAUSIBLE,
        Cause.DRIVE_FAULT,
        Cause.ACTUATOR_MISMATCH,
    }
)
"""Causes that brake to standstill before power is removed (if the controller is healthy)."""
IMMEDIATE = frozenset(
    {
        Cause.TILT,
        Cause.TORQUE_RANGE,
        Cause.TORQUE_SATURATED,
        Cause.HEARTBEAT_LOST,
        Cause.CONTROLLER_FAULT,
        Cause.DRIVES_SILENT,
        Cause.IMU_SILENT,
        Cause.STOP_TIMEOUT,
        Cause.MOTION_AFTER_STANDSTILL,
        Cause.STOP_INEFFECTIVE,
        Cause.DRIVE_NOT_DISABLED,
        Cause.CONTACTOR_FAULT,
        Cause.OPERATOR_CUT,
    }
)
"""Causes a healthy controller cannot be trusted to stop from: the supervisor's recovery law takes over (or,
without the inputs it needs, power goes off at once)."""
CUT_POWER = frozenset(
    {
        Cause.TILT,
        Cause.DRIVE_NOT_DISABLED,
        Cause.CONTACTOR_FAULT,
        Cause.OPERATOR_CUT,
    }
)
"""The only causes that cut power in motion: balance already lost (tilt beyond the recoverable bound), the
drives themselves are the fault (power that cannot be switched off), or the operator asked for category 0.
Drives that cannot be heard (DRIVES_SILENT) are the recovery law's to judge: it balances without one
encoder, and without two it is not `recoverable`."""
TAKEOVER_CAUSES = frozenset(
    {Cause.SENSOR_STUCK, Cause.SENSOR_DISAGREE, Cause.ACTUATOR_MISMATCH, Cause.DRIVE_FAULT}
)
"""Controlled causes the controller cannot stop from: it balances on a sensor that lies, or drives a drive
that does not do what it is told (or does not hear it). The recovery law, which drops what the diagnosis
names (and reaches the drives on a frame of its own), takes over at once instead."""
FINDINGS = (
    Cause.SENSOR_STUCK,
    Cause.SENSOR_DISAGREE,
    Cause.WRENCH_IMPLAUSIBLE,
    Cause.ACTUATOR_MISMATCH,
)
"""Causes the diagnostics report (safety/diagnostics.py), in their root-cause order: a frozen channel
makes its cross-checks disagree, a drive fault makes its torque mismatch."""
