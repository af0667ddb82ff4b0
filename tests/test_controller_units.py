"""The reference controller's parts, checked against physics and against independent solutions."""

import math

import numpy as np
import pytest

from controller.balance import equilibrium
from controller.command import CommandSpeed, deadband
from controller.config import ControllerConfig, Hacs, Lqr, RiderInfo, RiderProfile
from controller.core import Controller, Fault, Wrench
from controller.estimator import Estimator
from controller.model import lqr_gain, motor_jacobian, plane_model
from drivers.config import load_toml
from drivers.robot import RobotModel
from drivers.schemas import ScCommand
from drivers.vocabulary import ControllerState
from plant.ballbot import Plant, plane_params
from plant.params import RobotParams
from tests.helpers import RIDER_75, ROOT, sim

ROBOT = load_toml(ROOT / "configs/robot/pure.toml", RobotModel)


def test_lqr_gains_match_python_control():
    import control

    model = plane_model(ROBOT, 60.0, 1.80, "pitch")
    weights = Lqr()
    k = lqr_gain(model, weights)
    idx = [0, 2, 3]
    a, b = model.a[np.ix_(idx, idx)], model.b[idx]
    q, r = np.diag([weights.q_tilt, weights.q_tilt_rate, weights.q_ball_rate]), np.array([[weights.r_torque]])
    expected, _, _ = control.lqr(a, b, q, r)
    np.testing.assert_allclose(k[[0, 2, 3]], np.asarray(expected).ravel(), rtol=1e-8)
    assert k[1] == 0.0  # no gain on φ
    closed = np.linalg.eigvals(a - b @ k[[0, 2, 3]][None, :])
    assert (closed.real < 0).all()


def test_controller_model_agrees_with_the_plant_lumped_model():
    # Two independent lumpings (the controller's rigid-rider approximation, the plant's segments).
    ours = plane_model(ROBOT, 75.0, 1.75, "pitch")
    p = plane_params(RobotParams(), RIDER_75, "pitch", torso=False)
    assert ours.mass == pytest.approx(p.chassis.mass)
    assert ours.com == pytest.approx(p.chassis.up, abs=0.005)
    assert ours.unstable_pole == pytest.approx(6.0, abs=0.1)


def test_estimator_inverts_the_plant_kinematics_on_noiseless_data():
    plant = Plant(RobotParams(), None, sim(fixture="clamped"))
    rng = np.random.default_rng(2)
    est = Estimator(motor_jacobian(ROBOT), ROBOT.encoder.counts_per_rev, hold=1.0)
    plant.x[:] = [0.0] * 14
    for trial in range(20):
        phi_p, th_p, phi_r, th_r, yaw = rng.uniform(-3, 3, 5) * [10, 0.1, 10, 0.1, 2]
        rates = rng.uniform(-5, 5, 5)
        plant.x[0], plant.x[1], plant.x[3], plant.x[4] = phi_p, th_p, rates[0], rates[1]
        plant.x[6], plant.x[7], plant.x[9], plant.x[10] = phi_r, th_r, rates[2], rates[3]
        plant.x[12], plant.x[13] = yaw, rates[4]
        angles, motor_rates = plant.motor_angles_and_rates()
        t = float(trial)
        for i in range(3):
            # Counts as the encoder would report them (the estimator unwraps 32-bit counts).
            est.drive(i, round(angles[i] * ROBOT.encoder.counts_per_rev / (2 * math.pi)), motor_rates[i], t)
        est.imu_attitude(th_r, th_p, 0.0, t)
        est.imu_rate(rates[3], rates[1], rates[4], t)
        e = est.estimate(t)
        quantum = 2 * math.pi / ROBOT.encoder.counts_per_rev
        assert e.fault is None
        assert e.planes[0].ball_angle == pytest.approx(phi_p, abs=2 * quantum)
        assert e.planes[1].ball_angle == pytest.approx(phi_r, abs=2 * quantum)
        assert e.planes[0].ball_rate == pytest.approx(rates[0], abs=1e-9)
        assert e.planes[1].ball_rate == pytest.approx(rates[2], abs=1e-9)
        assert e.yaw_rate == rates[4]


def test_estimator_unwraps_counts_and_faults_when_silent():
    est = Estimator(motor_jacobian(ROBOT), 8192, hold=0.02)
    est.drive(0, 2**31 - 10, 0.0, 0.0)
    est.drive(0, -(2**31) + 10, 0.0, 0.001)  # wrapped forward by 20 counts
    assert est.counts[0] == 2**31 + 10
    for i in (1, 2):
        est.drive(i, 0, 0.0, 0.0)
    est.imu_attitude(0, 0, 0, 0.0)
    est.imu_rate(0, 0, 0, 0.0)
    assert est.estimate(0.015).fault is None
    # Everything silent: nothing is left to stand in for the attitude and its rate.
    assert est.estimate(0.03).fault == "roll: no attitude and no rate left"


