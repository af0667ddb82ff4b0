"""Sensor faults: one channel of the drive feedback, the IMU or the seat's load cells goes wrong.

Channels (unit of the fault's parameters):
    encoder1..3        motor angle behind DRIVEn_FEEDBACK.Position (rad at the motor; counts on the wire)
    drive1..3.velocity DRIVEn_FEEDBACK.Velocity (rad/s)
    drive1..3.torque   DRIVEn_TORQUE.Torque (Nm)
    imu.roll|pitch|yaw IMU_ATTITUDE (rad)
    imu.rate_x|y|z     IMU_RATE (rad/s)
    imu.accel_x|y|z    IMU_ACCEL (m/s²)
    tes.cell1..6       the seat's load cells (N; the seat computes wrench and COP from them)

The fault acts on the sample the sensor reports, after the sensor's own noise, before the frame is
encoded: the wire carries it with a valid counter and CRC, as a real faulty sensor's node would send it.
A faulty value saturates at what the channel's signal can carry, as a real sensor's converter does (an
encoder's count wraps over its word instead), so no fault parameter can make a frame unencodable; each
parameter is bounded by the channel's range on the wire (`Bound`, docs/faults.md).
"Off" silences the frame that carries the channel (a dead CAN node); a TES cell that is off reads 0 N.
"""

from __future__ import annotations

import math
import typing
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Literal

import msgspec

from drivers.can_codec import DRIVE_FEEDBACK, DRIVE_TORQUE, Catalog, MessageName
from drivers.schemas import Force
from hil.faults.base import Bound, FaultSpec, FaultState, FaultTarget, Hold, Limit, Period, Probability
from plant.params import Encoder
from plant.sensors import DriveFeedback, ImuSample, TesSample, counts_from_angle

if TYPE_CHECKING:
    from plant.core import PlantCore

SEAT = "tes"
"""The seat's cells travel in its zenoh payload, not in a CAN frame."""


@dataclass(frozen=True, slots=True)
class Wire:
    """Where a channel travels: its frame (or the seat's payload), its signal there, its unit."""

    frame: str
    signal: str
    unit: str


_IMU = {
    f"imu.{name}": Wire(frame, signal, unit)
    for frame, unit, names in (
        (MessageName.IMU_ATTITUDE, "rad", (("roll", "Roll"), ("pitch", "Pitch"), ("yaw", "Yaw"))),
        (MessageName.IMU_RATE, "rad/s", (("rate_x", "RateX"), ("rate_y", "RateY"), ("rate_z", "RateZ"))),
        (MessageName.IMU_ACCEL, "m/s²", (("accel_x", "AccX"), ("accel_y", "AccY"), ("accel_z", "AccZ"))),
    )
    for name, signal in names
}
CHANNELS: dict[str, Wire] = {
    **{f"encoder{i}": Wire(name, "Position", "rad") for i, name in enumerate(DRIVE_FEEDBACK, 1)},
    **{f"drive{i}.velocity": Wire(name, "Velocity", "rad/s") for i, name in enumerate(DRIVE_FEEDBACK, 1)},
    **{f"drive{i}.torque": Wire(name, "Torque", "Nm") for i, name in enumerate(DRIVE_TORQUE, 1)},
    **_IMU,
    **{f"tes.cell{i}": Wire(SEAT, "cells", "N") for i in range(1, 7)},
}
"""channel -> where it travels (its frame, or the seat's payload) and its unit."""
if TYPE_CHECKING:
    Channel = str  # a checker cannot evaluate the Literal below; msgspec validates against it
else:
    Channel = Literal[tuple(CHANNELS)]
_ORDER = tuple(CHANNELS)
_INDEX = {name: i for i, name in enumerate(_ORDER)}
OFF = None


def _saturation(wire: Wire) -> tuple[float, float] | None:
    """What a channel can carry, in its unit: its signal's range in the contract's DBC, or the seat payload's
    Force bounds (drivers/schemas.py); None for an encoder, whose count wraps over its word."""
    if wire.frame == SEAT:
        meta: msgspec.Meta = typing.get_args(Force)[1]
        return float(meta.ge or 0.0), float(meta.le or 0.0)
    if wire.signal == "Position":
        return None
    signal = Catalog()[wire.frame].message.get_signal_by_name(wire.signal)
    if signal.minimum is None or signal.maximum is None:
        raise ValueError(f"{wire.frame}.{wire.signal}: the contract's DBC declares no range")
    return float(signal.minimum), float(signal.maximum)


