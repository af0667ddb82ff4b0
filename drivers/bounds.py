"""The bound of every number a robot file, a rider file or a rider's intent holds, declared once.

Each is a type: the number's type with a `msgspec.Meta` that holds the bound and, as its `description`, why
it is the bound (a ballbot of PURE's size class, a seated adult). The plant (plant/params.py), the
controller (controller/config.py) and the supervisor (safety/config.py) decode the same files into their own
records, each field typed with the one declaration here, so the three refuse the same numbers: msgspec
checks a bound as it decodes and names the file, the field and the bound, and NaN fails every bound.
docs/configuration.md lists them all from here (hil/config_bounds.py).

Declarations only: the one module of drivers/ the plant may import (tests/test_boundaries.py).
"""

from __future__ import annotations

from typing import Annotated, Final, Literal

from msgspec import Meta

G0: Final = 9.80665
"""m/s²: standard gravity (3rd CGPM, 1901), the one physical constant every package reads."""

Positive = Annotated[float, Meta(gt=0)]
"""A number whose only bound is its sign, where a file's field has no tighter bound of its own."""
NonNegative = Annotated[float, Meta(ge=0)]

MAX_DURATION = 86400.0
"""s: one day of simulated time bounds a run, a fault's start and its length (a run folder grows by ~0.5 MB
per simulated second; a service runs for weeks as many runs)."""

