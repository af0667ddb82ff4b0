"""The supervisor's configuration (`configs/safety/default.toml`).

Like the controller, the supervisor decodes the robot file itself, into `drivers.robot.RobotModel` (the
geometry it needs to estimate speed, the masses its recovery law balances); its own maths on it shares no
code with the controller it watches: a bug in one is not a bug in both.
Every threshold has a documented default; docs/safety.md explains how they were chosen.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from drivers.bounds import (
    NonNegative,
    Positive,
)
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MessageName
from drivers.e2e import MAX_GAP
from drivers.rules import MotionLimits, SpeedLimits, StopLimits

Fraction = Annotated[float, msgspec.Meta(gt=0, le=1)]


class _Strict(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pass


# --------------------------------------------------------------------------------------------- rules
class SpeedRules(SpeedLimits, frozen=True, forbid_unknown_fields=True):
    """`absolute_cap`, `margin`, `enforce_requested_cap`: drivers/rules.py (the rig judges by them too)."""

    reduced_cap: NonNegative = 0.3
    """m/s: the cap while the SC agent is silent (LIMITING, SC_SILENT)."""
    window: Positive = 0.25
    """s above cap + margin before LIMITING (command idle)."""
    release_window: Positive = 0.5
    """s at or below cap + margin before LIMITING releases to NORMAL."""
    decel: Positive = 0.5
    """m/s²: when the cap drops below the speed, the speed must come down at least this fast (a braking
    ramp from the speed at the drop, as in IEC 61800-5-2's ramp-monitored stops); the cap is enforced
    against the ramp until the ramp reaches it."""
    brake_delay: NonNegative = 0.5
    """s after the drop before the ramp starts; meanwhile up to the speed at the drop + rise_margin is
    allowed: a ballbot first speeds up to tilt back (non-minimum phase; +0.45 m/s from 1.5 m/s here)."""
    rise_margin: Positive = 0.3
    """m/s: while limiting or stopping, a speed this far above the speed at entry means the command is not
    obeyed (overpowered: controlled stop; while stopping: drives off)."""
    limit_timeout: Positive = 3.0
    """s in LIMITING without getting back under the cap -> controlled stop (OVERPOWERED)."""
    hard_limit: Positive = 2.5
    """m/s: above this, a controlled stop whatever the cap."""


class StopRules(StopLimits, frozen=True, forbid_unknown_fields=True):
    """`standstill_speed`: drivers/rules.py."""

    standstill_tilt_deg: Positive = 3.0
    """deg: a controlled stop turns the drives off only with the chassis this close to upright: the rider's
    feet and the stand catch a robot at rest within 5 deg; tilted further (a rider still leaning) it would
    tip, so it keeps balancing at standstill until the chassis comes upright."""
    standstill_time: Positive = 0.3
    """s at standstill (and upright) before a controlled stop turns the drives off."""
    motion_after_standstill: Positive = 0.8
    """m/s: once at standstill, motion above this (for escalation_time) turns the drives off at once. A rider
    who swings their lean while the robot stands makes a healthy controller roll to rebalance: up to
    0.6 m/s for a 47 deg swing (speed_limiting's rider sitting back after an e-stop)."""
    escalation_time: Positive = 0.5
    """s a stop must fail (the speed above its entry + rise_margin, or moving again after standstill) before
    the drives go off at once: a ballbot tips when power is cut in motion, and a rider shifting their
    weight makes it move briefly to rebalance."""
    timeout: Positive = 6.0
    """s: a controlled stop that has not reached standstill by then turns the drives off (once it has,
    motion is motion_after_standstill's)."""


class MotionRules(MotionLimits, frozen=True, forbid_unknown_fields=True):
    """`tilt_limit_deg`: drivers/rules.py."""

    torque_range: Positive = 1.05
    """A torque command above this × the drive's limit is garbage: drives off."""
    saturation_fraction: Fraction = 0.97
    """A command at or above this × the limit counts as saturated."""
    saturation_time: Positive = 1.0
    """s of continuous saturation (the controller has lost authority): drives off."""
    rider_min_load: NonNegative = 150.0
    """N on the seat below which nobody is seated."""
    rider_absent_time: Positive = 0.5
    """s without a rider while moving: controlled stop."""


class Watchdogs(_Strict, frozen=True):
    """Consumer timeouts, each several producer periods (drives and IMU 400 Hz, heartbeat 400 Hz in the
    rig, TES 400 Hz, SC requests at least 2 Hz)."""

    drives: Positive = 0.025
    imu: Positive = 0.025
    heartbeat: Positive = 0.05
    wrench: Positive = 0.1
    sc: Positive = 1.0
    startup_grace: NonNegative = 0.5
    """s after start-up during which streams never heard from are not yet faults."""
    require_wrench: bool = True
    """A silent seat (TES) is a fault: the rider's input is lost."""


WindowChecks = Annotated[
    int,
    msgspec.Meta(
        ge=2,
        le=4000,
        description="checks (frames) of one stream; 4000 is 10 s at 400 Hz: a stream whose errors have "
        "stopped waits a whole clean window before it is trusted again",
    ),
]
BurstChecks = Annotated[
    int,
    msgspec.Meta(
        ge=0,
        le=MAX_GAP - 1,
        description="errors in a window; E2E's 4-bit alive counter bridges at most 7 corrupted frames in a "
        "row (drivers/e2e.py MAX_GAP): after a longer burst it reads out of order until it comes round, the "
        "stream is silent and its watchdog's",
    ),
]


class E2EWindowRules(_Strict, frozen=True):
    """One stream's E2E window (safety/e2e_window.py): of its last `window` checks at most `max_errors` may
    fail; docs/safety.md "E2E windows" derives each from the stream's fault-tolerant time."""

    window: WindowChecks
    max_errors: BurstChecks

    def __post_init__(self) -> None:
        if self.max_errors >= self.window:
            raise ValueError(
                f"max_errors ({self.max_errors}) must be below window ({self.window}): a window that "
                "tolerates all its checks failing trusts a dead stream"
            )


class Integrity(_Strict, frozen=True):
    """Each protected stream's E2E window, per message (the three drives' alike): a burst of at most
    `max_errors` is ridden through, more within `window` names the stream's parts (E2E_ERRORS)."""

    drive_feedback: E2EWindowRules = E2EWindowRules(window=100, max_errors=7)
    """DRIVEn_FEEDBACK, 400 Hz: its fault-tolerant time is `watchdogs.drives` (25 ms, 10 frames)."""
    drive_command: E2EWindowRules = E2EWindowRules(window=100, max_errors=7)
    """DRIVEn_COMMAND, 400 Hz: the drives' own command watchdog (20 ms, 8 frames)."""
    drive_torque: E2EWindowRules = E2EWindowRules(window=25, max_errors=2)
    """DRIVEn_TORQUE, 100 Hz: the torque check's `drives.torque_samples` (3 samples, 30 ms)."""
    imu_attitude: E2EWindowRules = E2EWindowRules(window=100, max_errors=7)
    """IMU_ATTITUDE, 400 Hz: `watchdogs.imu` (25 ms)."""
    imu_rate: E2EWindowRules = E2EWindowRules(window=100, max_errors=7)
    """IMU_RATE, 400 Hz: `watchdogs.imu` (25 ms)."""
    imu_accel: E2EWindowRules = E2EWindowRules(window=100, max_errors=7)
    """IMU_ACCEL, 400 Hz: `watchdogs.imu` (25 ms)."""
    controller_heartbeat: E2EWindowRules = E2EWindowRules(window=100, max_errors=7)
    """CONTROLLER_HEARTBEAT, 400 Hz in the rig: `watchdogs.heartbeat` (50 ms)."""
    operator_estop: E2EWindowRules = E2EWindowRules(window=3, max_errors=1)
    """OPERATOR_ESTOP, 10 Hz: no watchdog; the detection bound (250 ms) is its fault-tolerant time."""
    other: E2EWindowRules = E2EWindowRules(window=100, max_errors=7)
    """Any other protected message the supervisor hears (its own frames sent by another node)."""

    def rules(self, message: str) -> E2EWindowRules:
        """The window of a protected message."""
        rules: E2EWindowRules = getattr(self, WINDOW_OF.get(message, "other"))
        return rules


WINDOW_OF: dict[str, str] = {
    **dict.fromkeys(DRIVE_FEEDBACK, "drive_feedback"),
    **dict.fromkeys(DRIVE_COMMAND, "drive_command"),
    **dict.fromkeys(DRIVE_TORQUE, "drive_torque"),
    MessageName.IMU_ATTITUDE: "imu_attitude",
    MessageName.IMU_RATE: "imu_rate",
    MessageName.IMU_ACCEL: "imu_accel",
    MessageName.CONTROLLER_HEARTBEAT: "controller_heartbeat",
    MessageName.OPERATOR_ESTOP: "operator_estop",
}
"""The `[integrity]` window each protected message the supervisor reads is judged by (any other: `other`)."""


class DriveRules(_Strict, frozen=True):
    confirm: Positive = 0.02
    """s for the drives' feedback to confirm a change: off after the e-stop (else the main contactor
    opens: DRIVE_NOT_DISABLED), on once permitted and told to enable (else DRIVE_FAULT), the DC bus gone
    after the contactor opened (else CONTACTOR_FAULT). 8 feedback frames at 400 Hz."""
    torque_tolerance: Positive = 0.15
    """Nm: the measured torque (DRIVEn_TORQUE) may differ from the command it follows by this much ..."""
    torque_relative: Fraction = 0.1
    """... plus this fraction of the command."""
    torque_samples: Annotated[int, msgspec.Meta(ge=1)] = 3
    """Consecutive DRIVEn_TORQUE samples (100 Hz) beyond the tolerance: ACTUATOR_MISMATCH."""


class SensorRules(_Strict, frozen=True):
    """Cross-checks between independent measurements (docs/safety.md "Diagnostics")."""

    window: Positive = 0.025
    """s over which the rate cross-checks average (10 frames at 400 Hz)."""
    relative: Fraction = 0.05
    """Each rate tolerance grows by this fraction of the measured magnitude (scale errors of a healthy
    sensor, slip)."""
    yaw_tolerance: Positive = 0.15
    """rad/s: the yaw rate the three encoders determine vs the gyro's RateZ."""
    encoder_tolerance: Positive = 0.5
    """rad/s at the motor: a drive's position (counts) differentiated vs the velocity it reports."""
    attitude_tolerance: Positive = 0.01
    """rad: the attitude's change vs the body rates integrated over `attitude_memory` (a leaky sum), plus
    what the small-angle kinematics leave out (bounded by the rates and the tilt)."""
    attitude_memory: Positive = 0.5
    """s: time constant of the attitude-vs-rates sum."""
    trend_window: Positive = 0.25
    """s: the speed's change is compared with the accelerometer's over this window."""
    trend_tolerance: Positive = 0.1
    """m/s: the encoders' speed change vs the integrated horizontal acceleration over `trend_window`."""
    stuck_samples: Annotated[int, msgspec.Meta(ge=2)] = 20
    """A channel that repeats the same raw value this many frames in a row while other evidence says it
    moved is stuck: at the contract's resolution. An IMU stream whose values step coarser needs as many
    more as keep a live channel's chance of such a run the same, given the noise below
    (safety/diagnostics.py `Resolution`)."""
    attitude_noise: Positive = 8.7e-4
    """rad: 1σ per sample of the IMU's attitude output (0.05°, VN-100 class). With `rate_noise` and
    `accel_noise`: how often a live IMU channel changes its raw value at rest, at its stream's resolution.
    A lower bound: a quieter sensor repeats its values more often than the stuck check allows for."""
    rate_noise: Positive = 8.6e-4
    """rad/s: 1σ per sample of the gyro (6.1e-5 rad/s/√Hz over the 200 Hz band of a 400 Hz output)."""
    accel_noise: Positive = 0.019
    """m/s²: 1σ per sample of the accelerometer (1.37e-3 m/s²/√Hz over 200 Hz)."""


class SeatRules(_Strict, frozen=True):
    """Plausibility of the seat wrench (a rider's weight, posture and how fast they can change)."""

    tare_time: Positive = 0.5
    """s of seated load averaged as the rider's weight on the seat, from the first seated sample."""
    weight_band: Positive = 0.25
    """The seat load may exceed the tare by this fraction (plus the chassis' vertical acceleration's share)
    and fall below it by this fraction (down to rider_min_load: a rider getting off is RIDER_ABSENT's)."""
    radius: Positive = 0.3
    """m: the centre of pressure stays within this distance of the seat's centre."""
    cop_tolerance: Positive = 0.01
    """m: the reported COP vs the one the reported force and moment give."""
    force_rate: Positive = 6000.0
    """N/s: the largest change of any force component a rider and the chassis make (over rate_window)."""
    moment_rate: Positive = 4000.0
    """Nm/s: likewise for the moments."""
    rate_window: Positive = 0.025
    """s over which the rates of change are measured (the cells' noise averages out)."""
    stuck_samples: Annotated[int, msgspec.Meta(ge=2)] = 20
    """Samples in a row with every value unchanged while the chassis moves: frozen."""


class ScRules(_Strict, frozen=True):
    """Several SC agents: the most restrictive request of those heard wins (docs/safety.md)."""

    rate: Positive = 50.0
    """Requests per second accepted from one source (a token bucket); beyond, refused and counted."""
    burst: Annotated[int, msgspec.Meta(ge=1)] = 10
    """Requests one source may send at once before the rate applies."""
    max_sources: Annotated[int, msgspec.Meta(ge=1)] = 8
    """Sources tracked at once; a request from one more is refused and counted."""


class TwoWheelRules(_Strict, frozen=True):
    """The recovery law's weights on two wheels (a dead drive), apart from the three-drive law's. On two
    wheels every torque that brakes the coupled plane turns the chassis too, and a brake as hard as three
    wheels' spins it past what the pair can hold. These weights hold the tilt loosely, damp the ball's
    speed hard and let the anchor follow the robot: the rider's momentum comes down over seconds, at a yaw
    the pair keeps. Searched, not derived: `python benchmarks/recovery_weights.py` (optuna) over riders of
    45-120 kg, each drive, straight and turning at 0.8 and 1.0 m/s, riders who heed the alert (docs/safety.md
    "A dead drive")."""

    q_tilt: Positive = 80.0
    q_position: Positive = 0.2
    q_tilt_rate: Positive = 1.8
    q_ball_rate: Positive = 300.0
    r: Positive = 1.0
    position_limit: Positive = 0.22
    """m: how far from the anchor the position term pulls; beyond it the anchor follows the robot."""
    coupled_velocity_share: Fraction = 0.75
    """The share of the coupled plane's position and ball rate in its feedback; the rest of its ball rate
    is the yaw rate, which the pair's torque changes with it (docs/safety.md "A dead drive")."""


class RecoveryRules(_Strict, frozen=True):
    """The recovery law (safety/recovery.py): an LQR per plane on the supervisor's own model, weights on
    [tilt, ball angle since the takeover, tilt rate, ball rate] (docs/safety.md "Fail-operational"). These
    are the three-drive law's; on two wheels `two_wheels` holds its own."""

    enabled: bool = True
    """False: no takeover; a cause the controller cannot stop from cuts power at once (the supervisor as it
    was before it could recover: a positive control for what the recovery law saves)."""
    q_tilt: Positive = 500.0
    q_position: Positive = 20.0
    """Holds the robot near where the takeover began, so a leaning rider cannot drive it away."""
    q_tilt_rate: Positive = 10.0
    q_ball_rate: Positive = 5.0
    r: Positive = 1.0
    position_limit: Positive = 0.5
    """m: how far from the anchor the position term pulls; beyond it the anchor follows the robot."""
    yaw_gain: Positive = 10.0
    """Nm of ball yaw torque per rad/s of yaw rate: the robot stops turning."""
    rider_mass: Positive = 75.0
    """kg assumed before the seat has said what the rider weighs."""
    rider_com: Positive = 0.3
    """m of the rider's centre of mass above the seat (a seated adult's trunk, head and arms)."""
    rider_yaw_inertia: Positive = 0.035
    """kg m² per kg of rider about the chassis axis: a seated rider's trunk behind it, thighs and shanks
    ahead (Winter's segments at 1.75 m, docs/physics.md §5; two-wheel law only)."""
    rider_roll_yaw_product: float = 0.030
    """kg m² per kg of rider: −Σ m x z about the ball centre, the legs ahead and low, the trunk behind and
    high; it couples the chassis' roll to its yaw (two-wheel law only)."""
    two_wheels: TwoWheelRules = TwoWheelRules()
    attitude_filter: Positive = 2.0
    """s: the integrated rates are pulled toward a trusted attitude with this time constant; once the
    attitude is found faulty they carry it alone."""
    rate_filter: Positive = 0.02
    """s: low-pass on the attitude's derivative that stands in for a faulty or silent rate channel."""


class Output(_Strict, frozen=True):
    estop_frame_period: Positive = 0.01
    """s between SUPERVISOR_ESTOP frames (the DBC's 100 Hz); also sent at once on every transition."""
    sc_period: Positive = 0.05
    """s between repeats of an unchanged SC command (keeps it fresh for the controller)."""
    state_period: Positive = 0.1
    """s between repeats of pure/safety/state (it is also put on every transition)."""
    rate_hz: Positive = 400.0
    """Standalone: the supervisor's own timer (it also updates on every SYNC)."""


class Identity(_Strict, frozen=True):
    operators: list[str] = []
    """Sources (the payload's `source`) allowed to reset an e-stop or request an SC mode. Empty: not checked
    (the loopback default). On a bench this is defence in depth behind the router's ACL (docs/security.md):
    anything else is counted and ignored. An e-stop is accepted from anyone, always."""


class SupervisorConfig(_Strict, frozen=True):
    identity: Identity = Identity()
    speed: SpeedRules = SpeedRules()
    stop: StopRules = StopRules()
    motion: MotionRules = MotionRules()
    watchdogs: Watchdogs = Watchdogs()
    integrity: Integrity = Integrity()
    drives: DriveRules = DriveRules()
    sensors: SensorRules = SensorRules()
    seat: SeatRules = SeatRules()
    sc: ScRules = ScRules()
    recovery: RecoveryRules = RecoveryRules()
    output: Output = Output()
