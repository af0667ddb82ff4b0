"""End-to-end protection of safety-relevant CAN frames: 4-bit alive counter + CRC-8 (IEC 61784-3 style).

CRC: CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, no reflection, xorout 0xFF; check("123456789") = 0x4B),
as AUTOSAR E2E profile 1/2. It covers a data id, the 11-bit frame id as two little-endian bytes, then the
payload with the CRC field zeroed, so a valid payload sent under another id (a masquerading node) fails.

Receiver classification of the counter (delta = (counter − last) mod 16):
  1 -> OK;  0 -> REPEATED;  2..8 -> LOST (delta − 1 frames missing);  9..15 -> OUT_OF_ORDER (a late frame).
A bad CRC is CRC_ERROR and leaves the counter state alone. Beyond 8 lost frames the 4-bit counter aliases:
stream watchdogs (timing), not E2E, catch outages.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

from drivers.can_codec import MessageCodec

COUNTER = "Counter"
CRC = "Crc"
COUNTER_MODULO = 16
MAX_GAP = 8


def _crc8_table(poly: int = 0x1D) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _crc8_table()


def crc8(data: bytes | bytearray, crc: int = 0xFF) -> int:
    """CRC-8/SAE-J1850. Table-driven: a library call (crccheck) costs ~16 µs per frame here."""
    return _crc_continue(crc, data) ^ 0xFF


def _crc_continue(state: int, data: bytes | bytearray) -> int:
    table = _TABLE
    for b in data:
        state = table[state ^ b]
    return state


class _Layout:
    """Where a protected message keeps its counter and CRC, and the CRC state after its data id. The
    counter is a nibble and the CRC a byte of the payload (checked when the layout is made), so sealing and
    checking work on the payload's bytes: as one integer a 64-bit payload is beyond mypyc's short ints."""

    def __init__(self, name: str, counter_shift: int, crc_shift: int, seed: int, length: int) -> None:
        self.counter_shift = counter_shift
        self.counter_byte, self.counter_bit = divmod(counter_shift, 8)
        self.crc_shift = crc_shift
        self.crc_byte = crc_shift // 8
        self.seed = seed
        self.length = length
        self.ok = tuple(E2EEvent(name, E2EStatus.OK, c, c) for c in range(COUNTER_MODULO))
        """The OK event of each counter value, made once: most frames a node reads are OK."""

    def crc(self, payload: bytes | bytearray) -> int:
        """The CRC of `payload` with its CRC byte taken as zero."""
        table, state, at = _TABLE, self.seed, self.crc_byte
        for i in range(at):
            state = table[state ^ payload[i]]
        state = table[state]
        for i in range(at + 1, self.length):
            state = table[state ^ payload[i]]
        return state ^ 0xFF


_found: dict[int, _Layout | None] = {}
"""Every message looked at, by frame id: its layout, or None if it is not protected."""
_layouts: dict[int, _Layout] = {}
"""The protected ones alone (what sealing and checking look up)."""


def _find_layout(codec: MessageCodec) -> _Layout | None:
    """The message's layout, or None if it has no counter and CRC (cached either way)."""
    try:
        return _found[codec.frame_id]
    except KeyError:
        pass
    counter, crc = codec.field_position(COUNTER), codec.field_position(CRC)
    if counter is None or crc is None:
        layout = None
    else:
        if counter[1] != COUNTER_MODULO - 1 or crc[1] != 0xFF:
            raise ValueError(f"{codec.name}: E2E needs a 4-bit {COUNTER} and an 8-bit {CRC} signal")
        if crc[0] % 8 or counter[0] % 8 > 4:
            raise ValueError(f"{codec.name}: E2E needs its {CRC} on a byte and its {COUNTER} within one")
        seed = _crc_continue(0xFF, codec.frame_id.to_bytes(2, "little"))
        layout = _layouts[codec.frame_id] = _Layout(codec.name, counter[0], crc[0], seed, codec.length)
    _found[codec.frame_id] = layout
    return layout


