"""Scenarios: typed TOML files that say what to run and how to judge it (`configs/scenarios/*.toml`).

A scenario names the robot and rider files, the controller, the clock, the duration, the shared
controller's schedule, the rider's intent, scheduled faults with their expected reactions, and its
pass/fail criteria.
Criteria are declarative measurements with validators and units (after OpenHTF): a metric of the run,
a plane, and bounds; the verdict of each is recorded with the measured value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Literal

import msgspec

from drivers.bounds import MAX_DURATION
from drivers.rules import JudgedRules
from drivers.schemas import ScMode, Speed
from drivers.vocabulary import Cause
from hil.faults import Fault
from hil.run.measurements import MEASUREMENTS, with_unit
from plant.model3d import MAX_SINK, lowest_fall_geom, releasable_share
from plant.params import RiderParams, RobotParams
from plant.rider import LeanStyle, Segment, beyond_reach

TickRate = Annotated[float, msgspec.Meta(gt=0, le=100_000)]
Duration = Annotated[float, msgspec.Meta(gt=0, le=MAX_DURATION)]
Seed = Annotated[int, msgspec.Meta(ge=0)]
Moment = Annotated[float, msgspec.Meta(ge=0, le=MAX_DURATION)]
"""s into the run: within the longest run (drivers/bounds.py MAX_DURATION)."""


class _Record(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    pass


class ScEntry(_Record, frozen=True, kw_only=True):
    """From `at` seconds on, the shared controller asks for `mode` (`cap` m/s in limit mode): the scenario
    file's spelling of an ScRequest (drivers/schemas.py), which the rig sends."""

    at: Moment = 0.0
    mode: ScMode
    cap: Speed = 0.0


class OperatorEntry(_Record, frozen=True):
    """At `at` seconds the operator acts: `estop` or `reset` (the supervisor), `enable` or `disable` (the
    controller; it stays disabled after an e-stop until enabled)."""

    at: Moment
    action: Literal["estop", "reset", "enable", "disable"]


class Intent(_Record, frozen=True):
    """The rider's intent: lean profiles per plane (deg) and a twist profile (Nm); see plant/rider.py."""

    pitch: list[Segment] = []
    roll: list[Segment] = []
    twist: list[Segment] = []
    heeds_alert: bool = False
    """The rider sits up and holds still `alert_reaction_time` (the rider file) after the supervisor's first
    alert, as a rider instructed to would. False: exactly as scripted, whatever the supervisor says."""

    def check_reach(self, rider: RiderParams, rider_file: str, where: str = "intent") -> None:
        """Raise ValueError naming the segment, its field and the bound for a lean past the rider's
        max_lean_deg or a twist past their max_twist_torque (`rider_file`'s): no rider reaches past their own
        limits, and a profile that asks them to tests something no rider does (the rider would stop at the
        limit, silently)."""
        style = LeanStyle(rider.lean_amplitude_deg, rider.lean_rate_deg)
        for plane in ("pitch", "roll", "twist"):
            limit, unit, bound = (
                (rider.max_twist_torque, "Nm", "max_twist_torque")
                if plane == "twist"
                else (rider.max_lean_deg, "deg", "max_lean_deg")
            )
            segments: list[Segment] = getattr(self, plane)
            found = beyond_reach(segments, limit, style)
            if found is None:
                continue
            i, field, value, reached = found
            name = f"{where}.{plane}[{i}] ({segments[i].__struct_config__.tag}): {field} = {value:g}"
            reach = f"|{plane}| <= {limit:g} {unit} ({bound} of {rider_file})"
            if not math.isfinite(reached):
                raise ValueError(f"{name} is not a finite number (expected {reach})")
            about = "" if reached == value else f" about {reached - abs(value):g}: {reached:g} {unit}"
            raise ValueError(f"{name} {unit}{about} is past the rider's reach {reach}")


if TYPE_CHECKING:
    Metric = str  # a checker cannot evaluate the Literal below; msgspec validates against it
