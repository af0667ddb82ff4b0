"""The recovery channel's state estimate (Simplex; its law is safety/recovery.py): the state the recovery law
balances on, from the inputs the diagnosis has not named. Pure: no I/O, no clock (the monitors feed it).

Which input stands in for which (the redundancy PURE has):
- tilt: the IMU's attitude; once that is found faulty, the body rates integrated from the last trusted
  attitude (a complementary filter runs all along, so the integral starts where the attitude was good);
- tilt rate: the IMU's rate; when that is faulty or silent, the attitude's derivative (low-passed);
- ball rates: the three encoders; with one found faulty or silent, the other two and the gyro's yaw rate;
- yaw rate (to stop turning): the gyro, or the encoders when the gyro is the faulty one.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from drivers.can_codec import ENCODERS, TILT_INPUTS
from drivers.robot import RobotModel
from drivers.rotations import body_up, euler_rates, heading_frame
from safety.config import RecoveryRules
from safety.diagnostics import YawCheck, motor_jacobian

ATTITUDE_WINDOW = 40
"""Ticks (100 ms) over which the IMU point's acceleration is taken for the accelerometer's tilt."""
ATTITUDE_VOTE = 0.05
"""s: time constant of each attitude hypothesis' error (below)."""
ACCEL_AGREES = math.radians(2.0)
"""rad: a tilt hypothesis the accelerometer confirms (its noise over the window is a few tenths of this)."""
DECISIVE = math.radians(1.5)
"""rad between the two hypotheses' errors that settles which channel of a plane is wrong."""
ODD_ONE_OUT_TICKS = 40
"""Ticks (100 ms at 400 Hz) over which a yaw disagreement's hypotheses are compared: the yaw check's window
(25 ms) and the fault's onset before it."""


Solver = Callable[[Sequence[float], Sequence[float], float, float], tuple[float, float, float]]
"""(the two other drives' velocities, the body rates, roll, pitch) -> the ball-to-body rates (x, y, z)."""


def leave_one_out(jacobian: np.ndarray) -> list[tuple[Solver, list[int]]]:
    """For each drive, a solver for the ball-to-body rates from the other two drives' velocities, the gyro and
    the attitude: what the rates are if that drive's encoder is the wrong one. The third equation is the
    ball not spinning on the floor, (ω_rel + ω) · up = 0 (safety/diagnostics.py `YawCheck`). Scalar
    arithmetic: numpy's per-call overhead dominates a 2 x 2 solve, and the supervisor runs four every tick."""
    solvers: list[tuple[Solver, list[int]]] = []
    for i in range(3):
        others = [j for j in range(3) if j != i]
        (a0, b0, c0), (a1, b1, c1) = ((float(x) for x in jacobian[j]) for j in others)

        def solve(
            known: Sequence[float],
            rate: Sequence[float],
            roll: float,
            pitch: float,
            a0: float = a0,
            b0: float = b0,
            c0: float = c0,
            a1: float = a1,
            b1: float = b1,
            c1: float = c1,
        ) -> tuple[float, float, float]:
            # r_z = −ω_z − (u_x (r_x + ω_x) + u_y (r_y + ω_y)) / u_z into each motor's row: 2 x 2 in r_x, r_y.
            ux, uy, uz = body_up(roll, pitch)
            px, py = ux / uz, uy / uz
            z0 = -rate[2] - px * rate[0] - py * rate[1]
            m00, m01, m10, m11 = a0 - c0 * px, b0 - c0 * py, a1 - c1 * px, b1 - c1 * py
            k0, k1 = known[0] - c0 * z0, known[1] - c1 * z0
            det = m00 * m11 - m01 * m10
            x, y = (m11 * k0 - m01 * k1) / det, (m00 * k1 - m10 * k0) / det
            return x, y, z0 - px * x - py * y

        solvers.append((solve, others))
    return solvers


