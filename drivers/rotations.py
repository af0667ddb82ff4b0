"""Rotations and Euler angles, in one convention for every package: the plant, the supervisor and the rig's
outputs import them from here (drivers/ is the one room all of them may import; the plant only this module
and drivers.bounds, tests/test_boundaries.py).

The convention, ZYX (aerospace: yaw, then pitch, then roll about the turned axes):

    R = Rz(yaw) Ry(pitch) Rx(roll)        angles always in the order (roll, pitch, yaw), rad
    quaternion (w, x, y, z), unit         MuJoCo's order
    the heading frame                     the world turned to the chassis' heading: Ry(pitch) Rx(roll)

A function that turns a vector takes the vector first, then what turns it (a quaternion, or the angles).
Plain floats and tuples only: the plant's and the supervisor's ticks call these, compiled (setup.py).
tests/test_rotations.py checks them against scipy's Rotation and a finite difference.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
"""A unit quaternion (w, x, y, z)."""


def quaternion_zyx(roll: float, pitch: float, yaw: float) -> Quat:
    """Rz(yaw) Ry(pitch) Rx(roll) as a unit quaternion."""
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    return (
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )


def euler_zyx(q: Sequence[float]) -> Vec3:
    """(roll, pitch, yaw) of a unit quaternion: `quaternion_zyx` undone (pitch within ±π/2)."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(min(max(2.0 * (w * y - z * x), -1.0), 1.0))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def matrix_zyx(roll: float, pitch: float, yaw: float) -> tuple[Vec3, Vec3, Vec3]:
    """Rz(yaw) Ry(pitch) Rx(roll) as a rotation matrix, by rows."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


def euler_rates(rate: Sequence[float], roll: float, pitch: float) -> Vec3:
    """What the angles (roll, pitch, yaw) do at body rates `rate` (rad/s). A chassis tilted while it turns
    has body rates that differ from them by the turn rate times the tilt."""
    wx, wy, wz = rate
    sr, cr = math.sin(roll), math.cos(roll)
    turn = sr * wy + cr * wz
    return wx + turn * math.tan(pitch), cr * wy - sr * wz, turn / math.cos(pitch)


def rotate(v: Sequence[float], q: Sequence[float]) -> Vec3:
    """v turned by the unit quaternion q (q v q*)."""
    w, x, y, z = q
    vx, vy, vz = v
    # v + 2 w (u × v) + 2 u × (u × v), u = (x, y, z)
    cx, cy, cz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
    return (
        vx + 2.0 * (w * cx + y * cz - z * cy),
        vy + 2.0 * (w * cy + z * cx - x * cz),
        vz + 2.0 * (w * cz + x * cy - y * cx),
    )


def multiply(a: Sequence[float], b: Sequence[float]) -> Quat:
    """The rotation b, then a (Hamilton product a b)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def heading_frame(v: Sequence[float], roll: float, pitch: float) -> Vec3:
    """A body vector in the heading frame: Ry(pitch) Rx(roll) v."""
    bx, by, bz = v
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    u1, u2 = cr * by - sr * bz, sr * by + cr * bz
    return cp * bx + sp * u2, u1, -sp * bx + cp * u2


def body_frame(v: Sequence[float], roll: float, pitch: float) -> Vec3:
    """A heading-frame vector in body axes (`heading_frame` undone): Rx(−roll) Ry(−pitch) v."""
    hx, hy, hz = v
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    u0, u2 = cp * hx - sp * hz, sp * hx + cp * hz
    return u0, cr * hy + sr * u2, -sr * hy + cr * u2


def body_up(roll: float, pitch: float) -> Vec3:
    """The world's vertical in body axes (the heading frame's z seen from the chassis)."""
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    return -sp, cp * sr, cp * cr


def chassis_axis(roll: float, pitch: float) -> Vec3:
    """The chassis' own axis (body z) in the heading frame."""
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    return cr * sp, -sr, cr * cp
