"""What the supervisor's monitors see at one update (safety/monitors.py makes it, safety/machine.py decides
on it): the streams' ages, the drives' reports and the diagnostics' findings. Records only, no I/O."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from drivers.schemas import ScRequest
from drivers.vocabulary import Cause

STREAMS = ("drives", "imu", "heartbeat", "wrench", "sc")


@dataclass(frozen=True, slots=True)
class Finding:
    """A diagnostic that fails now: its cause, what it saw, and the parts it isolates (drivers.can_codec's
    PARTS)."""

    cause: Cause
    detail: str
    parts: tuple[str, ...] = ()


# The records made every update (DriveReport, Observation; safety/machine.py's Decision) are plain classes
# with a typed __init__, not dataclasses: compiled (mypyc), a dataclass keeps the __init__ the dataclasses
# module writes in Python, a plain class gets a native one. They are not changed once made.


class DriveReport:
    """One drive as its feedback and its commands show it."""

    def __init__(
        self,
        enabled: bool | None,
        watchdog: bool = False,
        fault: bool = False,
        bus_powered: bool | None = None,
        commanded_for: float = 0.0,
    ):
        self.enabled = enabled
        """DRIVEn_FEEDBACK.Enabled of the last trusted frame (None: no fresh one)."""
        self.watchdog = watchdog
        """WatchdogTripped: the drive turned itself off because its commands stopped."""
        self.fault = fault
        self.bus_powered = bus_powered
        """BusPowered: its DC bus is live (the main contactor is closed)."""
        self.commanded_for = commanded_for
        """s the controller has asked it to enable without a break (DRIVEn_COMMAND.Enable = 1)."""


class Observation:
    """What the supervisor knows at time t, from the bus and zenoh only (never the plant's truth)."""

    def __init__(
        self,
        t: float,
        speed: float | None,
        tilt: float | None,
        ages: Mapping[str, float],
        controller_state: int | None = None,
        torque_peak: float = 0.0,
        e2e_errors: int = 0,
        e2e_invalid: tuple[str, ...] = (),
        seat_load: float | None = None,
        button: bool = False,
        request: ScRequest | None = None,
        operator: str | None = None,
        operator_source: str = "",
        findings: tuple[Finding, ...] = (),
        drives: tuple[DriveReport, ...] = (),
        recoverable: bool = False,
    ):
        self.t = t
        self.speed = speed
        """Ground speed estimate, m/s (None: no estimate, a speed stream is silent)."""
        self.tilt = tilt
        """Largest chassis tilt of the two planes, rad."""
        self.ages = ages
        """Seconds since the last trusted frame or payload per stream in STREAMS (inf: never)."""
        self.controller_state = controller_state
        """The controller's last heartbeat State (None: never heard)."""
        self.torque_peak = torque_peak
        """Largest |torque command| since the previous observation, Nm."""
        self.e2e_errors = e2e_errors
        """E2E errors within the streams' windows (safety/e2e_window.py), for the record."""
        self.e2e_invalid = e2e_invalid
        """The protected streams whose E2E errors persist: more than their window tolerates (E2E_ERRORS)."""
        self.seat_load = seat_load
        """The rider's weight on the seat (−Fz), N."""
        self.button = button
        """The wired e-stop (OPERATOR_ESTOP frame) is pressed."""
        self.request = request
        self.operator = operator
        """An operator command since the previous observation: 'estop' or 'reset'."""
        self.operator_source = operator_source
        self.findings = findings
        """Diagnostics failing now (FINDINGS causes)."""
        self.drives = drives
        """The three drives (empty: not known to this observer; a stop can then not be confirmed)."""
        self.recoverable = recoverable
        """The recovery law has what it needs to balance (attitude or rate per plane, and the ball's rates
        from three encoders or two and the yaw rate, none of them found faulty). False: no takeover is
        possible."""
