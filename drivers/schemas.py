"""zenoh payloads: versioned msgspec Structs, encoded as msgpack maps (field name -> value).

Decodable from any language with a msgpack library: a map with the field names below, floats as float64,
ints as integers, strings as UTF-8. Every float has bounds, which also rejects NaN and infinities.
`decode()` never lets a msgspec exception escape: bad payloads raise `PayloadError` with a reason kind.

Time stamps (`stamp`) are the producing node's clock in seconds: simulated time for payloads made inside a
rig run (TES, supervisor), the wall clock (time.time) for operator tools.
"""

from __future__ import annotations

import inspect
import math
from typing import Annotated, Any, ClassVar, Literal, TypeVar

import msgspec

from drivers.vocabulary import OperatorCommand, StateName

VERSION = 1

Seq = Annotated[int, msgspec.Meta(ge=0, le=2**32 - 1, description="sequence number, +1 per message")]
Stamp = Annotated[float, msgspec.Meta(ge=0.0, le=1e10, description="seconds")]
Force = Annotated[float, msgspec.Meta(ge=-1e4, le=1e4, description="N")]
Moment = Annotated[float, msgspec.Meta(ge=-2e3, le=2e3, description="Nm")]
Metres = Annotated[float, msgspec.Meta(ge=-1.0, le=1.0, description="m")]
Speed = Annotated[float, msgspec.Meta(ge=0.0, le=5.0, description="m/s")]
Angle = Annotated[float, msgspec.Meta(ge=-7.0, le=7.0, description="rad")]
Rate = Annotated[float, msgspec.Meta(ge=-100.0, le=100.0, description="rad/s or m/s")]
Source = Annotated[str, msgspec.Meta(min_length=1, max_length=64, description="who sent it")]
Text = Annotated[str, msgspec.Meta(max_length=200)]

ScMode = Literal["free", "idle", "limit"]
"""What a shared-controller agent asks for, declared once (tests/test_vocabulary.py looks for another)."""


