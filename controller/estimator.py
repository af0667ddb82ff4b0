"""State estimation from the CAN frames: chassis tilt and rate per plane (IMU), ball angle and rate per
plane (encoders through the inverse omniwheel map, plus the chassis rotation), yaw rate.

Missing or untrusted frames (E2E) hold the last good value. An input that is lost (its stream silent longer
than `hold`) or that the supervisor's diagnosis names faulty (`drop`, SUPERVISOR_DIAGNOSIS) is stood in for
where PURE's redundancy allows, and the estimate says it is `degraded`:
- a rate channel (x or y): the attitude's derivative, low-passed;
- the attitude (roll or pitch): the body rates integrated from the last trusted attitude;
- one encoder: the other two and the gyro's yaw rate give the ball-to-body rates; the ball angle goes on
  from there by integration.
Only when no stand-in is left (both attitude and rates of a plane, two encoders, an encoder and the gyro's
yaw rate) does the estimate fault.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np

from drivers.can_codec import ENCODERS, TILT_INPUTS

# Final: compiled (mypyc), a constant rather than a look-up in the module's globals at every use.
PITCH: Final = 0
ROLL: Final = 1
INT32 = 1 << 32
DERIVATIVE_FILTER = 0.02
"""s: low-pass of the attitude's derivative that stands in for a rate channel."""
DRIVES = ("drive0", "drive1", "drive2")
STREAMS = ("imu_attitude", "imu_rate", *DRIVES)


def _dot(row: tuple[float, ...], v: Sequence[float]) -> float:
    """row · v for 3-vectors."""
    return row[0] * v[0] + row[1] * v[1] + row[2] * v[2]


# Plain classes with a typed __init__: compiled (mypyc), a dataclass keeps its generated Python __init__, a
# native one is a C constructor.
class PlaneState:
    def __init__(self, tilt: float, ball_angle: float, tilt_rate: float, ball_rate: float):
        self.tilt, self.ball_angle, self.tilt_rate, self.ball_rate = tilt, ball_angle, tilt_rate, ball_rate


class Estimate:
    def __init__(
        self,
        planes: tuple[PlaneState, PlaneState],
        yaw_rate: float,
        fault: str | None,
        degraded: tuple[str, ...] = (),
    ):
        self.planes, self.yaw_rate, self.fault = planes, yaw_rate, fault
        self.degraded = degraded
        """The inputs stood in for (SUPERVISOR_DIAGNOSIS's names: Encoder1, RateX, Pitch, ...)."""


