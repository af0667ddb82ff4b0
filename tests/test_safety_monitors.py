"""The supervisor's observations from real frames: its own speed estimate against the plant's truth,
integrity counting, and the per-update parts."""

import functools
import math

import numpy as np
import pytest

from drivers.can_bus import CanNode
from drivers.config import load_toml
from drivers.robot import RobotModel
from drivers.schemas import EstopCommand, ScRequest, TesWrench
from drivers.vocabulary import Cause
from plant.ballbot import Plant
from plant.params import RobotParams, SimParams
from safety.config import SupervisorConfig
from safety.monitors import Monitors, motor_jacobian
from tests.helpers import RIDER_75, ROOT

ROBOT = ROOT / "configs/robot/pure.toml"


class FakeBus:
    """CanNode only needs send() here: frames are decoded straight back."""

    def send(self, msg):
        self.last = msg


def frames(plant: Plant):
    """Drive feedback and IMU frames of the plant now, as the rig sends them, decoded by a receiver."""
    tx, rx = CanNode(FakeBus(), name="tx"), CanNode(FakeBus(), name="rx")
    feedback = plant.sample_drives()
    imu = plant.sample_imu()
    out = []
    for i, fb in enumerate(feedback, start=1):
        values = {"Position": fb.counts, "Velocity": fb.velocity, "Enabled": 1, "WatchdogTripped": 0}
        out.append(rx.decode(tx.message(f"DRIVE{i}_FEEDBACK", values)))
    att = {"Roll": imu.attitude[0], "Pitch": imu.attitude[1], "Yaw": imu.attitude[2], "Valid": 1}
    out.append(rx.decode(tx.message("IMU_ATTITUDE", att)))
    rate = {"RateX": imu.rate[0], "RateY": imu.rate[1], "RateZ": imu.rate[2], "Valid": 1}
    out.append(rx.decode(tx.message("IMU_RATE", rate)))
    return out


def monitors() -> Monitors:
    return Monitors(SupervisorConfig(), load_toml(ROBOT, RobotModel))


def test_own_jacobian_matches_the_plant_kinematics():
    from plant.omniwheel import motor_jacobian as plant_jacobian

    robot = load_toml(ROBOT, RobotParams)
    expected = plant_jacobian(robot.ball.radius, robot.drivetrain)
    assert motor_jacobian(load_toml(ROBOT, RobotModel)) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize(
    "ball_rate, tilt_rate, yaw_rate",
    [((8.0, 0.0), (0.0, 0.0), 0.0), ((5.0, -6.0), (0.4, -0.3), 0.0), ((-3.0, 2.0), (-0.5, 0.2), 0.8)],
)
def test_speed_estimate_matches_the_truth(ball_rate, tilt_rate, yaw_rate):
    plant = Plant(load_toml(ROBOT, RobotParams), RIDER_75, SimParams(seed=3))
    x = plant.x
    x[3], x[9] = ball_rate
    x[4], x[10] = tilt_rate
    x[13] = yaw_rate
    m = monitors()
    for rx in frames(plant):
        m.frame(rx, 0.0)
    truth = math.hypot(*plant.truth().velocity)
    # Noise: motor velocity 0.05 rad/s and its 0.01 rad/s quantisation, gyro; a few mm/s at the ball.
    assert m.speed() == pytest.approx(truth, abs=0.01)
    assert m.tilt() == pytest.approx(max(abs(x[1]), abs(x[7])), abs=0.002)


def test_no_estimate_until_both_speed_streams_spoke():
    m = monitors()
    assert m.speed() is None and m.tilt() is None
    plant = Plant(load_toml(ROBOT, RobotParams), None, SimParams())
    for rx in frames(plant)[:3]:
        m.frame(rx, 0.0)
    assert m.speed() is None, "drives alone: the chassis rate is missing"