@dataclass(slots=True)
class Plane:
    """One plane's state as the recovery law sees it (roll: about x; pitch: about y; docs/physics.md)."""

    tilt: float = 0.0
    """The attitude's angle (ZYX Euler: in the heading frame), rad."""
    tilt_rate: float = 0.0
    """Its rate (an Euler rate, not the gyro's body rate), rad/s."""
    ball_rate: float = 0.0
    """φ̇: the ball's rotation about the heading frame's axis, rad/s (its ground speed / r)."""
    ball_angle: float = 0.0
    """φ: the ball's travel since the takeover began (integrated in the world), about this axis, rad."""
    integrated: float | None = None
    """The complementary filter's tilt: rates integrated, pulled toward a trusted attitude."""
    derivative: float = 0.0
    """The attitude's derivative, low-passed."""
    last_attitude: float | None = None
    history: deque[tuple[float, float, float, float]] = field(
        default_factory=lambda: deque(maxlen=ATTITUDE_WINDOW + 1)
    )
    """Per tick: the IMU point's velocity if the rate is right, if the attitude is right; the specific
    force (forward, up) in the plane."""
    force_sum: list[float] = field(default_factory=lambda: [0.0, 0.0])
    """The specific force (forward, up) summed over `history`."""
    error_if_rate_wrong: float = 0.0
    """The attitude against the accelerometer's tilt (taking the tilt rate from the attitude), low-passed."""
    error_if_attitude_wrong: float = 0.0
    """The integrated rates against the accelerometer's tilt (taking the tilt rate from the gyro)."""
    blamed: str | None = None