SATURATION: dict[str, tuple[float, float] | None] = {name: _saturation(w) for name, w in CHANNELS.items()}
"""channel -> the (low, high) its value saturates at on the wire (None: an encoder, which wraps)."""
_SATURATION = [SATURATION[name] for name in _ORDER]


def channel_range(channel: str, encoder: Encoder | None) -> tuple[float, float] | None:
    """What `channel` can read, in its unit: where it saturates, or for an encoder the angles its count's
    word holds on `encoder` (None: no encoder known, so no range yet)."""
    saturation = SATURATION[channel]
    if saturation is not None:
        return saturation
    if encoder is None:
        return None
    half = 2.0 ** (encoder.word_bits - 1)
    per_rad = encoder.counts_per_rev / (2.0 * math.pi)
    return -half / per_rad, (half - 1) / per_rad


def _where(channel: str, encoder: Encoder | None) -> str:
    wire = CHANNELS[channel]
    if wire.frame == SEAT:
        return "the seat payload's Force bounds"
    if encoder is not None and wire.signal == "Position":
        return f"{wire.frame}.Position's {encoder.word_bits}-bit count at {encoder.counts_per_rev} counts/rev"
    return f"{wire.frame}.{wire.signal}"


def _channel_limit(fraction: float, what: str) -> Limit:
    """A Limit: `fraction` of the channel's span (its range's width), with what that is here."""

    def limit(spec: SensorFault, rig: FaultTarget | None) -> tuple[float, str] | None:
        encoder = None if rig is None else rig.plant.robot.encoder
        found = channel_range(spec.channel, encoder)
        if found is None:
            return None
        low, high = found
        unit = CHANNELS[spec.channel].unit
        where = _where(spec.channel, encoder)
        return fraction * (high - low), f"{what} of {spec.channel}, {where}: {low:g}..{high:g} {unit}"

    return limit


SPAN = "the channel's span"
Span = Annotated[
    float,
    Bound(
        magnitude=True,
        limit=_channel_limit(1.0, "the span"),
        limit_text=SPAN,
        why="the width of the channel's range on the wire (its DBC signal's, the seat payload's Force "
        "bounds, an encoder's word): beyond it every reading is full scale",
    ),
]
"""A size in the channel's unit, up to the channel's span."""
FullScale = Annotated[
    float,
    Bound(
        magnitude=True,
        limit=_channel_limit(0.5, "half the span"),
        limit_text="half the channel's span",
        why="a value the channel can carry on the wire (its range is symmetric about 0 to one step)",
    ),
]
"""A reading, within what the channel can carry."""


@dataclass(slots=True)
class Readings:
    """One tick's sensor outputs as channel values, and the frames that stay silent."""

    values: list[float]
    silent: set[str]

    @classmethod
    def of(cls, plant: PlantCore, fb: Sequence[DriveFeedback], imu: ImuSample, tes: TesSample) -> Readings:
        per_rad = plant.robot.encoder.counts_per_rev / (2.0 * math.pi)
        values = [
            *(f.counts / per_rad for f in fb),
            *(f.velocity for f in fb),
            *(f.torque for f in fb),
            *imu.attitude,
            *imu.rate,
            *imu.accel,
            *tes.cells,
        ]
        return cls(values, set())

    def feedback(self, encoder: Encoder) -> tuple[DriveFeedback, ...]:
        v = self.values
        return tuple(DriveFeedback(counts_from_angle(v[i], encoder), v[3 + i], v[6 + i]) for i in range(3))

    def imu(self) -> ImuSample:
        v = self.values
        return ImuSample((v[9], v[10], v[11]), (v[12], v[13], v[14]), (v[15], v[16], v[17]))

    def tes(self, plant: PlantCore, original: TesSample) -> TesSample:
        """The seat's output from the (possibly faulty) cells, through the seat's own calibration."""
        cells = self.values[18:24]
        return original if tuple(cells) == original.cells else plant.tes_model.from_cells(cells)