def _moving_estimator():
    """An estimator fed 0.5 s of a robot rolling forward and tilting (truth known), and the truth."""
    g = motor_jacobian(ROBOT)
    est = Estimator(g, ROBOT.encoder.counts_per_rev, hold=0.02)
    dt = 0.0025

    def truth(t):
        pitch, pitch_rate = 0.05 * math.sin(3 * t), 0.15 * math.cos(3 * t)
        rel = np.array([0.0, 4.0 + t, 0.2])  # ball-to-body rates (x, y, -yaw rate)
        return pitch, pitch_rate, rel

    angles = np.zeros(3)
    t = 0.0
    for k in range(200):
        t = k * dt
        pitch, pitch_rate, rel = truth(t)
        motor = g @ rel
        angles += motor * dt
        for i in range(3):
            est.drive(i, round(angles[i] * ROBOT.encoder.counts_per_rev / (2 * math.pi)), motor[i], t)
        est.imu_attitude(0.0, pitch, 0.0, t)
        est.imu_rate(0.0, pitch_rate, -rel[2], t)
    return est, t, truth(t)


def test_estimator_stands_in_for_an_encoder_the_diagnosis_names():
    est, t, (_pitch, pitch_rate, rel) = _moving_estimator()
    est.velocity[1] = -est.velocity[1]  # encoder 2 flipped: what the supervisor found
    assert abs(est.estimate(t).planes[0].ball_rate - (rel[1] + pitch_rate)) > 1.0, "the flip matters"
    est.drop(frozenset({"Encoder2"}))
    e = est.estimate(t)
    assert e.fault is None and e.degraded == ("Encoder2",)
    assert e.planes[0].ball_rate == pytest.approx(rel[1] + pitch_rate, abs=1e-9)


def test_estimator_stands_in_for_a_lost_rate_channel_and_a_named_attitude():
    est, t, (pitch, pitch_rate, rel) = _moving_estimator()
    later = t + 3 * est.hold  # the rate frames stop: their stand-in is the attitude's derivative
    est.imu_attitude(0.0, pitch, 0.0, later)
    est.drive(0, est._raw_counts[0], est.velocity[0], later)
    for i in range(3):
        est.last_good[f"drive{i}"] = later
    e = est.estimate(later)
    assert e.fault is None and set(e.degraded) == {"RateX", "RateY", "RateZ"}
    assert e.planes[0].tilt_rate == pytest.approx(pitch_rate, abs=0.02)
    assert e.yaw_rate == pytest.approx(-rel[2], abs=1e-9), "the yaw rate from the encoders"
    # A named attitude: the body rates carry the tilt on from the last trusted one.
    est, t, (pitch, pitch_rate, rel) = _moving_estimator()
    est.drop(frozenset({"Pitch"}))
    est.estimate(t)
    est.imu_attitude(0.0, pitch + 0.3, 0.0, t + 0.0025)  # lies from here on
    est.imu_rate(0.0, pitch_rate, -rel[2], t + 0.0025)
    e = est.estimate(t + 0.0025)
    assert "Pitch" in e.degraded
    assert e.planes[0].tilt == pytest.approx(pitch + pitch_rate * 0.0025, abs=1e-6)


def test_hacs_deadband_gain_and_limits():
    assert deadband(5.0, 3.0) == 2.0 and deadband(-5.0, 3.0) == -2.0 and deadband(2.0, 3.0) == 0.0
    params = Hacs(filter_hz=1000.0, deadband=3.0, gain=0.05, time_constant=0.4, max_speed=2.3, max_accel=1.5)
    cmd = CommandSpeed(params, 0.0025)
    for _ in range(4000):  # 10 s at a constant moment
        v = cmd.update(23.0, math.inf)
    assert v == pytest.approx(0.05 * 20.0, rel=1e-3)  # k/D_v × (s − d)
    cmd.reset()
    speeds = [cmd.update(200.0, math.inf) for _ in range(400)]
    assert max(np.diff(speeds)) <= 1.5 * 0.0025 + 1e-12  # acceleration limit
    assert max(speeds) <= 2.3
    assert cmd.update(200.0, 0.5) == 0.5  # an SC cap clamps at once
    assert cmd.update(-200.0, 0.0) == 0.0


def test_rider_profiles_override_the_sensitivity():
    config = ControllerConfig(riders={"s16": RiderProfile(gain=0.09, deadband=1.0)})
    assert config.hacs_for("s16").gain == 0.09 and config.hacs_for("s16").max_speed == 2.3
    assert config.hacs_for("someone") == config.hacs


@pytest.mark.parametrize(
    ("f_x", "m_y", "theta_deg", "tau"),
    [(20.0, 0.0, -0.99, -2.29), (0.0, 20.0, -1.98, 0.0), (-30.0, -15.0, 2.97, 3.44)],
)
def test_ihacs_equilibrium_is_the_closed_form(f_x, m_y, theta_deg, tau):
    # docs/physics.md §4.2 table (lumped 75 kg / 1.75 m rider); the controller's lumping is its own, so 2 %.
    model = plane_model(ROBOT, 75.0, 1.75, "pitch")
    theta, t = equilibrium(model, f_x, 0.0, m_y, 0.0)
    assert math.degrees(theta) == pytest.approx(theta_deg, rel=0.02)
    assert t == pytest.approx(tau, abs=0.01)
    # With speed: τ_EQ adds the viscous losses.
    _, t_moving = equilibrium(model, f_x, 0.0, m_y, 4.0)
    assert t_moving - t == pytest.approx(4.0 * (0.75 + 0.5))