# ------------------------------------------------------------------ the robot file (configs/robot/*.toml)
# PURE's nominal values (docs/physics.md §6.1) sit well inside each range; a range spans the riding and
# research ballbots of its size class, not the numbers a model would still compute with.
BallRadius = Annotated[
    float,
    Meta(
        ge=0.05,
        le=0.5,
        description="m; PURE's 0.1145; research and riding ballbots roll on 0.1-0.2 m: under 0.05 m three "
        "omniwheels do not fit around the ball, over 0.5 m it is no personal mobility device",
    ),
]
BallMass = Annotated[
    float,
    Meta(
        ge=0.2,
        le=50.0,
        description="kg; PURE's 3.6: a thin shell of the smallest ball to a solid one of ~0.2 m",
    ),
]
BallInertia = Annotated[
    float,
    Meta(
        ge=1e-4,
        le=10.0,
        description="kg m²; a solid sphere at the smallest mass and radius (2/5 m r² = 2e-4) to a thin shell "
        "at the largest (2/3 m r² = 8.3)",
    ),
]
FloorFriction = Annotated[
    float,
    Meta(ge=0.05, le=2.0, description="μ; wet ice about 0.05, rubber on rough concrete about 1.2"),
]
SpinFriction = Annotated[
    float,
    Meta(ge=0.0, le=0.1, description="m; about 2/3 μ a for a contact patch of radius a, a few cm at most"),
]
RollFriction = Annotated[
    float,
    Meta(
        ge=0.0,
        le=0.05,
        description="m; the lever of a ball's rolling resistance: mm for rubber, within the patch",
    ),
]
BodyMass = Annotated[
    float,
    Meta(
        ge=5.0,
        le=200.0,
        description="kg; PURE's chassis, drives, battery and seat are estimated at 14-56 kg (30)",
    ),
]
ComHeight = Annotated[
    float,
    Meta(
        ge=0.01,
        le=1.5,
        description="m above the ball's centre; PURE's 0.25; a person-tall ballbot has it under 1.5 m",
    ),
]
BodyInertia = Annotated[
    float,
    Meta(
        ge=1e-3,
        le=50.0,
        description="kg m² about the COM; the largest body mass at a 0.5 m radius of gyration (200 × 0.5²)",
    ),
]
TopHeight = Annotated[
    float,
    Meta(
        ge=0.05,
        le=1.5,
        description="m above the ball's centre; PURE's 0.386 (0.5 m above the floor); a seat must be "
        "reachable from the floor, no higher than a bar stool",
    ),
]
SeatHeight = Annotated[
    float, Meta(ge=0.0, le=0.5, description="m above the chassis' top: a cushion or a seat post")
]
ImuHeight = Annotated[
    float,
    Meta(ge=0.0, le=1.5, description="m above the ball's centre, on the body: within the chassis' height"),
]
ChassisRadius = Annotated[
    float,
    Meta(ge=0.05, le=0.6, description="m; PURE's 0.20; a chassis over 1.2 m wide does not pass a door"),
]
ChassisBottom = Annotated[
    float,
    Meta(
        ge=-0.5,
        le=1.5,
        description="m above the ball's centre (negative: below it), within the chassis' heights",
    ),
]
WheelRadius = Annotated[
    float, Meta(ge=0.01, le=0.3, description="m; PURE's 0.0625; omniwheels are 2-30 cm across or more")
]
ZenithDeg = Annotated[
    float,
    Meta(
        ge=10.0,
        le=80.0,
        description="deg; PURE's 45: nearer the top the wheels hold no tilt, nearer the equator no weight",
    ),
]
AzimuthDeg = Annotated[float, Meta(ge=-360.0, le=360.0, description="deg; a full turn either way")]
MotorSign = Annotated[
    Literal[-1, 1],
    Meta(description="+1 when the motor's positive rotation is the model's positive wheel rate, else -1"),
]
GearRatio = Annotated[
    float,
    Meta(
        ge=1.0,
        le=100.0,
        description="motor turns per wheel turn; PURE's about 8 (5-10): a direct drive to a gearbox",
    ),
]
WheelInertia = Annotated[
    float,
    Meta(ge=0.0, le=0.5, description="kg m² at the wheel's shaft; a 3 kg omniwheel of 0.3 m radius has 0.14"),
]
RotorInertia = Annotated[
    float,
    Meta(
        ge=0.0,
        le=0.01,
        description="kg m² at the motor's shaft; PURE's 1.2e-4: the rotors of kW servo motors",
    ),
]
TorqueLimit = Annotated[
    float,
    Meta(
        gt=0.0,
        le=50.0,
        description="Nm at the motor's shaft; PURE's 3.75 (30 Nm at the wheel): a ballbot's motors give "
        "tens of Nm at most",
    ),
]
StallTorque = Annotated[
    float,
    Meta(
        gt=0.0,
        le=200.0,
        description="Nm at the motor's shaft at standstill on the full bus voltage (k_t V / R), at least the "
        "torque limit; PURE's estimate 16.3",
    ),
]
NoLoadSpeed = Annotated[
    float,
    Meta(
        ge=10.0,
        le=327.0,
        description="rad/s at the motor's shaft where its back-EMF equals the bus voltage (V / k_e); at most "
        "327: DRIVEn_FEEDBACK.Velocity carries ±327.67 rad/s (a faster motor needs a new contract scaling)",
    ),
]
CurrentLoopTau = Annotated[
    float, Meta(ge=1e-5, le=0.05, description="s; a drive's current loop closes in 0.05-5 ms")
]
StreamTimeout = Annotated[
    float,
    Meta(
        ge=1e-3,
        le=1.0,
        description="s; a few periods of a 100-1000 Hz stream: silent for a second it is dead",
    ),
]
"""How long a drive waits on a silent command or supervisor stream before it acts on the silence."""
SupervisorLostGrace = Annotated[
    float,
    Meta(
        gt=0.0,
        le=600.0,
        description="s; long enough for the controller to brake from any speed to rest, at most 10 min",
    ),
]
ContactorTimeout = Annotated[
    float,
    Meta(ge=1e-3, le=10.0, description="s after the drives' grace: the second channel acts within seconds"),
]
TorqueNoise = Annotated[
    float, Meta(ge=0.0, le=1.0, description="Nm, 1σ; a drive's measured torque within a few % of its limit")
]
VelocityNoise = Annotated[float, Meta(ge=0.0, le=10.0, description="rad/s, 1σ; a motor's velocity estimate")]
Viscous = Annotated[
    float,
    Meta(
        ge=0.0,
        le=10.0,
        description="Nm s/rad; PURE's 0.5-0.75: 10 would take 100 Nm at 10 rad/s, more than the drives give",
    ),
]
DryFriction = Annotated[
    float,
    Meta(
        ge=0.0,
        le=50.0,
        description="Nm, ball-equivalent; PURE's 0.5-2: the drives' own torque (30 Nm at each wheel) at most",
    ),
]
StickVelocity = Annotated[
    float, Meta(ge=1e-4, le=1.0, description="rad/s; the Karnopp band, a small fraction of a turn per second")
]
CountsPerRev = Annotated[
    int, Meta(ge=1, le=2**24, description="a motor's hall sensors (a few) to a 24-bit absolute encoder")
]
WordBits = Annotated[int, Meta(ge=8, le=64, description="the widths of an integer on the bus")]
SensorRateHz = Annotated[
    float,
    Meta(ge=10.0, le=10_000.0, description="Hz; IMUs and load-cell amplifiers sample at 100 Hz to a few kHz"),
]
GyroNoiseDensity = Annotated[
    float, Meta(ge=0.0, le=0.01, description="rad/s/√Hz; PURE's VN-100 class 6.1e-5, a toy gyro's 1e-3")
]
AccelNoiseDensity = Annotated[
    float, Meta(ge=0.0, le=0.1, description="m/s²/√Hz; PURE's VN-100 class 1.37e-3, a toy's 1e-2")
]
GyroBiasSigma = Annotated[float, Meta(ge=0.0, le=0.1, description="rad/s, 1σ; a consumer MEMS gyro's 0.01")]
GyroBiasWalk = Annotated[float, Meta(ge=0.0, le=0.01, description="rad/s/√s")]
AccelBiasSigma = Annotated[
    float, Meta(ge=0.0, le=1.0, description="m/s², 1σ; a consumer MEMS accelerometer's 0.1")
]
AccelBiasWalk = Annotated[float, Meta(ge=0.0, le=0.01, description="m/s²/√s")]
AttitudeNoiseDeg = Annotated[
    float, Meta(ge=0.0, le=5.0, description="deg, 1σ; an AHRS of PURE's class 0.05, worse than 5 is no AHRS")
]
CellRadius = Annotated[float, Meta(ge=0.01, le=0.5, description="m; the load cells sit under a seat plate")]
CellNoise = Annotated[
    float,
    Meta(ge=0.0, le=100.0, description="N, 1σ; a load cell of a seat's range (a few kN) within a few %"),
]
CellRange = Annotated[
    float,
    Meta(
        ge=100.0,
        le=3000.0,
        description="N, each cell's full scale; a seat's cells are 1-3 kN, and three at full scale stay "
        "within the wire's ±10 kN",
    ),
]
CalibrationError = Annotated[
    float, Meta(ge=0.0, le=0.5, description="relative, 1σ; a calibration off by half is none")
]