class Payload(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    version: int = VERSION
    seq: Seq
    stamp: Stamp

    def __post_init__(self) -> None:
        if self.version != VERSION:
            raise ValueError(f"unsupported version {self.version} (this build speaks {VERSION})")


class TesWrench(Payload, frozen=True, kw_only=True):
    """The rider's wrench on the seat at P (chassis top centre), body axes: x forward, y left, z up.
    A seated rider pushes down: force[2] < 0. Untared: subtract the upright tare for lean control."""

    force: tuple[Force, Force, Force]
    """N."""
    moment: tuple[Moment, Moment, Moment]
    """Nm, about P."""
    cop: tuple[Metres, Metres]
    """Centre of pressure on the seat surface, body x and y, m; (0, 0) when the seat is empty."""
    cells: tuple[Force, Force, Force, Force, Force, Force] | None = None
    """The six load cells' raw readings the wrench was computed from, N (vertical 1-3, then tangential
    1-3), for diagnostics: six cells give six wrench components with nothing to spare, so only the cells
    themselves show one of them dead or frozen. None: a seat that does not publish them."""


class ScRequest(Payload, frozen=True, kw_only=True):
    """What a shared-controller agent asks for (pure/sc/request)."""

    mode: ScMode
    """free: rider in charge; idle: command speed 0 whatever the rider does; limit: clamp to speed_cap."""
    speed_cap: Speed = 0.0
    """m/s; used in `limit` mode."""
    source: Source

    def speed_limit(self) -> float:
        """The cap rule, written only here: how fast the request lets the robot go, m/s (idle 0, limit its
        speed_cap, free no limit)."""
        if self.mode == "idle":
            return 0.0
        return self.speed_cap if self.mode == "limit" else math.inf


class ScCommand(ScRequest, frozen=True, kw_only=True):
    """What the supervisor lets through (pure/sc/command): the only SC input the controller reads."""

    # An ScRequest and why the supervisor changed it: its source is the request's, or `supervisor` when the
    # supervisor imposed it, and its mode is never `free` (what the supervisor lets through is capped).
    reason: Text = ""
    """Why the supervisor changed the request (empty when forwarded as asked)."""


class SafetyState(Payload, frozen=True, kw_only=True):
    state: StateName
    reason: Text
    cap: Speed
    """The speed cap in force, m/s."""
    since: Stamp
    """When the supervisor entered this state, s."""
    estop_by: Text = ""
    """Whose operator e-stop is latched ('' none): the source of the last e-stop or cut_power taken in,
    in any state, until a valid reset. An operator tool confirms its own e-stop by it."""
    reset_refused: Text = ""
    """Why the supervisor refused the reset it just took in ('' none: no reset, or taken). An operator tool
    reads a refusal here; `reason` says it too, for people."""


class EstopCommand(Payload, frozen=True, kw_only=True):
    """Operator e-stop or reset (pure/safety/estop). A reset permits motion; it never causes it.
    `estop` stops without cutting power in motion (category 1: brake, or the recovery law, then power off at
    rest); `cut_power` is the explicit category-0 request: power off at once, even in motion."""

    action: OperatorCommand
    source: Source


class SafetyAlert(Payload, frozen=True, kw_only=True):
    """The supervisor's alert for the rider (pure/safety/alert), for a seat, handle or operator screen: on
    every change and periodically."""

    level: Annotated[int, msgspec.Meta(ge=0, le=2)]
    """0 none; 1 slow down (a speed cap or a diagnosis holds); 2 stop: sit up and hold still (a stop or the
    supervisor's recovery law is under way)."""
    reason: Text
    """The supervisor's cause (SafetyState.reason)."""


class ControllerCommand(Payload, frozen=True, kw_only=True):
    """Operator request to the controller (pure/controller/command). After an e-stop or a fault the
    controller stays disabled until it receives `enable`."""

    action: Literal["enable", "disable"]
    source: Source


class ControllerTelemetry(Payload, frozen=True, kw_only=True):
    """What the controller commanded at a tick (pure/controller/telemetry), for recording and metrics.
    `seq` is the controller's tick count; `stamp` its time (tick / tick rate)."""

    state: Annotated[int, msgspec.Meta(ge=0, le=15)]
    mode: Literal["hacs", "ihacs"]
    command_speed: tuple[Rate, Rate]
    """Command speed (pitch forward, roll forward = −y), m/s."""
    tilt_command: tuple[Angle, Angle]
    """θ_EQ per plane (0 for HACS), rad."""
    yaw_rate_command: Rate
    ball_torque: tuple[Moment, Moment, Moment]
    """Ball torque (x, y, z body axes) before the motor map, Nm."""


class RigTick(Payload, frozen=True, kw_only=True):
    """Lockstep only (pure/rig/tick): the rig has put every zenoh input of tick `seq`. zenoh keeps one key's
    puts in order but not puts on different keys, so the fence counts: `puts` is how many payloads the rig's
    process has put on each key so far (seat wrench, SC requests and commands, operator commands, garbage
    included). A node that has received that many on each key it reads has exactly the tick's inputs."""

    puts: dict[Annotated[str, msgspec.Meta(max_length=200)], Annotated[int, msgspec.Meta(ge=0)]]


TICK_MODULO = 1 << 16
"""Tick counts on the wire (the SYNC frame's Tick, the tick a lockstep put is tagged with) wrap here."""


def tick_after(a: int, b: int) -> bool:
    """Tick a is later than tick b, either given in full or wrapped (at most half the range apart)."""
    return 0 < (a - b) % TICK_MODULO < TICK_MODULO // 2


P = TypeVar("P", bound=Payload)

_encoder = msgspec.msgpack.Encoder()
_decoders: dict[type, msgspec.msgpack.Decoder[Any]] = {}


class PayloadError(ValueError):
    """A payload that cannot be accepted. kind: 'garbage' (not msgpack / wrong shape), 'schema' (a field is
    missing, mistyped, out of range or not finite), 'version' (another protocol version)."""

    KINDS: ClassVar[tuple[str, ...]] = ("garbage", "schema", "version")

    def __init__(self, kind: str, detail: str):
        super().__init__(f"{kind}: {detail}")
        self.kind, self.detail = kind, detail


def encode(payload: Payload) -> bytes:
    return _encoder.encode(payload)


def decode(data: bytes | bytearray | memoryview, type: type[P]) -> P:
    decoder: msgspec.msgpack.Decoder[P] | None = _decoders.get(type)
    if decoder is None:
        decoder = _decoders[type] = msgspec.msgpack.Decoder(type)
    try:
        return decoder.decode(data)
    except msgspec.ValidationError as exc:
        text = str(exc)
        kind = "version" if text.startswith("unsupported version") else "schema"
        if kind == "schema" and text.startswith("Expected `object`"):
            kind = "garbage"
        raise PayloadError(kind, text) from None
    except (msgspec.DecodeError, UnicodeDecodeError) as exc:
        # msgspec lets invalid UTF-8 in map keys escape as UnicodeDecodeError (found by fuzzing).
        raise PayloadError("garbage", str(exc)) from None


def json_schema(payload: type[Payload]) -> dict[str, Any]:
    """msgspec's JSON Schema of a payload, its descriptions cleaned as `inspect.cleandoc` does: msgspec 0.23
    dedents a docstring where 0.22 kept its indentation, and a published schema must not change with that."""

    def clean(node: object) -> object:
        if isinstance(node, dict):
            return {
                k: inspect.cleandoc(v) if k == "description" and isinstance(v, str) else clean(v)
                for k, v in node.items()
            }
        if isinstance(node, list):
            return [clean(v) for v in node]
        return node

    schema = clean(msgspec.json.schema(payload))
    assert isinstance(schema, dict)
    return schema
