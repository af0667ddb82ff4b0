"""Typed parameter records of the plant: robot, rider and simulation settings.

Plain msgspec Structs (data only, no I/O): the rig decodes them from TOML under `configs/`, tests build
them in code. Every field is SI unless its name says otherwise (`_deg`, `_hz`). Sources and estimates
for the defaults are in `docs/plant.md` and `docs/physics.md` §6.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec

import drivers.robot as robot_file
from drivers.bounds import (
    AccelBiasSigma,
    AccelBiasWalk,
    AccelNoiseDensity,
    AttitudeNoiseDeg,
    AzimuthDeg,
    CalibrationError,
    CellNoise,
    CellRadius,
    CellRange,
    ChassisBottom,
    ChassisRadius,
    ContactorTimeout,
    DryFriction,
    FloorFriction,
    GyroBiasSigma,
    GyroBiasWalk,
    GyroNoiseDensity,
    HipHalfWidth,
    HipTorque,
    HipX,
    LeanAccelDeg,
    LeanDeg,
    LeanRateDeg,
    Positive,
    ReactionTime,
    RiderHeight,
    RiderMass,
    RollFriction,
    SensorRateHz,
    SpinFriction,
    StickVelocity,
    SupervisorLostGrace,
    TorqueNoise,
    TrunkDamping,
    TrunkStiffness,
    TwistTorque,
    VelocityNoise,
    Viscous,
)


class _Record(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Immutable, strict record: an unknown key in a config file is a typo, not an extension."""


# --------------------------------------------------------------------------------------------- robot
# Each section extends the one every package reads (drivers/robot.py: its fields, defaults and bounds) with
# what only the plant's physics needs, and refuses unknown fields: here a key nobody reads is a typo.
class Ball(robot_file.Ball, frozen=True, forbid_unknown_fields=True, kw_only=True):
    floor_friction: FloorFriction = 0.8
    """μ: ball-floor sliding friction coefficient (3-D plant: the ball slips past μ N)."""
    spin_friction: SpinFriction = 0.01
    """Ball-floor torsional friction, m: the contact holds a spin torque up to this times the normal force
    (3-D plant; about (2/3) μ a for a contact patch of radius a)."""
    roll_friction: RollFriction = 0.0
    """Ball-floor dry rolling friction, m (3-D plant; the viscous `friction.rolling_viscous` is the
    rolling resistance both plants share)."""


class Body(robot_file.Body, frozen=True, forbid_unknown_fields=True, kw_only=True):
    chassis_radius: ChassisRadius = 0.20
    """Radius of the chassis' lowest rim, m (3-D plant: touching the floor with it is a fall)."""
    chassis_bottom: ChassisBottom = 0.05
    """Height of that rim above the ball centre, m."""

    def __post_init__(self) -> None:
        # A rigid body's principal inertias obey the triangle inequality (each at most the sum of the others).
        i = (self.inertia_pitch, self.inertia_roll, self.inertia_yaw)
        if 2.0 * max(i) > sum(i):
            raise ValueError(
                f"inertia_pitch, inertia_roll, inertia_yaw = {i}: no rigid body has them (each must be at "
                "most the sum of the other two)"
            )


class Drivetrain(robot_file.Drivetrain, frozen=True, forbid_unknown_fields=True, kw_only=True):
    pass


class Drive(robot_file.Drive, frozen=True, forbid_unknown_fields=True, kw_only=True):
    supervisor_lost_grace: SupervisorLostGrace = 30.0
    """s the drives go on following the controller once the supervisor is lost (its frame silent, not an
    e-stop): cutting power in motion tips a ballbot, and the controller, which sees the silence too, brakes
    to rest and turns them off itself (docs/contract.md). Then off whatever the controller does."""
    contactor_timeout: ContactorTimeout = 0.1
    """The main contactor opens when SUPERVISOR_ESTOP has been silent this long after the drives' grace, s:
    the second channel, slower than the drives' own so that the first acts first."""
    torque_noise: TorqueNoise = 0.005
    """1σ of the measured-torque feedback, Nm."""
    velocity_noise: VelocityNoise = 0.05
    """1σ of the motor velocity feedback, rad/s."""

    def __post_init__(self) -> None:
        if self.stall_torque < self.torque_limit:
            raise ValueError(
                f"stall_torque = {self.stall_torque} Nm is below torque_limit = {self.torque_limit} Nm: the "
                "current limit could never be reached (stall_torque must be at least torque_limit)"
            )


