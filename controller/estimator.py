"""State estimation from the CAN frames: chassis tilt and rate per plane (IMU), ball angle and rate per
plane (encoders through the inverse omniwheel map, plus the chassis rotation), yaw rate.

Missing or untrusted frames (E2E) hold the last good value; a stream silent longer than `hold` faults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PITCH, ROLL = 0, 1
INT32 = 1 << 32


def _dot(row: tuple[float, float, float], v) -> float:
    return row[0] * v[0] + row[1] * v[1] + row[2] * v[2]


@dataclass(slots=True)
class PlaneState:
    tilt: float = 0.0
    ball_angle: float = 0.0
    tilt_rate: float = 0.0
    ball_rate: float = 0.0

    def vector(self) -> tuple[float, float, float, float]:
        return (self.tilt, self.ball_angle, self.tilt_rate, self.ball_rate)


@dataclass(slots=True)
class Estimate:
    planes: tuple[PlaneState, PlaneState]
    yaw_rate: float
    fault: str | None


class Estimator:
    def __init__(self, motor_jacobian: np.ndarray, counts_per_rev: int, hold: float):
        self.to_relative = np.linalg.inv(motor_jacobian)
        # Rows of it as floats: numpy's per-call overhead dominates a 3-vector product at 400 Hz.
        self._roll_row, self._pitch_row = (tuple(float(x) for x in row) for row in self.to_relative[:2])
        self.rad_per_count = 2.0 * math.pi / counts_per_rev
        self.hold = hold
        self.attitude = (0.0, 0.0, 0.0)
        self.rate = (0.0, 0.0, 0.0)
        self.counts = [0, 0, 0]
        self.velocity = [0.0, 0.0, 0.0]
        self._raw_counts: list[int | None] = [None, None, None]
        self.last_good = {
            "imu_attitude": None,
            "imu_rate": None,
            "drive0": None,
            "drive1": None,
            "drive2": None,
        }

    # Frame inputs (only trusted frames are passed in).
    def imu_attitude(self, roll: float, pitch: float, yaw: float, t: float) -> None:
        self.attitude = (roll, pitch, yaw)
        self.last_good["imu_attitude"] = t

    def imu_rate(self, x: float, y: float, z: float, t: float) -> None:
        self.rate = (x, y, z)
        self.last_good["imu_rate"] = t

    def drive(self, index: int, counts: int, velocity: float, t: float) -> None:
        previous = self._raw_counts[index]
        if previous is not None:
            # The 32-bit count wraps: accumulate the signed difference.
            delta = (counts - previous + INT32 // 2) % INT32 - INT32 // 2
            self.counts[index] += delta
        else:
            self.counts[index] = counts
        self._raw_counts[index] = counts
        self.velocity[index] = velocity
        self.last_good[f"drive{index}"] = t

    def estimate(self, t: float) -> Estimate:
        fault = None
        for stream, seen in self.last_good.items():
            if seen is None or t - seen > self.hold:
                fault = f"{stream} silent" if seen is not None else f"{stream} never received"
                break
        roll, pitch, _ = self.attitude
        rate_x, rate_y, rate_z = self.rate
        roll_row, pitch_row, counts = self._roll_row, self._pitch_row, self.counts
        rel_roll, rel_pitch = (
            _dot(roll_row, counts) * self.rad_per_count,
            _dot(pitch_row, counts) * self.rad_per_count,
        )
        rate_roll, rate_pitch = _dot(roll_row, self.velocity), _dot(pitch_row, self.velocity)
        # ω_rel = [φ_x − θ_x, φ_y − θ_y, −ψ]: add the chassis rotation back to get the ball's.
        pitch_state = PlaneState(pitch, rel_pitch + pitch, rate_y, rate_pitch + rate_y)
        roll_state = PlaneState(roll, rel_roll + roll, rate_x, rate_roll + rate_x)
        return Estimate((pitch_state, roll_state), rate_z, fault)
