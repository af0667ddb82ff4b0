"""Sensor models: motor encoders and drive feedback, the body IMU, and the TES force-sensing seat.

Each model owns a numpy Generator (seeded by the plant) so results are reproducible for a seed. White noise
is converted from a density to a per-sample σ as σ = ND · √(f_s / 2): the sensor band-limits to its Nyquist
frequency. Bias random walks advance with √dt.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from plant.params import Drive, Encoder, Imu, Tes

BLOCK = 64
"""Rows drawn per numpy call. A refill is one lump on the tick that makes it: the plant's three streams at
1024 rows took ~1.8 ms of every 1024th tick (an overrun in real time); at 64, ~0.1 ms. A Generator's normal
draws are the same sequence however they are chunked, so every seed's noise is what it was."""


class NoiseStream:
    """Standard normal draws, generated in blocks (one numpy call per block): rows of Python floats, or
    numpy views of the block's rows."""

    def __init__(self, rng: np.random.Generator, width: int, block: int = BLOCK, as_array: bool = False):
        """as_array: draw numpy rows (views of the block) for a model whose maths is numpy's."""
        self.rng, self.width, self.block, self.as_array = rng, width, block, as_array
        self._rows: list[list[float]] = []
        self._array: np.ndarray = np.empty((0, width))
        self._next = 0

    def _refill(self) -> None:
        self._array = self.rng.standard_normal((self.block, self.width))
        if not self.as_array:
            self._rows = self._array.tolist()
        self._next = 0

    def draw(self) -> list[float]:
        if self._next == len(self._array):
            self._refill()
        row = self._rows[self._next]
        self._next += 1
        return row

    def draw_array(self) -> np.ndarray:
        """The next row as a numpy view (a stream made with as_array=True)."""
        if self._next == len(self._array):
            self._refill()
        row: np.ndarray = self._array[self._next]
        self._next += 1
        return row


def counts_from_angle(angle: float, encoder: Encoder) -> int:
    """Motor angle (rad, from power-up) -> quantised count, wrapped to a signed word like the hardware."""
    raw = round(angle * encoder.counts_per_rev / (2.0 * math.pi))
    half = 1 << (encoder.word_bits - 1)
    return (raw + half) % (2 * half) - half


class Record:
    """A sample or state made every tick: read-only by convention, compared and shown by its values like
    the frozen dataclasses these were. Not dataclasses: compiled, a dataclass's __init__ stays the Python
    function `dataclasses` writes, a microsecond a record (the plant makes six a tick)."""

    def _values(self) -> tuple[object, ...]:
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and isinstance(other, Record) and self._values() == other._values()

    def __repr__(self) -> str:
        return f"{type(self).__name__}{self._values()}"


class DriveFeedback(Record):
    """One drive's feedback sample."""

    counts: int
    velocity: float
    """Motor velocity, rad/s."""
    torque: float
    """Measured motor torque, Nm."""

    def __init__(self, counts: int, velocity: float, torque: float) -> None:
        self.counts, self.velocity, self.torque = counts, velocity, torque

    def _values(self) -> tuple[object, ...]:
        return self.counts, self.velocity, self.torque


class DriveFeedbackModel:
    def __init__(self, encoder: Encoder, drive: Drive, rng: np.random.Generator):
        self.encoder, self.drive = encoder, drive
        self.noise = NoiseStream(rng, 6)

    def sample(
        self, angles: Sequence[float], velocities: Sequence[float], torques: Sequence[float]
    ) -> tuple[DriveFeedback, DriveFeedback, DriveFeedback]:
        n = self.noise.draw()
        sv, st = self.drive.velocity_noise, self.drive.torque_noise
        enc = self.encoder
        return (
            DriveFeedback(
                counts_from_angle(angles[0], enc), velocities[0] + sv * n[0], torques[0] + st * n[3]
            ),
            DriveFeedback(
                counts_from_angle(angles[1], enc), velocities[1] + sv * n[1], torques[1] + st * n[4]
            ),
            DriveFeedback(
                counts_from_angle(angles[2], enc), velocities[2] + sv * n[2], torques[2] + st * n[5]
            ),
        )


