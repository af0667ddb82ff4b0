"""The supervisor's diagnostics, check by check: each stays quiet on consistent evidence (physics from the
plant where it can be) and fires on the fault it is there for (the positive control)."""

import math

import numpy as np
import pytest

from drivers.config import load_toml
from drivers.robot import RobotModel
from drivers.rotations import heading_frame
from drivers.vocabulary import Cause
from hil.run.truth_balancer import TruthBalancer
from plant.ballbot3d import Plant3D
from plant.core import RiderIntent
from plant.params import RobotParams, SimParams
from plant.rider import Hold, Ramp
from safety.config import SupervisorConfig
from safety.diagnostics import (
    AttitudeCheck,
    EncoderCheck,
    Replay,
    Resolution,
    SeatCheck,
    Stuck,
    TorqueCheck,
    TrendCheck,
    YawCheck,
    live_run,
    motor_jacobian,
    trend_inputs,
)
from tests.helpers import RIDER_75, ROOT

CFG = SupervisorConfig()
SENSORS = CFG.sensors
GEOMETRY = load_toml(ROOT / "configs/robot/pure.toml", RobotModel)
ROBOT = load_toml(ROOT / "configs/robot/pure.toml", RobotParams)
DT = 1.0 / 400
RAD_PER_COUNT = 2 * math.pi / 8192


def encoder(velocities, counts0=0):
    """A drive turning at the given velocities, one per frame: (counts, velocity) as it reports them."""
    angle, out = counts0 * RAD_PER_COUNT, []
    for v0, v1 in zip([velocities[0], *velocities], velocities, strict=False):
        angle += 0.5 * (v0 + v1) * DT
        out.append((round(angle / RAD_PER_COUNT), v1))
    return out


def run_encoder(frames, periods=1):
    check = EncoderCheck(1, SENSORS, DT, RAD_PER_COUNT, 1 << 32)
    found = [check.frame(c, v, periods) for c, v in frames]
    return check, [f for f in found if f is not None]


# ----------------------------------------------------------------------------------------- encoders
def test_position_and_velocity_of_a_healthy_drive_agree_even_across_lost_frames_and_wraps():
    velocities = list(40.0 * np.sin(np.linspace(0, 6, 800)))
    check, found = run_encoder(encoder(velocities, counts0=(1 << 31) - 2000))  # the 32-bit count wraps
    assert not found and check.peak < 0.3
    every_other = encoder(velocities)[::2]  # a frame lost between each: two periods each
    check, found = run_encoder(every_other, periods=2)
    assert not found and check.peak < 0.3


@pytest.mark.parametrize("fault", ["sign flip", "stuck position", "half velocity"])
def test_a_wrong_position_or_velocity_disagrees_within_the_window(fault):
    frames = encoder([20.0] * 100)
    if fault == "sign flip":
        frames = [(c, -v) for c, v in frames]
    elif fault == "stuck position":
        frames = [(frames[0][0], v) for _, v in frames]
    else:
        frames = [(c, 0.5 * v) for c, v in frames]
    check = EncoderCheck(1, SENSORS, DT, RAD_PER_COUNT, 1 << 32)
    first = next(i for i, (c, v) in enumerate(frames) if check.frame(c, v, 1))
    assert first <= round(SENSORS.window / DT) + 1
    assert check.cause is Cause.SENSOR_DISAGREE


# --------------------------------------------------------------------------------------------- yaw
def turning_plant(seed=2):
    """The 3-D plant under the truth balancer, rolling forward and sideways, turning and tilted (the rider
    leaning), for checks that must hold on a robot that moves in every way at once."""
    plant = Plant3D(
        ROBOT,
        RIDER_75,
        SimParams(seed=seed),
        RiderIntent(
            pitch=[Hold(duration=0.5), Ramp(to=8.0, duration=1.0)], roll=[Ramp(to=-6.0, duration=2.0)]
        ),
    )
    return plant, TruthBalancer(plant)