def test_untrusted_frames_change_nothing_and_count_as_errors():
    m = monitors()
    tx, rx = CanNode(FakeBus()), CanNode(FakeBus())
    good = tx.message("DRIVE1_COMMAND", {"Torque": 1.0, "Tick": 1, "Enable": 1})
    m.frame(rx.decode(good), 0.0)
    bad = tx.message("DRIVE1_COMMAND", {"Torque": 3.0, "Tick": 2, "Enable": 1})
    bad.data[0] ^= 0x01  # a bit flip: the CRC fails
    m.frame(rx.decode(bad), 0.1)
    obs = m.observe(0.2)
    assert obs.torque_peak == pytest.approx(1.0)
    assert obs.e2e_errors == 1
    assert obs.e2e_invalid == (), "one corrupted frame is transient"
    for i in range(SupervisorConfig().integrity.drive_command.window):
        m.frame(rx.decode(tx.message("DRIVE1_COMMAND", {"Torque": 1.0, "Tick": 3 + i, "Enable": 1})), 0.2)
    assert m.observe(0.3).e2e_errors == 0, "errors age out of the stream's window"


def test_per_update_parts_start_afresh():
    m = monitors()
    m.operator_command(EstopCommand(seq=1, stamp=0.0, action="estop", source="op"))
    m.operator_command(EstopCommand(seq=2, stamp=0.0, action="reset", source="op"))
    first = m.observe(1.0)
    assert first.operator == "estop", "an e-stop outranks a reset that arrived after it in one update"
    assert m.observe(1.1).operator is None


def test_zenoh_inputs_set_ages_and_values():
    m = monitors()
    m.wrench(
        TesWrench(seq=1, stamp=0.0, force=(0.0, 0.0, -600.0), moment=(0.0, 0.0, 0.0), cop=(0.0, 0.0)), 1.0
    )
    m.sc_request(ScRequest(seq=1, stamp=0.0, mode="limit", speed_cap=0.5, source="agent"), 1.0)
    obs = m.observe(1.5)
    assert obs.seat_load == 600.0
    assert (obs.request.mode, obs.request.speed_cap) == ("limit", 0.5)
    assert obs.ages["wrench"] == obs.ages["sc"] == 0.5
    assert obs.ages["heartbeat"] == math.inf


def test_a_stale_wrench_repeated_unchanged_does_not_feed_the_watchdog():
    """Found by the zenoh.wrench_stale fault: a seat re-publishing its last sample looked alive."""
    m = monitors()
    sample = TesWrench(seq=7, stamp=0.1, force=(0.0, 0.0, -600.0), moment=(0.0, 0.0, 0.0), cop=(0.0, 0.0))
    m.wrench(sample, 1.0)
    m.wrench(sample, 1.2)
    m.wrench(sample, 1.4)
    assert m.observe(1.5).ages["wrench"] == pytest.approx(0.5)
    assert m.stale_wrench == 2
    m.wrench(TesWrench(seq=0, stamp=0.0, force=(0.0, 0.0, -600.0), moment=(0.0,) * 3, cop=(0.0, 0.0)), 1.5)
    assert m.observe(1.5).ages["wrench"] == 0.0, "a restarted seat (seq from 0) is fresh"


# ----------------------------------------------------------------------------------- stuck IMU channels
def imu_near_rest(rng: np.random.Generator, rate_y: float | None = None) -> dict[str, dict[str, float]]:
    """One IMU sample of a robot near rest with the configured noise (rate_y: RateY frozen at it)."""
    s = SupervisorConfig().sensors
    a, g, f = (rng.normal(0.0, sigma, 3) for sigma in (s.attitude_noise, s.rate_noise, s.accel_noise))
    return {
        "IMU_ATTITUDE": {"Roll": a[0], "Pitch": 0.01 + a[1], "Yaw": 0.3 + a[2], "Valid": 1},
        "IMU_RATE": {"RateX": g[0], "RateY": g[1] if rate_y is None else rate_y, "RateZ": g[2], "Valid": 1},
        "IMU_ACCEL": {"AccX": f[0], "AccY": f[1], "AccZ": 9.80665 + f[2], "Valid": 1},
    }


def contract_imu():
    """The sample as the contract's IMU frames, decoded by the supervisor's node."""
    tx, rx = CanNode(FakeBus(), name="tx"), CanNode(FakeBus(), name="rx")
    return lambda sample, k: [rx.decode(tx.message(name, values)) for name, values in sample.items()]


