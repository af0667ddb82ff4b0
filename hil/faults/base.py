"""What every fault has: when it acts, what reaction it expects, and its per-run state.

A fault is a typed, frozen msgspec Struct (its parameters, validated when a scenario or a live request is
read) whose `kind` names it in TOML and JSON. Its behaviour lives in small hooks of its family's base class
(sensors, frames, topics, actuators, processes); the runtime (hil/faults/runtime.py) owns the timing, the
event log and the random streams, and calls a hook only while the fault is active.
"""

from __future__ import annotations

import functools
import math
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, Protocol, cast

import msgspec
import numpy as np

from drivers.bounds import MAX_DURATION, NonNegative, Positive
from drivers.vocabulary import Cause, ReactionStateName

if TYPE_CHECKING:
    from drivers.can_bus import CanNode
    from drivers.dut import DutHandle
    from drivers.keys import Keys
    from drivers.plugs import Supervisor
    from plant.core import PlantCore


class FaultTarget(Protocol):
    """What a fault acts on: the rig, as much of it as faults touch (hil/run/rig.py's Rig is one).
    Declared here so the faults depend on nothing above them."""

    plant: PlantCore
    can: CanNode
    """The rig's own node on the bus: its catalog, its transmit and its receive hooks."""
    keys: Keys
    bitrate: int
    dut: DutHandle | None
    """The controller under test when it runs in the rig's process (None elsewhere)."""
    supervisor: Supervisor | None
    """The supervisor when it runs in the rig's process (None elsewhere)."""


Limit = Callable[[Any, "FaultTarget | None"], "tuple[float, str] | None"]
"""A bound that depends on the fault's other parameters or on the rig: (fault, rig or None) -> (the bound,
what it is here), or None when it cannot be known without the rig."""


@dataclass(frozen=True, slots=True)
class Bound:
    """A fault parameter's physical or wire bound, declared once with its type (`Annotated[float,
    Bound(...)]`): checked when a fault is read (a scenario file, a live request), again against the rig it
    will act on where the bound depends on the rig (`limit`), and listed in docs/faults.md from here
    (hil/faults/bounds.py). NaN and infinities are refused for every parameter, bounded or not."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    """low < value (else low <= value)."""
    high_open: bool = False
    magnitude: bool = False
    """The bound is on |value|: -high <= value <= high."""
    limit: Limit | None = None
    """The high bound when it depends on the fault or the rig (`high` is then None)."""
    limit_text: str = ""
    """What `limit` is, for the docs ("the channel's range")."""
    why: str = ""
    """Why it is the bound: the physics or the wire behind it."""

    def check(self, spec: FaultSpec, name: str, value: float, rig: FaultTarget | None) -> None:
        """Raise ValueError naming the parameter and its bound if `value` is outside it."""
        high: float | None = self.high
        here = ""
        if self.limit is not None:
            found = self.limit(spec, rig)
            if found is None:
                return  # known only on the rig: checked again there
            high, here = found
        low = -high if self.magnitude and high is not None else self.low
        below = low is not None and (value <= low if self.low_open else value < low)
        above = high is not None and (value >= high if self.high_open else value > high)
        if below or above:
            raise ValueError(
                f"{spec.kind}: {name} = {number(value)} is out of its bound {self.text(name, high)} "
                f"({here or self.why})"
            )

    def text(self, name: str, high: float | None = None) -> str:
        """`0 < sigma <= 3.2`: with the high bound given, else the declared one (a limit by its text)."""
        if high is None and self.high is not None:
            high = self.high
        top = number(high) if high is not None else self.limit_text or None
        if self.magnitude:
            return f"|{name}| <= {top}"
        lower = "" if self.low is None else f"{number(self.low)} {'<' if self.low_open else '<='} "
        upper = "" if top is None else f" {'<' if self.high_open else '<='} {top}"
        return f"{lower}{name}{upper}"


def number(x: float) -> str:
    """A bound or a value as a person reads it: whole numbers in full (4294967295, not 4.29497e+09)."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"


