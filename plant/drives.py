"""Motor drives: torque command -> torque limit and the motor's torque-speed line -> current-loop lag, with
enable and a command watchdog; and the main contactor in their power feed.

Two ways to remove torque, as two-channel stops are built (IEC 60204-1, ISO 13849): each drive's own
power stage (disabled by its enable, its watchdog or the loss of the supervisor's permission: safe torque
off), and the main contactor that cuts the DC bus of all three whatever their own state.

Time comes in as an argument (the plant has no clock). Torques are at the motor shaft, in Nm; the gear
ratio and direction live in the omniwheel map.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

from mypy_extensions import mypyc_attr

from plant.params import Drive


class DriveState(IntEnum):
    DISABLED = 0
    ENABLED = 1
    WATCHDOG = 2
    """Disabled by the drive itself because commands stopped arriving; a fresh command re-arms it."""


@mypyc_attr(allow_interpreted_subclasses=True)  # tests/test_failop.py watches its setpoints in a subclass
@dataclass(slots=True)
class MotorDrive:
    params: Drive
    command: float = 0.0
    torque: float = 0.0
    """Torque the motor produces now (after lag and limit), Nm."""
    state: DriveState = DriveState.DISABLED
    last_command_time: float = -math.inf
    permitted: bool = True
    """The supervisor's permission to run (its SUPERVISOR_ESTOP frame, fresh and not asserting e-stop)."""
    gain: float = 1.0
    """Torque actually produced per torque commanded (a failing drive: < 1; lost: 0)."""
    stuck_enabled: bool = False
    """A failed power stage that cannot be switched off: disable, loss of permission and the watchdog are
    ignored, the last setpoint is held."""
    bus_powered: bool = True
    """The DC bus is live (the main contactor is closed): without it the power stage makes no torque."""

    def set_command(self, torque: float, enable: bool, now: float) -> None:
        """A command frame arrived: store the setpoint and feed the watchdog (ignored without permission:
        commands from before the permission returned are never applied)."""
        if not self.permitted and not self.stuck_enabled:
            return
        if not math.isfinite(torque):
            torque = 0.0
            enable = False
        self.command = torque
        self.last_command_time = now
        self.state = DriveState.ENABLED if enable or self.stuck_enabled else DriveState.DISABLED

    def available(self, torque: float, speed: float) -> float:
        """`torque` (within the current limit) as the motor can make it at `speed` (rad/s, its shaft).
        Driving (torque and speed of one sign) the back-EMF k_e·ω leaves V - k_e·ω for the current: at most
        stall_torque (1 - |ω| / no_load_speed), none at the top speed, and past it the current reverses (a
        brake, within the current limit). Braking, the back-EMF helps the supply: the current limit holds."""
        if torque * speed <= 0.0:
            return torque
        p = self.params
        most = max(p.stall_torque * (1.0 - abs(speed) / p.no_load_speed), -p.torque_limit)
        if abs(torque) <= most:
            return torque
        return most if torque > 0.0 else -most  # a negative `most` is a brake against the motion

    def advance(self, dt: float, now: float, speed: float) -> float:
        """Advance the current loop by dt ending at `now`, the motor turning at `speed` (rad/s) as it starts;
        returns the torque held over the interval."""
        if self.stuck_enabled:
            self.state = DriveState.ENABLED
        elif self.state is DriveState.ENABLED and now - self.last_command_time > self.params.watchdog_timeout:
            self.state = DriveState.WATCHDOG
        if self.state is not DriveState.ENABLED or not self.bus_powered:
            # Power stage off or no DC bus: no torque, at once.
            self.torque = 0.0
            return 0.0
        limit = self.params.torque_limit
        target = self.available(min(max(self.command * self.gain, -limit), limit), speed)
        start = self.torque
        decay = math.exp(-dt / self.params.current_loop_tau)
        self.torque = target + (start - target) * decay
        # Mean of the exponential over the interval: the torque the mechanics feel during dt.
        return target + (start - target) * (1.0 - decay) * self.params.current_loop_tau / dt

    def set_permission(self, permitted: bool) -> None:
        """Losing it turns the power stage off at once; regaining it enables nothing until a command."""
        if not permitted and not self.stuck_enabled:
            self.state = DriveState.DISABLED
            self.torque = 0.0
            self.command = 0.0
        self.permitted = permitted


class DriveArray:
    """The three drives of the robot and the main contactor in their power feed."""

    def __init__(self, params: Drive):
        self.motors = tuple(MotorDrive(params) for _ in range(3))
        self.contactor_closed = True
        self.contactor_welded = False
        """A failed contactor whose contacts stay closed whatever it is told."""

    def set_contactor(self, closed: bool) -> None:
        """Close or open the main contactor: open, no drive makes torque whatever its own state."""
        self.contactor_closed = closed or self.contactor_welded
        for m in self.motors:
            m.bus_powered = self.contactor_closed

    def set_commands(self, torques: tuple[float, float, float], enable: bool, now: float) -> None:
        for m, t in zip(self.motors, torques, strict=True):
            m.set_command(t, enable, now)

    def advance(self, dt: float, now: float, speeds: Sequence[float]) -> tuple[float, float, float]:
        """The three drives over dt ending at `now`, their motors turning at `speeds` (rad/s) as it starts."""
        a, b, c = self.motors
        return a.advance(dt, now, speeds[0]), b.advance(dt, now, speeds[1]), c.advance(dt, now, speeds[2])

    def set_permission(self, permitted: bool) -> None:
        for m in self.motors:
            m.set_permission(permitted)

    @property
    def powered(self) -> bool:
        """Any drive can make torque: its power stage is on and the DC bus is live."""
        return self.contactor_closed and any(m.state is DriveState.ENABLED for m in self.motors)

    @property
    def torques(self) -> tuple[float, float, float]:
        a, b, c = self.motors
        return a.torque, b.torque, c.torque
