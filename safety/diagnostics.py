"""Diverse evidence: each check compares two independent measurements of one physical quantity, or a value
with what physics allows, and says when they disagree (pure: values in, a finding out; no I/O, no clock).

What PURE's sensors make redundant (docs/safety.md "Diagnostics"):
- the three encoders determine the ball's rotation relative to the chassis; with the ball not spinning on
  the floor and the gyro's roll and pitch rates, that is the chassis' yaw rate, which RateZ measures too;
- each drive reports its position and its velocity: the position's derivative must match the velocity;
- the attitude must follow the integrated body rates;
- the horizontal specific force (accelerometer, rotated by the attitude) integrates to the change of the
  IMU point's velocity: the encoders' speed plus the chassis' rotation about the ball (in the heading frame,
  which turns with the chassis);
- the measured torque follows the command through the drive's current loop;
- a seat carries a seated rider: weight within a band of the tared weight, COP on the seat, COP consistent
  with force and moment, no faster change than a body and the chassis make;
- a noisy sensor never repeats its raw value many frames in a row while other evidence says it moved (how
  many: as many as make such a run unlikely for a live one at its stream's step, `Resolution`).

Every check keeps `peak`: the largest |residual| / bound it has seen, so a run shows how close it came to a
false trip (summary.json → safety.diagnostics).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from drivers.robot import RobotModel
from drivers.rotations import body_up, chassis_axis, euler_rates, heading_frame
from drivers.vocabulary import Cause
from safety.config import SeatRules, SensorRules
from safety.observation import Finding


class Window:
    """The running sum of the last `n` values."""

    def __init__(self, n: int):
        self.values: deque[float] = deque(maxlen=n)
        self.total = 0.0

    def add(self, x: float) -> None:
        if len(self.values) == self.values.maxlen:
            self.total -= self.values[0]
        self.values.append(x)
        self.total += x

    @property
    def full(self) -> bool:
        return len(self.values) == self.values.maxlen

    def clear(self) -> None:
        self.values.clear()
        self.total = 0.0


class Check:
    """A residual against its bound: `exceeds` records the peak ratio and says when it is over; `finding` says
    what was seen (its text is built only then: formatting it at every frame cost more than the check)."""

    cause: ClassVar[Cause] = Cause.SENSOR_DISAGREE

    def __init__(self, name: str, parts: tuple[str, ...] = ()):
        self.name = name
        self.parts = parts
        """The parts a failure isolates by itself (empty: it needs other evidence, safety/monitors.py)."""
        self.peak = 0.0

    def exceeds(self, residual: float, bound: float) -> bool:
        ratio = abs(residual) / bound
        self.peak = max(self.peak, ratio)
        return ratio > 1.0

    def finding(self, detail: str) -> Finding:
        return Finding(self.cause, f"{self.name}: {detail}", self.parts)


def live_run(step: float, contract: float, noise: float, samples: int) -> float:
    """Frames in a row a channel whose values step by `step` must repeat its raw value to be as unlikely
    for a live one as `samples` frames are at the contract's `contract` step.

    A live sensor's reading stays on its step from one frame to the next with probability at most
    p(q) = erf(q / (2√2 σ)) (its true value at the step's middle, white noise of 1σ `noise`), so a run of
    n frames has at most p(q)^(n - 1). At the contract's step p = p(contract); at a coarser one the run
    that keeps p^(n - 1) the same is longer. A step no coarser than the contract's keeps `samples`; one so
    coarse that a live reading (numerically) never leaves it gives inf: repetition then proves nothing."""
    if step <= contract * (1.0 + 1e-9):
        return float(samples)
    scale = 1.0 / (2.0 * math.sqrt(2.0) * noise)
    p0, p = math.erf(contract * scale), math.erf(step * scale)
    if p >= 1.0:
        return math.inf
    return float(1 + math.ceil((samples - 1) * math.log(p0) / math.log(p) - 1e-9))


class Resolution:
    """A stream's resolution as its values show it: the smallest step any of its signals has made, never
    taken finer than the contract's (a message's signals share one scaling, in the contract and in every
    device profile), and from it the run of repeated raw values that shows a channel frozen (`live_run`).

    The supervisor reads the logical messages a device profile's host makes of the device's own frames
    (drivers/devices/): it is not told their scaling, but a live stream shows it within a few frames (its
    noise moves it by single steps). Until a step is seen the contract's holds; a step seen only lowers
    what is taken, so the check never becomes less sensitive than the steps the stream has shown."""

    def __init__(self, contract: float, noise: float, samples: int):
        self.contract, self.noise, self.base = contract, noise, samples
        self.step = math.inf
        """The smallest step seen (inf: none yet)."""
        self.samples = float(samples)  # mypyc: one float representation, whatever live_run gives
        """Frames in a row a channel of this stream must repeat its raw value to count as frozen."""

    def moved(self, step: float) -> None:
        if 0.0 < step < self.step:
            self.step = step
            self.samples = live_run(max(step, self.contract), self.contract, self.noise, self.base)


class Stuck:
    """Counts how many frames in a row a channel repeated its raw value, and how far the other evidence
    says it should have moved over that run."""

    def __init__(self, samples: int, need: float, resolution: Resolution | None = None):
        """`resolution`: the stream's, shared by its channels (None: `samples` whatever the values' step)."""
        self.samples, self.need, self.resolution = samples, need, resolution
        self.last: object = None
        self.run = 0
        self.evidence = 0.0

    @property
    def required(self) -> float:
        """Frames in a row that show the channel frozen (with the evidence)."""
        return float(self.samples) if self.resolution is None else self.resolution.samples

    def sample(self, raw: object, evidence: float) -> bool:
        """One frame's raw value and how far the other evidence moved since the previous frame; True if
        the channel is stuck: the same value `required` times in a row while the evidence moved `need`."""
        if raw == self.last:
            self.run += 1
            self.evidence += evidence
        else:
            last = self.last
            # Types as a tuple: `int | float` would be made anew at every frame (compiled too).
            if (
                self.resolution is not None
                and isinstance(raw, (int, float))
                and isinstance(last, (int, float))
            ):
                self.resolution.moved(abs(raw - last))
            self.last, self.run, self.evidence = raw, 1, 0.0
        return self.run >= self.required and self.evidence >= self.need

    def clear(self) -> None:
        self.last, self.run, self.evidence = None, 0, 0.0


class Replay:
    """A stream whose last `period` frames each repeat, signal for signal, the frame `period` before it,
    while they differ among themselves: frames replayed from exactly one alive-counter period back. The
    4-bit counter aliases and the CRC is the original's, so E2E sees nothing; a live sensor's noise never
    repeats a whole cycle. A constant stream is not a replay (that is the stuck check's, with evidence)."""

    def __init__(self, period: int):
        self.period = period
        self.history: deque[tuple[float | int, ...]] = deque(maxlen=period)
        self.matches = 0

    def frame(self, data: tuple[float | int, ...]) -> bool:
        """One trusted frame's data signals (without counter and CRC); True while replayed."""
        full = len(self.history) == self.period
        self.matches = self.matches + 1 if full and data == self.history[0] else 0
        self.history.append(data)
        return self.matches >= self.period and len(set(self.history)) > 1


class EncoderCheck(Check):
    """One drive: its position differentiated vs the velocity it reports, over a window of frames."""

    def __init__(self, index: int, rules: SensorRules, period: float, rad_per_count: float, wrap: int):
        super().__init__(f"drive {index} position vs velocity", (f"Encoder{index}",))
        self.rules, self.period, self.rad_per_count, self.wrap = rules, period, rad_per_count, wrap
        n = max(round(rules.window / period), 2)
        self.moved, self.integral, self.time, self.magnitude = Window(n), Window(n), Window(n), Window(n)
        self.previous: tuple[int, float] | None = None

    def frame(self, counts: int, velocity: float, periods: int) -> Finding | None:
        """A trusted feedback frame; `periods`: sample periods since the previous one (1 + frames lost)."""
        previous, self.previous = self.previous, (counts, velocity)
        if previous is None:
            return None
        half = self.wrap // 2
        moved = ((counts - previous[0] + half) % self.wrap - half) * self.rad_per_count
        dt = periods * self.period
        self.moved.add(moved)
        self.integral.add(0.5 * (velocity + previous[1]) * dt)
        self.time.add(dt)
        self.magnitude.add(abs(velocity) * dt)
        if not self.time.full:
            return None
        span = self.time.total
        derived, reported = self.moved.total / span, self.integral.total / span
        bound = self.rules.encoder_tolerance + self.rules.relative * self.magnitude.total / span
        if not self.exceeds(derived - reported, bound):
            return None
        return self.finding(f"{derived:.2f} rad/s from the position, {reported:.2f} rad/s reported")

    def reset(self) -> None:
        """A gap the window must not span (a frame it could not trust)."""
        self.previous = None
        for w in (self.moved, self.integral, self.time, self.magnitude):
            w.clear()


class YawCheck(Check):
    """The chassis' yaw rate the encoders give vs the gyro's RateZ.

    The three encoders measure the ball's rotation relative to the chassis, all three components. A ball that
    does not spin on the floor turns about a horizontal axis, so (ω_rel + ω) · up = 0 (body axes, `up` the
    world's vertical from the attitude): with the gyro's roll and pitch rates that fixes the chassis' rate
    about its own axis. Tilted and rolling, the ball's rotation has a part along the chassis axis (ball rate ×
    tilt across the motion: 0.5 rad/s at 1.4 m/s and 2.5 deg), which a level-robot relation takes for yaw."""

    def __init__(self, rules: SensorRules, period: float):
        super().__init__("yaw rate, encoders vs gyro")
        self.rules = rules
        n = max(round(rules.window / period), 2)
        self.difference, self.magnitude, self.time = Window(n), Window(n), Window(n)

    @staticmethod
    def encoders(relative: Sequence[float], rate: Sequence[float], roll: float, pitch: float) -> float:
        """The chassis' rate about its own axis from the relative ball rates (G⁻¹ m) and the gyro's x, y."""
        ux, uy, uz = body_up(roll, pitch)
        return -(ux * (relative[0] + rate[0]) + uy * (relative[1] + rate[1])) / uz - relative[2]

    def update(
        self, relative: Sequence[float], rate: Sequence[float], roll: float, pitch: float, dt: float
    ) -> Finding | None:
        encoders, gyro = self.encoders(relative, rate, roll, pitch), rate[2]
        self.difference.add((encoders - gyro) * dt)
        self.magnitude.add(max(abs(encoders), abs(gyro)) * dt)
        self.time.add(dt)
        if not self.time.full:
            return None
        span = self.time.total
        bound = self.rules.yaw_tolerance + self.rules.relative * self.magnitude.total / span
        if not self.exceeds(self.difference.total / span, bound):
            return None
        return self.finding(f"{encoders:.3f} rad/s from the encoders, {gyro:.3f} rad/s from the gyro")

    def reset(self) -> None:
        for w in (self.difference, self.magnitude, self.time):
            w.clear()


class AttitudeCheck(Check):
    """One plane: the attitude's change vs the body rate integrated (a leaky sum, so slow drifts add up
    too), with room for what the small-angle kinematics neglect (rate × tilt cross terms)."""

    def __init__(self, plane: str, rules: SensorRules):
        super().__init__(f"{plane} attitude vs integrated rate")
        self.rules = rules
        self.error = self.allowance = 0.0
        self.previous: tuple[float, float] | None = None

    def update(self, angle: float, rate: float, coupling: float, dt: float) -> Finding | None:
        """`coupling`: the largest neglected kinematic term now, rad/s (|rates| × tan(tilt))."""
        previous, self.previous = self.previous, (angle, rate)
        if previous is None:
            return None
        keep = math.exp(-dt / self.rules.attitude_memory)
        self.error = keep * self.error + (angle - previous[0]) - 0.5 * (rate + previous[1]) * dt
        self.allowance = keep * self.allowance + coupling * dt
        if not self.exceeds(self.error, self.rules.attitude_tolerance + self.allowance):
            return None
        return self.finding(f"attitude ran {self.error * 1e3:+.1f} mrad off the integrated rate")

    def reset(self) -> None:
        self.previous, self.error, self.allowance = None, 0.0, 0.0


class TrendCheck(Check):
    """One direction of the heading frame: the change of the IMU point's horizontal velocity (the ball's
    ground speed plus the chassis turning about the ball) vs the horizontal specific force integrated."""

    def __init__(self, plane: str, rules: SensorRules, period: float):
        super().__init__(f"{plane} speed trend vs accelerometer")
        self.rules = rules
        self.window = max(round(rules.trend_window / period), 2)
        """Samples the trend is judged over (the history's length)."""
        self.history: deque[tuple[float, float]] = deque(maxlen=self.window)
        self.integral = 0.0
        self.previous_accel: float | None = None

    def update(self, velocity: float, accel: float, dt: float) -> Finding | None:
        """`velocity`: the IMU point's horizontal velocity from the encoders, m/s; `accel`: what changes it,
        m/s²: the horizontal specific force, plus the turn of the heading frame it is measured in (a velocity
        fixed in the world turns under a chassis turning at ψ̇: ψ̇ × v, 0.56 m/s² at 0.7 m/s and 0.8 rad/s)."""
        if self.previous_accel is not None:
            self.integral += 0.5 * (accel + self.previous_accel) * dt
        self.previous_accel = accel
        self.history.append((velocity, self.integral))
        if len(self.history) < self.window:
            return None
        v0, i0 = self.history[0]
        changed, integrated = velocity - v0, self.integral - i0
        if not self.exceeds(changed - integrated, self.rules.trend_tolerance):
            return None
        return self.finding(f"speed changed {changed:+.3f} m/s, the accelerometer says {integrated:+.3f} m/s")

    def reset(self) -> None:
        self.history.clear()
        self.previous_accel = None


class TorqueCheck(Check):
    """One drive: its measured torque vs the command it follows (the last one before the sample)."""

    cause: ClassVar[Cause] = Cause.ACTUATOR_MISMATCH

    def __init__(
        self,
        index: int,
        tolerance: float,
        relative: float,
        samples: int,
        limit: float,
        stall: float = math.inf,
        top_speed: float = math.inf,
    ):
        """limit: the drive's current limit; stall, top_speed: its motor's torque-speed line (Nm, rad/s)."""
        super().__init__(f"drive {index} torque", (f"Drive{index}",))
        self.tolerance, self.relative, self.samples, self.limit = tolerance, relative, samples, limit
        self.stall, self.top_speed = stall, top_speed
        self.over = 0

    def expected(self, commanded: float, speed: float) -> float:
        """What a healthy drive makes of `commanded` at `speed` (rad/s): within its current limit and,
        driving, below its motor's line (stall at rest, none at the top speed, a brake past it: the
        back-EMF; plant/drives.py)."""
        torque = min(max(commanded, -self.limit), self.limit)
        if torque * speed > 0.0:
            most = max(self.stall * (1.0 - abs(speed) / self.top_speed), -self.limit)
            if abs(torque) > most:
                torque = most if torque > 0.0 else -most  # negative: a brake against the motion
        return torque

    def sample(
        self,
        measured: float,
        commanded: float | None,
        producing: bool,
        speed: float = 0.0,
        speed_before: float | None = None,
        asked: bool = False,
    ) -> Finding | None:
        """`commanded`: the torque the drive was last told (None: not yet); `producing`: it reports itself
        enabled on a live bus, and that command asked it to enable (else it must make none); `speed`,
        `speed_before`: its motor's last two reported velocities, rad/s (the drive set its torque somewhere
        between them: near the top speed what it may make moves with the speed); `asked`: the command asked
        it to enable, whatever it reports."""
        if commanded is None:
            return None
        expected = self.expected(commanded, speed) if producing else 0.0
        residual = measured - expected
        if producing and speed_before is not None:
            other = self.expected(commanded, speed_before)
            if min(expected, other) <= measured <= max(expected, other):
                residual = 0.0
            elif abs(measured - other) < abs(residual):
                expected, residual = other, measured - other
        elif not producing and asked:
            # It reports itself off yet makes what it was told: its report is what is wrong, not its torque
            # (a status bit flipped where nothing protects the frame, as on CAN Simple or CANopen's PDOs);
            # the state machine judges the report (DRIVE_FAULT).
            told = self.expected(commanded, speed)
            if abs(measured - told) < abs(residual):
                expected, residual = told, measured - told
        bound = self.tolerance + self.relative * abs(expected)
        self.over = self.over + 1 if self.exceeds(residual, bound) else 0
        if self.over < self.samples:
            return None
        return self.finding(
            f"measured {measured:+.3f} Nm, expected {expected:+.3f} Nm for {self.over} samples in a row"
        )


class SeatCheck(Check):
    """The seat wrench as a seated rider can make it."""

    cause: ClassVar[Cause] = Cause.WRENCH_IMPLAUSIBLE

    def __init__(self, rules: SeatRules, min_load: float, seat_height: float, period: float, moved: float):
        super().__init__("seat")
        self.rules, self.min_load, self.seat_height = rules, min_load, seat_height
        self.tare: float | None = None
        self._tare_sum, self._tare_n = 0.0, 0
        self._tare_samples = max(round(rules.tare_time / period), 1)
        n = max(round(rules.rate_window / period), 1)
        self.history: deque[tuple[float, ...]] = deque(maxlen=n + 1)
        self.span = n * period
        self.stuck = Stuck(rules.stuck_samples, moved)
        self.cells_stuck = [Stuck(rules.stuck_samples, moved) for _ in range(6)]
        self.peaks = {"weight": 0.0, "cop": 0.0, "consistency": 0.0, "force rate": 0.0, "moment rate": 0.0}

    def sample(
        self,
        force: Sequence[float],
        moment: Sequence[float],
        cop: Sequence[float],
        vertical_accel: float,
        moved: float,
        cells: Sequence[float] | None = None,
        g: float = 9.80665,
    ) -> Finding | None:
        """One payload; `vertical_accel`: the IMU's vertical specific force (m/s², ~g at rest); `moved`:
        how much other evidence (the IMU) changed since the previous sample (for the frozen checks);
        `cells`: the six raw load-cell readings, if the seat publishes them."""
        values = (*force, *moment)
        self.history.append(values)
        if self.stuck.sample(values, moved):
            return self.finding(f"every value frozen for {self.stuck.run} samples")
        # A dead or frozen cell only shifts the wrench along its own calibration column, often by less
        # than the weight band allows (a lean unloads it); its raw reading repeating shows it at once.
        for i, value in enumerate(cells or ()):
            if self.cells_stuck[i].sample(value, moved):
                return self.finding(
                    f"load cell {i + 1} reads {value:.1f} N, unchanged for {self.cells_stuck[i].run} "
                    "samples while the chassis moved",
                )
        load = -force[2]
        if self.tare is None:
            if load >= self.min_load:
                self._tare_sum += load
                self._tare_n += 1
                if self._tare_n >= self._tare_samples:
                    self.tare = self._tare_sum / self._tare_n
            return None
        r = self.rules
        # Weight: within the band of the tare, scaled by the chassis' vertical acceleration; below the
        # smallest seated load it is a rider getting off (RIDER_ABSENT), not this check's.
        expected = self.tare * vertical_accel / g
        if load >= self.min_load:
            over = self._ratio("weight", abs(load - expected), r.weight_band * self.tare)
            if over:
                return self.finding(
                    f"load {load:.0f} N, a rider tared at {self.tare:.0f} N gives {expected:.0f} N",
                )
            fx, fy, fz = force
            mx, my, _ = moment
            h = self.seat_height
            derived = ((h * fx - my) / fz, (mx + h * fy) / fz)
            # A seat reports a COP off its footprint at the footprint's edge (plant/sensors.py cop): the
            # wrench's own COP says how far off it really is.
            distance = max(math.hypot(*cop), math.hypot(*derived))
            if self._ratio("cop", distance, r.radius):
                return self.finding(f"centre of pressure {distance:.3f} m off the centre")
            gap = math.hypot(derived[0] - cop[0], derived[1] - cop[1])
            if self._ratio("consistency", gap, r.cop_tolerance):
                return self.finding(f"reported COP {gap * 1e3:.0f} mm from the force and moment's")
        if len(self.history) == self.history.maxlen:
            old = self.history[0]
            dforce = max(abs(values[i] - old[i]) for i in range(3)) / self.span
            dmoment = max(abs(values[i] - old[i]) for i in range(3, 6)) / self.span
            if self._ratio("force rate", dforce, r.force_rate):
                return self.finding(f"force changing at {dforce:.0f} N/s")
            if self._ratio("moment rate", dmoment, r.moment_rate):
                return self.finding(f"moment changing at {dmoment:.0f} Nm/s")
        return None

    def _ratio(self, part: str, value: float, bound: float) -> bool:
        ratio = value / bound
        self.peaks[part] = max(self.peaks[part], ratio)
        self.peak = max(self.peak, ratio)
        return ratio > 1.0


def motor_jacobian(robot: RobotModel) -> np.ndarray:
    """Motor-shaft rates = G @ [φ̇_x − θ̇_x, φ̇_y − θ̇_y, −ψ̇] (each wheel's contact direction on the ball)."""
    d = robot.drivetrain
    rho = robot.ball.radius / d.wheel_radius
    zenith = math.radians(d.zenith_deg)
    rows = []
    for i, sign in enumerate(d.motor_sign):
        azimuth = math.radians(d.azimuth0_deg) + 2.0 * math.pi * i / 3.0
        direction = (
            -math.cos(zenith) * math.cos(azimuth),
            -math.cos(zenith) * math.sin(azimuth),
            math.sin(zenith),
        )
        rows.append([sign * d.gear_ratio * rho * x for x in direction])
    return np.array(rows)


def trend_inputs(
    relative: Sequence[float],
    rate: Sequence[float],
    accel: Sequence[float],
    roll: float,
    pitch: float,
    radius: float,
    imu_height: float,
) -> tuple[tuple[float, float], tuple[float, float]]:
    """For the speed-trend checks, forward and left in the heading frame: the IMU point's velocity and what
    changes it. The velocity is the ball's (its rotation, relative + the chassis', turned into the frame)
    plus the chassis' rotation about the ball (ω × h·axis); it changes by the horizontal specific force and
    by the frame's own turn at the heading's rate, which turns a velocity fixed in the world under it."""
    ball = heading_frame((relative[0] + rate[0], relative[1] + rate[1], relative[2] + rate[2]), roll, pitch)
    wx, wy, wz = heading_frame(rate, roll, pitch)
    nx, ny, nz = chassis_axis(roll, pitch)
    forward = radius * ball[1] + imu_height * (wy * nz - wz * ny)
    left = -radius * ball[0] + imu_height * (wz * nx - wx * nz)
    turn = euler_rates(rate, roll, pitch)[2]
    ax, ay, _ = heading_frame(accel, roll, pitch)
    return (forward, ax + turn * left), (left, ay - turn * forward)
