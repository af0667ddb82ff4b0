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
"Off" silences the frame that carries the channel (a dead CAN node); a TES cell that is off reads 0 N.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Literal

from drivers.can_codec import DRIVE_FEEDBACK, DRIVE_TORQUE, MessageName
from hil.faults.base import FaultSpec, FaultState, Positive, Probability
from plant.params import Encoder
from plant.sensors import DriveFeedback, ImuSample, TesSample, counts_from_angle

if TYPE_CHECKING:
    from plant.ballbot import PlantCore

_IMU = {
    "imu.roll": (MessageName.IMU_ATTITUDE, "rad"),
    "imu.pitch": (MessageName.IMU_ATTITUDE, "rad"),
    "imu.yaw": (MessageName.IMU_ATTITUDE, "rad"),
    "imu.rate_x": (MessageName.IMU_RATE, "rad/s"),
    "imu.rate_y": (MessageName.IMU_RATE, "rad/s"),
    "imu.rate_z": (MessageName.IMU_RATE, "rad/s"),
    "imu.accel_x": (MessageName.IMU_ACCEL, "m/s²"),
    "imu.accel_y": (MessageName.IMU_ACCEL, "m/s²"),
    "imu.accel_z": (MessageName.IMU_ACCEL, "m/s²"),
}
CHANNELS: dict[str, tuple[str, str]] = {
    **{f"encoder{i}": (name, "rad") for i, name in enumerate(DRIVE_FEEDBACK, 1)},
    **{f"drive{i}.velocity": (name, "rad/s") for i, name in enumerate(DRIVE_FEEDBACK, 1)},
    **{f"drive{i}.torque": (name, "Nm") for i, name in enumerate(DRIVE_TORQUE, 1)},
    **_IMU,
    **{f"tes.cell{i}": ("tes", "N") for i in range(1, 7)},
}
"""channel -> (the frame that carries it, or 'tes'; unit)."""
if TYPE_CHECKING:
    Channel = str  # a checker cannot evaluate the Literal below; msgspec validates against it
else:
    Channel = Literal[tuple(CHANNELS)]
_ORDER = tuple(CHANNELS)
_INDEX = {name: i for i, name in enumerate(_ORDER)}
OFF = None


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

    family: ClassVar[str] = "sensors"

    def apply(self, readings: Readings, t: float, state: FaultState) -> None:
        i = _INDEX[self.channel]
        value = self.faulty(readings.values[i], t, state)
        if value is OFF:
            frame = CHANNELS[self.channel][0]
            if frame == "tes":
                readings.values[i] = 0.0
            else:
                readings.silent.add(frame)
        else:
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

    value: float | None = None

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        if "held" not in state.memory:
            state.memory["held"] = x if self.value is None else self.value
        held: float = state.memory["held"]
        return held


class Bias(SensorFault, frozen=True, tag="sensor.bias"):
    """A constant offset of `offset` (in the channel's unit) added to every sample."""

    offset: float

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return x + self.offset


class Scale(SensorFault, frozen=True, tag="sensor.scale"):
    """A gain error: the channel reads `factor` times the truth."""

    factor: float

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return x * self.factor


class Drift(SensorFault, frozen=True, tag="sensor.drift"):
    """An offset that grows at `rate` (channel unit per second) from the fault's start."""

    rate: float

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return x + self.rate * (t - self.at)


class Noise(SensorFault, frozen=True, tag="sensor.noise"):
    """Added white Gaussian noise of standard deviation `sigma` (channel unit)."""

    sigma: Positive

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        return x + self.sigma * state.rng.standard_normal()


class Spikes(SensorFault, frozen=True, tag="sensor.spikes"):
    """With probability `rate` per sample, a spike of ±`amplitude` (channel unit)."""

    amplitude: float
    rate: Probability = 0.05

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        if state.rng.random() >= self.rate:
            return x
        return x + (self.amplitude if state.rng.random() < 0.5 else -self.amplitude)


class Delayed(SensorFault, frozen=True, tag="sensor.delayed"):
    """The channel reports what it measured `delay` seconds ago (held at its first value until then)."""

    delay: Positive

    def faulty(self, x: float, t: float, state: FaultState) -> float | None:
        history: deque[tuple[float, float]] = state.memory.setdefault("history", deque())
        history.append((t, x))
        while len(history) > 1 and history[1][0] <= t - self.delay + 1e-9:
            history.popleft()
        return history[0][1]


class Slow(SensorFault, frozen=True, tag="sensor.slow"):
    """The channel updates only every `period` seconds (a lower rate; the frame still goes every tick)."""

    period: Positive

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
