"""CAN frame faults: what happens to one message's frames between their sender and the drives, the
controller and the supervisor.

A frame fault names a DBC message. On frames the rig sends (drive feedback and torque, IMU, SYNC) it acts
before they reach the bus, so every receiver sees it; on frames the rig receives as the emulated drives
(DRIVEn_COMMAND, SUPERVISOR_ESTOP, CONTROLLER_HEARTBEAT) it acts on what the drives get (the controller
and the supervisor still see their own traffic). `count` limits the fault to that many frames (a burst).
Time is simulated time: in lockstep a delay of 10 ms is 4 ticks at 400 Hz, whatever the wall clock does.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import can

from drivers.bounds import MAX_DURATION
from drivers.bus_load import frame_bits, frames_per_tick
from drivers.can_codec import DRIVE_COMMAND, MessageName
from drivers.devices import ProfileNode, Translator
from drivers.e2e import counter_of, is_protected, with_counter
from hil.faults.base import Bound, FaultSpec, FaultState, FaultTarget, Hold, Probability, number


def _run_frames(spec: FaultSpec, rig: FaultTarget | None) -> tuple[float, str] | None:
    if rig is None:
        return None
    tick_hz = rig.plant.sim.tick_hz
    return MAX_DURATION * tick_hz, f"one frame a tick at {tick_hz:g} Hz for the longest run"


def _copies(spec: Repeat, rig: FaultTarget | None) -> tuple[float, str] | None:
    """A frame and its repeats share the tick's bus time."""
    if rig is None:
        return None
    tick_hz, length = rig.plant.sim.tick_hz, rig.can.catalog[spec.message].length
    fit = frames_per_tick(rig.bitrate, tick_hz, length)
    return (
        fit - 1,
        f"{fit} frames of {length} bytes fill a tick at {number(rig.bitrate)} bit/s and {tick_hz:g} Hz",
    )


def _flood(spec: Babble, rig: FaultTarget | None) -> tuple[float, str] | None:
    if rig is None:
        return None
    tick_hz = rig.plant.sim.tick_hz
    return spec.capacity(rig), (
        f"frames of {spec.length} bytes one tick carries at {number(rig.bitrate)} bit/s and {tick_hz:g} Hz"
    )


Count = Annotated[
    int,
    Bound(
        1,
        limit=_run_frames,
        limit_text="the frames of the longest run",
        why="a burst of at most every frame the longest run sends of the message",
    ),
]
FRAME_BYTES = Bound(0, 8, why="a classic CAN frame carries 0..8 data bytes")
Message = Annotated[
    str,
    Bound(limit_text="a message of the bench's DBC", why="checked against the rig's when it is scheduled"),
]
RX_MESSAGES = frozenset([*DRIVE_COMMAND, MessageName.SUPERVISOR_ESTOP, MessageName.CONTROLLER_HEARTBEAT])
"""Messages the rig receives (as the drives); the rest of the catalog the rig sends (or nobody does)."""


def _copy(
    msg: can.Message, data: bytes | bytearray | None = None, arbitration_id: int | None = None
) -> can.Message:
    return can.Message(
        arbitration_id=msg.arbitration_id if arbitration_id is None else arbitration_id,
        is_extended_id=False,
        data=msg.data if data is None else data,
        dlc=None if data is None else len(data),
    )


class CanFault(FaultSpec, frozen=True, kw_only=True):
    message: Message
    count: Count | None = None

    both_ways: ClassVar[bool] = True
    """Acts on received frames too (else only on frames the rig sends)."""

    def validate(self, rig: FaultTarget) -> None:
        try:
            rig.can.catalog[self.message]
        except KeyError:
            names = ", ".join(c.name for c in rig.can.catalog)
            raise ValueError(f"{self.kind}: no message {self.message!r} in the DBC (have {names})") from None
        if not self.both_ways and self.message in RX_MESSAGES:
            raise ValueError(f"{self.kind} acts on frames the rig sends; {self.message} is one it receives")

    def tx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> list[can.Message]:
        """Frames to put on the bus instead of `msg`."""
        out = self.rx(msg, rig, state)
        return [] if out is None else [out]

    def rx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> can.Message | None:
        """What the drives get instead of `msg` (None: nothing)."""
        raise NotImplementedError

    def flush(self, rig: FaultTarget, state: FaultState, t: float) -> None:
        """Send what the fault held back and is due by `t` (delay, reorder)."""