class Friction(robot_file.Friction, frozen=True, forbid_unknown_fields=True, kw_only=True):
    drivetrain_coulomb: DryFriction = 1.5
    """τ_c: ball-equivalent kinetic (Coulomb) friction, Nm."""
    drivetrain_stiction: DryFriction = 2.0
    """τ_s: breakaway torque; ψ stays stuck while the torque needed to hold it is below this, Nm."""
    stick_velocity: StickVelocity = 0.01
    """|ψ̇| below which the drivetrain may stick, rad/s (Karnopp band)."""
    yaw_viscous: Viscous = 0.5
    """b_z: ball-body relative yaw viscous friction, Nm s/rad."""
    yaw_coulomb: DryFriction = 0.5
    """Yaw kinetic friction, Nm."""
    yaw_stiction: DryFriction = 0.8
    """Yaw breakaway torque, Nm."""

    def __post_init__(self) -> None:
        if self.drivetrain_stiction < self.drivetrain_coulomb:
            raise ValueError("drivetrain_stiction must be >= drivetrain_coulomb (breakaway exceeds kinetic)")
        if self.yaw_stiction < self.yaw_coulomb:
            raise ValueError("yaw_stiction must be >= yaw_coulomb (breakaway exceeds kinetic)")


class Encoder(robot_file.Encoder, frozen=True, forbid_unknown_fields=True, kw_only=True):
    pass


class Imu(_Record, frozen=True):
    rate_hz: SensorRateHz = 400.0
    gyro_noise_density: GyroNoiseDensity = 6.1e-5
    """rad/s/√Hz (VN-100 class)."""
    accel_noise_density: AccelNoiseDensity = 1.37e-3
    """m/s²/√Hz (VN-100 class)."""
    gyro_bias_sigma: GyroBiasSigma = 1e-4
    """1σ of the turn-on gyro bias, rad/s."""
    gyro_bias_walk: GyroBiasWalk = 1e-5
    """Gyro bias random walk, rad/s/√s."""
    accel_bias_sigma: AccelBiasSigma = 0.02
    """1σ of the turn-on accelerometer bias, m/s²."""
    accel_bias_walk: AccelBiasWalk = 5e-5
    """Accelerometer bias random walk, m/s²/√s (m/s³/√Hz)."""
    attitude_noise_deg: AttitudeNoiseDeg = 0.05
    """1σ white noise of the AHRS attitude output, deg."""


class Tes(_Record, frozen=True):
    """Force-sensing seat: six uniaxial load cells (three vertical, three tangential) under the seat plate."""

    rate_hz: SensorRateHz = 400.0
    cell_radius: CellRadius = 0.12
    """Radius of the circle of load cells around P, m."""
    cell_azimuth0_deg: AzimuthDeg = 90.0
    """Azimuth of the first pair of cells from body +x, deg; the others at +120°, +240°."""
    cell_noise: CellNoise = 0.5
    """1σ white noise per load cell, N."""
    cell_range: CellRange = 2000.0
    """Each cell's full scale, N: a reading saturates there (a fall's impact, a hard push) [EST: a 200 kg
    cell, four times the share of a 150 kg rider's weight each vertical cell carries]."""
    calibration_error: CalibrationError = 0.0
    """Relative 1σ error of each entry of the calibration matrix (0: perfect calibration)."""


class RobotParams(_Record, frozen=True):
    name: str = "PURE"
    ball: Ball = Ball()
    body: Body = Body()
    drivetrain: Drivetrain = Drivetrain()
    drive: Drive = Drive()
    friction: Friction = Friction()
    encoder: Encoder = Encoder()
    imu: Imu = Imu()
    tes: Tes = Tes()

    def __post_init__(self) -> None:
        r, w = self.ball.radius, self.drivetrain.wheel_radius
        alpha = math.radians(self.drivetrain.zenith_deg)
        # Wheel centres sit r + r_W from the ball's centre at the zenith angle, 120° apart: neighbours are
        # √3 (r + r_W) sin α apart, and two wheels of radius r_W closer than 2 r_W run into each other.
        gap = math.sqrt(3.0) * (r + w) * math.sin(alpha)
        if gap < 2.0 * w:
            raise ValueError(
                f"ball.radius {r:g} m is too small for drivetrain.wheel_radius {w:g} m at zenith_deg "
                f"{self.drivetrain.zenith_deg:g}: the wheels' centres are {gap:.3f} m apart, under the "
                f"{2.0 * w:.3f} m two wheels need"
            )
        if (
            math.hypot(self.body.chassis_radius, self.body.chassis_bottom) <= r
            or self.body.chassis_bottom <= -r
        ):
            raise ValueError(
                f"body.chassis_radius {self.body.chassis_radius:g} m and chassis_bottom "
                f"{self.body.chassis_bottom:g} m put the chassis' rim inside the ball or under the floor"
            )


