"""The supervisor's configuration (`configs/safety/default.toml`) and its own view of the robot.

Like the controller, the supervisor decodes the robot file into its own types (only the geometry it needs
to estimate speed), so it shares no code with the controller it watches: a bug in one is not a bug in both.
Every threshold has a documented default; docs/safety.md explains how they were chosen.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]
Fraction = Annotated[float, msgspec.Meta(gt=0, le=1)]


class _Lenient(msgspec.Struct, frozen=True, kw_only=True):
    """A subset of a file written for someone else: unknown fields are ignored."""


class _Strict(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pass


# --------------------------------------------------------------------- the robot, as the supervisor sees it
class Ball(_Lenient):
    radius: Positive = 0.1145


class Drivetrain(_Lenient):
    wheel_radius: Positive = 0.0625
    zenith_deg: Positive = 45.0
    azimuth0_deg: float = 0.0
    motor_sign: tuple[int, int, int] = (1, 1, 1)
    gear_ratio: Positive = 8.0


class DriveLimits(_Lenient):
    torque_limit: Positive = 3.75


class RobotGeometry(_Lenient):
    """Decoded from the robot TOML the plant and the controller read (configs/robot/pure.toml)."""

    ball: Ball = Ball()
    drivetrain: Drivetrain = Drivetrain()
    drive: DriveLimits = DriveLimits()


# --------------------------------------------------------------------------------------------- rules
class SpeedRules(_Strict):
    absolute_cap: Positive = 2.0
    """m/s: the cap in NORMAL; a `free` SC request is forwarded as `limit` at this cap."""
    reduced_cap: NonNegative = 0.3
    """m/s: the cap while the SC agent is silent (LIMITING, SC_SILENT)."""
    enforce_requested_cap: bool = True
    """Enforce the SC request's cap too (not just the absolute cap). The paper's tasks turn this off: they
    measure how well the controller alone keeps the cap, as on the real robot."""
    margin: NonNegative = 0.15
    """m/s above the cap before the over-cap window starts."""
    window: Positive = 0.25
    """s above cap + margin before LIMITING (command idle)."""
    release_window: Positive = 0.5
    """s at or below cap + margin before LIMITING releases to NORMAL."""
    decel: Positive = 0.5
    """m/s²: when the cap drops below the speed, the speed must come down at least this fast (a braking
    ramp from the speed at the drop, as in IEC 61800-5-2's ramp-monitored stops); the cap is enforced
    against the ramp until the ramp reaches it."""
    brake_delay: NonNegative = 0.5
    """s after the drop before the ramp starts; meanwhile up to the speed at the drop + rise_margin is
    allowed: a ballbot first speeds up to tilt back (non-minimum phase; +0.45 m/s from 1.5 m/s here)."""
    rise_margin: Positive = 0.3
    """m/s: while limiting or stopping, a speed this far above the speed at entry means the command is not
    obeyed (overpowered: controlled stop; while stopping: drives off)."""
    limit_timeout: Positive = 3.0
    """s in LIMITING without getting back under the cap -> controlled stop (OVERPOWERED)."""
    hard_limit: Positive = 2.5
    """m/s: above this, a controlled stop whatever the cap."""


class StopRules(_Strict):
    standstill_speed: Positive = 0.05
    """m/s at or below which the robot is at standstill."""
    standstill_time: Positive = 0.3
    """s at standstill before a controlled stop turns the drives off."""
    motion_after_standstill: Positive = 0.2
    """m/s: once at standstill, motion above this turns the drives off at once."""
    timeout: Positive = 6.0
    """s: a controlled stop that has not reached standstill by then turns the drives off."""


class MotionRules(_Strict):
    tilt_limit_deg: Positive = 20.0
    """Chassis tilt beyond this in either plane: balance is lost, drives off."""
    torque_range: Positive = 1.05
    """A torque command above this × the drive's limit is garbage: drives off."""
    saturation_fraction: Fraction = 0.97
    """A command at or above this × the limit counts as saturated."""
    saturation_time: Positive = 1.0
    """s of continuous saturation (the controller has lost authority): drives off."""
    rider_min_load: NonNegative = 150.0
    """N on the seat below which nobody is seated."""
    rider_absent_time: Positive = 0.5
    """s without a rider while moving: controlled stop."""


class Watchdogs(_Strict):
    """Consumer timeouts, each several producer periods (drives and IMU 400 Hz, heartbeat 400 Hz in the
    rig, TES 400 Hz, SC requests at least 2 Hz)."""

    drives: Positive = 0.025
    imu: Positive = 0.025
    heartbeat: Positive = 0.05
    wrench: Positive = 0.1
    sc: Positive = 1.0
    startup_grace: NonNegative = 0.5
    """s after start-up during which streams never heard from are not yet faults."""
    require_wrench: bool = True
    """A silent seat (TES) is a fault: the rider's input is lost."""


class Integrity(_Strict):
    e2e_window: Positive = 1.0
    """s over which E2E errors (CRC, repeated, out of order, lost frames) are counted."""
    e2e_max_errors: Annotated[int, msgspec.Meta(ge=1)] = 20
    """This many in the window: the bus cannot be trusted, controlled stop."""


class Output(_Strict):
    estop_frame_period: Positive = 0.01
    """s between SUPERVISOR_ESTOP frames (the DBC's 100 Hz); also sent at once on every transition."""
    sc_period: Positive = 0.05
    """s between repeats of an unchanged SC command (keeps it fresh for the controller)."""
    state_period: Positive = 0.1
    """s between repeats of pure/safety/state (it is also put on every transition)."""
    rate_hz: Positive = 400.0
    """Standalone: the supervisor's own timer (it also updates on every SYNC)."""


class Identity(_Strict):
    operators: list[str] = []
    """Sources (the payload's `source`) allowed to reset an e-stop or request an SC mode. Empty: not checked
    (the loopback default). On a bench this is defence in depth behind the router's ACL (docs/security.md):
    anything else is counted and ignored. An e-stop is accepted from anyone, always."""


class SupervisorConfig(_Strict):
    identity: Identity = Identity()
    speed: SpeedRules = SpeedRules()
    stop: StopRules = StopRules()
    motion: MotionRules = MotionRules()
    watchdogs: Watchdogs = Watchdogs()
    integrity: Integrity = Integrity()
    output: Output = Output()
