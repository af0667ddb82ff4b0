"""Where the rider wants to go: the HACS command-speed generator, gated by the shared controller.

Per plane: tared seat moment -> low-pass -> deadband -> gain -> virtual mass-damper -> speed and
acceleration limits (docs/physics.md §8). Yaw: twist moment -> deadband -> gain -> limit. The SC command then
clamps the result: idle = 0 whatever the rider does, limit = |v| ≤ cap, free = unchanged.
"""

from __future__ import annotations

import math

from controller.config import Hacs


def deadband(x: float, width: float) -> float:
    return math.copysign(max(abs(x) - width, 0.0), x)


class CommandSpeed:
    """One plane's admittance: v_c (m/s along the plane's forward direction) from the plane's seat moment."""

    def __init__(self, params: Hacs, dt: float):
        self.p, self.dt = params, dt
        self.alpha = 1.0 - math.exp(-2.0 * math.pi * params.filter_hz * dt)
        self.filtered = 0.0
        self.speed = 0.0

    def update(self, moment: float, cap: float) -> float:
        """Advance one tick with the tared moment (Nm); cap limits |v_c| (m/s)."""
        p = self.p
        self.filtered += self.alpha * (moment - self.filtered)
        target = p.gain * deadband(self.filtered, p.deadband)
        # M_v v̇ + D_v v = k s  <=>  v̇ = (target − v) / (M_v / D_v)
        accel = (target - self.speed) / p.time_constant
        accel = min(max(accel, -p.max_accel), p.max_accel)
        limit = min(p.max_speed, cap)
        self.speed = min(max(self.speed + accel * self.dt, -limit), limit)
        return self.speed

    def reset(self) -> None:
        self.speed = 0.0


class YawCommand:
    def __init__(self, params: Hacs, dt: float):
        self.p = params
        self.alpha = 1.0 - math.exp(-2.0 * math.pi * params.filter_hz * dt)
        self.filtered = 0.0

    def update(self, twist: float) -> float:
        self.filtered += self.alpha * (twist - self.filtered)
        rate = self.p.yaw_gain * deadband(self.filtered, self.p.yaw_deadband)
        return min(max(rate, -self.p.max_yaw_rate), self.p.max_yaw_rate)