Probability = Annotated[
    float, Bound(0.0, 1.0, low_open=True, why="a probability per frame or sample; 1: every one")
]
Hold = Annotated[
    float,
    Bound(
        0.0,
        10.0,
        low_open=True,
        why="s; the fault holds that long of samples, frames or commands in memory (4000 ticks at 400 Hz): "
        "every consumer's timeout in the contract is a fraction of a second, so a longer hold is the same "
        "fault as a dead source",
    ),
]
"""A delay: how far back a fault holds what it delays."""
Motor = Annotated[int, Bound(1, 3, why="one of PURE's three drives")]
Period = Annotated[
    float,
    Bound(
        0.0,
        MAX_DURATION,
        low_open=True,
        why="s; at most the longest run (drivers/bounds.py MAX_DURATION): a longer period never comes round",
    ),
]


class Expect(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The reaction a fault should cause; each field given becomes a verdict of the run.

    `reaction = "none"`: the fault must be tolerated, no supervisor transition from its start to the end of
    the run. `state` and/or `cause`: the supervisor must enter that state with that cause within `within`
    seconds of the fault's start. `fall = false`: the robot must not fall. `max_speed`: the true ground speed
    stays at or below it (m/s) from the fault's start on."""

    reaction: Literal["none", "supervisor"] | None = None
    state: ReactionStateName | None = None
    cause: str | None = None
    within: Positive = 0.1
    fall: bool | None = None
    max_speed: NonNegative | None = None

    def __post_init__(self) -> None:
        if self.cause is not None and self.cause not in Cause.__members__:
            raise ValueError(f"unknown cause {self.cause!r}: expected one of {', '.join(Cause.__members__)}")
        if self.reaction == "none" and (self.state or self.cause):
            raise ValueError("reaction 'none' cannot also name a state or cause")
        if self.reaction == "supervisor" and not (self.state or self.cause):
            raise ValueError("reaction 'supervisor' needs a state, a cause or both")
        if self.reaction is None and not self.supervisor and self.fall is None and self.max_speed is None:
            raise ValueError("expect needs reaction, state, cause, fall or max_speed")

    @property
    def supervisor(self) -> bool:
        """A supervisor reaction is expected (a state or a cause is named)."""
        return bool(self.state or self.cause)


class FaultError(ValueError):
    """A fault that cannot act on this rig (an unknown message, a process that is not in this process)."""


class FaultSpec(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True, tag_field="kind"):
    """Common to every fault: active from `at` (s) for `duration` (s; none: to the end of the run)."""

    at: Annotated[
        float, Bound(0.0, MAX_DURATION, why="s; within the longest run (drivers/bounds.py MAX_DURATION)")
    ] = 0.0
    duration: (
        Annotated[
            float,
            Bound(
                0.0, MAX_DURATION, low_open=True, why="s; the longest run (drivers/bounds.py MAX_DURATION)"
            ),
        ]
        | None
    ) = None
    expect: Expect | None = None

    summary: ClassVar[str] = ""
    detect_within: ClassVar[float] = 0.25
    """s the supervisor has to see this fault on its own evidence (docs/safety.md, the coverage campaign)."""
    latent: ClassVar[bool] = False
    """The fault shows only on a demand (the drives told to turn off): its detection time counts from the
    supervisor's first e-stop after the fault started, not from the fault's start."""
    disturbance: ClassVar[bool] = False
    """Not a fault of the robot but something the world or the rider does to it (a push, a weight shift):
    it must be ridden through without a hazard, whatever it changes."""

    def __post_init__(self) -> None:
        self.check_bounds(None)

    def check_bounds(self, rig: FaultTarget | None) -> None:
        """Every parameter a number (msgspec accepts NaN and infinities for a float) within its declared
        Bound; on `rig` also the bounds that depend on it. ValueError names the parameter and the bound."""
        bounds = bounds_of(type(self))
        for name in self.__struct_fields__:
            value = getattr(self, name)
            bound = bounds.get(name)
            for x in value if isinstance(value, tuple) else (value,):
                if isinstance(x, float) and not math.isfinite(x):
                    what = "nan is not a number" if math.isnan(x) else f"{x} is not a finite number"
                    expected = "" if bound is None else f" (expected {bound.text(name)})"
                    raise ValueError(f"{self.kind}: {name} = {what}{expected}")
                if bound is not None and isinstance(x, (int, float)) and not isinstance(x, bool):
                    bound.check(self, name, x, rig)

    @property
    def kind(self) -> str:
        return kind_of(type(self))

    def ticks(self, tick_hz: float, now: int = 0) -> tuple[int, int | None]:
        """The ticks it is active in, [first, end) (end None: to the run's end), `at` counted from tick
        `now`: times become ticks once, when the fault is scheduled, so no tolerance is ever needed."""
        first = now + round(self.at * tick_hz)
        return first, None if self.duration is None else first + max(1, round(self.duration * tick_hz))

    def describe(self) -> str:
        """`kind` and the parameters that differ from their defaults, for logs and reports."""
        params = {
            k: v
            for k, v in msgspec.structs.asdict(self).items()
            if k not in ("at", "duration", "expect") and v != _default(type(self), k)
        }
        return self.kind + ("" if not params else " " + " ".join(f"{k}={v}" for k, v in params.items()))

    def check(self, rig: FaultTarget) -> None:
        """Raise ValueError if the fault cannot act on this rig: a bound that depends on the rig, or
        `validate`'s reasons."""
        self.check_bounds(rig)
        self.validate(rig)

    # Hooks: no-ops unless a family needs them.
    def validate(self, rig: FaultTarget) -> None:
        """Raise ValueError if the fault cannot act on this rig (unknown message, no such process, ...)."""

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        """The fault becomes active (before the plant's step of the tick)."""

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        """The fault ends (its duration ran out, or it was cleared)."""


def kind_of(cls: type[FaultSpec]) -> str:
    """A fault class's `kind`: the tag each one declares, a str (msgspec's own type allows int or None)."""
    return cast(str, cls.__struct_config__.tag)


@functools.cache
def bounds_of(cls: type[FaultSpec]) -> dict[str, Bound]:
    """Each parameter's declared Bound (in its type, also inside `X | None` or a tuple)."""
    hints = typing.get_type_hints(cls, include_extras=True)
    found = {}
    for name in cls.__struct_fields__:
        bound = _bound_in(hints[name])
        if bound is not None:
            found[name] = bound
    return found


def _bound_in(hint: Any) -> Bound | None:
    for meta in getattr(hint, "__metadata__", ()):
        if isinstance(meta, Bound):
            return meta
    for arg in typing.get_args(hint):
        bound = _bound_in(arg)
        if bound is not None:
            return bound
    return None


def _default(cls: type, name: str) -> Any:
    for f in msgspec.structs.fields(cls):
        if f.name == name:
            return f.default
    return msgspec.NODEFAULT


@dataclass(slots=True)
class FaultState:
    """One fault's life in a run: its random stream and whatever its hooks keep between ticks."""

    rng: np.random.Generator
    first_tick: int = 0
    end_tick: int | None = None
    """Active in ticks [first_tick, end_tick) (FaultSpec.ticks); None: to the end of the run."""
    active: bool = False
    started: float | None = None
    ended: float | None = None
    remaining: int | None = None
    """Frames still to affect (CAN faults with a count)."""
    memory: dict[str, Any] = field(default_factory=dict)


FaultAction = Literal["inject", "start", "end", "clear"]


class FaultEvent(msgspec.Struct, frozen=True):
    """A line of the fault log: `action` is inject (live request taken), start, end or clear."""

    t: float
    fault: int
    """The fault's number in the run (scenario order, then live injections)."""
    kind: str
    action: FaultAction
    detail: str = ""