class SensorFault(FaultSpec, frozen=True, kw_only=True):
    channel: Channel

    def apply(self, readings: Readings, t: float, state: FaultState) -> None:
        i = _INDEX[self.channel]
        value = self.faulty(readings.values[i], t, state)
        if value is OFF:
            frame = CHANNELS[self.channel].frame
            if frame == SEAT:
                readings.values[i] = 0.0
            else:
                readings.silent.add(frame)
            return
        saturation = _SATURATION[i]
        if saturation is not None:  # as the sensor's converter does; NaN too (no comparison holds for it)
            low, high = saturation
            value = value if low <= value <= high else low if value < low else high
        readings.values[i] = value

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        """The channel's faulty value from its healthy one `x` (None: off)."""
        raise NotImplementedError


class Off(SensorFault, frozen=True, tag="sensor.off"):
    """The channel is dead: its frame is not sent (a TES cell reads 0 N)."""

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return OFF


class Stuck(SensorFault, frozen=True, tag="sensor.stuck"):
    """The channel holds one value: `value`, or the one it had when the fault started."""

    value: FullScale | None = None

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        if "held" not in state.memory:
            state.memory["held"] = x if self.value is None else self.value
        held: float = state.memory["held"]
        return held


class Bias(SensorFault, frozen=True, tag="sensor.bias"):
    """A constant offset of `offset` (in the channel's unit) added to every sample."""

    offset: Span

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return x + self.offset


class Scale(SensorFault, frozen=True, tag="sensor.scale"):
    """A gain error: the channel reads `factor` times the truth."""

    factor: Annotated[
        float,
        Bound(
            magnitude=True,
            high=1000.0,
            why="beyond 1000x every reading above a thousandth of the channel's range saturates: a larger "
            "gain is no other fault",
        ),
    ]

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return x * self.factor


class Drift(SensorFault, frozen=True, tag="sensor.drift"):
    """An offset that grows at `rate` (channel unit per second) from the fault's start."""

    rate: Annotated[
        float,
        Bound(
            magnitude=True,
            limit=_channel_limit(1.0, "the span per second"),
            limit_text=SPAN + " per s",
            why="faster, the offset crosses the channel's whole range within a second: a step "
            "(sensor.bias), not a drift",
        ),
    ]

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return x + self.rate * (t - self.at)


class Noise(SensorFault, frozen=True, tag="sensor.noise"):
    """Added white Gaussian noise of standard deviation `sigma` (channel unit)."""

    sigma: Annotated[
        float,
        Bound(
            0.0,
            low_open=True,
            limit=_channel_limit(1.0, "the span"),
            limit_text=SPAN,
            why="noise wider than the channel's range reads full scale at random: nothing more to inject",
        ),
    ]

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return x + self.sigma * state.rng.standard_normal()


class Spikes(SensorFault, frozen=True, tag="sensor.spikes"):
    """With probability `rate` per sample, a spike of ±`amplitude` (channel unit)."""

    amplitude: Span
    rate: Probability = 0.05

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        if state.rng.random() >= self.rate:
            return x
        return x + (self.amplitude if state.rng.random() < 0.5 else -self.amplitude)


class Delayed(SensorFault, frozen=True, tag="sensor.delayed"):
    """The channel reports what it measured `delay` seconds ago (held at its first value until then)."""

    delay: Hold

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        history: deque[tuple[float, float]] = state.memory.setdefault("history", deque())
        history.append((t, x))
        while len(history) > 1 and history[1][0] <= t - self.delay + 1e-9:
            history.popleft()
        return history[0][1]


class Slow(SensorFault, frozen=True, tag="sensor.slow"):
    """The channel updates only every `period` seconds (a lower rate; the frame still goes every tick)."""

    period: Period

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        if "held" not in state.memory or t - state.memory["since"] >= self.period - 1e-9:
            state.memory["held"], state.memory["since"] = x, t
        held: float = state.memory["held"]
        return held


class Intermittent(SensorFault, frozen=True, tag="sensor.intermittent"):
    """With probability `rate` per sample the channel is off (a loose connector)."""

    rate: Probability = 0.2

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return OFF if state.rng.random() < self.rate else x


class SignFlip(SensorFault, frozen=True, tag="sensor.sign_flip"):
    """The channel's sign is inverted (a sensor mounted the wrong way round)."""

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return -x


FAULTS: tuple[type[SensorFault], ...] = (
    Off,
    Stuck,
    Bias,
    Scale,
    Drift,
    Noise,
    Spikes,
    Delayed,
    Slow,
    Intermittent,
    SignFlip,
)