# --------------------------------------------------------------------------------------------- rider
class RiderParams(_Record, frozen=True):
    """A seated rider: anthropometry (Winter fractions of mass and height) and torso capability."""

    name: str
    mass: RiderMass
    """Body mass, kg."""
    height: RiderHeight
    """Standing height, m."""
    max_lean_deg: LeanDeg = 30.0
    """Largest torso lean relative to the chassis the rider can reach, deg (fore-aft and sideways)."""
    max_hip_torque: HipTorque = 150.0
    """Largest hip torque the rider can produce on the torso, Nm."""
    max_twist_torque: TwistTorque = 20.0
    """Largest twisting moment the rider can put on the seat, Nm."""
    max_lean_rate_deg: LeanRateDeg = 40.0
    """Fastest change of the intended lean, deg/s."""
    lean_amplitude_deg: LeanDeg = 25.0
    """How far this rider leans, relative to the chassis, when a trial asks them to lean as far as they can
    (an `until` segment without its own amplitude), deg, clipped to max_lean_deg. Default from the paper's
    Table II (docs/riders.md)."""
    lean_rate_deg: LeanRateDeg = 4.0
    """How fast this rider leans in such a trial, deg/s. Default from the paper's Table II and Fig. 4
    (docs/riders.md)."""
    alert_reaction_time: ReactionTime = 1.0
    """s from the supervisor's alert to this rider starting to sit up, when the scenario's rider heeds it:
    a driver's brake reaction to an expected signal is ~0.7 s, to an unexpected but common one ~1.25 s
    (Green 2000; docs/riders.md)."""
    max_lean_accel_deg: LeanAccelDeg = 400.0
    """Fastest change of the intended lean's rate, deg/s² [EST]: a trunk cannot change its angular velocity
    at once (40 deg/s is reached in 0.1 s), so the hip torque and the seat's load change smoothly."""
    trunk_stiffness: TrunkStiffness = 800.0
    """Proportional gain of the rider's lean control, Nm/rad."""
    trunk_damping: TrunkDamping = 120.0
    """Derivative gain of the rider's lean control, Nm s/rad."""
    hip_x: HipX | None = None
    """Hip joint along body x from the ball axis, m; None places the seat so that the upright
    rider + robot COM lies over the ball."""
    hip_half_width: HipHalfWidth = 0.085
    """Half the distance between the hip joint centres, m."""
    notes: str = ""


# ----------------------------------------------------------------------------------------------- sim
class MujocoParams(_Record, frozen=True):
    """How the 3-D plant's engine steps (docs/plant.md, Numerics)."""

    steps_per_tick: Annotated[int, msgspec.Meta(ge=1, le=100)] = 2
    """MuJoCo steps per bus tick (the drives' and the rider's torques are held over a tick)."""
    contact_time_constant: Positive = 0.005
    """Time constant of the ball-floor contact, s (MuJoCo's solref; at least two steps)."""
    integrator: Literal["implicitfast", "implicit", "Euler"] = "implicitfast"
    """MuJoCo's integrator (its option of that name). Each integrates damping implicitly, which the drives'
    friction needs (its stuck band is a stiff damper); RK4 does not, and the plant's first step of a tick
    reuses the last tick's forward pass, which MuJoCo's RK4 cannot."""
    impratio: Annotated[float, msgspec.Meta(ge=1)] = 10.0
    """Ratio of frictional to normal constraint impedance: higher holds the rolling contact tighter."""


class SimParams(_Record, frozen=True):
    tick_hz: Positive = 400.0
    """Bus tick: rate of sensor frames and SYNC."""
    plant: str = "3d"
    """An installed plant (entry points `pure_hil.plants`, hil/run/plants.py): 3d, rigid bodies in MuJoCo
    (plant/ballbot3d.py); planar, two vertical planes and yaw (plant/ballbot.py), kept for regression; or a
    lab's own."""
    mujoco: MujocoParams = MujocoParams()
    substeps: Annotated[int, msgspec.Meta(ge=1, le=100)] = 1
    """Fixed RK4 steps per tick (internal rate = tick_hz × substeps). One step at 400 Hz already agrees
    with eight to ~1e-5 on task metrics (tests/test_plant_dynamics.py::test_rk4_converges)."""
    seed: int = 0
    fixture: Literal["free", "clamped"] = "free"
    """free: the robot rolls on the floor; clamped: chassis held upright on a stand (only the torso moves)."""
    fall_tilt_deg: Annotated[float, msgspec.Meta(gt=0, lt=90)] = 30.0
    """A chassis tilt beyond this in either plane is a fall."""
    rest_speed: Positive = 0.1
    """m/s: with every drive off below this speed (and tilt), the robot comes to rest on the rider's feet
    or its stand instead of falling (a stop category 1 ends like this)."""
    rest_tilt_deg: Annotated[float, msgspec.Meta(gt=0, lt=90)] = 5.0
    """... and below this chassis tilt, deg."""
    floor_half_x: Positive = 25.0
    """The ball must stay within ±floor_half_x of the start along world x, m."""
    floor_half_y: Positive = 25.0
    """... and within ±floor_half_y along world y, m."""

    @property
    def dt(self) -> float:
        return 1.0 / self.tick_hz

    @property
    def fall_tilt(self) -> float:
        return math.radians(self.fall_tilt_deg)

    @property
    def rest_tilt(self) -> float:
        return math.radians(self.rest_tilt_deg)