def drive_turning(plant, bal, k):
    bal.set_velocity(0.8 * min(k / 400, 1.0) if k < 1000 else 0.0, 0.3 if 400 < k < 1200 else 0.0)
    # Into the turn and out of it over 0.5 s, as a rider turns: a step would ask the floor for more yaw
    # torque than it holds (spin_friction x N, about 10 Nm), and the ball would spin on it.
    bal.yaw_rate_command = 0.8 * min(max(min(k - 600, 1100 - k) / 200, 0.0), 1.0)
    bal.drive()
    plant.step()


def test_the_encoders_yaw_rate_agrees_with_the_gyro_on_a_tilted_rolling_turning_robot():
    # Physics against physics: MuJoCo's wheel rates and gyro while the robot rolls at up to 0.85 m/s, leans
    # 6 deg sideways and turns at 0.8 rad/s. The ball's rotation has a part along the tilted chassis axis;
    # the level relation (yaw = −(G⁻¹ m)_z) takes it for yaw and would fire (the positive control).
    plant, bal = turning_plant()
    g = motor_jacobian(GEOMETRY)
    to_relative = np.linalg.inv(g)
    check, worst_level = YawCheck(SENSORS, DT), 0.0
    for k in range(1600):
        drive_turning(plant, bal, k)
        (roll, pitch, _), rate, _ = plant.imu_truth()
        relative = to_relative @ np.asarray(plant.motor_angles_and_rates()[1])
        assert check.update(relative, rate, roll, pitch, DT) is None
        worst_level = max(worst_level, abs(-relative[2] - rate[2]))
    assert check.peak < 0.3
    assert worst_level > SENSORS.yaw_tolerance + SENSORS.relative * 0.8, "the level relation would trip"


def test_a_flipped_encoder_disagrees_with_the_gyro():
    g = motor_jacobian(GEOMETRY)
    check = YawCheck(SENSORS, DT)
    relative = np.array([0.3, 6.0, -0.8])  # rolling forward while turning at 0.8 rad/s, level
    assert all(check.update(relative, (0.0, 0.0, 0.8), 0.0, 0.0, DT) is None for _ in range(40))
    motors = g @ relative
    flipped = np.linalg.solve(g, [-motors[0], *motors[1:]])
    found = [check.update(flipped, (0.0, 0.0, 0.8), 0.0, 0.0, DT) for _ in range(12)]
    assert any(found)
    assert "encoders" in next(f for f in found if f).detail


# ---------------------------------------------------------------------------------------- attitude
def test_attitude_follows_its_integrated_rate_and_a_frozen_one_does_not():
    check = AttitudeCheck("pitch", SENSORS)
    t = np.arange(0, 2.0, DT)
    angle, rate = 0.1 * np.sin(3 * t), 0.3 * np.cos(3 * t)
    assert all(check.update(a, r, 0.0, DT) is None for a, r in zip(angle, rate, strict=True))
    assert check.peak < 0.2
    # Frozen while the rate says it moves: caught once the motion adds up to the tolerance.
    frozen = [check.update(angle[-1], 0.3, 0.0, DT) for _ in range(400)]
    caught = next(i for i, f in enumerate(frozen) if f)
    assert caught * DT == pytest.approx(SENSORS.attitude_tolerance / 0.3, rel=0.2)


def test_what_small_angle_kinematics_neglect_widens_the_attitude_bound():
    quiet, coupled = AttitudeCheck("roll", SENSORS), AttitudeCheck("roll", SENSORS)
    for _ in range(40):  # 5 mrad/s off: the neglected rate × tilt terms can be that large
        quiet.update(0.0, 0.1, 0.0, DT)
        coupled.update(0.0, 0.1, 0.5, DT)
    assert coupled.peak < quiet.peak