class Drop(CanFault, frozen=True, tag="can.drop"):
    """Frames are lost with probability `rate` (1: all; with `count`: a burst of that many)."""

    rate: Probability = 1.0

    def rx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> can.Message | None:
        return None if self.rate >= 1.0 or state.rng.random() < self.rate else msg


class Delay(CanFault, frozen=True, tag="can.delay"):
    """Every frame arrives `delay` seconds late (a gateway or a queue in the way)."""

    delay: Hold
    both_ways: ClassVar[bool] = False

    def tx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> list[can.Message]:
        state.memory.setdefault("queue", []).append((rig.plant.t + self.delay, msg))
        return []

    def flush(self, rig: FaultTarget, state: FaultState, t: float) -> None:
        queue = state.memory.get("queue", [])
        while queue and queue[0][0] <= t + 1e-9:
            rig.can.transmit(self.message, queue.pop(0)[1])

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        self.flush(rig, state, float("inf"))


class Repeat(CanFault, frozen=True, tag="can.repeat"):
    """Every frame is sent `times` more times (a retransmission bug: the receiver sees REPEATED)."""

    times: Annotated[
        int,
        Bound(
            1,
            limit=_copies,
            limit_text="the frames one tick's bus time carries, less one",
            why="a frame and its copies go out within its tick",
        ),
    ] = 1
    both_ways: ClassVar[bool] = False

    def tx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> list[can.Message]:
        return [msg] * (1 + self.times)


class Reorder(CanFault, frozen=True, tag="can.reorder"):
    """Consecutive frames swap places: each is held and sent after the next one (OUT_OF_ORDER)."""

    both_ways: ClassVar[bool] = False

    def tx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> list[can.Message]:
        held = state.memory.pop("held", None)
        if held is None:
            state.memory["held"] = msg
            return []
        return [msg, held]

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        held = state.memory.pop("held", None)
        if held is not None:
            rig.can.transmit(self.message, held)


