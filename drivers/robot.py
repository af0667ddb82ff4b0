"""The robot file's parts that more than one package reads (configs/robot/*.toml), each field's default and
bound declared once.

`RobotModel` is what the controller and the supervisor read of a robot file: each decodes its own copy
from its own file (a controller may be given another robot file than the plant's, to test model mismatch),
into these records. The plant's `plant.params.RobotParams` extends each section with what only its physics
needs, and refuses unknown fields. Fields are positional-or-keyword, not keyword-only, so that a section
extended by the plant keeps these fields first, in the file's order.

Declarations only, like drivers/bounds.py: the plant imports it too (tests/test_boundaries.py).
"""

from __future__ import annotations

import msgspec

from drivers.bounds import (
    AzimuthDeg,
    BallInertia,
    BallMass,
    BallRadius,
    BodyInertia,
    BodyMass,
    ComHeight,
    CountsPerRev,
    CurrentLoopTau,
    GearRatio,
    ImuHeight,
    MotorSign,
    NoLoadSpeed,
    RotorInertia,
    SeatHeight,
    StallTorque,
    StreamTimeout,
    TopHeight,
    TorqueLimit,
    Viscous,
    WheelInertia,
    WheelRadius,
    WordBits,
    ZenithDeg,
)


class _Section(msgspec.Struct, frozen=True):
    """A part of a file written for several readers: a field another reader reads is ignored here."""


class Ball(_Section, frozen=True):
    radius: BallRadius = 0.1145
    """r_K, m."""
    mass: BallMass = 3.6
    """m_K, kg."""
    inertia: BallInertia = 0.047
    """Θ_K about the ball centre, kg m²."""


class Body(_Section, frozen=True):
    """Everything above the ball that is not the rider: chassis, drivetrain, seat, TES, battery, footrest."""

    mass: BodyMass = 30.0
    """kg."""
    com_height: ComHeight = 0.25
    """COM above the ball centre along the body axis, m."""
    inertia_pitch: BodyInertia = 0.5
    """About the COM, about body y, kg m²."""
    inertia_roll: BodyInertia = 0.5
    """About the COM, about body x, kg m²."""
    inertia_yaw: BodyInertia = 0.3
    """About the body axis, kg m²."""
    top_height: TopHeight = 0.386
    """h_P: point P (top centre of the chassis, TES origin) above the ball centre, m."""
    seat_height: SeatHeight = 0.03
    """Seat surface above P, m (the seat's COP is computed on it)."""
    imu_height: ImuHeight = 0.20
    """Body IMU above the ball centre on the body axis, m: its acceleration includes the chassis' rotation
    about the ball."""


class Drivetrain(_Section, frozen=True):
    wheel_radius: WheelRadius = 0.0625
    """r_W, m."""
    zenith_deg: ZenithDeg = 45.0
    """α: angle between the body z axis and the ball-centre-to-contact line, deg."""
    azimuth0_deg: AzimuthDeg = 0.0
    """β_0: azimuth of wheel 1 from body +x, deg; wheels follow at +120° and +240°."""
    motor_sign: tuple[MotorSign, MotorSign, MotorSign] = (1, 1, 1)
    """Per-motor direction: +1 when positive motor rotation is the positive wheel rate of the model."""
    gear_ratio: GearRatio = 8.0
    """N, motor turns per wheel turn."""
    wheel_inertia: WheelInertia = 0.0015
    """Omniwheel inertia at the wheel shaft, kg m²."""
    rotor_inertia: RotorInertia = 1.2e-4
    """Motor rotor inertia at the motor shaft, kg m²."""


class Drive(_Section, frozen=True):
    torque_limit: TorqueLimit = 3.75
    """Motor-shaft torque limit, Nm (× gear ratio at the wheel): the drive's current limit."""
    stall_torque: StallTorque = 16.3
    no_load_speed: NoLoadSpeed = 282.0
    """The motor's top speed: driving (torque and speed of one sign), the torque available falls from
    `stall_torque` at rest to 0 at `no_load_speed`, the back-EMF taking the bus voltage; braking, the whole
    `torque_limit` (plant/drives.py, docs/physics.md §3.6). A drive near its top speed makes less than it is
    told, and is not faulty for it (safety/diagnostics.py TorqueCheck)."""
    current_loop_tau: CurrentLoopTau = 0.0005  # the plant's alone: here so the file's order holds
    """First-order lag of the torque (current) loop, s."""
    watchdog_timeout: StreamTimeout = 0.02
    """The drive disables itself when no command arrives for this long, s (the supervisor's root-cause rule:
    it trips before the heartbeat's)."""
    permission_timeout: StreamTimeout = 0.05
    """The supervisor is lost when its SUPERVISOR_ESTOP frame (100 Hz) is silent this long, s: the
    controller then stops on its own (the drives follow it for their grace)."""


class Friction(_Section, frozen=True):
    rolling_viscous: Viscous = 0.75
    """b_φ: ball-floor rolling resistance, Nm s/rad on φ."""
    drivetrain_viscous: Viscous = 0.5
    """b_ψ: ball-equivalent drivetrain viscous friction, Nm s/rad on ψ = φ - θ."""


class Encoder(_Section, frozen=True):
    counts_per_rev: CountsPerRev = 8192
    """Quadrature counts per motor revolution."""
    word_bits: WordBits = 32
    """The count wraps as a signed integer of this width."""


class RobotModel(_Section, frozen=True, kw_only=True):
    """What the controller and the supervisor read of a robot file: its own model of the robot."""

    ball: Ball = Ball()
    body: Body = Body()
    drivetrain: Drivetrain = Drivetrain()
    drive: Drive = Drive()
    friction: Friction = Friction()
    encoder: Encoder = Encoder()