# ---------------------------------------------------------------------------------- state machine
def feed(c: Controller, t: float, pitch: float = 0.0) -> None:
    for i in range(3):
        c.estimator.drive(i, 0, 0.0, t)
    c.estimator.imu_attitude(0.0, pitch, 0.0, t)
    c.estimator.imu_rate(0.0, 0.0, 0.0, t)


SEATED = Wrench((0.0, 0.0, -600.0), (0.0, -20.0, 0.0))


def run_ticks(c, start, n, wrench=SEATED, sc=("free", 0.0), estop=False, pitch=0.0, leaning=0.0):
    out = None
    for k in range(start, start + n):
        t = k / 400
        feed(c, t, pitch)
        w = Wrench(wrench.force, (wrench.moment[0], wrench.moment[1] + leaning, wrench.moment[2]))
        out = c.step(
            t, w, 0.0, ScCommand(seq=0, stamp=t, mode=sc[0], speed_cap=sc[1], source="supervisor"), estop
        )
    return out


def test_stale_sc_command_falls_back_to_idle():
    c = Controller(ControllerConfig(), ROBOT, RiderInfo())
    run_ticks(c, 0, 400)
    out = run_ticks(c, 400, 800, leaning=60.0)  # leaning hard, SC free and fresh: the command moves
    assert out.command_speed[0] > 1.0
    # The same lean with an SC command stamped 1 s ago (older than sc_max_age = 0.5 s): idle.
    for k in range(1200, 1300):
        t = k / 400
        feed(c, t)
        out = c.step(
            t,
            Wrench(SEATED.force, (0.0, 40.0, 0.0)),
            0.0,
            ScCommand(seq=0, stamp=t - 1.0, mode="free", speed_cap=0.0, source="supervisor"),
            False,
        )
    assert out.command_speed == (0.0, 0.0)


def test_sc_idle_and_limit():
    c = Controller(ControllerConfig(), ROBOT, RiderInfo())
    run_ticks(c, 0, 400)
    assert run_ticks(c, 400, 800, sc=("limit", 0.5), leaning=60.0).command_speed[0] == pytest.approx(0.5)
    assert run_ticks(c, 1200, 10, sc=("idle", 0.0), leaning=60.0).command_speed == (0.0, 0.0)


def test_estop_disables_and_reset_does_not_re_enable():
    c = Controller(ControllerConfig(), ROBOT, RiderInfo())
    assert run_ticks(c, 0, 10).state is ControllerState.BALANCING
    out = run_ticks(c, 10, 5, estop=True)
    assert (out.state, out.enable, out.motor_torque) == (ControllerState.DISABLED, False, (0.0, 0.0, 0.0))
    assert out.fault is Fault.ESTOP
    out = run_ticks(c, 15, 50)  # e-stop released (reset): permitted, not caused
    assert out.state is ControllerState.DISABLED and not out.enable
    c.request_enable()
    out = run_ticks(c, 65, 1)
    assert out.state is ControllerState.BALANCING and out.enable


def test_sensor_silence_faults_and_holds_the_drives_off():
    c = Controller(ControllerConfig(), ROBOT, RiderInfo())
    run_ticks(c, 0, 10)
    out = c.step(
        0.1, SEATED, 0.0, ScCommand(seq=0, stamp=0.1, mode="free", speed_cap=0.0, source="supervisor"), False
    )  # no frames for 75 ms
    assert (out.state, out.fault, out.enable) == (ControllerState.FAULT, Fault.SENSOR_TIMEOUT, False)
    out = run_ticks(c, 41, 10)  # sensors back: still down until an explicit enable
    assert out.state is ControllerState.FAULT and not out.enable


def test_ihacs_weighs_the_rider_and_personalises_gains():
    c = Controller(ControllerConfig(mode="ihacs"), ROBOT, RiderInfo(height=1.64))
    before = c.balancers[0].k.copy()
    run_ticks(c, 0, 400, wrench=Wrench((0.0, 0.0, -0.878 * 50.0 * 9.80665), (0.0, -15.0, 0.0)))
    assert c.rider_mass == pytest.approx(50.0, rel=1e-6)
    assert not np.allclose(c.balancers[0].k, before)
    assert c.balancers[0].model.mass == pytest.approx(ROBOT.body.mass + 50.0)


def test_hacs_keeps_the_reference_gains():
    c = Controller(ControllerConfig(mode="hacs"), ROBOT, RiderInfo(height=1.64))
    before = c.balancers[0].k.copy()
    run_ticks(c, 0, 400, wrench=Wrench((0.0, 0.0, -400.0), (0.0, -15.0, 0.0)))
    np.testing.assert_array_equal(c.balancers[0].k, before)
    assert c.balancers[0].model.mass == pytest.approx(ROBOT.body.mass + 60.0)