def xsens_imu():
    """The sample as the emulated Xsens group, read by the supervisor's host (drivers/devices/xsens.py)."""
    from drivers.devices import Devices
    from drivers.devices.xsens import XsensHost
    from hil.devices.xsens import XsensImu

    devices = Devices(imu="xsens")
    imu, host = XsensImu(devices, 8192, 400.0), XsensHost(devices, 8192, "supervisor")

    def send(sample, k):
        frames = [f for name, values in sample.items() for f in imu.outgoing(name, values)]
        imu.on_sync(k)
        return [rx for f in frames if (rx := host.incoming(f)) is not None]

    return send


@pytest.mark.parametrize("profile, required", [("pure", 20), ("xsens", 54)])
def test_a_live_imu_near_rest_is_not_stuck_and_a_frozen_rate_is_found(profile, required):
    """Near rest a live Xsens RateY (2^-9 rad/s steps, about twice the gyro's noise) reads one value for
    20 frames and more: at its step the check asks 54 (the same chance for a live channel as 20 at the
    contract's 1e-3); a rate frozen while the attitude moves is found at that many, on either profile."""
    m, rng = monitors(), np.random.default_rng(7)
    send = contract_imu() if profile == "pure" else xsens_imu()
    dt, k = 1.0 / 400, 0
    for k in range(1, 20 * 400):  # 20 s near rest
        for rx in send(imu_near_rest(rng), k):
            m.frame(rx, k * dt)
        assert not [f for f in m.findings(k * dt) if f.cause is Cause.SENSOR_STUCK], (profile, k * dt)
    assert m.imu_resolution["IMU_RATE"].samples == required
    found = []
    for i in range(required + 5):  # RateY frozen at a rate it has while moving (the sensor.stuck fault)
        t = (k + 1 + i) * dt
        for rx in send(imu_near_rest(rng, rate_y=0.0137), k + 1 + i):
            m.frame(rx, t)
        found.append([f for f in m.findings(t) if f.cause is Cause.SENSOR_STUCK])
    first = next(i for i, f in enumerate(found) if f)
    assert first == required - 1 and found[first][0].parts == ("RateY",), found[first]


def test_judged_by_the_contracts_20_frames_the_same_live_xsens_stream_looks_frozen():
    """Test the test: without the stream's own step (20 frames whatever it is) the live stream above trips,
    as speed_limiting on the xsens bench did at 0.503 s."""
    from safety.diagnostics import Stuck
    from safety.monitors import MOVED

    m, rng, send = monitors(), np.random.default_rng(7), xsens_imu()
    # The checks as they were, without a resolution (the compiled build's classes cannot be patched).
    for name, checks in m._imu_stuck.items():
        m._imu_stuck[name] = [Stuck(20, MOVED) for _ in checks]
    for k in range(1, 20 * 400):
        for rx in send(imu_near_rest(rng), k):
            m.frame(rx, k / 400)
        if found := [f for f in m.findings(k / 400) if f.cause is Cause.SENSOR_STUCK]:
            assert "for 20 frames" in found[0].detail
            return
    pytest.fail("the live stream never looked frozen: the test above proves nothing")


def test_the_contract_steps_the_stuck_check_starts_from_are_the_dbcs():
    from drivers.can_codec import Catalog
    from safety.monitors import CONTRACT_STEP, IMU_CHANNELS

    catalog = Catalog()
    for name, step in CONTRACT_STEP.items():
        scales = {s.name: s.scale for s in catalog[name].signals}
        assert all(scales[signal] == step for signal in IMU_CHANNELS[name]), name


# ------------------------------------------------------------------------------ a drive the law loses
def drive_flags(plant: Plant, tripped: set[int]):
    """The plant's frames with the drives in `tripped` (1-3) reporting their command watchdog tripped."""
    out = frames(plant)
    tx, rx = CanNode(FakeBus(), name="tx"), CanNode(FakeBus(), name="rx")
    for i in tripped:
        fb = out[i - 1].signals
        values = {"Position": fb["Position"], "Velocity": fb["Velocity"], "Enabled": 0, "WatchdogTripped": 1}
        out[i - 1] = rx.decode(tx.message(f"DRIVE{i}_FEEDBACK", values))
    return out


def named_drives(m: Monitors, plant: Plant, ticks: int, t0: float, tripped, law: bool) -> list[frozenset]:
    """`ticks` updates at 400 Hz from t0; with `law`, the recovery law commands the drives after each."""
    out = []
    for k in range(ticks):
        t = t0 + k / 400
        for rx in drive_flags(plant, tripped(k)):
            m.frame(rx, t)
        m.observe(t)
        out.append(frozenset(n for n in m.named if n.startswith("Drive")))
        if law:
            m.recovery_commanded((0.1, 0.1, 0.1))
    return out