class IsolatedEstimator:
    """The state the recovery law needs, from the inputs the diagnosis has not named."""

    def __init__(self, robot: RobotModel, rules: RecoveryRules, period: float):
        jacobian = motor_jacobian(robot)
        self.imu_height = robot.body.imu_height
        self._to_relative = np.linalg.inv(jacobian)
        self._rows = tuple(tuple(float(x) for x in row) for row in self._to_relative)
        self._leave_one_out = leave_one_out(jacobian)
        self.radius, self.rules, self.period = robot.ball.radius, rules, period
        self.planes = (Plane(), Plane())
        """(roll, pitch)."""
        self.yaw_rate = 0.0
        """The chassis' rate about its own axis (the gyro's RateZ, or the encoders' when it is named)."""
        self.heading = 0.0
        """rad the chassis has turned since the takeover began (the attitude's yaw rate integrated)."""
        self.travel = [0.0, 0.0]
        """The ball's rotation since the takeover began, about the world's x and y (its ground travel / r)."""
        self._candidates: list[tuple[float, float]] | None = None
        """The ball rates (x, y) under each single-fault hypothesis: the gyro wrong (three encoders), or
        encoder 1, 2 or 3 wrong (the other two and the gyro)."""
        self._roughness: list[deque[float]] = [deque(maxlen=ODD_ONE_OUT_TICKS) for _ in range(4)]
        self._odd: str | None = None
        self.ready = False
        """The inputs needed to balance are there: attitude or rate per plane, and the ball rates from three
        trusted encoders or two and a trusted gyro yaw rate."""
        self._t: float | None = None

    def update(
        self,
        t: float,
        attitude: Sequence[float] | None,
        rate: Sequence[float] | None,
        velocities: Sequence[float | None],
        suspects: frozenset[str],
        accel: Sequence[float] | None = None,
        doubted: frozenset[str] = frozenset(),
    ) -> None:
        """One observation: the last trusted attitude (roll, pitch), rates (x, y, z) and specific force
        (x, y, z) if fresh (None: silent), each motor's velocity if fresh (None: silent), and the inputs the
        diagnosis names; `doubted`: channels a check has implicated without settling it yet (a doubted
        attitude still counts, but the integrated rates are no longer pulled toward it)."""
        dt = self.period if self._t is None else max(t - self._t, 0.0)
        self._t = t
        rules = self.rules
        planes_ok = True
        measured: list[float | None] = [None, None]
        body: list[float | None] = [None, None]
        # Indexed loops here, not zip(..., strict=True): compiled, that is generic iteration every update.
        for i, plane in enumerate(self.planes):
            attitude_name, rate_name = TILT_INPUTS[i]
            measured[i] = None if attitude is None or attitude_name in suspects else attitude[i]
            body[i] = None if rate is None or rate_name in suspects else rate[i]
            if attitude is not None and dt > 0.0:
                if plane.last_attitude is not None:
                    raw = (attitude[i] - plane.last_attitude) / dt
                    plane.derivative += (raw - plane.derivative) * min(dt / rules.rate_filter, 1.0)
                plane.last_attitude = attitude[i]
            # A faulty rate is replaced by the attitude's derivative; both missing: nothing to balance on.
            has_rate = body[i] is not None or (measured[i] is not None and attitude is not None)
            planes_ok = planes_ok and (plane.integrated is not None or measured[i] is not None) and has_rate
        roll, pitch = (m if m is not None else p.tilt for m, p in zip(measured, self.planes, strict=True))
        # The body rates as best known: a named roll or pitch rate stands in from its attitude's derivative.
        wx, wy = (b if b is not None else p.derivative for b, p in zip(body, self.planes, strict=True))
        gyro_z = None if rate is None or "RateZ" in suspects else rate[2]
        self._track_hypotheses(velocities, rate, roll, pitch)
        relative = self._relative(
            velocities, (wx, wy, 0.0 if gyro_z is None else gyro_z), gyro_z is None, suspects, roll, pitch
        )
        if gyro_z is not None:
            self.yaw_rate = gyro_z
        elif relative is not None:
            self.yaw_rate = YawCheck.encoders(relative, (wx, wy), roll, pitch)
        euler = euler_rates((wx, wy, self.yaw_rate), roll, pitch)
        for i, plane in enumerate(self.planes):
            plane.tilt_rate = euler[i] if body[i] is not None else plane.derivative
            trusted = measured[i]
            if plane.integrated is None:
                plane.integrated = trusted
            elif dt > 0.0:
                plane.integrated += plane.tilt_rate * dt
                if trusted is not None and TILT_INPUTS[i][0] not in doubted:
                    plane.integrated += (trusted - plane.integrated) * min(dt / rules.attitude_filter, 1.0)
            if trusted is not None:
                plane.tilt = trusted
            elif plane.integrated is not None:
                plane.tilt = plane.integrated
        self.ready = planes_ok and relative is not None
        if relative is None:
            return
        if attitude is not None and rate is not None and accel is not None:
            self._vote_attitude(attitude, rate, accel, relative, dt)
        self.heading += euler[2] * dt
        # The ball's rotation in the heading frame: the relative rates turned by the tilt, plus the chassis'
        # own horizontal rotation there (φ̇ cos θ, θ̇). A ball spinning on the floor spins about the
        # vertical: it drops out of both.
        roll_plane, pitch_plane = self.planes
        rx, ry, _ = heading_frame(relative, roll, pitch)
        roll_plane.ball_rate = rx + roll_plane.tilt_rate * math.cos(pitch)
        pitch_plane.ball_rate = ry + pitch_plane.tilt_rate
        c, s = math.cos(self.heading), math.sin(self.heading)
        self.travel[0] += (c * roll_plane.ball_rate - s * pitch_plane.ball_rate) * dt
        self.travel[1] += (s * roll_plane.ball_rate + c * pitch_plane.ball_rate) * dt
        self._travel_in_heading()

    def _travel_in_heading(self) -> None:
        """The planes' ball angles: the world travel seen from the current heading."""
        c, s = math.cos(self.heading), math.sin(self.heading)
        x, y = self.travel
        self.planes[0].ball_angle = c * x + s * y
        self.planes[1].ball_angle = -s * x + c * y

    def hold_within(self, angle: float) -> None:
        """The anchor follows the robot beyond `angle` (rad of ball travel) from it: a rider who leaned it
        away and then sits up is not driven back further than that."""
        x, y = self.travel
        far = math.hypot(x, y)
        if far > angle:
            self.travel = [x * angle / far, y * angle / far]
            self._travel_in_heading()

    def _track_hypotheses(
        self, velocities: Sequence[float | None], rate: Sequence[float] | None, roll: float, pitch: float
    ) -> None:
        """How much each hypothesis' ball rates jumped tick to tick over the last ticks: a sensor that
        steps, flips or drifts makes every estimate that uses it jump; the one without it stays smooth."""
        m0, m1, m2 = velocities
        if rate is None or m0 is None or m1 is None or m2 is None:
            return
        (r00, r01, r02), (r10, r11, r12) = self._rows[:2]
        known = (m0, m1, m2)
        candidates = [(r00 * m0 + r01 * m1 + r02 * m2, r10 * m0 + r11 * m1 + r12 * m2)]
        for solve, others in self._leave_one_out:
            x, y, _ = solve([known[j] for j in others], rate, roll, pitch)
            candidates.append((x, y))
        if self._candidates is not None:
            for i, before in enumerate(self._candidates):
                now = candidates[i]
                self._roughness[i].append(abs(now[0] - before[0]) + abs(now[1] - before[1]))
        self._candidates = candidates

    def _vote_attitude(
        self,
        attitude: Sequence[float],
        rate: Sequence[float],
        accel: Sequence[float],
        relative: tuple[float, float, float],
        dt: float,
    ) -> None:
        """Per plane, the accelerometer's tilt under each hypothesis, against the tilt that hypothesis keeps.

        The specific force in the plane (body forward, up) rotated by the true tilt θ is the IMU point's
        horizontal acceleration a (the encoders' ball speed plus the chassis turning about the ball,
        differentiated): cos θ f_fwd + sin θ f_up = a, so θ = asin(a / |f|) − atan2(f_fwd, f_up), a third
        tilt independent of both IMU channels. The tilt rate in a depends on which channel lies: taken from
        the attitude's derivative it tests "the rate is wrong", from the gyro "the attitude is wrong"."""
        h, r = self.imu_height, self.radius
        up = accel[2]
        for i, plane in enumerate(self.planes):
            forward = accel[0] if i == 1 else -accel[1]  # the roll plane's forward is body −y
            rel = relative[i]
            cos = math.cos(attitude[i])
            v_rate = r * (rel + rate[i]) + h * cos * rate[i]
            v_attitude = r * (rel + plane.derivative) + h * cos * plane.derivative
            history = plane.history
            if len(history) == history.maxlen:  # running sums: the oldest sample leaves the window
                _, _, old_forward, old_up = history[0]
                plane.force_sum[0] -= old_forward
                plane.force_sum[1] -= old_up
            history.append((v_rate, v_attitude, forward, up))
            plane.force_sum[0] += forward
            plane.force_sum[1] += up
            if len(history) <= ATTITUDE_WINDOW or dt <= 0.0:
                continue
            first, span, n = history[0], ATTITUDE_WINDOW * self.period, len(history)
            f_fwd, f_up = plane.force_sum[0] / n, plane.force_sum[1] / n
            norm = math.hypot(f_fwd, f_up)
            if norm < 1.0:
                continue  # free fall or a dead accelerometer: no tilt to be had
            offset = math.atan2(f_fwd, f_up)
            tilt_if_rate_wrong = accelerometer_tilt((v_attitude - first[1]) / span, norm, offset)
            tilt_if_attitude_wrong = accelerometer_tilt((v_rate - first[0]) / span, norm, offset)
            # The accelerometer's tilt is the window's mean: compare with the tilt half a window ago.
            k = min(dt / ATTITUDE_VOTE, 1.0)
            lag = rate[i] * span / 2
            plane.error_if_rate_wrong += (
                abs(attitude[i] - lag - tilt_if_rate_wrong) - plane.error_if_rate_wrong
            ) * k
            integrated = plane.integrated if plane.integrated is not None else attitude[i]
            plane.error_if_attitude_wrong += (
                abs(integrated - lag - tilt_if_attitude_wrong) - plane.error_if_attitude_wrong
            ) * k

    def blame(self, plane: int, accel_suspect: bool) -> str:
        """Which channel of a plane a disagreement blames: 'attitude' or 'rate', the one whose hypothesis
        leaves the accelerometer's tilt further from the tilt it keeps; with `accel_suspect` (only the
        speed trend, which rests on the accelerometer, disagrees) 'accel' unless one hypothesis agrees
        with the accelerometer within ACCEL_AGREES. A slow fault (a drift) is seen before the evidence is
        clear: the answer is the best guess until the two hypotheses differ by DECISIVE, then latched until
        `clear`."""
        p = self.planes[plane]
        if p.blamed is not None:
            return p.blamed
        rate_wrong, attitude_wrong = p.error_if_rate_wrong, p.error_if_attitude_wrong
        if accel_suspect and min(rate_wrong, attitude_wrong) > ACCEL_AGREES:
            guess = "accel"
        else:
            guess = "attitude" if rate_wrong > attitude_wrong else "rate"
        if abs(rate_wrong - attitude_wrong) > DECISIVE:
            p.blamed = guess
        return guess

    def odd_one_out(self) -> str:
        """Which of the gyro's RateZ and the three encoders a yaw disagreement blames: the one whose
        exclusion leaves the ball rates without a jump over the last ODD_ONE_OUT_TICKS ticks (latched until
        `clear`). Four measurements of three unknowns detect one fault but cannot say which by themselves;
        the fault's onset can."""
        if self._odd is None:
            # The largest single-tick jump: a step or a flip stands out of the sensors' noise by orders of
            # magnitude, where a sum over the window would add the noise up.
            scores = [max(r, default=0.0) for r in self._roughness]
            self._odd = ("RateZ", *ENCODERS)[scores.index(min(scores))]
        return self._odd

    def clear(self) -> None:
        """A reset: the sensors were found healthy again."""
        self._odd = None
        for plane in self.planes:
            plane.blamed = None

    def _relative(
        self,
        velocities: Sequence[float | None],
        rate: Sequence[float],
        no_yaw_rate: bool,
        suspects: frozenset[str],
        roll: float,
        pitch: float,
    ) -> tuple[float, float, float] | None:
        """Ball-to-body rates (x, y, z) from the trusted encoders (two, the gyro and the attitude if one is
        not: the ball does not spin on the floor); `no_yaw_rate`: the gyro's RateZ is not to be used."""
        bad = [i for i in range(3) if velocities[i] is None or ENCODERS[i] in suspects]
        if not bad:
            m0, m1, m2 = velocities
            if m0 is not None and m1 is not None and m2 is not None:  # none is bad: always
                (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self._rows
                return (
                    r00 * m0 + r01 * m1 + r02 * m2,
                    r10 * m0 + r11 * m1 + r12 * m2,
                    r20 * m0 + r21 * m1 + r22 * m2,
                )
        if len(bad) > 1 or no_yaw_rate:
            return None
        solve, others = self._leave_one_out[bad[0]]
        return solve(cast("list[float]", [velocities[j] for j in others]), rate, roll, pitch)

    def engage(self) -> None:
        """The takeover begins: the heading and the ball's travel count from here."""
        self.heading = 0.0
        self.travel = [0.0, 0.0]
        self._travel_in_heading()

    @property
    def speed(self) -> float:
        roll, pitch = self.planes
        return self.radius * math.hypot(roll.ball_rate, pitch.ball_rate)

    @property
    def tilt(self) -> float:
        roll, pitch = self.planes
        return max(abs(roll.tilt), abs(pitch.tilt))


def accelerometer_tilt(a: float, norm: float, offset: float) -> float:
    """The tilt at which a specific force of magnitude `norm`, `offset` from the body's up in the plane,
    makes the horizontal acceleration `a` (`IsolatedEstimator._vote_attitude`)."""
    return math.asin(min(max(a / norm, -1.0), 1.0)) - offset