# ------------------------------------------------------------------------------ speed vs accelerometer
def test_the_plants_accelerometer_integrates_to_its_speed_change():
    # Physics against physics: MuJoCo's accelerometer (the IMU point's specific force) integrated over a
    # window equals the change of the IMU point's velocity the wheel rates, gyro and attitude give, in both
    # directions of the heading frame, while the robot accelerates, leans, turns and stops. Turning at 0.8
    # rad/s at 0.85 m/s, the frame's own turn (0.7 m/s² here) is most of it: left out, the check trips.
    plant, bal = turning_plant()
    to_relative = np.linalg.inv(motor_jacobian(GEOMETRY))
    checks = (TrendCheck("forward", SENSORS, DT), TrendCheck("left", SENSORS, DT))
    frame_fixed = TrendCheck("left", SENSORS, DT)
    h, r = ROBOT.body.imu_height, ROBOT.ball.radius
    for k in range(1600):
        drive_turning(plant, bal, k)
        (roll, pitch, _), rate, accel = plant.imu_truth()
        relative = to_relative @ np.asarray(plant.motor_angles_and_rates()[1])
        (forward, a_forward), (left, a_left) = trend_inputs(relative, rate, accel, roll, pitch, r, h)
        assert checks[0].update(forward, a_forward, DT) is None
        assert checks[1].update(left, a_left, DT) is None
        frame_fixed.update(left, heading_frame(accel, roll, pitch)[1], DT)
    assert max(c.peak for c in checks) < 0.3
    assert frame_fixed.peak > 1.0, "without the frame's turn the left trend would trip"
    # Positive control: a speed read 50 % high is a disagreement once the robot accelerates (1 m/s²).
    check = TrendCheck("forward", SENSORS, DT)
    found = [check.update(1.5 * 1.0 * k * DT, 1.0, DT) for k in range(400)]
    assert any(found)


# ------------------------------------------------------------------------------------------- stuck
def test_a_repeated_value_is_stuck_only_when_other_evidence_moved():
    still = Stuck(20, need=3e-4)
    assert not any(still.sample(0.1234, 0.0) for _ in range(100)), "at rest a constant reading is fine"
    moving = Stuck(20, need=3e-4)
    flags = [moving.sample(0.1234, 1e-4) for _ in range(25)]
    assert flags.index(True) == 19
    assert not moving.sample(0.1235, 1e-4), "a new value ends the run"


XSENS_RATE = 2**-9
"""rad/s: the Xsens profile's gyro step (configs/devices/xsens_mti.dbc), about twice the gyro's noise."""


def test_the_run_that_shows_a_channel_frozen_grows_with_its_streams_step_against_its_noise():
    sigma = SENSORS.rate_noise
    assert live_run(1e-3, 1e-3, sigma, 20) == 20, "at the contract's step: stuck_samples"
    assert live_run(1e-4, 1e-3, sigma, 20) == 20, "a finer step is taken as the contract's"
    n = live_run(XSENS_RATE, 1e-3, sigma, 20)
    assert n == 54

    def stay(q):  # a live reading's chance to stay on its step for one more frame (the worst case)
        return math.erf(q / (2 * math.sqrt(2) * sigma))

    # The same chance for a live channel as 20 frames at the contract's step, and no shorter run has it.
    assert stay(XSENS_RATE) ** (n - 1) <= stay(1e-3) ** 19 < stay(XSENS_RATE) ** (n - 2)
    assert live_run(2 * XSENS_RATE, 1e-3, sigma, 20) > n
    assert live_run(100 * sigma, 1e-3, sigma, 20) == math.inf, "a step a live reading never leaves"


def near_rest(rng, n, q):
    """A live gyro channel near rest as a stream of step q carries it: a slow true rate within a quarter
    step of zero plus the configured noise, rounded to the step (the emulated Xsens: round to the count)."""
    true = 0.25 * q * np.sin(np.arange(n) * DT * 2 * math.pi / 3.0)
    return [round(float(v) / q) * q for v in true + rng.normal(0.0, SENSORS.rate_noise, n)]


