"""Seated rider as rigid segments (Winter 2009 fractions), placed on the robot's body frame.

Body frame: origin at the ball centre, x forward, y left, z up along the body axis. The rider sits with
thighs horizontal along +x, shanks vertical down to the footrest, HAT (head-arms-trunk) upright over the
hip. Lower limbs move with the chassis and are lumped into it; the HAT is its own body, hinged at the hip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from plant.params import RiderParams, RobotParams

# Winter (2009) Table 4.1, via docs/physics.md §5.1: mass fraction, COM from proximal end / length,
# radius of gyration about the COM / length, length / standing height.
HAT_MASS, HAT_COM, HAT_GYR, HAT_LEN = 0.678, 0.626, 0.496, 0.288
THIGH_MASS, THIGH_COM, THIGH_GYR, THIGH_LEN = 0.100, 0.433, 0.323, 0.245
LEG_MASS, LEG_COM, LEG_GYR, LEG_LEN = 0.061, 0.606, 0.416, 0.246
# de Leva (1996): longitudinal radius of gyration of the trunk / trunk length, trunk length / height.
TRUNK_LONG_GYR, TRUNK_LEN = 0.191, 0.3055
# About its own long axis a limb segment is slender: radius of gyration ≈ 0.15 × length [EST].
LIMB_LONG_GYR = 0.15
# How far a seated adult's trunk bends at the hip and the lumbar spine, deg [OTHER: Troke et al. 2005,
# Manual Therapy 10(3), 405 adults: lumbar flexion 73 -> 40, extension 29 -> 6, lateral flexion 28 -> 14 per
# side from age 16 to 90; the young adults' values, as the hinge's hard stops].
TRUNK_FLEXION_DEG, TRUNK_EXTENSION_DEG, TRUNK_LATERAL_DEG = 70.0, 25.0, 28.0
HIP_ABOVE_SEAT = 0.09
"""Hip joint centre above the seat surface, m [EST, docs/physics.md §5.2]."""


@dataclass(frozen=True, slots=True)
class Segment:
    """A rigid segment in the body frame: mass, COM (x, y, z), inertias about its COM."""

    mass: float
    x: float
    y: float
    z: float
    i_pitch: float
    i_roll: float
    i_yaw: float


@dataclass(frozen=True, slots=True)
class Hat:
    """The torso (HAT) hinged at the hip: COM distance along the torso axis and inertias about the COM."""

    mass: float
    com_distance: float
    i_pitch: float
    i_roll: float
    i_yaw: float


@dataclass(frozen=True, slots=True)
class SeatedRider:
    hat: Hat
    hip_x: float
    hip_z: float
    thighs: tuple[Segment, Segment]
    legs: tuple[Segment, Segment]

    @property
    def lower_limbs(self) -> tuple[Segment, ...]:
        return self.thighs + self.legs

    def hat_segment(self) -> Segment:
        """The HAT upright, as a segment of the body frame."""
        h = self.hat
        return Segment(h.mass, self.hip_x, 0.0, self.hip_z + h.com_distance, h.i_pitch, h.i_roll, h.i_yaw)


def seat_rider(robot: RobotParams, rider: RiderParams) -> SeatedRider:
    m, height = rider.mass, rider.height
    hip_z = robot.body.top_height + robot.body.seat_height + HIP_ABOVE_SEAT

    hat_len = HAT_LEN * height
    hat_m = HAT_MASS * m
    i_hat = hat_m * (HAT_GYR * hat_len) ** 2
    hat = Hat(hat_m, HAT_COM * hat_len, i_hat, i_hat, hat_m * (TRUNK_LONG_GYR * TRUNK_LEN * height) ** 2)

    thigh_len, leg_len = THIGH_LEN * height, LEG_LEN * height
    thigh_m, leg_m = THIGH_MASS * m, LEG_MASS * m
    # Offsets of the lower-limb COMs from the hip (x forward, z up).
    thigh_dx, thigh_dz = THIGH_COM * thigh_len, 0.0
    leg_dx, leg_dz = thigh_len, -LEG_COM * leg_len
    if rider.hip_x is None:
        # Seat placed so that the upright rider's COM lies on the ball axis (the robot body's COM is on it).
        # The HAT, thigh and leg fractions sum to 1, so the rider's COM is m-weighted over them.
        hip_x = -2.0 * (thigh_m * thigh_dx + leg_m * leg_dx) / m
    else:
        hip_x = rider.hip_x

    thigh_tr = thigh_m * (THIGH_GYR * thigh_len) ** 2
    thigh_long = thigh_m * (LIMB_LONG_GYR * thigh_len) ** 2
    leg_tr = leg_m * (LEG_GYR * leg_len) ** 2
    leg_long = leg_m * (LIMB_LONG_GYR * leg_len) ** 2
    w = rider.hip_half_width
    # Thighs lie along x: pitch and yaw are transverse axes, roll is the long axis. Legs stand along z.
    thighs = (
        Segment(thigh_m, hip_x + thigh_dx, w, hip_z + thigh_dz, thigh_tr, thigh_long, thigh_tr),
        Segment(thigh_m, hip_x + thigh_dx, -w, hip_z + thigh_dz, thigh_tr, thigh_long, thigh_tr),
    )
    legs = (
        Segment(leg_m, hip_x + leg_dx, w, hip_z + leg_dz, leg_tr, leg_tr, leg_long),
        Segment(leg_m, hip_x + leg_dx, -w, hip_z + leg_dz, leg_tr, leg_tr, leg_long),
    )
    return SeatedRider(hat, hip_x, hip_z, thighs, legs)


def robot_body_segment(robot: RobotParams) -> Segment:
    b = robot.body
    return Segment(b.mass, 0.0, 0.0, b.com_height, b.inertia_pitch, b.inertia_roll, b.inertia_yaw)


@dataclass(frozen=True, slots=True)
class Composite:
    """Rigid composite in one plane: mass, COM (forward, up) in the plane, inertia about the COM."""

    mass: float
    forward: float
    up: float
    inertia: float

    @property
    def distance(self) -> float:
        """Distance of the COM from the ball centre, m."""
        return math.hypot(self.forward, self.up)

    @property
    def offset_angle(self) -> float:
        """Angle of the COM from the body axis toward the plane's forward direction, rad."""
        return math.atan2(self.forward, self.up)


def composite(segments: tuple[Segment, ...] | list[Segment], plane: str) -> Composite:
    """Lump segments into one rigid body for the pitch plane (forward = x) or the roll plane (forward = -y).

    The roll plane's generalised coordinates are rotations about +x, which move the top toward -y.
    """
    if plane == "pitch":
        fwd = [s.x for s in segments]
        own = [s.i_pitch for s in segments]
    elif plane == "roll":
        fwd = [-s.y for s in segments]
        own = [s.i_roll for s in segments]
    else:
        raise ValueError(f"plane must be 'pitch' or 'roll', got {plane!r}")
    mass = sum(s.mass for s in segments)
    f_c = sum(s.mass * f for s, f in zip(segments, fwd, strict=True)) / mass
    z_c = sum(s.mass * s.z for s in segments) / mass
    inertia = sum(
        i + s.mass * ((f - f_c) ** 2 + (s.z - z_c) ** 2) for s, f, i in zip(segments, fwd, own, strict=True)
    )
    return Composite(mass, f_c, z_c, inertia)


def yaw_inertia(segments: tuple[Segment, ...] | list[Segment]) -> float:
    """Inertia about the body z axis through the ball centre, kg m²."""
    return sum(s.i_yaw + s.mass * (s.x**2 + s.y**2) for s in segments)