else:
    Metric = Literal[tuple(MEASUREMENTS)]
"""A measurement of a run (hil/run/measurements.py declares each with its unit)."""


CHECK_TOLERANCE = 1e-9
"""Bounds are met within float rounding (far below any quantity a criterion measures)."""


class Criterion(_Record, frozen=True):
    """A measurement and its validator: `min <= value <= max`, or `value == equals`."""

    metric: Metric
    plane: Literal["pitch", "roll", "both"] = "pitch"
    min: float | None = None
    max: float | None = None
    equals: float | bool | None = None
    after: Moment = 0.0
    """Evaluate only the part of the run after this time, s (stop_time, safety_reaction, drives_off_after:
    the time measured from)."""
    cause: str = ""
    """safety_reaction: the supervisor's cause (drivers.vocabulary.Cause) whose first transition is timed."""
    note: str = ""

    def __post_init__(self) -> None:
        if self.min is None and self.max is None and self.equals is None:
            raise ValueError(f"criterion on {self.metric} needs min, max or equals")
        for name in ("min", "max", "equals"):
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):  # msgspec takes nan and inf for a float
                raise ValueError(f"criterion on {self.metric}: {name} = {value} is not a finite number")
        if (self.metric == "safety_reaction") != bool(self.cause):
            raise ValueError("safety_reaction needs a cause, and only it takes one")
        if self.cause and self.cause not in Cause.__members__:
            raise ValueError(f"unknown cause {self.cause!r}: expected one of {', '.join(Cause.__members__)}")

    def check(self, value: float) -> bool:
        if self.equals is not None:
            return value == self.equals
        # Times are differences of tick times: 1.5025 - 1.5 is 0.0025000000000004, and one tick must pass.
        tol = CHECK_TOLERANCE
        return (self.min is None or value >= self.min - tol) and (self.max is None or value <= self.max + tol)

    @property
    def label(self) -> str:
        if self.cause:
            return f"{self.metric} [{self.cause}]"
        return f"{self.metric} [{self.plane}]" if MEASUREMENTS[self.metric].per_plane else self.metric

    def describe(self) -> str:
        unit = MEASUREMENTS[self.metric].unit
        if self.equals is not None:
            return f"== {self.equals}"
        parts = []
        if self.min is not None:
            parts.append(with_unit(f">= {self.min:g}", unit))
        if self.max is not None:
            parts.append(with_unit(f"<= {self.max:g}", unit))
        return " and ".join(parts)


@dataclass(frozen=True, slots=True)
class Verdict:
    """A criterion's outcome: what was measured, against which limit, and why it failed (`note`)."""

    criterion: str
    value: float
    limit: str
    units: str
    passed: bool
    note: str = ""


