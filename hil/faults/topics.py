"""zenoh faults: the seat wrench and the shared-controller requests go wrong on their way.

They act on what the rig publishes in the tick (the seat wrench; the scenario's SC requests) and add
traffic of their own (floods, a conflicting SC agent, garbage). Receivers (the controller, the supervisor)
see them through the real zenoh session.
"""

from __future__ import annotations

import typing
from typing import Annotated, Literal

import msgspec

from drivers.schemas import ScMode, ScRequest, Source, Speed, TesWrench, encode
from hil.faults.base import Bound, FaultSpec, FaultState, FaultTarget, Period

ETHERNET_BITRATE = 100e6
"""bit/s of the link an agent reaches the bench over (100BASE-TX: the Ethernet of a bench's computers)."""
SEGMENT_OVERHEAD = 78
"""Bytes on the wire around each put sent as a TCP segment of its own: Ethernet framing with preamble and
inter-frame gap (38), IPv4 (20), TCP (20)."""
SEGMENT_PAYLOAD = 1460
"""Bytes of payload one TCP segment carries on Ethernet (1500 MTU less the IPv4 and TCP headers)."""
_SPEED: msgspec.Meta = typing.get_args(Speed)[1]
Cap = Annotated[
    float, Bound(_SPEED.ge, _SPEED.le, why="m/s; what ScRequest.speed_cap carries (drivers/schemas.py)")
]


def _requests_per_tick(spec: ScFlood, rig: FaultTarget | None) -> tuple[float, str] | None:
    """The requests a tick's share of the agent's link carries, each its own segment."""
    if rig is None:
        return None
    tick_hz = rig.plant.sim.tick_hz
    longest = ScRequest(seq=2**32 - 1, stamp=0.0, mode=spec.mode, speed_cap=spec.cap, source=spec.source)
    wire = SEGMENT_OVERHEAD + len(encode(longest))
    return ETHERNET_BITRATE / 8 / wire / tick_hz // 1, (
        f"requests of {wire} bytes on the wire a {ETHERNET_BITRATE / 1e6:g} Mbit/s link carries in a tick "
        f"at {tick_hz:g} Hz"
    )


class TopicFault(FaultSpec, frozen=True, kw_only=True):
    def wrench(self, payload: TesWrench, data: bytes, state: FaultState) -> list[bytes]:
        """The payloads to publish on pure/tes/wrench instead of `data` (the encoded `payload`)."""
        return [data]

    def extra(self, rig: FaultTarget, state: FaultState) -> list[tuple[str, bytes]]:
        """More (key, payload) puts this tick."""
        return []


class WrenchDropout(TopicFault, frozen=True, tag="zenoh.wrench_dropout"):
    """The seat stops publishing (a crashed TES node or a cut link)."""

    def wrench(self, payload: TesWrench, data: bytes, state: FaultState) -> list[bytes]:
        return []


class WrenchStale(TopicFault, frozen=True, tag="zenoh.wrench_stale"):
    """The seat keeps re-publishing its last sample from before the fault: same seq, same stamp."""

    def wrench(self, payload: TesWrench, data: bytes, state: FaultState) -> list[bytes]:
        return [state.memory.setdefault("last", data)]


class WrenchFrozen(TopicFault, frozen=True, tag="zenoh.wrench_frozen"):
    """The seat's values freeze at the fault's start while seq and stamp go on (a hung ADC behind a live
    publisher): only a plausibility check can tell."""

    def wrench(self, payload: TesWrench, data: bytes, state: FaultState) -> list[bytes]:
        frozen = state.memory.setdefault("frozen", payload)
        return [encode(msgspec.structs.replace(frozen, seq=payload.seq, stamp=payload.stamp))]


class Malformed(TopicFault, frozen=True, tag="zenoh.malformed"):
    """Undecodable bytes on `key` (`payload`, hex) every tick; on the seat wrench they replace the sample."""

    key: Literal["tes/wrench", "sc/request", "safety/estop", "controller/command"] = "tes/wrench"
    payload: Annotated[
        str,
        msgspec.Meta(
            min_length=2,
            max_length=2 * SEGMENT_PAYLOAD,
            description="hex digits: at most one TCP segment's payload on Ethernet (1460 bytes)",
        ),
    ] = "c1ffee"

    def __post_init__(self) -> None:
        super().__post_init__()
        try:
            bytes.fromhex(self.payload)
        except ValueError:
            raise ValueError(f"zenoh.malformed: payload {self.payload!r} is not hex") from None

    def wrench(self, payload: TesWrench, data: bytes, state: FaultState) -> list[bytes]:
        return [bytes.fromhex(self.payload)] if self.key == "tes/wrench" else [data]

    def extra(self, rig: FaultTarget, state: FaultState) -> list[tuple[str, bytes]]:
        if self.key == "tes/wrench":
            return []
        return [(f"{rig.keys.prefix}/{self.key}", bytes.fromhex(self.payload))]


class ScFlood(TopicFault, frozen=True, tag="zenoh.sc_flood"):
    """An SC agent floods `per_tick` requests per tick (valid ones: `mode`, `cap`)."""

    per_tick: Annotated[
        int,
        Bound(
            1,
            limit=_requests_per_tick,
            limit_text="the requests the agent's link carries in a tick",
            why="an agent's 100 Mbit/s Ethernet, each request a TCP segment of its own",
        ),
    ] = 20
    mode: ScMode = "free"
    cap: Cap = 0.0
    source: Source = "flood"

    def extra(self, rig: FaultTarget, state: FaultState) -> list[tuple[str, bytes]]:
        puts = []
        for _ in range(self.per_tick):
            n = state.memory["seq"] = state.memory.get("seq", 0) + 1
            request = ScRequest(
                seq=n, stamp=rig.plant.t, mode=self.mode, speed_cap=self.cap, source=self.source
            )
            puts.append((rig.keys.sc_request, encode(request)))
        return puts


class ScConflict(TopicFault, frozen=True, tag="zenoh.sc_conflict"):
    """A second SC agent (`source`) asks for something else (`mode`, `cap`) every `period` seconds,
    interleaved with the scenario's own requests."""

    mode: ScMode = "free"
    cap: Cap = 0.0
    period: Period = 0.05
    source: Source = "rogue-agent"

    def extra(self, rig: FaultTarget, state: FaultState) -> list[tuple[str, bytes]]:
        t = rig.plant.t
        if t - state.memory.get("sent", -1e9) < self.period - 1e-9:
            return []
        state.memory["sent"] = t
        n = state.memory["seq"] = state.memory.get("seq", 0) + 1
        request = ScRequest(seq=n, stamp=t, mode=self.mode, speed_cap=self.cap, source=self.source)
        return [(rig.keys.sc_request, encode(request))]


FAULTS: tuple[type[TopicFault], ...] = (
    WrenchDropout,
    WrenchStale,
    WrenchFrozen,
    Malformed,
    ScFlood,
    ScConflict,
)