def _layout(codec: MessageCodec) -> _Layout:
    """The layout of a protected message; ValueError for a message without E2E fields (see is_protected)."""
    try:
        return _layouts[codec.frame_id]
    except KeyError:
        pass
    layout = _find_layout(codec)
    if layout is None:
        raise ValueError(f"{codec.name} is not E2E-protected: it has no {COUNTER} and {CRC} signals")
    return layout


def is_protected(codec: MessageCodec) -> bool:
    return _find_layout(codec) is not None


class E2EStatus(IntEnum):
    OK = 0
    REPEATED = 1
    LOST = 2
    OUT_OF_ORDER = 3
    CRC_ERROR = 4


class E2EEvent(NamedTuple):
    """One protected frame's classification (a tuple: one is made for every frame a node reads)."""

    message: str
    status: E2EStatus
    counter: int
    expected: int | None
    """The counter that would have been OK (None for the first frame of a stream)."""
    lost: int = 0
    """Frames missing before this one (LOST only)."""


class E2EProtector:
    """Sender side: per message, the next alive counter and the CRC."""

    def __init__(self) -> None:
        self._next: dict[int, int] = {}

    def seal(self, codec: MessageCodec, raw: int) -> bytes:
        """Payload integer (counter and CRC fields zero) -> protected payload bytes."""
        lay = _layout(codec)
        counter = self._next.get(codec.frame_id, 0)
        self._next[codec.frame_id] = (counter + 1) % COUNTER_MODULO
        raw |= counter << lay.counter_shift
        crc = lay.crc(raw.to_bytes(lay.length, "little"))
        return (raw | crc << lay.crc_shift).to_bytes(lay.length, "little")


def with_counter(codec: MessageCodec, payload: bytes | bytearray, counter: int) -> bytes:
    """A protected payload with its alive counter replaced and the CRC made valid again (a sender whose
    counter is wrong, as opposed to a frame corrupted on the wire)."""
    lay = _layout(codec)
    out = bytearray(payload)
    nibble = (COUNTER_MODULO - 1) << lay.counter_bit
    out[lay.counter_byte] = out[lay.counter_byte] & ~nibble | (counter % COUNTER_MODULO) << lay.counter_bit
    out[lay.crc_byte] = lay.crc(out)
    return bytes(out)


def counter_of(codec: MessageCodec, payload: bytes | bytearray) -> int:
    lay = _layout(codec)
    return (payload[lay.counter_byte] >> lay.counter_bit) & (COUNTER_MODULO - 1)


class E2EChecker:
    """Receiver side: classifies every protected frame; never raises."""

    def __init__(self) -> None:
        self._last: dict[int, int] = {}

    def check(self, codec: MessageCodec, payload: bytes | bytearray) -> E2EEvent:
        lay = _layout(codec)
        if len(payload) != lay.length:
            return E2EEvent(codec.name, E2EStatus.CRC_ERROR, 0, None)
        counter = (payload[lay.counter_byte] >> lay.counter_bit) & (COUNTER_MODULO - 1)
        last = self._last.get(codec.frame_id)
        if payload[lay.crc_byte] != lay.crc(payload):
            expected = None if last is None else (last + 1) % COUNTER_MODULO
            return E2EEvent(codec.name, E2EStatus.CRC_ERROR, counter, expected)
        if last is None:
            self._last[codec.frame_id] = counter
            return E2EEvent(codec.name, E2EStatus.OK, counter, None)
        delta = (counter - last) % COUNTER_MODULO
        if delta == 1:
            self._last[codec.frame_id] = counter
            return lay.ok[counter]
        expected = (last + 1) % COUNTER_MODULO
        if delta == 0:
            return E2EEvent(codec.name, E2EStatus.REPEATED, counter, expected)
        if delta > MAX_GAP:
            return E2EEvent(codec.name, E2EStatus.OUT_OF_ORDER, counter, expected)
        self._last[codec.frame_id] = counter
        return E2EEvent(codec.name, E2EStatus.LOST, counter, expected, delta - 1)
