"""The supervisor's recovery channel (Simplex): its own state estimate, which drops every input the diagnosis
names, and a small balancing law that brings the robot to rest when the controller cannot be trusted to.

Pure: no I/O, no clock (the monitors feed the estimator; the node sends the law's torques on
SUPERVISOR_RECOVERY while the takeover is announced). It shares no code with the controller: its model is
the planar ballbot linearised from the supervisor's own view of the robot file, with the rider lumped into
the body (mass from the seat's load), and an LQR per plane on [tilt, ball angle since the takeover, tilt
rate, ball rate] brings the robot to rest near where the takeover began (docs/safety.md "Fail-operational").

Which input stands in for which (the redundancy PURE has):
- tilt: the IMU's attitude; once that is found faulty, the body rates integrated from the last trusted
  attitude (a complementary filter runs all along, so the integral starts where the attitude was good);
- tilt rate: the IMU's rate; when that is faulty or silent, the attitude's derivative (low-passed);
- ball rates: the three encoders; with one found faulty or silent, the other two and the gyro's yaw rate;
- yaw rate (to stop turning): the gyro, or the encoders when the gyro is the faulty one.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from scipy.linalg import solve_continuous_are

from drivers.bounds import G0
from drivers.can_codec import ENCODERS, TILT_INPUTS
from drivers.robot import RobotModel
from drivers.rotations import body_frame, body_up, euler_rates, heading_frame
from safety.config import RecoveryRules, TwoWheelRules
from safety.diagnostics import YawCheck, motor_jacobian

ATTITUDE_WINDOW = 40
"""Ticks (100 ms) over which the IMU point's acceleration is taken for the accelerometer's tilt."""
ATTITUDE_VOTE = 0.05
"""s: time constant of each attitude hypothesis' error (below)."""
ACCEL_AGREES = math.radians(2.0)
"""rad: a tilt hypothesis the accelerometer confirms (its noise over the window is a few tenths of this)."""
DECISIVE = math.radians(1.5)
"""rad between the two hypotheses' errors that settles which channel of a plane is wrong."""
MAX_RIDER, RIDER_STEP = 200.0, 25.0
"""kg: the riders the recovery law's gains are solved for (interpolated between)."""
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


def plane_gain(
    robot: RobotModel,
    rules: RecoveryRules,
    rider_mass: float,
    inertia: float,
    chassis: float = 1.0,
    weights: RecoveryRules | TwoWheelRules | None = None,
) -> np.ndarray:
    """LQR gain K (τ = −K s, s = [θ, φ, θ̇, φ̇]) of the planar ballbot linearised upright (Fankhauser &
    Gwerder's model, the rider a point mass `rider_com` above the seat, the drivetrain's inertia left out:
    under 1 % of the body's here). `chassis`: how the chassis takes the reaction of a torque τ on the ball,
    as −chassis·τ (1 in a plane of its own; a pair of wheels' coupled plane differs: `chassis_factor`).
    `weights`: the LQR's (`rules`' own, the three-drive law's, if None)."""
    ball, body = robot.ball, robot.body
    seat = body.top_height + body.seat_height + rules.rider_com
    mass = body.mass + rider_mass
    com = (body.mass * body.com_height + rider_mass * seat) / mass
    theta_b = inertia + body.mass * (body.com_height - com) ** 2 + rider_mass * (seat - com) ** 2
    r = ball.radius
    m11 = ball.mass * r**2 + ball.inertia + mass * r**2
    m12 = mass * r * com
    m22 = theta_b + mass * com**2
    det = m11 * m22 - m12**2
    gravity = mass * G0 * com
    a = np.zeros((4, 4))
    a[0, 2] = a[1, 3] = 1.0
    a[2, 0] = m11 * gravity / det
    a[3, 0] = -m12 * gravity / det
    b = np.array([[0.0], [0.0], [-(m11 * chassis + m12) / det], [(m22 + m12 * chassis) / det]])
    w = rules if weights is None else weights
    q = np.diag([w.q_tilt, w.q_position, w.q_tilt_rate, w.q_ball_rate])
    rr = np.array([[w.r]])
    p = solve_continuous_are(a, b, q, rr)
    gain: np.ndarray = np.linalg.solve(rr, b.T @ p)[0]
    return gain


@dataclass(frozen=True, slots=True)
class Pair:
    """The two drives left when one is dead, and what their torques can do. Their two torques make a torque
    on the ball in a plane of three dimensions: about one horizontal axis (`free`) without any yaw torque,
    about the axis across it (`coupled`) only with a yaw torque `yaw_per_torque` times as large, whose
    reaction turns the chassis (docs/safety.md "A dead drive")."""

    drives: list[int]
    to_motor: np.ndarray
    """2 x 2: a horizontal torque on the ball (x, y) -> the two drives' torques."""
    free: tuple[float, float]
    coupled: tuple[float, float]
    yaw_per_torque: float