class ImuSample(Record):
    """One IMU sample."""

    attitude: tuple[float, float, float]
    """Roll, pitch, yaw (ZYX Euler), rad; yaw wrapped to [-π, π)."""
    rate: tuple[float, float, float]
    """Angular rate in the body frame, rad/s."""
    accel: tuple[float, float, float]
    """Specific force in the body frame, m/s² (at rest upright: (0, 0, +g))."""

    def __init__(
        self,
        attitude: tuple[float, float, float],
        rate: tuple[float, float, float],
        accel: tuple[float, float, float],
    ) -> None:
        self.attitude, self.rate, self.accel = attitude, rate, accel

    def _values(self) -> tuple[object, ...]:
        return self.attitude, self.rate, self.accel


class ImuModel:
    def __init__(self, params: Imu, rng: np.random.Generator):
        self.p = params
        self.gyro_bias = (params.gyro_bias_sigma * rng.standard_normal(3)).tolist()
        self.accel_bias = (params.accel_bias_sigma * rng.standard_normal(3)).tolist()
        self.noise = NoiseStream(rng, 15)
        band = math.sqrt(params.rate_hz / 2.0)
        self.gyro_sigma = params.gyro_noise_density * band
        self.accel_sigma = params.accel_noise_density * band
        self.attitude_sigma = math.radians(params.attitude_noise_deg)
        period = 1.0 / params.rate_hz
        self.gyro_step = params.gyro_bias_walk * math.sqrt(period)
        self.accel_step = params.accel_bias_walk * math.sqrt(period)

    def sample(self, attitude: Sequence[float], rate: Sequence[float], accel: Sequence[float]) -> ImuSample:
        """One output sample from the true attitude, body rate and body specific force."""
        n = self.noise.draw()
        gb, ab = self.gyro_bias, self.accel_bias
        for i in range(3):
            gb[i] += self.gyro_step * n[9 + i]
            ab[i] += self.accel_step * n[12 + i]
        sa, sg, sf = self.attitude_sigma, self.gyro_sigma, self.accel_sigma
        # An AHRS reports its heading wrapped to [-π, π) (the DBC's range), however far the robot has turned.
        yaw = (attitude[2] + sa * n[2] + math.pi) % (2.0 * math.pi) - math.pi
        return ImuSample(
            (attitude[0] + sa * n[0], attitude[1] + sa * n[1], yaw),
            (rate[0] + gb[0] + sg * n[3], rate[1] + gb[1] + sg * n[4], rate[2] + gb[2] + sg * n[5]),
            (accel[0] + ab[0] + sf * n[6], accel[1] + ab[1] + sf * n[7], accel[2] + ab[2] + sf * n[8]),
        )


def load_cell_geometry(tes: Tes) -> np.ndarray:
    """A (6×6): seat wrench at P [Fx, Fy, Fz, Mx, My, Mz] = A @ cell forces.

    Three vertical cells and three tangential cells share three azimuths on a circle around P; column i is
    [n_i; p_i × n_i] for cell position p_i and measuring axis n_i.
    """
    cols = []
    for axis in ("vertical", "tangential"):
        for k in range(3):
            a = math.radians(tes.cell_azimuth0_deg) + k * 2.0 * math.pi / 3.0
            p = np.array([tes.cell_radius * math.cos(a), tes.cell_radius * math.sin(a), 0.0])
            n = (
                np.array([0.0, 0.0, 1.0])
                if axis == "vertical"
                else np.array([-math.sin(a), math.cos(a), 0.0])
            )
            cols.append(np.concatenate([n, np.cross(p, n)]))
    return np.array(cols).T