class Estimator:
    def __init__(self, motor_jacobian: np.ndarray, counts_per_rev: int, hold: float):
        self.jacobian = motor_jacobian
        self.to_relative = np.linalg.inv(motor_jacobian)
        # Rows of it as floats: numpy's per-call overhead dominates a 3-vector product at 400 Hz.
        rows = (tuple(float(x) for x in row) for row in self.to_relative)
        self._roll_row, self._pitch_row, self._yaw_row = rows
        self.rad_per_count = 2.0 * math.pi / counts_per_rev
        self.hold = hold
        self.attitude = (0.0, 0.0, 0.0)
        self.rate = (0.0, 0.0, 0.0)
        self.counts = [0, 0, 0]
        self.velocity = [0.0, 0.0, 0.0]
        self._raw_counts: list[int | None] = [None, None, None]
        self.last_good: dict[str, float | None] = dict.fromkeys(STREAMS)
        self.dropped: frozenset[str] = frozenset()
        """What the supervisor's diagnosis names faulty (SUPERVISOR_DIAGNOSIS), not used while named."""
        self._derivative = [0.0, 0.0]
        """The attitude's derivative (roll, pitch), low-passed."""
        self._integrated: list[float] | None = None
        """The attitude (roll, pitch) carried by the body rates from the last trusted one."""
        self._rate_at: float | None = None
        self._relative_angle: tuple[float, float] | None = None
        """Ball-to-body angles (roll, pitch) integrated once an encoder is stood in for."""
        self._estimated_at: float | None = None

    def drop(self, parts: frozenset[str]) -> None:
        """The supervisor's diagnosis (SUPERVISOR_DIAGNOSIS): stop using what it names."""
        self.dropped = parts

    # Frame inputs (only trusted frames are passed in).
    def imu_attitude(self, roll: float, pitch: float, yaw: float, t: float) -> None:
        seen = self.last_good["imu_attitude"]
        if seen is not None and t > seen:
            for i, now in enumerate((roll, pitch)):
                raw = (now - self.attitude[i]) / (t - seen)
                self._derivative[i] += (raw - self._derivative[i]) * min((t - seen) / DERIVATIVE_FILTER, 1.0)
        self.attitude = (roll, pitch, yaw)
        self.last_good["imu_attitude"] = t

    def imu_rate(self, x: float, y: float, z: float, t: float) -> None:
        if self._integrated is not None and self._rate_at is not None and t > self._rate_at:
            dt = t - self._rate_at
            self._integrated[0] += x * dt
            self._integrated[1] += y * dt
        self.rate = (x, y, z)
        self._rate_at = t
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
        self.last_good[DRIVES[index]] = t

    def _lost(self, stream: str, t: float) -> bool:
        seen = self.last_good[stream]
        return seen is None or t - seen > self.hold

    def estimate(self, t: float) -> Estimate:
        dropped = self.dropped
        for stream in STREAMS:
            if self.last_good[stream] is None:
                return self._nominal(t, f"{stream} never received")
        attitude_ok = not self._lost("imu_attitude", t)
        rates_ok = not self._lost("imu_rate", t)
        bad_drives = [i for i in range(3) if self._lost(DRIVES[i], t) or ENCODERS[i] in dropped]
        degraded: list[str] = []
        trusted_attitude = attitude_ok and "Roll" not in dropped and "Pitch" not in dropped
        if trusted_attitude or self._integrated is None:
            self._integrated = [self.attitude[0], self.attitude[1]]
        tilt, tilt_rate = [0.0, 0.0], [0.0, 0.0]
        for i, (angle, rate) in enumerate(TILT_INPUTS):
            use_attitude = attitude_ok and angle not in dropped
            use_rate = rates_ok and rate not in dropped
            if not use_attitude and not use_rate:
                return self._nominal(t, f"{angle.lower()}: no attitude and no rate left")
            tilt[i] = self.attitude[i] if use_attitude else self._integrated[i]
            tilt_rate[i] = self.rate[i] if use_rate else self._derivative[i]
            if not use_attitude:
                degraded.append(angle)
            if not use_rate:
                degraded.append(rate)
        gyro_yaw_ok = rates_ok and "RateZ" not in dropped
        if len(bad_drives) > 1 or (bad_drives and not gyro_yaw_ok):
            return self._nominal(t, "two encoders (or one and the gyro's yaw rate) lost")
        yaw_rate = self.rate[2] if gyro_yaw_ok else -_dot(self._yaw_row, self.velocity)
        if not gyro_yaw_ok:
            degraded.append("RateZ")
        roll_state, pitch_state = self._planes(t, tilt, tilt_rate, bad_drives)
        degraded += [ENCODERS[i] for i in bad_drives]
        return Estimate((pitch_state, roll_state), yaw_rate, None, tuple(degraded))

    def _planes(
        self, t: float, tilt: Sequence[float], tilt_rate: Sequence[float], bad_drives: Sequence[int]
    ) -> tuple[PlaneState, PlaneState]:
        """(roll, pitch) plane states from the encoders, or from two and the gyro's yaw rate."""
        dt = 0.0 if self._estimated_at is None else max(t - self._estimated_at, 0.0)
        self._estimated_at = t
        roll_row, pitch_row, counts = self._roll_row, self._pitch_row, self.counts
        if not bad_drives:
            rel_angle = (
                _dot(roll_row, counts) * self.rad_per_count,
                _dot(pitch_row, counts) * self.rad_per_count,
            )
            rel_rate = (_dot(roll_row, self.velocity), _dot(pitch_row, self.velocity))
            self._relative_angle = None
        else:
            bad = bad_drives[0]
            others = [j for j in range(3) if j != bad]
            # ω_rel = [φ_x − θ_x, φ_y − θ_y, −ψ̇]: the remaining motors less their yaw part, through 2 x 2.
            known = np.array([self.velocity[j] for j in others]) + self.jacobian[others, 2] * self.rate[2]
            x, y = np.linalg.solve(self.jacobian[np.ix_(others, [0, 1])], known)
            rel_rate = (float(x), float(y))
            if self._relative_angle is None:  # goes on from where the counts left it
                self._relative_angle = (
                    _dot(roll_row, counts) * self.rad_per_count,
                    _dot(pitch_row, counts) * self.rad_per_count,
                )
            self._relative_angle = (
                self._relative_angle[0] + rel_rate[0] * dt,
                self._relative_angle[1] + rel_rate[1] * dt,
            )
            rel_angle = self._relative_angle
        roll = PlaneState(tilt[0], rel_angle[0] + tilt[0], tilt_rate[0], rel_rate[0] + tilt_rate[0])
        pitch = PlaneState(tilt[1], rel_angle[1] + tilt[1], tilt_rate[1], rel_rate[1] + tilt_rate[1])
        return roll, pitch

    def _nominal(self, t: float, fault: str | None) -> Estimate:
        """Every input as it is (the fault says why that is not good enough)."""
        roll, pitch = self._planes(t, self.attitude[:2], self.rate[:2], [])
        return Estimate((pitch, roll), self.rate[2], fault)
