"""Balance per plane: the cascaded LQR-PI of docs/physics.md §1.3, with the iHACS interaction compensation.

    τ_r = −K (s − s_c)                        LQR reference torque, s = [θ, φ, θ̇, φ̇], no gain on φ
    φ̈_r = A[3,:] (s − s_c) + B[3] τ_r         reference model, linearised about the command state
    φ̇_r = ∫ φ̈_r dt
    τ_e = K_p (φ̇_r − φ̇) + K_i ∫ (φ̇_r − φ̇) dt   PI on the speed error (stiction, friction)
    τ   = τ_ff + τ_r + τ_e                    HACS: s_c = [0, φ, 0, φ̇_c], τ_ff = 0
                                              iHACS: s_c = [θ_EQ, φ, 0, φ̇_c], τ_ff = τ_EQ

Anti-windup: the integrator holds while the output saturates in the direction of the error.
"""

from __future__ import annotations

import math

import numpy as np

from controller.config import SpeedPi
from controller.estimator import PlaneState
from controller.model import PlaneModel
from drivers.bounds import G0


def equilibrium(
    model: PlaneModel, f_x: float, f_z: float, m_y: float, ball_rate: float
) -> tuple[float, float]:
    """θ_EQ and τ_EQ (docs/physics.md §4.2) for a wrench (F_x, F_z world, M_y) at P and a ball rate.

    The wrench is the rider's *deviation* from sitting upright (the tared seat wrench, convention (a) of
    docs/physics.md §4.3), so the model's m_B and l include the upright rider.
    """
    a_ = model.mass * G0 * model.com - model.top_height * f_z
    b_ = model.top_height * f_x
    c_ = model.ball_radius * f_x + m_y - model.rolling_viscous * ball_rate
    ratio = max(-1.0, min(1.0, -c_ / math.hypot(a_, b_)))
    theta = math.asin(ratio) - math.atan2(b_, a_)
    tau = -model.ball_radius * f_x + (model.rolling_viscous + model.drivetrain_viscous) * ball_rate
    return theta, tau


class PlaneBalancer:
    def __init__(self, model: PlaneModel, gain: np.ndarray, pi: SpeedPi, dt: float, torque_limit: float):
        self.pi, self.dt, self.torque_limit = pi, dt, torque_limit
        # Read once: a compiled look-up into a config Struct is a dict's.
        self._kp, self._ki, self._integral_limit = pi.kp, pi.ki, pi.integral_limit
        self.set_model(model, gain)
        self.reset(0.0)

    def set_model(self, model: PlaneModel, gain: np.ndarray) -> None:
        self.model, self.k = model, np.asarray(gain, float)
        self.a_row, self.b_row = model.a[3].copy(), float(model.b[3, 0])
        # As floats: numpy's per-call overhead dominates 4-vector products at 400 Hz.
        self._k = tuple(float(x) for x in self.k.ravel())
        self._a = tuple(float(x) for x in self.a_row)

    def reset(self, ball_rate: float) -> None:
        """Start (or restart after a stop): the reference model starts at the measured speed."""
        self.ref_rate = ball_rate
        self.integral = 0.0
        self.saturated = 0.0

    def torque(
        self, s: PlaneState, ball_rate_cmd: float, tilt_cmd: float = 0.0, feedforward: float = 0.0
    ) -> float:
        """Ball torque (Nm) for the plane's estimated state s (θ, φ, θ̇, φ̇) and the command."""
        err = (s.tilt - tilt_cmd, 0.0, s.tilt_rate, s.ball_rate - ball_rate_cmd)  # the ball's angle is free
        k, a = self._k, self._a
        tau_r = -(k[0] * err[0] + k[1] * err[1] + k[2] * err[2] + k[3] * err[3])
        # The reference model is linearised about the commanded equilibrium (upright for HACS, θ_EQ for
        # iHACS, where the rider's moment is what holds the tilt): there it predicts no acceleration.
        accel_ref = a[0] * err[0] + a[1] * err[1] + a[2] * err[2] + a[3] * err[3] + self.b_row * tau_r
        self.ref_rate += accel_ref * self.dt
        speed_err = self.ref_rate - s.ball_rate
        # Conditional integration: do not wind up into a saturated output.
        if not (self.saturated and math.copysign(1.0, speed_err) == self.saturated):
            self.integral += self._ki * speed_err * self.dt
            self.integral = min(max(self.integral, -self._integral_limit), self._integral_limit)
        tau = feedforward + tau_r + self._kp * speed_err + self.integral
        if abs(tau) > self.torque_limit:
            self.saturated = math.copysign(1.0, tau)
            return math.copysign(self.torque_limit, tau)
        self.saturated = 0.0
        return tau