def test_a_live_channel_at_the_xsens_step_near_rest_is_not_stuck_and_a_frozen_one_is():
    rng = np.random.default_rng(1)
    live = near_rest(rng, 40 * 400, XSENS_RATE)  # 40 s
    moved = 1e-3  # the evidence: the attitude's noise alone moves it this much a frame
    check = Stuck(20, 3e-4, Resolution(1e-3, SENSORS.rate_noise, 20))
    assert not any(check.sample(v, moved) for v in live)
    assert check.resolution.step == XSENS_RATE and check.required == 54
    # Test the test: judged by the contract's 20 frames, the same live stream looks frozen.
    old = Stuck(20, 3e-4)
    assert any(old.sample(v, moved) for v in live)
    # The positive control: frozen at a value of the xsens step (a rate it had while moving), the channel is
    # found at its 54th frame.
    flags = [check.sample(7 * XSENS_RATE, moved) for _ in range(60)]
    assert flags.index(True) == 53 and all(flags[53:])
    # Without other evidence (a robot truly at rest, the evidence silent) it is not.
    resting = Stuck(20, 3e-4, Resolution(1e-3, SENSORS.rate_noise, 20))
    for v in live[:400]:
        resting.sample(v, 0.0)
    assert not any(resting.sample(live[399], 0.0) for _ in range(200))


def test_at_the_contracts_step_a_frozen_channel_is_found_after_stuck_samples_and_a_live_one_is_not():
    rng = np.random.default_rng(2)
    live = near_rest(rng, 40 * 400, 1e-3)
    resolution = Resolution(1e-3, SENSORS.rate_noise, 20)
    check = Stuck(20, 3e-4, resolution)
    assert not any(check.sample(v, 1e-3) for v in live)
    assert check.required == 20
    frozen = 0.123  # a value the live stream never had: the run starts at the first frozen frame
    flags = [check.sample(frozen, 1e-3) for _ in range(25)]
    assert flags.index(True) == 19
    # A stream whose steps were never seen (frozen from the start) is judged at the contract's step.
    fresh = Stuck(20, 3e-4, Resolution(1e-3, SENSORS.rate_noise, 20))
    assert [fresh.sample(0.5, 1e-3) for _ in range(25)].index(True) == 19


def test_a_replay_from_one_counter_period_back_is_seen_and_a_live_or_constant_stream_is_not():
    rng = np.random.default_rng(0)
    live = Replay(16)
    assert not any(live.frame((round(float(x), 4),)) for x in rng.normal(0, 1e-3, 2000))
    constant = Replay(16)
    assert not any(constant.frame((0.0, 1)) for _ in range(200))
    replay = Replay(16)
    recorded = [(round(float(x), 4),) for x in rng.normal(0, 1e-3, 16)]
    flags = [replay.frame(recorded[i % 16]) for i in range(64)]
    assert flags.index(True) == 31, "a whole cycle replayed after the recorded one"


# ------------------------------------------------------------------------------------------- torque
def test_measured_torque_must_follow_the_command():
    check = TorqueCheck(1, 0.15, 0.1, 3, 3.75)
    assert all(check.sample(c + 0.01, c, True) is None for c in np.linspace(-4, 4, 50))  # clamped at 3.75
    assert check.sample(0.0, 2.0, False) is None, "a disabled drive makes none"
    found = [check.sample(0.0, 1.0, True) for _ in range(3)]
    assert found[:2] == [None, None] and found[2].cause is Cause.ACTUATOR_MISMATCH
    # It names its drive: the recovery law balances on the other two only if the diagnosis says which one
    # is dead (without the name it commanded the dead drive, and a dead drive 2 or 3 in motion fell).
    assert found[2].parts == ("Drive1",)


