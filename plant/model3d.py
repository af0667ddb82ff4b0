"""PURE + rider as a MuJoCo model (MJCF), written from the robot's and the rider's parameter records.

The robot is described once, as data: the same `RobotParams` and `RiderParams` the planar plant reads
become bodies, joints, actuators and sensors here, and MuJoCo simulates them (docs/physics.md §11).

- `ball`: a free rigid body on the floor (condim 6: sliding, spin and rolling friction; it slips past μN).
- `chassis`: on the ball by a ball joint (`drive`), three rotational degrees of freedom relative to the
  ball. The three omniwheel motors are actuators on that joint: motor i's gear is minus row i of the motor
  Jacobian G (docs/physics.md §3): MuJoCo applies +gear·ctrl to the chassis and the reaction to the ball,
  so a positive motor torque T_i turns the ball about +G_i relative to the chassis, and the actuator's
  velocity is the motor-shaft rate G_i·ω_rel the encoder counts.
- The rider's thighs and shanks ride with the chassis; the torso (HAT) is a body on the seat with two
  hinges at the hip (forward lean about y, then sideways lean about x), driven by the rider's hip torques
  and stopped where a seated adult's trunk stops bending (plant/anthropometry.py).
- Sensors: gyro, accelerometer and orientation at the IMU site on the chassis.
- The floor and every geom that touches it carry the same `solref`: MuJoCo mixes two geoms' values, so a
  floor left at its default would make the contact's time constant the mean of the two.

Per-degree-of-freedom values the MJCF has only one number for per joint (the drives' reflected inertia
differs between the tilt axes and yaw) are set on the compiled model by `apply_dof_parameters`; the drives'
friction, which depends on the joint's rate, by the plant before every step (plant/ballbot3d.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.bounds import G0
from drivers.rotations import matrix_zyx
from plant.anthropometry import (
    LEG_COM,
    TRUNK_EXTENSION_DEG,
    TRUNK_FLEXION_DEG,
    TRUNK_LATERAL_DEG,
    SeatedRider,
    Segment,
    robot_body_segment,
    seat_rider,
)
from plant.omniwheel import motor_jacobian, wheel_jacobian
from plant.params import MujocoParams, RiderParams, RobotParams

FLOOR, BALL, CHASSIS, TORSO = "floor", "ball", "chassis", "torso"
DRIVE_JOINT = "drive"
LEAN_JOINTS = ("lean_pitch", "lean_roll")
MOTORS = ("motor_1", "motor_2", "motor_3")
HIPS = ("hip_pitch", "hip_roll")
IMU_SITE, P_SITE = "imu", "P"
HOLDS = ("hold_ball", "hold_chassis")
"""Welds to the world, active while the robot is held (the clamped fixture's stand, the feet at rest)."""
FALL_GEOMS = ("chassis_rim", "foot_left", "foot_right")
"""Geoms other than the ball that may touch the floor only in a fall (docs/physics.md §11.3)."""
FOOT_RADIUS = 0.045
"""A shoe, as a capsule along the foot, m [EST]."""
FOOT_LENGTH = 0.26
"""Heel to toe, m [EST]."""
HEEL_SHARE = 0.25
"""The share of the foot's length behind the shank's axis [EST]."""
RIM_HALF_HEIGHT = 0.01
"""Half the height of the chassis' lowest rim, m."""
MAX_SINK = 0.01
"""m: the ball sinks less than this into the floor's soft contact under the robot and its rider (Plant3D
settles it within it before the first tick)."""

# Contact bits: the floor collides with the ball and with the fall geoms, nothing else collides.
_FLOOR_AFFINITY, _BALL_TYPE, _FALL_TYPE = 6, 2, 4


@dataclass(frozen=True, slots=True)
class ModelInfo:
    """What the plant needs to know of the model besides MuJoCo's own arrays."""

    xml: str
    seated: SeatedRider | None
    """The rider as seated (segments in the chassis frame); None without a rider."""
    motor_gear: tuple[tuple[float, float, float], ...]
    """Each motor's gear on the drive joint (−G_i)."""


def _f(*values: float) -> str:
    return " ".join(repr(float(v)) for v in values)


def _segment_body(name: str, s: Segment, geom: str) -> str:
    # A rigid segment of the chassis (no joint): its mass and inertia at its COM, a capsule to see it.
    return (
        f'<body name="{name}" pos="{_f(s.x, s.y, s.z)}">'
        f'<inertial pos="0 0 0" mass="{s.mass!r}" diaginertia="{_f(s.i_roll, s.i_pitch, s.i_yaw)}"/>'
        f"{geom}</body>"
    )


def build_model(robot: RobotParams, rider: RiderParams | None, engine: MujocoParams, dt: float) -> ModelInfo:
    """The MJCF of PURE with `rider` (None: the robot alone), `engine.steps_per_tick` steps a tick."""
    body, ball = robot.body, robot.ball
    r, top = ball.radius, body.top_height
    gear = -motor_jacobian(r, robot.drivetrain)
    gears = tuple((float(g[0]), float(g[1]), float(g[2])) for g in gear)
    h = dt / engine.steps_per_tick
    solref = f'solref="{_f(engine.contact_time_constant, 1.0)}"'

    rb = robot_body_segment(robot)
    drives = drive_inertia(robot)
    cx, cy, cz = drives.chassis
    chassis_inertial = (
        f'<inertial pos="{_f(rb.x, rb.y, rb.z)}" mass="{rb.mass!r}" '
        f'diaginertia="{_f(rb.i_roll + cx, rb.i_pitch + cy, rb.i_yaw + cz)}"/>'
    )
    ball_inertia = ball.inertia + drives.ball
    rim = (
        f'<geom name="chassis_rim" type="cylinder" size="{_f(body.chassis_radius, RIM_HALF_HEIGHT)}" '
        f'pos="0 0 {body.chassis_bottom!r}" contype="{_FALL_TYPE}" conaffinity="0" {solref} '
        f'friction="{_f(ball.floor_friction, 0.0, 0.0)}" condim="3" rgba="0.3 0.3 0.35 1"/>'
        f'<geom type="cylinder" size="{_f(body.chassis_radius, 0.5 * (top - body.chassis_bottom))}" '
        f'pos="0 0 {0.5 * (top + body.chassis_bottom)!r}" rgba="0.3 0.3 0.35 0.4"/>'
    )
    sites = (
        f'<site name="{IMU_SITE}" pos="0 0 {body.imu_height!r}"/><site name="{P_SITE}" pos="0 0 {top!r}"/>'
    )
    rider_bodies = ""
    hip_actuators = ""
    seated = None
    if rider is not None:
        seated = seat_rider(robot, rider)
        hat = seated.hat
        limbs = []
        for side, thigh, leg in zip(("left", "right"), seated.thighs, seated.legs, strict=True):
            limbs.append(
                _segment_body(
                    f"thigh_{side}",
                    thigh,
                    f'<geom type="capsule" size="0.07" rgba="0.2 0.3 0.6 1" '
                    f'fromto="{_f(seated.hip_x - thigh.x, 0, 0, leg.x - thigh.x, 0, 0)}"/>',
                )
            )
            knee_z, foot_z = _shank(seated, leg)
            heel, toe = _foot(0.0, 0.0, foot_z)  # in the shank's frame
            limbs.append(
                _segment_body(
                    f"shank_{side}",
                    leg,
                    f'<geom type="capsule" fromto="{_f(0, 0, knee_z, 0, 0, foot_z)}" size="0.05" '
                    f'rgba="0.2 0.3 0.6 1"/>'
                    f'<geom name="foot_{side}" type="capsule" '
                    f'fromto="{_f(*heel, *toe)}" '
                    f'size="{FOOT_RADIUS!r}" contype="{_FALL_TYPE}" conaffinity="0" {solref} condim="3" '
                    f'rgba="0.15 0.15 0.15 1"/>',
                )
            )
        torso = (
            f'<body name="{TORSO}" pos="{_f(seated.hip_x, 0, seated.hip_z)}">'
            f'<joint name="{LEAN_JOINTS[0]}" type="hinge" axis="0 1 0" '
            f'range="{_f(-math.radians(TRUNK_EXTENSION_DEG), math.radians(TRUNK_FLEXION_DEG))}"/>'
            f'<joint name="{LEAN_JOINTS[1]}" type="hinge" axis="1 0 0" '
            f'range="{_f(-math.radians(TRUNK_LATERAL_DEG), math.radians(TRUNK_LATERAL_DEG))}"/>'
            f'<inertial pos="0 0 {hat.com_distance!r}" mass="{hat.mass!r}" '
            f'diaginertia="{_f(hat.i_roll, hat.i_pitch, hat.i_yaw)}"/>'
            f'<geom type="capsule" fromto="0 0 0.05 0 0 {2.0 * hat.com_distance!r}" size="0.13" '
            f'rgba="0.8 0.5 0.3 1"/></body>'
        )
        rider_bodies = "".join(limbs) + torso
        limit = rider.max_hip_torque
        hip_actuators = "".join(
            f'<general name="{name}" joint="{joint}" gainprm="1" biastype="affine" '
            f'biasprm="{_f(0.0, -rider.trunk_stiffness, -rider.trunk_damping)}" '
            f'forcelimited="true" forcerange="{_f(-limit, limit)}"/>'
            for name, joint in zip(HIPS, LEAN_JOINTS, strict=True)
        )
    motors = "".join(
        f'<motor name="{name}" joint="{DRIVE_JOINT}" gear="{_f(*g, 0, 0, 0)}"/>'
        for name, g in zip(MOTORS, gears, strict=True)
    )
    xml = f"""<mujoco model="{robot.name}">
  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>
  <option timestep="{h!r}" gravity="0 0 {-G0!r}" integrator="{engine.integrator}" cone="elliptic"
          impratio="{engine.impratio!r}" jacobian="dense">
    <flag energy="enable"/>
  </option>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <geom name="{FLOOR}" type="plane" size="0 0 1" contype="0" conaffinity="{_FLOOR_AFFINITY}"
          friction="0 0 0" {solref} rgba="0.8 0.8 0.8 1"/>
    <body name="{BALL}" pos="0 0 {r!r}">
      <freejoint name="{BALL}"/>
      <inertial pos="0 0 0" mass="{ball.mass!r}" diaginertia="{_f(*(ball_inertia,) * 3)}"/>
      <geom name="{BALL}" type="sphere" size="{r!r}" contype="{_BALL_TYPE}" conaffinity="0" condim="6"
            friction="{_f(ball.floor_friction, ball.spin_friction, ball.roll_friction)}" {solref}
            rgba="0.9 0.4 0.1 1"/>
      <body name="{CHASSIS}">
        <joint name="{DRIVE_JOINT}" type="ball"/>
        {chassis_inertial}{rim}{sites}{rider_bodies}
      </body>
    </body>
  </worldbody>
  <equality>
    <weld name="{HOLDS[0]}" body1="{BALL}" active="false" {solref}/>
    <weld name="{HOLDS[1]}" body1="{CHASSIS}" active="false" {solref}/>
  </equality>
  <actuator>{motors}{hip_actuators}</actuator>
  <sensor>
    <gyro name="gyro" site="{IMU_SITE}"/>
    <accelerometer name="accelerometer" site="{IMU_SITE}"/>
    <framequat name="attitude" objtype="site" objname="{IMU_SITE}"/>
  </sensor>
</mujoco>
"""
    return ModelInfo(xml, seated, gears)


def _shank(seated: SeatedRider, leg: Segment) -> tuple[float, float]:
    """The knee's and the foot's heights relative to the shank's COM: the shank hangs from the knee (at hip
    height: the thigh is horizontal) to the foot, which points forward."""
    knee_z = seated.hip_z - leg.z
    return knee_z, knee_z - knee_z / LEG_COM


Vec = tuple[float, float, float]


def _foot(x: float, y: float, z: float) -> tuple[Vec, Vec]:
    """A foot's capsule, heel to toe, with its ankle at (x, y, z)."""
    return (x - HEEL_SHARE * FOOT_LENGTH, y, z), (x + (1.0 - HEEL_SHARE) * FOOT_LENGTH, y, z)


@dataclass(frozen=True, slots=True)
class FallGeom:
    """One of FALL_GEOMS in the chassis' frame (origin at the ball's centre): a capsule (a segment and its
    radius) or a cylinder with flat ends (its axis and its radius)."""

    name: str
    ends: tuple[Vec, Vec]
    radius: float
    capsule: bool

    def lowest(self, rotation: np.ndarray) -> float:
        """The height of its lowest point above the ball's centre with the chassis turned by `rotation`."""
        a, b = (rotation @ np.asarray(end) for end in self.ends)
        if self.capsule:
            return float(min(a[2], b[2])) - self.radius
        # A flat end's lowest point: its centre, down by the radius times the sine of its tilt.
        axis_z = (b[2] - a[2]) / float(np.linalg.norm(b - a))
        return float(min(a[2], b[2])) - self.radius * math.sqrt(max(0.0, 1.0 - axis_z * axis_z))


def fall_geoms(robot: RobotParams, rider: RiderParams | None) -> tuple[FallGeom, ...]:
    """The geoms build_model gives FALL_GEOMS' names, where it puts them."""
    body = robot.body
    bottom = body.chassis_bottom
    rim_ends = ((0.0, 0.0, bottom - RIM_HALF_HEIGHT), (0.0, 0.0, bottom + RIM_HALF_HEIGHT))
    geoms = [FallGeom("chassis_rim", rim_ends, body.chassis_radius, capsule=False)]
    if rider is not None:
        seated = seat_rider(robot, rider)
        for side, leg in zip(("left", "right"), seated.legs, strict=True):
            foot = _foot(leg.x, leg.y, leg.z + _shank(seated, leg)[1])
            geoms.append(FallGeom(f"foot_{side}", foot, FOOT_RADIUS, capsule=True))
    return tuple(geoms)


def lowest_fall_geom(
    robot: RobotParams, rider: RiderParams | None, pitch: float, roll: float
) -> tuple[str, float]:
    """With the chassis at the tilt (pitch, roll), rad, the fall geom nearest the floor and its height above
    it, m, the ball sunk MAX_SINK into the floor: at 0 or below it may touch the floor, which the 3-D plant
    counts as a fall (Plant3D._check_fall)."""
    rotation = np.array(matrix_zyx(roll, pitch, 0.0))  # the chassis released at that tilt
    centre = robot.ball.radius - MAX_SINK
    return min(
        ((g.name, centre + g.lowest(rotation)) for g in fall_geoms(robot, rider)), key=lambda found: found[1]
    )


def releasable_share(robot: RobotParams, rider: RiderParams | None, pitch: float, roll: float) -> float:
    """The largest share s of the tilt (pitch, roll) at which every fall geom is off the floor (1 if the
    whole of it is; to 1e-4): the robot can be released from (s pitch, s roll)."""
    if lowest_fall_geom(robot, rider, pitch, roll)[1] > 0.0:
        return 1.0
    low, high = 0.0, 1.0  # upright, every fall geom is off the floor (RobotParams checks the rim's place)
    while high - low > 1e-4:
        mid = 0.5 * (low + high)
        if lowest_fall_geom(robot, rider, mid * pitch, mid * roll)[1] > 0.0:
            low = mid
        else:
            high = mid
    return low


@dataclass(frozen=True, slots=True)
class DriveInertia:
    """Where the drives' inertia goes in the model (docs/physics.md §11.2), kg m².

    The planar model's drives are a wheel of inertia Θ_W per plane turning at ρψ̇ − θ̇ (docs/physics.md §3.4):
    their kinetic energy is ½ J_act (ρ ω_rel − ω_c)ᵀ D (ρ ω_rel − ω_c), D = diag(3/2 cos²α, 3/2 cos²α,
    3 sin²α), ω_c the chassis' and ω_rel the ball's rotation relative to it, in the chassis frame. MuJoCo
    has no body that turns at ρ ω_rel − ω_c, so the energy is split over three places whose sum is it:
    an isotropic inertia f on the ball (which turns at ω_c + ω_rel) makes the cross term, the chassis and
    the drive joint's armature take the rest. Exact in the tilt axes; about yaw the cross term is half the
    planar model's (below 1 % of the yaw inertia)."""

    ball: float
    """Added to the ball's inertia (negative: f = −ρ J_act D_xx)."""
    chassis: tuple[float, float, float]
    """Added to the chassis' principal inertias (x, y, z)."""
    armature: tuple[float, float, float]
    """The drive joint's armature per axis (x, y, z)."""


def drive_inertia(robot: RobotParams) -> DriveInertia:
    dt = robot.drivetrain
    j_act = dt.wheel_inertia + dt.gear_ratio**2 * dt.rotor_inertia
    j = wheel_jacobian(robot.ball.radius, dt)
    rho = robot.ball.radius / dt.wheel_radius
    diag = (np.diag(j.T @ j) / (rho * rho)).tolist()  # D
    f = -rho * j_act * diag[0]
    chassis = tuple(j_act * v - f for v in diag)
    armature = tuple(rho * rho * j_act * v - f for v in diag)
    return DriveInertia(f, (chassis[0], chassis[1], chassis[2]), (armature[0], armature[1], armature[2]))


def apply_dof_parameters(model: object, robot: RobotParams) -> None:
    """The drive joint's armature and the ball's rolling resistance, on the compiled model. The drives'
    friction is not MuJoCo's per-axis `frictionloss` (a box, √2 times as strong on a diagonal): Plant3D sets
    it as the drive joint's damping before every step (DriveFriction)."""
    import mujoco

    m = model
    assert isinstance(m, mujoco.MjModel)
    f = robot.friction
    drive = m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, DRIVE_JOINT)]
    ball = m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, BALL)]
    m.dof_armature[drive : drive + 3] = drive_inertia(robot).armature
    # Rolling resistance b_φ on the ball's rotation (its free joint's angular dofs, 3..5).
    m.dof_damping[ball + 3 : ball + 6] = f.rolling_viscous