def pair(jacobian: np.ndarray, dead: int) -> Pair:
    drives = [j for j in range(3) if j != dead]
    rows = jacobian[drives]  # each drive's torque axis on the ball (τ = Gᵀ T)
    to_motor = np.linalg.inv(rows[:, :2].T)
    yaw = to_motor.T @ rows[:, 2]  # τ_z = yaw · (τ_x, τ_y) for any torque the pair makes
    k = float(np.hypot(*yaw))
    coupled = (float(yaw[0]) / k, float(yaw[1]) / k)
    return Pair(drives, to_motor, (-coupled[1], coupled[0]), coupled, k)


MASSES = np.arange(0.0, MAX_RIDER + RIDER_STEP / 2, RIDER_STEP)
"""kg: the riders the gains are solved for."""
FACTORS = np.linspace(-4.0, 4.0, 17)
"""The chassis factors the coupled plane's gains are solved for (interpolated between): PURE's pairs with
a 50-120 kg rider and up to 15 deg of tilt lie within ±3.5."""


@functools.cache
def gain_tables(robot: RobotModel, rules: RecoveryRules) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gains for riders every RIDER_STEP kg: the (roll, pitch) planes' on three wheels and on two (their
    free axis), and the coupled plane of a pair for every chassis factor. Solved once per process and robot
    (a takeover only interpolates: a Riccati solve at the takeover would delay its frame by milliseconds;
    the 189 of them take about a second on a loaded 2-core machine)."""
    body, pair_weights = robot.body, rules.two_wheels
    inertias = (body.inertia_roll, body.inertia_pitch)
    planes = np.array([[plane_gain(robot, rules, m, i) for i in inertias] for m in MASSES])
    pair_planes = np.array(
        [[plane_gain(robot, rules, m, i, 1.0, pair_weights) for i in inertias] for m in MASSES]
    )
    inertia = 0.5 * (body.inertia_roll + body.inertia_pitch)
    coupled = np.array(
        [[plane_gain(robot, rules, m, inertia, float(f), pair_weights) for f in FACTORS] for m in MASSES]
    )
    for table in (planes, pair_planes, coupled):
        table.setflags(write=False)  # shared by every law of the process
    return planes, pair_planes, coupled


class RecoveryLaw:
    """τ = −K s per plane, the yaw rate damped, mapped onto the motors and held to their limit.

    Without one drive (found not to make its torque) the other two balance in two planes of their own:
    about their yaw-free axis as in a plane of three drives (this brakes without turning the robot), and
    across it, where every torque turns the chassis too. There the yaw is left free but not ignored: the
    pair's torque ties the yaw rate to that plane's momentum (J_z ψ̇ + κ p = const), so that plane's
    velocity feedback is partly the yaw rate (`coupled_velocity_share`), and its gains follow how the
    chassis takes the pair's torque now: the rider's legs ahead of the axis and the chassis' own tilt couple
    its roll to the yaw the torque brings (`chassis_factor`). Two wheels have weights of their own
    (`TwoWheelRules`: the ball's speed damped hard, the tilt held loosely, so the rider's momentum comes
    down at a yaw the pair keeps), and their tilt rates are the world-fixed tilt's (the heading frame turns
    at several rad/s under them)."""

    def __init__(self, robot: RobotModel, rules: RecoveryRules):
        self.robot, self.rules = robot, rules
        jacobian = motor_jacobian(robot)
        self._to_motor = np.linalg.inv(jacobian.T)
        self._pairs = tuple(pair(jacobian, i) for i in range(3))
        self.limit = robot.drive.torque_limit
        self._masses = MASSES
        self._table, self._pair_table, self._coupled_table = gain_tables(robot, rules)
        self.gains = self.design(None)

    def design(self, seat_load: float | None) -> tuple[np.ndarray, np.ndarray]:
        """The (roll, pitch) gains for the rider the seat weighs (N; None: the configured rider mass)."""
        rider = self.rules.rider_mass if seat_load is None else seat_load / G0
        rider = min(max(rider, 0.0), MAX_RIDER)
        gains, pair_gains = (
            np.array([[np.interp(rider, self._masses, t[:, p, i]) for i in range(4)] for p in range(2)])
            for t in (self._table, self._pair_table)
        )
        self.gains = (gains[0], gains[1])
        self._pair_gains = (pair_gains[0], pair_gains[1])
        self._coupled_gains = np.array(
            [
                [np.interp(rider, self._masses, self._coupled_table[:, f, i]) for i in range(4)]
                for f in range(len(FACTORS))
            ]
        )
        self._chassis_inertia(rider)
        return self.gains

    def _chassis_inertia(self, rider: float) -> None:
        """The chassis' and the seated rider's inertia about the ball centre, body axes (the rider a point
        mass for roll and pitch, as in `plane_gain`; per kg of rider for yaw and the roll-yaw product)."""
        body, rules = self.robot.body, self.rules
        seat = body.top_height + body.seat_height + rules.rider_com
        level = body.mass * body.com_height**2 + rider * seat**2
        xz = rules.rider_roll_yaw_product * rider
        inertia = np.array(
            [
                [body.inertia_roll + level, 0.0, xz],
                [0.0, body.inertia_pitch + level, 0.0],
                [xz, 0.0, body.inertia_yaw + rules.rider_yaw_inertia * rider],
            ]
        )
        self._inverse_inertia = np.linalg.inv(inertia)
        self._yaw_inertia = float(inertia[2, 2])
        r, mass = self.robot.ball.radius, body.mass + rider
        self._ball_inertia = self.robot.ball.mass * r**2 + self.robot.ball.inertia + mass * r**2

    def chassis_factor(self, dead: int, roll: float, pitch: float) -> float:
        """How the chassis takes the pair's torque about the coupled axis, against a plane of its own (1):
        its tilt rate's response to that torque with the yaw free, the reaction of the torque and of the yaw
        torque that comes with it (both about body axes) through the inertia tilted with the chassis. The
        rider's legs ahead of the axis (a roll-yaw product of inertia) and a chassis tilted back under a
        leaning rider move it far from 1, to below 0 (docs/safety.md)."""
        p = self._pairs[dead]
        ex, ey = p.coupled
        q = body_frame((ex, ey, 0.0), roll, pitch)  # the heading frame's coupled axis, in body axes
        inverse = self._inverse_inertia
        push = inverse @ np.array([ex, ey, p.yaw_per_torque])
        qv = np.asarray(q)
        return float(qv @ push) / float(qv @ inverse @ qv)

    def torques(self, estimate: IsolatedEstimator, without: int | None = None) -> tuple[float, float, float]:
        """The motor torques for the estimate; `without`: a drive (0-2) that makes no torque."""
        two_wheels = self.rules.two_wheels
        # Anti-windup: beyond the limit the anchor moves with the robot, so a rider who leaned it away and
        # then sits up is not driven back further than the limit.
        anchor = self.rules.position_limit if without is None else two_wheels.position_limit
        estimate.hold_within(anchor / estimate.radius)
        roll, pitch = estimate.planes
        states = [(p.tilt, p.ball_angle, p.tilt_rate, p.ball_rate) for p in estimate.planes]
        if without is not None:
            # On two wheels the heading frame turns at several rad/s: the planes' LQR wants the rate of the
            # tilt fixed in the world, not of its components in a turning frame (they differ by ψ̇ × θ).
            yaw = estimate.yaw_rate
            states[0] = (roll.tilt, roll.ball_angle, roll.tilt_rate - yaw * pitch.tilt, roll.ball_rate)
            states[1] = (pitch.tilt, pitch.ball_angle, pitch.tilt_rate + yaw * roll.tilt, pitch.ball_rate)
        if without is None:
            ball = [
                -sum(k * x for k, x in zip(g, s, strict=True))
                for g, s in zip(self.gains, states, strict=True)
            ]
            ball.append(self.rules.yaw_gain * estimate.yaw_rate)
            motor = self._to_motor @ np.asarray(ball)
        else:
            p = self._pairs[without]
            (dx, dy), (ex, ey) = p.free, p.coupled
            free = [dx * a + dy * b for a, b in zip(*states, strict=True)]
            coupled = [ex * a + ey * b for a, b in zip(*states, strict=True)]
            share = two_wheels.coupled_velocity_share
            # The yaw rate stands in for part of the coupled plane's ball rate: the pair's torque changes
            # them together, ψ̇ by −κ/J_z per unit of that plane's momentum m11 φ̇.
            coupled[1] *= share
            coupled[3] = (
                share * coupled[3]
                - (1.0 - share)
                * self._yaw_inertia
                / (p.yaw_per_torque * self._ball_inertia)
                * estimate.yaw_rate
            )
            factor = self.chassis_factor(without, roll.tilt, pitch.tilt)
            gain_free = dx * dx * self._pair_gains[0] + dy * dy * self._pair_gains[1]
            gain_coupled = [np.interp(factor, FACTORS, self._coupled_gains[:, i]) for i in range(4)]
            t_free = -sum(k * x for k, x in zip(gain_free, free, strict=True))
            t_coupled = -sum(k * x for k, x in zip(gain_coupled, coupled, strict=True))
            motor = np.zeros(3)
            motor[p.drives] = p.to_motor @ np.array(
                [t_free * dx + t_coupled * ex, t_free * dy + t_coupled * ey]
            )
        limit = self.limit
        m0, m1, m2 = (float(m) for m in motor)
        return min(max(m0, -limit), limit), min(max(m1, -limit), limit), min(max(m2, -limit), limit)
