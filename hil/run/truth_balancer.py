"""An ideal balancer: full-state LQR on the plant's *true* state, for plant checks and the plant-only demo.

Not the device under test (that is `controller/`, which sees only CAN and zenoh). This one reads the truth,
so it isolates the physics from estimation and wire effects. Per plane it stabilises s = [θ, θ̇, φ̇] about a
commanded ball rate on the rigid-rider (lumped) linearisation; yaw gets a rate PD.
"""

from __future__ import annotations

from dataclasses import replace

import control
import numpy as np

from plant.ballbot import plane_params
from plant.core import PITCH, ROLL, PlantCore
from plant.plane import PlaneDynamics, PlaneParams

DEFAULT_Q = (100.0, 1.0, 10.0)
"""LQR weights on [θ, θ̇, φ̇] (docs/physics.md §6.1's illustrative order of magnitude)."""
DEFAULT_R = 0.1


def linearise_plane(params: PlaneParams, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """A (4×4), B (4×1) about upright rest for s = [θ, φ, θ̇, φ̇] by central differences of the EOM.

    Two-body planes only (rider absent or lumped). Coulomb friction and stiction are dropped (not
    differentiable at rest); viscous terms stay.
    """
    if params.hat_mass > 0.0:
        raise ValueError("linearise the rigid-rider (two-body) plane")
    dyn = PlaneDynamics(replace(params, drivetrain_coulomb=0.0, drivetrain_stiction=0.0))

    def acc(th: float, dphi: float, dth: float, tau: float) -> np.ndarray:
        ddphi, ddth, _ = dyn.accelerations(th, th, dphi, dth, dth, tau, 0.0, None)
        return np.array([ddth, ddphi])

    a = np.zeros((4, 4))
    a[0, 2] = a[1, 3] = 1.0
    for col, args in ((0, (1, 0, 0, 0)), (2, (0, 0, 1, 0)), (3, (0, 1, 0, 0))):
        d = np.array(args, dtype=float) * eps
        a[2:, col] = (acc(*d) - acc(*(-d))) / (2 * eps)
    d = np.array([0, 0, 0, eps])
    b = np.zeros((4, 1))
    b[2:, 0] = (acc(*d) - acc(*(-d))) / (2 * eps)
    return a, b


class TruthBalancer:
    """LQR on the true state; outputs motor torque commands through the inverse omniwheel torque map."""

    def __init__(
        self,
        plant: PlantCore,
        q: tuple[float, float, float] = DEFAULT_Q,
        r: float = DEFAULT_R,
        yaw_gains: tuple[float, float] = (20.0, 0.0),
    ) -> None:
        self.plant = plant
        self.gains = []
        for name in ("pitch", "roll"):
            a4, b4 = linearise_plane(plane_params(plant.robot, plant.rider, name, torso=False))
            idx = [0, 2, 3]  # θ, θ̇, φ̇: φ itself is not regulated
            k, _, _ = control.lqr(a4[np.ix_(idx, idx)], b4[idx], np.diag(q), np.array([[r]]))
            self.gains.append(np.asarray(k).ravel())
        g = np.array(plant._g)
        self.torque_to_motor = np.linalg.inv(g.T)
        self.yaw_gains = yaw_gains
        self.ball_rate_command = [0.0, 0.0]
        """Commanded ball rate per plane, rad/s (speed = r_K × rate; the roll plane's forward is −y)."""
        self.yaw_rate_command = 0.0

    def set_velocity(self, forward: float, left: float = 0.0) -> None:
        r = self.plant.robot.ball.radius
        self.ball_rate_command = [forward / r, -left / r]

    def command(self) -> tuple[float, float, float]:
        """Motor torques for the plant's current true state."""
        truth = self.plant.truth()
        tau_plane = []
        for k in (PITCH, ROLL):
            th, dth, dphi = truth.tilt[k], truth.tilt_rate[k], truth.ball_rate[k]
            kth, kdth, kdphi = self.gains[k]
            tau_plane.append(-(kth * th + kdth * dth + kdphi * (dphi - self.ball_rate_command[k])))
        kp, _ = self.yaw_gains
        # The body yaws under −τ_z, so a positive τ_z slows a positive yaw rate.
        tau_z = kp * (truth.yaw_rate - self.yaw_rate_command)
        tau = np.array([tau_plane[ROLL], tau_plane[PITCH], tau_z])
        motor = self.torque_to_motor @ tau
        return float(motor[0]), float(motor[1]), float(motor[2])

    def drive(self) -> None:
        """Send this tick's commands to the plant's drives (enabled)."""
        self.plant.drives.set_commands(self.command(), True, self.plant.t)