def test_a_drive_at_its_top_speed_makes_less_than_it_is_told_and_is_not_named_for_it():
    """Near its no-load speed a motor's back-EMF leaves less torque than commanded (plant/drives.py): a
    physical limit, not a fault. The check expects what the motor's line allows at the reported speed."""
    from plant.drives import MotorDrive
    from plant.params import RobotParams

    params = RobotParams().drive
    plant_drive = MotorDrive(params)
    check = TorqueCheck(1, 0.15, 0.1, 3, params.torque_limit, params.stall_torque, params.no_load_speed)
    for speed in np.linspace(-1.2 * params.no_load_speed, 1.2 * params.no_load_speed, 41):
        for told in (-params.torque_limit, -1.0, 0.5, params.torque_limit):
            made = plant_drive.available(told, speed)
            assert [check.sample(made, told, True, speed) for _ in range(4)] == [None] * 4, (speed, told)
    # Spinning up, the drive set its torque at the speed the tick began with, and reports the next one.
    fresh = TorqueCheck(3, 0.15, 0.1, 3, params.torque_limit, params.stall_torque, params.no_load_speed)
    before, now = 241.0, 249.5
    made = plant_drive.available(params.torque_limit, before)
    assert [fresh.sample(made, params.torque_limit, True, now, before) for _ in range(4)] == [None] * 4
    alone = TorqueCheck(3, 0.15, 0.1, 3, params.torque_limit, params.stall_torque, params.no_load_speed)
    named = [alone.sample(made, params.torque_limit, True, now) for _ in range(3)][-1]
    assert named is not None, "judged at the reported speed alone, a healthy drive spinning up was named"
    # Positive control: the same shortfall at rest is a drive that fails to follow.
    top = 0.98 * params.no_load_speed
    made = plant_drive.available(params.torque_limit, top)
    found = [check.sample(made, params.torque_limit, True, 0.0) for _ in range(3)]
    assert found[2] is not None and found[2].cause is Cause.ACTUATOR_MISMATCH


# --------------------------------------------------------------------------------------------- seat
def seated(check, n=400, load=600.0, **kw):
    return [
        check.sample((0.0, 0.0, -load), (0.0, -15.0, 0.0), (-0.025, 0.0), 9.80665, 1e-3, **kw)
        for _ in range(n)
    ]


def seat_check():
    return SeatCheck(CFG.seat, CFG.motion.rider_min_load, GEOMETRY.body.seat_height, DT, 3e-4)


def test_the_seat_tares_the_rider_and_accepts_what_a_rider_does():
    check = seat_check()
    # Noise so the values are not frozen; a slow lean moves the COP and the moment together.
    rng = np.random.default_rng(0)
    for k in range(2000):
        fz = -600.0 + rng.normal(0, 1)
        my = -15.0 - 40.0 * math.sin(k * DT)
        cop = ((0.03 * 0.0 - my) / fz, 0.0)
        assert check.sample((0.0, 0.0, fz), (0.0, my, 0.0), cop, 9.80665, 1e-3) is None
    assert check.tare == pytest.approx(600.0, abs=1.0)


@pytest.mark.parametrize(
    "wrench, what",
    [
        (((0.0, 0.0, -1900.0), (0.0, -15.0, 0.0), (-0.008, 0.0)), "load"),
        (((0.0, 0.0, -400.0), (0.0, -15.0, 0.0), (-0.0375, 0.0)), "load"),
        (((0.0, 0.0, -600.0), (0.0, -240.0, 0.0), (-0.4, 0.0)), "centre of pressure"),
        # The seat reports a COP off its footprint at the edge (plant/sensors.py cop): the wrench's own is
        # judged, not a "reported COP" fault of the seat's.
        (((0.0, 0.0, -600.0), (0.0, -240.0, 0.0), (-0.3, 0.0)), "centre of pressure 0.400 m"),
        (((0.0, 0.0, -600.0), (0.0, -15.0, 0.0), (0.1, 0.0)), "reported COP"),
    ],
)
def test_a_seat_wrench_no_seated_rider_makes_is_implausible(wrench, what):
    check = seat_check()
    rng = np.random.default_rng(0)
    for _ in range(400):
        check.sample((0.0, 0.0, -600.0 + rng.normal()), (0.0, -15.0, 0.0), (-0.025, 0.0), 9.80665, 1e-3)
    found = check.sample(*wrench, 9.80665, 1e-3)
    assert found is not None and found.cause is Cause.WRENCH_IMPLAUSIBLE and what in found.detail


