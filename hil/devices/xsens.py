"""The rig's emulated Xsens MTi 600-series IMU on its CAN output (docs/devices.md).

The plant's IMU sample of a tick goes out as one Xsens data group, at the bench's output rate: SampleTime
(the tick's time in 100 us ticks), GroupCounter (one more per group), StatusWord (self test and filter
valid), then EulerAngles (deg), RateOfTurn (rad/s) and Acceleration (m/s^2), each int16 at the protocol's
resolution (configs/devices/xsens_mti.dbc). A value beyond the protocol's range is sent saturated, as a
clipping sensor would.

The fault hook `sample_counter_frozen` (hil/faults/devices.py) stops SampleTime and GroupCounter while the
values go on: a stuck firmware pipeline that repeats its group header.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import can

from drivers.can_bus import Received
from drivers.can_codec import MessageName
from drivers.devices import Devices, Translator
from drivers.devices.xsens import TIME_TICKS_PER_S, Status, XsensWire

FIELDS: dict[str, tuple[str, tuple[tuple[str, str], ...]]] = {
    MessageName.IMU_ATTITUDE: ("EulerAngles", (("Roll", "Roll"), ("Pitch", "Pitch"), ("Yaw", "Yaw"))),
    MessageName.IMU_RATE: ("RateOfTurn", (("gyrX", "RateX"), ("gyrY", "RateY"), ("gyrZ", "RateZ"))),
    MessageName.IMU_ACCEL: ("Acceleration", (("accX", "AccX"), ("accY", "AccY"), ("accZ", "AccZ"))),
}
"""Logical message -> the Xsens message and its (Xsens signal, contract signal) pairs."""
HEALTHY = Status.SELF_TEST | Status.FILTER_VALID


class XsensImu(Translator):
    """The device side of an Xsens MTi on CAN."""

    profile = "xsens"

    def __init__(self, devices: Devices, counts_per_rev: int, tick_hz: float):
        super().__init__()
        options = devices.xsens
        self.wire = XsensWire(options.base_id)
        self.every = max(1, round(tick_hz / options.rate_hz))
        """Ticks per output group."""
        self.time_per_tick = TIME_TICKS_PER_S / tick_hz
        self.names = frozenset(FIELDS)
        self.frame_ids: frozenset[int] = frozenset()
        self.sends = frozenset(self.wire.ids.values())
        self.ticks = 0
        """SYNCs so far: the device's clock."""
        self.sample_time = 0
        self.counter = 0
        self.groups = 0
        self.frozen = False
        self._started = False
        """The current tick's group header is out (or this tick sends no group)."""
        self._sending = False

    def on_sync(self, tick: int) -> None:
        super().on_sync(tick)
        self.ticks += 1
        self._started = False

    def incoming(self, msg: can.Message) -> Received | None:
        return None

    def outgoing(self, name: str, values: Mapping[str, float]) -> list[can.Message]:
        frames = []
        if not self._started:
            self._started = True
            self._sending = self.ticks % self.every == 0
            if self._sending:
                frames += self._header(values if name == MessageName.IMU_ATTITUDE else {})
        if not self._sending:
            return frames
        message, pairs = FIELDS[name]
        wire = self.wire
        raw = {sig: wire.raw(message, sig, self._unit(name, values[key])) for sig, key in pairs}
        frames.append(wire.frame(message, {sig: r * wire.scale(message, sig) for sig, r in raw.items()}))
        return frames

    @staticmethod
    def _unit(name: str, value: float) -> float:
        return math.degrees(value) if name == MessageName.IMU_ATTITUDE else value

    def _header(self, attitude: Mapping[str, float]) -> list[can.Message]:
        if not self.frozen:
            self.sample_time = round(self.ticks * self.time_per_tick) % (1 << 32)
            self.counter = self.groups % (1 << 16)
        self.groups += 1
        status = HEALTHY if attitude.get("Valid", 1) else Status.SELF_TEST
        return [
            self.wire.frame("SampleTime", {"SampleTime": self.sample_time}),
            self.wire.frame("GroupCounter", {"GroupCounter": self.counter}),
            self.wire.frame("StatusWord", {"StatusWord": int(status)}),
        ]

    # ------------------------------------------------------------------ protocol faults (hil/faults)
    def sample_counter_frozen(self, frozen: bool) -> None:
        """SampleTime and GroupCounter stop at their last values while the data goes on."""
        self.frozen = frozen


def emulate(devices: Devices, counts_per_rev: int, tick_hz: float) -> XsensImu:
    return XsensImu(devices, counts_per_rev, tick_hz)