class Scenario(_Record, frozen=True):
    name: str
    description: str = ""
    robot: str = "configs/robot/pure.toml"
    rider: str = "configs/riders/ref_60kg_180.toml"
    law: Literal["hacs", "ihacs"] = "hacs"
    """The reference controller's control law (a bench may run another, or a controller of its own)."""
    clock: Literal["lockstep", "realtime"] = "lockstep"
    duration: Duration = 10.0
    seed: Seed = 0
    tick_hz: TickRate = 400.0
    initial_tilt_deg: tuple[float, float] = (0.0, 0.0)
    """The chassis tilt the robot is released at, [pitch, roll] deg: finite, within the bench's fall bound
    (the bench's sim file's) and releasable, no foot and not the rim on the floor (`check_start`)."""
    fall: Literal["forbidden", "expected"] = "forbidden"
    """forbidden: a fall fails the run, whatever its criteria say (the verdict `no fall`, part of every run's
    verdict). expected: the run is meant to end in a fall (a push beyond the robot's limit) and fails if the
    robot stays up (the verdict `expected fall`)."""
    sc: list[ScEntry] = msgspec.field(default_factory=lambda: [ScEntry(mode="free")])
    intent: Intent = Intent()
    operator: list[OperatorEntry] = []
    safety: dict[str, dict[str, Any]] = {}
    """Overrides of the supervisor's rules for this scenario, by section (`[safety.speed]` ...): on top of
    the bench's supervisor config (configs/safety/default.toml by default; docs/safety.md)."""
    faults: list[Fault] = []
    """Scheduled faults, each with the reaction it expects (hil/faults, docs/faults.md)."""
    criteria: list[Criterion] = []

    def __post_init__(self) -> None:
        try:  # the limits the rig reads are checked at once; the rest by the bench's supervisor (build.py)
            msgspec.convert(self.safety, JudgedRules)
        except msgspec.ValidationError as exc:
            raise ValueError(f"safety: {exc}") from None
        for plane, deg in zip(("pitch", "roll"), self.initial_tilt_deg, strict=True):
            if not math.isfinite(deg):  # msgspec takes nan and inf for a float
                raise ValueError(
                    f"initial_tilt_deg = {list(self.initial_tilt_deg)}: the {plane} tilt must be a finite "
                    "number of degrees"
                )
        for i, fault in enumerate(self.faults):
            if fault.at >= self.duration:  # it would never act, and a fault without `expect` would pass
                raise ValueError(
                    f"faults[{i}] ({fault.kind}): at = {fault.at:g} s is not within the scenario's duration: "
                    f"0 <= at < {self.duration:g} s"
                )
        if self.fall == "expected":
            for c in self.criteria:
                if c.metric == "fallen" and not c.check(1.0):
                    raise ValueError(f'fall = "expected" and a criterion {c.label} {c.describe()} contradict')

    def check_start(
        self, fall_tilt_deg: float, sim_file: str, robot: RobotParams, rider: RiderParams, files: str
    ) -> None:
        """Raise ValueError unless the start state is one the robot can be released in (a robot that starts
        fallen tests nothing): each tilt within the fall bound, and no foot of the rider and not the chassis'
        rim on the floor (plant/model3d.py: the releasable tilt of this robot with this rider, whichever the
        plant). `files`: where the robot and the rider come from, for the message."""
        tilt = list(self.initial_tilt_deg)
        for plane, deg in zip(("pitch", "roll"), self.initial_tilt_deg, strict=True):
            if abs(deg) >= fall_tilt_deg:
                raise ValueError(
                    f"initial_tilt_deg = {tilt}: the {plane} tilt must be within "
                    f"±{fall_tilt_deg:g} deg, the fall bound (fall_tilt_deg of {sim_file})"
                )
        pitch, roll = (math.radians(deg) for deg in self.initial_tilt_deg)
        share = releasable_share(robot, rider, pitch, roll)
        if share < 1.0:
            name, height = lowest_fall_geom(robot, rider, pitch, roll)
            bound = [math.trunc(share * deg * 10.0) / 10.0 for deg in self.initial_tilt_deg]  # never past it
            raise ValueError(
                f"initial_tilt_deg = {tilt}: the {name.replace('_', ' ')} would be {-1000.0 * height:.0f} mm "
                f"into the floor; along this tilt the robot can be released from at most {bound} deg (the "
                f"releasable tilt of {files}, the ball sunk {1000.0 * MAX_SINK:g} mm into the floor)"
            )

    def tick_of(self, t: float) -> int:
        """The tick a scheduled time (s) falls on: times become ticks once, when the run is built, and the
        rig compares ticks, never floats."""
        return round(t * self.tick_hz)

    def rules_over(self, base: dict[str, Any]) -> dict[str, Any]:
        """A supervisor's rules (`base`, as its file has them) with this scenario's `[safety]` overrides,
        key by key."""
        merged = dict(base)
        for section, values in self.safety.items():
            if not isinstance(values, dict) or not isinstance(merged.get(section, {}), dict):
                raise ValueError(f"[safety.{section}]: {section} is not a section of the supervisor's rules")
            merged[section] = {**merged.get(section, {}), **values}
        return merged