class TesSample(Record):
    """One seat sample."""

    force: tuple[float, float, float]
    """Force of the rider on the seat, body axes at P, N (seated upright: Fz < 0)."""
    moment: tuple[float, float, float]
    """Moment of the rider on the seat about P, body axes, Nm."""
    cop: tuple[float, float]
    """Centre of pressure on the seat surface, body x and y from P's axis, m; (0, 0) when unloaded."""
    cells: tuple[float, float, float, float, float, float]
    """Raw load-cell readings m, N (PURE convention: wrench = −E m)."""

    def __init__(
        self,
        force: tuple[float, float, float],
        moment: tuple[float, float, float],
        cop: tuple[float, float],
        cells: tuple[float, float, float, float, float, float],
    ) -> None:
        self.force, self.moment, self.cop, self.cells = force, moment, cop, cells

    def _values(self) -> tuple[object, ...]:
        return self.force, self.moment, self.cop, self.cells


MIN_SEATED_LOAD = 20.0
"""Below this vertical load (N) the seat is empty and the COP is undefined (reported as 0, 0)."""

SEAT_RADIUS = 0.3
"""The seat's footprint around P's axis, m: pelvis and thighs press within it (the supervisor's default COP
bound, safety.config, is this edge; riding peaks at half of it, docs/safety.md)."""


class TesModel:
    """The force-sensing seat: true wrench -> six cell forces + noise -> calibration matrix -> wrench, COP."""

    def __init__(self, params: Tes, seat_height: float, rng: np.random.Generator):
        self.p, self.seat_height = params, seat_height
        self.geometry = load_cell_geometry(params)
        self.to_cells = np.linalg.inv(self.geometry)
        error = params.calibration_error * rng.standard_normal((6, 6))
        self.calibration = -self.geometry * (1.0 + error)
        """E: the calibration the seat firmware applies (wrench = −E m)."""
        self._neg_calibration = -self.calibration
        self.noise = NoiseStream(rng, 6, as_array=True)

    def sample(self, wrench: Sequence[float]) -> TesSample:
        """wrench: true [Fx, Fy, Fz, Mx, My, Mz] of the rider on the seat at P, body axes."""
        # numpy's products, not scalar sums: OpenBLAS's kernel (fused multiply-adds, its own order) rounds
        # them, and the seat's readings must stay those of earlier runs bit for bit.
        cells = np.dot(self.to_cells, wrench) + self.p.cell_noise * self.noise.draw_array()
        # A cell's amplifier saturates at its full scale: what a fall's impact puts on the seat is read as
        # that, not as tens of kN.
        limit = self.p.cell_range
        return self._report(np.clip(cells, -limit, limit, out=cells))

    def from_cells(self, cells: Sequence[float] | np.ndarray) -> TesSample:
        """What the seat reports for these cell readings (N): wrench through its calibration, and COP."""
        return self._report(np.asarray(cells, float))

    def _report(self, cells: np.ndarray) -> TesSample:
        fx, fy, fz, mx, my, mz = np.dot(self._neg_calibration, cells).tolist()
        cop_xy = cop(fx, fy, fz, mx, my, self.seat_height)
        return TesSample((fx, fy, fz), (mx, my, mz), cop_xy, tuple(cells.tolist()))


def cop(fx: float, fy: float, fz: float, mx: float, my: float, seat_height: float) -> tuple[float, float]:
    """Centre of pressure on the seat surface (seat_height above P) for a wrench at P, z up.

    The load acts at (x, y, h): M = r × F gives Mx = y Fz − h Fy and My = h Fx − x Fz. This is the AMTI
    formula of docs/physics.md §1.4 written for a z-up frame with the surface above the origin.

    A point off the seat's footprint (SEAT_RADIUS) is reported at the footprint's edge, in its direction:
    a seat can only be pressed, never pulled, so its pressure's centre stays on it. Beyond it the wrench is
    one no seated body makes (a hard push carried through the rider's hip, or a few newtons of load with a
    moment); the force and moment still say so, as they are.
    """
    if abs(fz) < MIN_SEATED_LOAD:
        return 0.0, 0.0
    x, y = (seat_height * fx - my) / fz, (mx + seat_height * fy) / fz
    off = math.hypot(x, y)
    if off > SEAT_RADIUS:
        scale = SEAT_RADIUS / off
        return x * scale, y * scale
    return x, y
