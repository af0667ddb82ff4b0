"""Worst-case CAN bus load from the catalog, the message rates and the bitrate (bit stuffing included).

Worst-case length of a classic data frame with n data bytes (Davis, Burns, Bril, Lukkien 2007):
    standard 11-bit id: 8n + 47 + floor((34 + 8n − 1) / 4) bits
    extended 29-bit id: 8n + 67 + floor((54 + 8n − 1) / 4) bits
(44/64 frame bits plus a 3-bit interframe space; only the 34/54 bits from SOF to CRC are stuffed.)
Rates: a message with a GenMsgCycleTime in the DBC is sent at that cycle; the others once per SYNC tick.
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.can_codec import Catalog


class BusLoadError(ValueError):
    """The configured traffic does not fit the bus with the required margin."""


def frame_bits(data_bytes: int, extended: bool = False, stuffing: bool = True) -> int:
    """Bits a frame takes on the bus: the worst case (every stuff bit), or without stuffing the fewest."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"classic CAN carries 0..8 data bytes, got {data_bytes}")
    stuffed = (54 if extended else 34) + 8 * data_bytes
    return 8 * data_bytes + (67 if extended else 47) + ((stuffed - 1) // 4 if stuffing else 0)


def frames_per_tick(bitrate: int, tick_hz: float, data_bytes: int) -> int:
    """The most standard frames of `data_bytes` a bus carries in one tick: its bit time over the shortest
    such frame (no stuff bit)."""
    return int(bitrate / tick_hz // frame_bits(data_bytes, stuffing=False))


@dataclass(frozen=True, slots=True)
class MessageLoad:
    name: str
    rate_hz: float
    bits: int

    @property
    def bits_per_second(self) -> float:
        return self.rate_hz * self.bits


@dataclass(frozen=True, slots=True)
class BusLoad:
    bitrate: int
    messages: tuple[MessageLoad, ...]

    @property
    def bits_per_second(self) -> float:
        return sum(m.bits_per_second for m in self.messages)

    @property
    def fraction(self) -> float:
        return self.bits_per_second / self.bitrate

    def table(self) -> str:
        rows = [f"{'message':<22} {'rate Hz':>8} {'bits':>5} {'kbit/s':>8}"]
        rows += [
            f"{m.name:<22} {m.rate_hz:8.1f} {m.bits:5d} {m.bits_per_second / 1e3:8.1f}" for m in self.messages
        ]
        rows.append(
            f"{'total':<22} {'':>8} {'':>5} {self.bits_per_second / 1e3:8.1f}  = {self.fraction:.1%} "
            f"of {self.bitrate / 1e3:g} kbit/s"
        )
        return "\n".join(rows)


def bus_load(catalog: Catalog, tick_hz: float, bitrate: int) -> BusLoad:
    messages = tuple(
        MessageLoad(
            c.name,
            1000.0 / c.cycle_time_ms if c.cycle_time_ms else tick_hz,
            frame_bits(c.length, c.message.is_extended_frame),
        )
        for c in catalog
    )
    return BusLoad(bitrate, messages)


def check_bus_load(catalog: Catalog, tick_hz: float, bitrate: int, max_fraction: float = 0.70) -> BusLoad:
    """The load, or BusLoadError with the figure if it exceeds max_fraction of the bitrate."""
    load = bus_load(catalog, tick_hz, bitrate)
    if load.fraction > max_fraction:
        raise BusLoadError(
            f"worst-case bus load {load.fraction:.1%} at {tick_hz:g} Hz tick on {bitrate / 1e3:g} kbit/s "
            f"exceeds the {max_fraction:.0%} bound ({load.bits_per_second / 1e3:.1f} kbit/s)\n{load.table()}"
        )
    return load
