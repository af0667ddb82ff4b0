"""The reference controller's configuration: its own view of the robot, the rider, and its tuning.

A real controller carries its own model, so this package decodes the robot and rider files itself (only
the fields it needs: the robot file's `drivers.robot.RobotModel`; the rest of those files is ignored) and
never imports the plant. A model that differs from the plant's truth is set up by pointing the controller at
a different robot file.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from drivers.bounds import (
    NonNegative,
    Positive,
    RiderHeight,
)


class _Lenient(msgspec.Struct, frozen=True, kw_only=True):
    """Decodes a subset of a file written for someone else: unknown fields are ignored."""


class _Strict(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pass


# ---------------------------------------------------------------------------- the rider, as it is told


class RiderInfo(_Lenient, frozen=True):
    """What the controller is told about the rider: a name (for the sensitivity profile) and a height.
    The weight is measured on the seat while parked (iHACS)."""

    name: str = "unknown"
    height: RiderHeight = 1.80


# ----------------------------------------------------------------------------------------------- tuning
class Lqr(_Strict, frozen=True):
    q_tilt: Positive = 100.0
    """Weight on θ (rad)."""
    q_tilt_rate: Positive = 10.0
    """Weight on θ̇ (rad/s)."""
    q_ball_rate: Positive = 1.0
    """Weight on φ̇ − φ̇_c (rad/s). There is no weight on φ: no position hold."""
    r_torque: Positive = 0.1
    """Weight on the ball torque (Nm)."""


class SpeedPi(_Strict, frozen=True):
    kp: NonNegative = 3.0
    """Nm per rad/s of ball-rate error against the reference model."""
    ki: NonNegative = 15.0
    """Nm per rad of integrated ball-rate error."""
    integral_limit: Positive = 20.0
    """|τ_e| the integrator may hold, Nm."""


class Hacs(_Strict, frozen=True):
    """Command speed (docs/physics.md §8): tared seat moment -> deadband -> gain -> mass-damper -> limits."""

    filter_hz: Positive = 8.0
    """Low-pass on the tared TES moments."""
    deadband: NonNegative = 3.0
    """Nm of tared moment ignored (≈ 1-2° of lean)."""
    gain: Positive = 0.05
    """Steady speed per Nm beyond the deadband, m/s/Nm (k / D_v)."""
    time_constant: Positive = 0.4
    """M_v / D_v of the virtual mass-damper, s."""
    max_speed: Positive = 2.3
    max_accel: Positive = 1.5
    yaw_deadband: NonNegative = 2.0
    yaw_gain: NonNegative = 0.1
    """rad/s per Nm of twist beyond the deadband."""
    max_yaw_rate: Positive = 1.5


class Ihacs(_Strict, frozen=True):
    planes: tuple[Literal["pitch", "roll"], ...] = ("pitch", "roll")
    """Planes with interaction compensation (the paper applied it to the sagittal plane)."""
    personalise_gains: bool = True
    seat_mass_fraction: Annotated[float, msgspec.Meta(gt=0.3, le=1.0)] = 0.878
    """Share of body mass the seat carries (torso + thighs, Winter): weight = −Fz / (g × this)."""


class Timing(_Strict, frozen=True):
    tick_hz: Positive = 400.0
    tare_time: Positive = 0.5
    """Taring (and weighing) the seat at start, with the command speed held at 0, s."""
    sensor_hold: Positive = 0.02
    """Hold the last good IMU/encoder value this long, then fault, s."""
    tes_hold: Positive = 0.1
    """Without fresh seat data this long, the rider's input is treated as zero, s."""
    sc_max_age: Positive = 0.5
    """An SC command older than this (controller time) falls back to idle, s."""


class RiderProfile(_Strict, frozen=True):
    """Per-rider sensitivity (the paper's riders each tuned theirs)."""

    deadband: NonNegative | None = None
    gain: Positive | None = None
    time_constant: Positive | None = None
    yaw_gain: NonNegative | None = None


class ControllerConfig(_Strict, frozen=True):
    mode: Literal["hacs", "ihacs"] = "hacs"
    reference_rider_mass: Positive = 60.0
    reference_rider_height: Positive = 1.80
    """HACS (and iHACS until the rider is weighed) use the gains of this rider for everyone."""
    auto_enable: bool = True
    """Start balancing at start-up without an explicit enable (never again after an e-stop)."""
    lqr: Lqr = Lqr()
    pi: SpeedPi = SpeedPi()
    hacs: Hacs = Hacs()
    ihacs: Ihacs = Ihacs()
    timing: Timing = Timing()
    riders: dict[str, RiderProfile] = {}

    def hacs_for(self, rider: str) -> Hacs:
        profile = self.riders.get(rider)
        if profile is None:
            return self.hacs
        overrides = {k: v for k, v in msgspec.structs.asdict(profile).items() if v is not None}
        return msgspec.structs.replace(self.hacs, **overrides)