def test_a_drive_that_stays_off_under_the_recovery_law_is_named_and_one_that_comes_back_is_not():
    """A drive the recovery law's commands do not reach (cia402: they ride in its lost RPDO1) reports its
    watchdog tripped for as long as the law holds the drives: after drives.confirm it is named, and the
    law balances on the other two. Drives that come back within a few frames of the takeover (a dead
    controller's tripped watchdogs) are not; nor is a tripped drive before any takeover (the controller's
    own commands are lost: a DRIVE_FAULT the law may still fix)."""
    plant = Plant(load_toml(ROBOT, RobotParams), RIDER_75, SimParams(seed=3))
    confirm_ticks = round(SupervisorConfig().drives.confirm * 400)
    m = monitors()
    before = named_drives(m, plant, 40, 0.0, lambda k: {2}, law=False)
    assert not any(before), "no takeover: nothing named"
    lost = named_drives(m, plant, 20, 0.1, lambda k: {2}, law=True)
    first = next(k for k, named in enumerate(lost) if named)
    assert lost[first] == {"Drive2"} and confirm_ticks <= first <= confirm_ticks + 2
    assert lost[-1] == {"Drive2"}, "latched"
    # Control: all three tripped at the takeover (a dead controller), back on the law's commands in 4 frames.
    m = monitors()
    named_drives(m, plant, 10, 0.0, lambda k: set(), law=False)
    back = named_drives(m, plant, 30, 0.025, lambda k: {1, 2, 3} if k < 4 else set(), law=True)
    assert not any(back)


def test_one_drives_monitor_reports_only_what_is_fresh_and_times_a_drive_that_stays_off():
    """safety/drive_monitor.py alone: a report says nothing of a drive not heard within the timeout (None,
    not its last word), counts how long the drive has been commanded on, and `dead_to_the_law` names a drive
    only once it has stayed off under the law for `confirm`, and never while the law does not hold it."""
    from safety.drive_monitor import Drive

    period, confirm = 1 / 400, 0.05
    drive = Drive(2, SupervisorConfig(), load_toml(ROBOT, RobotModel), period)
    frame = {"Position": 0, "Velocity": 0.0, "Enabled": 0, "WatchdogTripped": 1, "Fault": 0, "BusPowered": 1}
    drive.feedback(frame, 1.0, 0)
    drive.commanded({"Torque": 0.5, "Enable": 1}, 1.0)
    fresh = drive.report(1.0 + period, timeout=0.02)
    assert (fresh.enabled, fresh.watchdog, fresh.bus_powered) == (False, True, True)
    assert fresh.commanded_for == pytest.approx(period)
    stale = drive.report(1.03, timeout=0.02)
    assert (stale.enabled, stale.watchdog, stale.bus_powered) == (None, False, None)
    assert not drive.dead_to_the_law(1.0, held=False, confirm=confirm), "not held: not the law's to judge"
    ticks = [drive.dead_to_the_law(1.0 + k * period, held=True, confirm=confirm) for k in range(30)]
    assert ticks.index(True) == round(confirm / period), "named after exactly `confirm` off"
    drive.feedback({**frame, "Enabled": 1, "WatchdogTripped": 0}, 1.1, 0)
    assert not drive.dead_to_the_law(1.1, held=True, confirm=confirm), "back on: the count starts again"


# ----------------------------------------------------------------------- a drive's frame that lies
@functools.cache
def rolling_geometry() -> tuple[np.ndarray, float]:
    """The robot file's motor Jacobian and encoder counts per rad, read once for every tick's frames."""
    robot = load_toml(ROBOT, RobotModel)
    return motor_jacobian(robot), robot.encoder.counts_per_rev / (2 * math.pi)


