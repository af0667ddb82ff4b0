"""The rider's torso control: a rate- and acceleration-limited lean command, the bounded PD that produces
the hip torque, and the twisting moment on the seat (plant/rider.py's profiles say what the rider aims at).

Apart from plant/rider.py, whose segments are msgspec Structs, so that the compiled build compiles this
per-tick maths (setup.py: msgspec does not see the class keywords of a Struct compiled by mypyc).
"""

from __future__ import annotations

import math

from plant.params import RiderParams
from plant.rider import Profile

SLIP_TIME = 0.03
"""s: time constant of a sudden weight shift (a slip on the seat): fast, but a body's mass cannot jump."""


class TorsoController:
    """One plane of the rider: a rate- and acceleration-limited lean command and the bounded PD that
    produces hip torque."""

    def __init__(self, rider: RiderParams, hat_mass: float, hat_com: float, profile: Profile):
        self.profile = profile
        self.max_lean = math.radians(rider.max_lean_deg)
        self.max_rate = math.radians(rider.max_lean_rate_deg)
        self.max_accel = math.radians(rider.max_lean_accel_deg)
        self.kp, self.kd = rider.trunk_stiffness, rider.trunk_damping
        self.max_torque = rider.max_hip_torque
        self.gravity = 9.80665 * hat_mass * hat_com
        self.lean_cmd = 0.0
        self.lean_rate_cmd = 0.0
        self.shift = 0.0
        """A sudden shift of the rider's weight (rad of lean), outside the rate limit (a fault). The body's
        mass still takes time to move: the shift comes in with the time constant SLIP_TIME."""
        self._shifted = 0.0

    def update(self, t: float, dt: float, speed: float) -> None:
        """Move the lean command toward the profile's target (once per tick)."""
        self._shifted += (self.shift - self._shifted) * (1.0 - math.exp(-dt / SLIP_TIME))
        target = math.radians(self.profile.target(t, speed, math.degrees(self.max_lean)))
        error = min(max(target, -self.max_lean), self.max_lean) - self.lean_cmd
        dv = self.max_accel * dt
        if abs(error) <= abs(self.lean_rate_cmd) * dt and abs(self.lean_rate_cmd) <= dv:
            self.lean_cmd += error  # arrived: at rest on the target
            self.lean_rate_cmd = 0.0
            return
        # The fastest rate from which the rider can still stop at the target braking tick by tick (the
        # discrete form of √(2 a |error|)), approached no faster than the acceleration limit allows.
        stop = dv * (math.sqrt(0.25 + 2.0 * abs(error) / (dv * dt)) - 0.5)
        wanted = math.copysign(min(self.max_rate, stop), error)
        self.lean_rate_cmd += min(max(wanted - self.lean_rate_cmd, -dv), dv)
        self.lean_cmd += self.lean_rate_cmd * dt

    def hip_torque(self, torso_angle: float, lean: float, lean_rate: float) -> float:
        """Hip torque on the torso: gravity compensation of the rider's own torso + PD, saturated."""
        u = (
            -self.gravity * math.sin(torso_angle)
            + self.kp * (self.lean_cmd + self._shifted - lean)
            + self.kd * (self.lean_rate_cmd - lean_rate)
        )
        return min(max(u, -self.max_torque), self.max_torque)

    def hip_feedforward(self, torso_angle: float) -> float:
        """hip_torque without its terms in the lean's state (the 3-D plant's engine adds −kp lean − kd lean
        rate and saturates; hip_torque keeps its own order of operations, which the planar runs' files
        depend on bit for bit)."""
        return (
            -self.gravity * math.sin(torso_angle)
            + self.kp * (self.lean_cmd + self._shifted)
            + self.kd * self.lean_rate_cmd
        )


class TwistController:
    """The rider's twisting moment on the seat, from a profile, bounded by capability."""

    def __init__(self, rider: RiderParams, profile: Profile):
        self.profile = profile
        self.max_torque = rider.max_twist_torque
        self.torque = 0.0

    def update(self, t: float) -> None:
        target = self.profile.target(t, 0.0, self.max_torque)
        self.torque = min(max(target, -self.max_torque), self.max_torque)
