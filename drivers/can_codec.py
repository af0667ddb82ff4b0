"""The CAN catalog: messages of `configs/can/pure.dbc` loaded with cantools, with fast per-message codecs.

cantools is the reference; its per-frame cost (2-5 µs encode, 1.4 µs decode, measured) is too much for a
400 Hz tick that handles a dozen frames, so each message gets a codec compiled from the cantools signal
definitions (start bit, length, sign, scale, offset, range): one integer shift/mask per signal, no
hand-written offsets. `tests/test_can.py` proves them identical to cantools on random signals.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import cantools

from drivers.resources import SHIPPED

DEFAULT_DBC = SHIPPED / "can" / "pure.dbc"


class MessageName(StrEnum):
    """The DBC's message names, spelled once. Code outside drivers/ names a message only through these
    (tests/test_boundaries.py); tests/test_can.py checks they are exactly the DBC's messages."""

    SYNC = "SYNC"
    SUPERVISOR_ESTOP = "SUPERVISOR_ESTOP"
    OPERATOR_ESTOP = "OPERATOR_ESTOP"
    SUPERVISOR_RECOVERY = "SUPERVISOR_RECOVERY"
    SUPERVISOR_DIAGNOSIS = "SUPERVISOR_DIAGNOSIS"
    CONTROLLER_HEARTBEAT = "CONTROLLER_HEARTBEAT"
    DRIVE1_COMMAND = "DRIVE1_COMMAND"
    DRIVE2_COMMAND = "DRIVE2_COMMAND"
    DRIVE3_COMMAND = "DRIVE3_COMMAND"
    DRIVE1_FEEDBACK = "DRIVE1_FEEDBACK"
    DRIVE2_FEEDBACK = "DRIVE2_FEEDBACK"
    DRIVE3_FEEDBACK = "DRIVE3_FEEDBACK"
    DRIVE1_TORQUE = "DRIVE1_TORQUE"
    DRIVE2_TORQUE = "DRIVE2_TORQUE"
    DRIVE3_TORQUE = "DRIVE3_TORQUE"
    IMU_ATTITUDE = "IMU_ATTITUDE"
    IMU_RATE = "IMU_RATE"
    IMU_ACCEL = "IMU_ACCEL"


DRIVE_COMMAND = (MessageName.DRIVE1_COMMAND, MessageName.DRIVE2_COMMAND, MessageName.DRIVE3_COMMAND)
DRIVE_FEEDBACK = (MessageName.DRIVE1_FEEDBACK, MessageName.DRIVE2_FEEDBACK, MessageName.DRIVE3_FEEDBACK)
DRIVE_TORQUE = (MessageName.DRIVE1_TORQUE, MessageName.DRIVE2_TORQUE, MessageName.DRIVE3_TORQUE)
"""Each drive's messages, in motor order (motor 1 first)."""
MOTOR_OF: dict[str, int] = {
    name: motor for names in (DRIVE_FEEDBACK, DRIVE_COMMAND, DRIVE_TORQUE) for motor, name in enumerate(names)
}
"""Which motor (0, 1, 2) a drive's message is about, keyed as a frame carries its name (a str)."""

ENCODERS = ("Encoder1", "Encoder2", "Encoder3")
"""SUPERVISOR_DIAGNOSIS's flags of the drives' encoders, in motor order."""
TILT_INPUTS = (("Roll", "RateX"), ("Pitch", "RateY"))
"""SUPERVISOR_DIAGNOSIS's flags of each plane's (roll, pitch) attitude and rate."""
PARTS = (
    *ENCODERS,
    *(name for names in zip(*TILT_INPUTS, strict=True) for name in names),  # Roll, Pitch, RateX, RateY
    *("RateZ", "Accel", "Seat", "Drive1", "Drive2", "Drive3"),
)
"""What a diagnosis can name faulty, the sensors' channels, the seat and the drives: SUPERVISOR_DIAGNOSIS's
flags, spelled as its signals (tests/test_can.py: all its signals but Alert and the E2E's, in order)."""


class CanCodecError(ValueError):
    """A frame that does not match its message definition (wrong length, unknown id)."""


@dataclass(frozen=True, slots=True)
class _Signal:
    name: str
    shift: int
    mask: int
    sign_bit: int  # 0 for unsigned
    scale: float
    offset: float
    raw_min: int
    raw_max: int
    integer: bool  # scale 1, offset 0: decode to int
    half: int
    """In an 8-byte payload read as two 32-bit halves: 0 low, 1 high, 2 across both."""


def raw_range(signal: cantools.database.Signal) -> tuple[int, int]:
    """The raw values a signal may take: its width's, narrowed to the DBC's minimum and maximum."""
    lo = -(1 << (signal.length - 1)) if signal.is_signed else 0
    hi = (1 << (signal.length - 1)) - 1 if signal.is_signed else (1 << signal.length) - 1
    if signal.minimum is not None:
        lo = max(lo, round((signal.minimum - signal.offset) / signal.scale))
    if signal.maximum is not None:
        hi = min(hi, round((signal.maximum - signal.offset) / signal.scale))
    return lo, hi