# ------------------------------------------------------------------ the rider file (configs/riders/*.toml)
# A seated adult (docs/riders.md): the paper's riders are 50-79 kg, 1.60-1.80 m; a person's trunk and its
# muscles bound the rest.
RiderMass = Annotated[
    float,
    Meta(
        gt=20.0, lt=250.0, description="kg; a child of 20 kg to the heaviest adult a personal device carries"
    ),
]
RiderHeight = Annotated[
    float, Meta(gt=1.0, lt=2.3, description="m standing; a child of 1 m to the tallest adults")
]
LeanDeg = Annotated[
    float,
    Meta(
        gt=0.0,
        le=60.0,
        description="deg relative to the chassis; the paper's riders reached 29 ± 6 deg: a seated trunk "
        "leaning 60 deg has the head at the knees",
    ),
]
"""A lean a rider can reach (their largest, the one a trial asks of them)."""
HipTorque = Annotated[
    float,
    Meta(gt=0.0, le=500.0, description="Nm; an athlete's strongest trunk extension is 300-400 Nm"),
]
TwistTorque = Annotated[
    float, Meta(ge=0.0, le=150.0, description="Nm; a person's strongest trunk rotation is about 100 Nm")
]
LeanRateDeg = Annotated[
    float,
    Meta(gt=0.0, le=360.0, description="deg/s; a trunk's fastest flexion is about 200 deg/s"),
]
LeanAccelDeg = Annotated[
    float,
    Meta(gt=0.0, le=5000.0, description="deg/s²; 200 deg/s reached in no less than 0.04 s"),
]
ReactionTime = Annotated[
    float,
    Meta(
        gt=0.0,
        le=10.0,
        description="s; a person reacts in 0.2-2.5 s (Green 2000), never at once; 10 s on is no reaction",
    ),
]
TrunkStiffness = Annotated[
    float,
    Meta(gt=0.0, le=10_000.0, description="Nm/rad; a trunk's active stiffness is hundreds to a few thousand"),
]
TrunkDamping = Annotated[
    float, Meta(gt=0.0, le=2000.0, description="Nm s/rad; a trunk's damping, a fraction of its stiffness")
]
HipX = Annotated[
    float, Meta(ge=-0.5, le=0.5, description="m from the ball's axis; a seat over the chassis, not beside it")
]
HipHalfWidth = Annotated[
    float, Meta(ge=0.03, le=0.25, description="m; an adult's hip joints are 0.15-0.2 m apart")
]

# --------------------------------------------------------- a rider's intent (plant/rider.py's segments)
SegmentDuration = Annotated[
    float, Meta(gt=0.0, le=MAX_DURATION, description="s; within the longest run (MAX_DURATION)")
]
SwayHz = Annotated[
    float, Meta(gt=0.0, le=5.0, description="Hz; a person sways their trunk a few times a second at most")
]
RobotSpeed = Annotated[float, Meta(gt=0.0, le=10.0, description="m/s; faster than any riding ballbot goes")]
