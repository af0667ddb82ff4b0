"""The supervisor's recovery law (Simplex): a small balancing law that brings the robot to rest when the
controller cannot be trusted to, on the state safety/estimator.py keeps from the inputs the diagnosis has
not named.

Pure: no I/O, no clock (the node sends the law's torques on SUPERVISOR_RECOVERY while the takeover is
announced). It shares no code with the controller: its model is the planar ballbot linearised from the
supervisor's own view of the robot file, with the rider lumped into the body (mass from the seat's load),
and an LQR per plane on [tilt, ball angle since the takeover, tilt rate, ball rate] brings the robot to rest
near where the takeover began (docs/safety.md "Fail-operational"); on two wheels, with weights of its own.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_continuous_are

from drivers.bounds import G0
from drivers.robot import RobotModel
from drivers.rotations import body_frame
from safety.config import RecoveryRules, TwoWheelRules
from safety.diagnostics import motor_jacobian
from safety.estimator import IsolatedEstimator

MAX_RIDER, RIDER_STEP = 200.0, 25.0
"""kg: the riders the recovery law's gains are solved for (interpolated between)."""


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
        if without is None:
            states = [(p.tilt, p.ball_angle, p.tilt_rate, p.ball_rate) for p in estimate.planes]
            ball = [
                -sum(k * x for k, x in zip(g, s, strict=True))
                for g, s in zip(self.gains, states, strict=True)
            ]
            ball.append(self.rules.yaw_gain * estimate.yaw_rate)
            motor = self._to_motor @ np.asarray(ball)
        else:
            # On two wheels the heading frame turns at several rad/s: the planes' LQR wants the rate of the
            # tilt fixed in the world, not of its components in a turning frame (they differ by ψ̇ × θ).
            yaw = estimate.yaw_rate
            states = [
                (roll.tilt, roll.ball_angle, roll.tilt_rate - yaw * pitch.tilt, roll.ball_rate),
                (pitch.tilt, pitch.ball_angle, pitch.tilt_rate + yaw * roll.tilt, pitch.ball_rate),
            ]
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