class MessageCodec:
    """Encode/decode one message; signals little-endian (Intel), as every message of the catalog."""

    def __init__(self, message: cantools.database.Message):
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.length: int = message.length
        self.cycle_time_ms: int | None = message.cycle_time or None
        self.message = message
        signals = []
        for s in message.signals:
            if s.byte_order != "little_endian" or s.is_float:
                raise CanCodecError(
                    f"{message.name}.{s.name}: only little-endian integer signals are supported"
                )
            lo, hi = raw_range(s)
            integer = s.scale == 1 and s.offset == 0
            sign_bit = 1 << (s.length - 1) if s.is_signed else 0
            half = 1 if s.start >= 32 else 0 if s.start + s.length <= 32 else 2
            signals.append(
                _Signal(
                    s.name, s.start, (1 << s.length) - 1, sign_bit, s.scale, s.offset, lo, hi, integer, half
                )
            )
        self.signals = tuple(signals)
        self.signal_names = tuple(s.name for s in signals)
        self._by_name = {s.name: s for s in signals}
        zero = bytes(self.length)
        self._last_decoded: tuple[bytes, dict[str, float | int]] = (zero, self.decode(zero))
        """(payload, its signals) of the last `decode_shared`: one tuple, replaced whole, so a reader on
        another thread never pairs one frame's payload with another's signals."""

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Physical values -> payload. Missing signals encode as 0 (raw); out-of-range values saturate."""
        return self.encode_int(values).to_bytes(self.length, "little")

    def encode_int(self, values: Mapping[str, float]) -> int:
        """The payload as a little-endian integer (the E2E layer adds counter and CRC before to_bytes)."""
        raw, by_name = 0, self._by_name
        for name, v in values.items():
            s = by_name.get(name)
            if s is not None:
                # Inline, not a method with min/max: half an encode's cost, a dozen encodes a tick.
                r = int(v) if s.integer else round((v - s.offset) / s.scale)
                # Out-of-range values saturate, as a real transmitter's fixed-point conversion would.
                r = s.raw_min if r < s.raw_min else s.raw_max if r > s.raw_max else r
                raw |= (r & s.mask) << s.shift
        return raw

    def decode(self, data: bytes | bytearray) -> dict[str, float | int]:
        if len(data) != self.length:
            raise CanCodecError(f"{self.name}: expected {self.length} bytes, got {len(data)}")
        if self.length != 8:
            return self.decode_int(int.from_bytes(data, "little"))
        # Two 32-bit halves: as one integer an 8-byte payload is beyond the compiled build's short ints
        # (62 bits) whenever its top byte (the CRC) is 0x40 or more, and every shift and mask on it is a
        # Python long's (a decode 1.25 -> ~0.8 us compiled).
        low, high = int.from_bytes(data[:4], "little"), int.from_bytes(data[4:], "little")
        out: dict[str, float | int] = {}
        for s in self.signals:
            if s.half == 0:
                r = (low >> s.shift) & s.mask
            elif s.half == 1:
                r = (high >> (s.shift - 32)) & s.mask
            else:
                r = ((high << (32 - s.shift)) | (low >> s.shift)) & s.mask
            if r & s.sign_bit:
                r -= s.mask + 1
            out[s.name] = r if s.integer else r * s.scale + s.offset
        return out

    def decode_shared(self, data: bytes | bytearray) -> dict[str, float | int]:
        """`decode(data)`, copied from the previous call's when the payload is the same: on the in-process
        bus every reader of a frame decodes the same payload, and the nodes of one DBC share its codecs
        (Catalog), so only the first of them decodes it. Each caller gets a dict of its own: a reader that
        changes its signals (a controller under test) must never change what the supervisor reads. Keyed
        on the payload's bytes, not the frame object: the signals are a function of those alone."""
        last = self._last_decoded
        if data != last[0]:
            last = self._last_decoded = (bytes(data), self.decode(data))
        return dict(last[1])

    def decode_int(self, raw: int) -> dict[str, float | int]:
        out: dict[str, float | int] = {}
        for s in self.signals:
            r = (raw >> s.shift) & s.mask
            if r & s.sign_bit:
                r -= s.mask + 1
            out[s.name] = r if s.integer else r * s.scale + s.offset
        return out

    def field_position(self, name: str) -> tuple[int, int] | None:
        """(shift, mask) of a signal in the payload integer, or None if the message has no such signal."""
        s = self._by_name.get(name)
        return None if s is None else (s.shift, s.mask)

    def has(self, name: str) -> bool:
        return name in self._by_name

    def values(self, signal: str) -> dict[int, str]:
        """The signal's value table in the DBC (VAL_): raw value -> name; empty if it has none."""
        choices = self.message.get_signal_by_name(signal).choices
        if choices is None:
            return {}
        return {int(raw): str(name) for raw, name in choices.items()}


_loaded: dict[tuple[Path, bytes], tuple[cantools.database.can.Database, tuple[MessageCodec, ...]]] = {}
"""Every CAN database loaded in this process and its codecs, by resolved path and content (a file rewritten
in place is loaded afresh): the Catalogs of one file share them, so it is parsed once and a frame read by
several nodes is decoded once (MessageCodec.decode_shared). Nothing changes a database or a codec once
made."""


def _load(path: Path) -> tuple[cantools.database.can.Database, tuple[MessageCodec, ...]]:
    key = (path.resolve(), path.read_bytes())
    loaded = _loaded.get(key)
    if loaded is None:
        database = cantools.database.load_file(str(path))
        if not isinstance(database, cantools.database.can.Database):
            raise CanCodecError(f"{path}: not a CAN database (DBC, KCD, ARXML, SYM)")
        loaded = _loaded[key] = (database, tuple(MessageCodec(m) for m in database.messages))
    return loaded


class Catalog:
    """All messages of a DBC, by name and by frame id (its codecs shared with every Catalog of the file)."""

    def __init__(self, dbc: Path | str = DEFAULT_DBC):
        self.path = Path(dbc)
        self.database, self.codecs = _load(self.path)
        self._by_name = {c.name: c for c in self.codecs}
        self._by_id = {c.frame_id: c for c in self.codecs}

    def __getitem__(self, name: str) -> MessageCodec:
        return self._by_name[name]

    def by_id(self, frame_id: int) -> MessageCodec | None:
        return self._by_id.get(frame_id)

    def __iter__(self) -> Iterator[MessageCodec]:
        return iter(self.codecs)