class Corrupt(CanFault, frozen=True, tag="can.corrupt"):
    """One payload bit flips on the wire (`bit`, counted from the payload's least significant bit; none: a
    random bit per frame), so the CRC no longer matches."""

    bit: Annotated[int, Bound(0, 63, why="a payload bit of a classic frame (at most 8 bytes)")] | None = None

    def rx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> can.Message | None:
        nbits = 8 * len(msg.data)
        bit = (self.bit if self.bit is not None else int(state.rng.integers(nbits))) % nbits
        data = bytearray(msg.data)
        data[bit // 8] ^= 1 << (bit % 8)
        return _copy(msg, data)


class WrongCounter(CanFault, frozen=True, tag="can.wrong_counter"):
    """The sender's alive counter misbehaves with a valid CRC: `frozen` (every frame repeats the counter
    it had when the fault started: REPEATED) or `skip` (it advances by 2: LOST every frame)."""

    mode: Literal["frozen", "skip"] = "frozen"

    def validate(self, rig: FaultTarget) -> None:
        super().validate(rig)
        if not is_protected(rig.can.catalog[self.message]):
            raise ValueError(f"{self.kind}: {self.message} carries no alive counter")

    def rx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> can.Message | None:
        codec = rig.can.catalog[self.message]
        counter = state.memory.get("counter")
        if counter is None:
            counter = counter_of(codec, msg.data)
        elif self.mode == "skip":
            counter += 2
        state.memory["counter"] = counter
        return _copy(msg, with_counter(codec, msg.data, counter))


class WrongDlc(CanFault, frozen=True, tag="can.wrong_dlc"):
    """Frames carry `length` bytes instead of the DBC's (truncated, or padded with zeros)."""

    length: Annotated[int, FRAME_BYTES]

    def rx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> can.Message | None:
        data = bytes(msg.data[: self.length]).ljust(self.length, b"\0")
        return _copy(msg, data)


class Masquerade(CanFault, frozen=True, tag="can.masquerade"):
    """A node sends this message's valid payload under `as_message`'s id as well (a node impersonating
    another): the E2E data id in the CRC makes receivers of `as_message` see CRC errors. On a device
    profile the copy goes out under the profile's id of the same frame of `as_message`'s device (no E2E)."""

    as_message: Message
    both_ways: ClassVar[bool] = False

    def validate(self, rig: FaultTarget) -> None:
        super().validate(rig)
        try:
            target = rig.can.catalog[self.as_message]
        except KeyError:
            raise ValueError(f"{self.kind}: no message {self.as_message!r} in the DBC") from None
        if target.length != rig.can.catalog[self.message].length:
            raise ValueError(f"{self.kind}: {self.message} and {self.as_message} differ in length")
        own, other = _translator(rig, self.message), _translator(rig, self.as_message)
        if own is not other:  # on a device profile: the same frame of another device of that profile
            family = [t.profile if t else "the contract's" for t in (own, other)]
            raise ValueError(
                f"{self.kind}: {self.message} ({family[0]}) and {self.as_message} ({family[1]}) are not "
                "frames of one family on this bench"
            )
        if own is not None:
            # Refused here, not mid-run, when the profile cannot: asked with one of its own frames.
            own.frame_id_as(can.Message(arbitration_id=min(own.sends)), self.as_message)

    def tx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> list[can.Message]:
        translator = _translator(rig, self.message)
        frame_id = (
            rig.can.catalog[self.as_message].frame_id
            if translator is None
            else translator.frame_id_as(msg, self.as_message)
        )
        return [msg, _copy(msg, arbitration_id=frame_id)]


def _translator(rig: FaultTarget, name: str) -> Translator | None:
    """The device profile's translator that sends `name` on this bench (None: the contract's frame)."""
    return rig.can.translator_of(name) if isinstance(rig.can, ProfileNode) else None


class Replay(CanFault, frozen=True, tag="can.replay"):
    """A node records `frames` of this message's frames, then replays the recording in a loop instead of
    fresh ones, each frame as it was (counter and CRC intact). At 16 frames the 4-bit alive counter comes
    round exactly: E2E sees a healthy stream of stale data (a replay attack, or a stuck buffer)."""

    frames: Annotated[
        int,
        Bound(2, 1024, why="the recording the fault keeps; 16 is the 4-bit alive counter's period"),
    ] = 16
    both_ways: ClassVar[bool] = False

    def tx(self, msg: can.Message, rig: FaultTarget, state: FaultState) -> list[can.Message]:
        recorded: list[can.Message] = state.memory.setdefault("recorded", [])
        if len(recorded) < self.frames:
            recorded.append(msg)
            return [msg]
        n = state.memory["replayed"] = state.memory.get("replayed", -1) + 1
        return [recorded[n % self.frames]]


class Babble(FaultSpec, frozen=True, kw_only=True, tag="can.babble"):
    """A babbling node floods `per_tick` frames of id `can_id` (high priority: low id) every tick (none: as
    many as the bus carries). When the flood fills the tick's bus time (at the bus bitrate), frames with
    higher ids lose every arbitration: the rig's own frames and those it receives above `can_id` are lost,
    as on a saturated real bus."""

    can_id: Annotated[int, Bound(0, 0x7FF, why="an 11-bit standard id")] = 0x001
    per_tick: (
        Annotated[
            int,
            Bound(
                1,
                limit=_flood,
                limit_text="the frames one tick's bus time carries",
                why="a bus carries no more frames in a tick than its bitrate allows",
            ),
        ]
        | None
    ) = None
    length: Annotated[int, FRAME_BYTES] = 8

    def capacity(self, rig: FaultTarget) -> int:
        """The most frames of this length the bus carries in one tick."""
        return frames_per_tick(rig.bitrate, rig.plant.sim.tick_hz, self.length)

    def frames(self, rig: FaultTarget) -> int:
        """Frames it sends each tick."""
        return self.capacity(rig) if self.per_tick is None else self.per_tick

    def saturates(self, rig: FaultTarget) -> bool:
        return self.frames(rig) * frame_bits(self.length) >= rig.bitrate * rig.plant.dt

    def babble(self, rig: FaultTarget) -> None:
        msg = can.Message(arbitration_id=self.can_id, is_extended_id=False, data=b"\xaa" * self.length)
        for _ in range(self.frames(rig)):
            rig.can.transmit("BABBLE", msg)


class BusOff(FaultSpec, frozen=True, kw_only=True, tag="can.bus_off"):
    """The rig's node (the drives and the IMU) goes bus-off: it neither sends nor receives until it
    recovers at the end of `duration` (bus silence as the controller and the supervisor see it)."""

    def validate(self, rig: FaultTarget) -> None:
        if self.duration is None:
            raise ValueError("can.bus_off needs a duration (the recovery time)")


FAULTS: tuple[type[FaultSpec], ...] = (
    Drop,
    Delay,
    Repeat,
    Reorder,
    Corrupt,
    WrongCounter,
    WrongDlc,
    Masquerade,
    Replay,
    Babble,
    BusOff,
)
