"""The rules a run is judged by: the few limits in a supervisor's rules file that the rig itself reads.

A bench's supervisor has its rules file (`[supervisor] config`, configs/safety/default.toml for the reference
supervisor) and a scenario overrides it key by key (`[safety]`). The file's format is the supervisor's own:
the rig hands it over whole (`SupervisorSpec.rules`) and checks it with the type the plug registers in
`pure_hil.supervisor_rules` (drivers/registry.py), if it registers one. Of its content the rig reads only
these sections and keys, to judge a run against the limits the supervisor was told to keep (the hazard
speed, standstill, the tilt a fall starts at) whichever supervisor ran. A lab's supervisor that keeps other
limits writes them under these names, or is judged by these defaults.

The reference supervisor's rules (safety/config.py) extend these sections, so each limit is declared once.
"""

from __future__ import annotations

import msgspec

from drivers.bounds import NonNegative, Positive


class SpeedLimits(msgspec.Struct, frozen=True, kw_only=True):
    absolute_cap: Positive = 2.0
    """m/s: the cap in NORMAL; a `free` SC request is forwarded as `limit` at this cap."""
    margin: NonNegative = 0.15
    """m/s above the cap before the over-cap window starts."""
    enforce_requested_cap: bool = True
    """Enforce the SC request's cap too (not just the absolute cap). The paper's tasks turn this off: they
    measure how well the controller alone keeps the cap, as on the real robot."""


class StopLimits(msgspec.Struct, frozen=True, kw_only=True):
    standstill_speed: Positive = 0.05
    """m/s at or below which the robot is at standstill."""


class MotionLimits(msgspec.Struct, frozen=True, kw_only=True):
    tilt_limit_deg: Positive = 20.0
    """Chassis tilt beyond this in either plane: balance is lost, drives off."""


class JudgedRules(msgspec.Struct, frozen=True, kw_only=True):
    """What the rig reads of a supervisor's rules (a file's other sections and keys are the supervisor's)."""

    speed: SpeedLimits = SpeedLimits()
    stop: StopLimits = StopLimits()
    motion: MotionLimits = MotionLimits()