def rolling_frames(
    rng: np.random.Generator,
    t: float,
    ball_rate: float = 0.0,
    lie: float = 0.0,
    fault1: int = 0,
    accel_x: float = 0.0,
):
    """The contract's frames of a robot rolling sideways at a steady `ball_rate` (rad/s about the ball's x
    axis), upright, not turning: drive 1's reported velocity off by `lie` rad/s (its position true) and
    reporting `fault1`; the accelerometer off by `accel_x` m/s² forward."""
    jacobian, per_rad = rolling_geometry()
    velocities = jacobian @ np.array([ball_rate, 0.0, 0.0])
    tx, rx = CanNode(FakeBus(), name="tx"), CanNode(FakeBus(), name="rx")
    sample = imu_near_rest(rng)
    sample["IMU_ACCEL"]["AccX"] += accel_x
    for i, v in enumerate(velocities, 1):
        sample[f"DRIVE{i}_FEEDBACK"] = {
            "Position": round(v * t * per_rad),
            "Velocity": v + rng.normal(0.0, 0.05) + (lie if i == 1 else 0.0),  # live: not frozen
            "Enabled": 1,
            "WatchdogTripped": 0,
            "Fault": fault1 if i == 1 else 0,
            "BusPowered": 1,
        }
    return [rx.decode(tx.message(name, values)) for name, values in sample.items()]


def named_over(m: Monitors, rng: np.random.Generator, ticks: int, t0: float, **how) -> list[frozenset[str]]:
    """`ticks` updates at 400 Hz from t0 on `rolling_frames(how)`: what the diagnosis names after each."""
    out = []
    for k in range(ticks):
        t = t0 + k / 400
        for rx in rolling_frames(rng, t, **how):
            m.frame(rx, t)
        m.observe(t)
        out.append(frozenset(m.named))
    return out


IMU_PARTS = {"Accel", "Roll", "Pitch", "RateX", "RateY", "RateZ"}


def test_a_lying_encoder_that_fails_the_speed_trend_first_leaves_the_imu_unblamed():
    """The speed trend rests on the encoders and the accelerometer. In motion a drive's velocity that jumps
    for a frame (a bit flipped where no CRC guards it, as on CAN Simple) fails the trend at once, while the
    encoder's own position-vs-velocity window, whose bound grows with the speed, names it a frame later;
    the trend's blame fell on an IMU channel in between. Once the encoder is named it explains the trend:
    the IMU is not blamed any more (it stayed blamed, and on odrive's `slalom` the recovery law balanced
    without the accelerometer and the pitch rate, and fell)."""
    m, rng = monitors(), np.random.default_rng(3)
    assert not any(named_over(m, rng, 400, 0.0, ball_rate=5.0)), "rolling, honest frames: nothing named"
    lied = named_over(m, rng, 1, 1.0, ball_rate=5.0, lie=40.0) + named_over(m, rng, 40, 1.0025, ball_rate=5.0)
    assert lied[0] & IMU_PARTS and "Encoder1" not in lied[0], "the trend fails first and blames the IMU"
    assert lied[-1] == {"Encoder1"}, lied[-1]
    # Positive control: the accelerometer lying, the encoders honest, is still what the trend blames.
    m = monitors()
    named_over(m, rng, 400, 0.0, ball_rate=5.0)
    accel = named_over(m, rng, 120, 1.0, ball_rate=5.0, accel_x=3.0)
    assert accel[-1] == {"Accel"}, accel[-1]


def test_one_fault_report_does_not_name_a_drive_lost_and_one_that_persists_does():
    """A drive's own fault report names it lost to the recovery law only once it has stood for
    drives.confirm: one frame with the bit set (a flipped bit where nothing protects the frame) is ridden
    through, as a burst shorter than an E2E window is. The state machine still reacts to the first report
    (DRIVE_FAULT: safety/machine.py); this is only whom the law leaves out."""
    m, rng = monitors(), np.random.default_rng(5)
    named_over(m, rng, 400, 0.0)
    m.recovery_commanded((0.1, 0.1, 0.1))
    once = named_over(m, rng, 1, 1.0, fault1=1) + named_over(m, rng, 40, 1.0025)
    assert not any("Drive1" in named for named in once), "one report: not named"
    confirm_ticks = round(SupervisorConfig().drives.confirm * 400)
    held = named_over(m, rng, 20, 2.0, fault1=1)
    first = next(k for k, named in enumerate(held) if "Drive1" in named)
    assert first == confirm_ticks, "named once the report has stood for `confirm`"
    assert "Drive1" in named_over(m, rng, 5, 2.05)[-1], "latched"