def test_a_seat_that_jumps_faster_than_a_body_or_freezes_is_implausible():
    check = seat_check()
    rng = np.random.default_rng(0)
    for _ in range(400):
        check.sample((rng.normal(), 0.0, -600.0), (0.0, -15.0, 0.0), (-0.025, 0.0), 9.80665, 1e-3)
    h = GEOMETRY.body.seat_height
    jump = check.sample(
        (250.0, 0.0, -600.0), (0.0, -15.0, 0.0), ((h * 250.0 + 15.0) / -600.0, 0.0), 9.80665, 1e-3
    )
    assert "force changing" in jump.detail
    frozen = seat_check()
    found = seated(frozen, n=500)
    assert any(f and "frozen" in f.detail for f in found)
    resting = seat_check()  # frozen values while the chassis does not move at all: no evidence
    assert not any(
        f and "frozen" in f.detail
        for f in [
            resting.sample((0.0, 0.0, -600.0), (0.0, -15.0, 0.0), (-0.025, 0.0), 9.80665, 0.0)
            for _ in range(500)
        ]
    )


def test_a_dead_load_cell_that_hides_in_the_weight_band_is_seen_in_its_raw_reading():
    """The seat's own model makes the samples: a rider leaning off cell 1 so it carries ~60 N of a 600 N
    rider. Read as 0 N, the wrench only loses 10 % of the weight: within the band, consistent in itself."""
    from plant.params import Tes
    from plant.sensors import TesModel

    seat = TesModel(Tes(), GEOMETRY.body.seat_height, np.random.default_rng(1))
    wrench = np.array([0.0, 0.0, -600.0, 25.0, -15.0, 0.0])  # leaning right: cell 1 (body +y) unloads
    assert 40.0 < -(seat.to_cells @ wrench)[0] < 90.0

    def run(dead: bool, with_cells: bool) -> list:
        check = seat_check()
        found = []
        for k in range(800):
            s = seat.sample(wrench)
            if dead and k >= 400:
                s = seat.from_cells([0.0, *s.cells[1:]])
            found.append(
                check.sample(s.force, s.moment, s.cop, 9.80665, 1e-3, s.cells if with_cells else None)
            )
        return found

    dead = run(dead=True, with_cells=True)
    first = next(k for k, f in enumerate(dead) if f is not None)
    assert first == 400 + CFG.seat.stuck_samples - 1 and "load cell 1" in dead[first].detail
    assert not any(run(dead=False, with_cells=True)), "a live cell's noise never repeats"
    # Positive control: the wrench alone (a seat that does not publish its cells) never shows it.
    assert not any(run(dead=True, with_cells=False))


def test_a_drive_that_reports_itself_off_yet_makes_what_it_was_told_is_not_a_torque_mismatch():
    """Told to enable, a drive whose status says off (a bit flipped where nothing protects the frame, as in
    CAN Simple's heartbeat or a CANopen PDO) but whose measured torque follows the command is not named for
    its torque: what is wrong is its report, which the state machine judges (DRIVE_FAULT). Named as before:
    one that makes nothing while on, and one that reports itself off and makes something it was not told."""
    check = TorqueCheck(1, 0.15, 0.1, 3, 3.75)
    assert [check.sample(1.2, 1.2, False, asked=True) for _ in range(5)] == [None] * 5
    assert [check.sample(0.0, 1.2, False, asked=True) for _ in range(5)] == [None] * 5, "off, and makes none"
    wrong = [check.sample(-1.2, 1.2, False, asked=True) for _ in range(3)]
    assert wrong[2] is not None and wrong[2].cause is Cause.ACTUATOR_MISMATCH
    not_asked = TorqueCheck(1, 0.15, 0.1, 3, 3.75)
    found = [not_asked.sample(1.2, 1.2, False, asked=False) for _ in range(3)]
    assert found[2] is not None, "told to stay off, it makes torque: named"
    dead = TorqueCheck(1, 0.15, 0.1, 3, 3.75)
    assert [dead.sample(0.0, 1.2, True, asked=True) for _ in range(3)][2] is not None, "a dead drive: named"
