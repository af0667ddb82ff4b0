"""Sensor models: noise statistics against their densities, bias walk, quantisation, the seat, determinism."""

import math

import numpy as np
import pytest

from hil.run.truth_balancer import TruthBalancer
from plant.ballbot import Plant
from plant.core import RiderIntent
from plant.params import Encoder, Imu, RobotParams, Tes
from plant.rider import Ramp, Sine
from plant.sensors import ImuModel, TesModel, cop, counts_from_angle, load_cell_geometry
from tests.helpers import RIDER_75, deg, sim

G = 9.80665


def test_encoder_quantisation_and_wrap():
    enc = Encoder(counts_per_rev=8192, word_bits=16)
    assert counts_from_angle(2 * math.pi, enc) == 8192
    assert counts_from_angle(2 * math.pi * 0.49 / 8192, enc) == 0  # below half a count
    assert counts_from_angle(2 * math.pi * 0.51 / 8192, enc) == 1
    assert counts_from_angle(-2 * math.pi * 3.2 / 8192, enc) == -3
    assert counts_from_angle(2 * math.pi * 4.0, enc) == 32768 - 65536  # wraps like a 16-bit register
    assert counts_from_angle(2 * math.pi * 4.0, Encoder(word_bits=32)) == 32768


def test_drive_feedback_counts_and_noise():
    plant = Plant(RobotParams(), None, sim(fixture="clamped"))
    plant.x[0] = 0.5
    angles, _ = plant.motor_angles_and_rates()
    samples = [plant.sample_drives() for _ in range(4000)]
    for i in range(3):
        assert {s[i].counts for s in samples} == {round(angles[i] * 8192 / (2 * math.pi))}
    vel = np.array([[s[i].velocity for i in range(3)] for s in samples])
    assert vel.std(axis=0) == pytest.approx([0.05] * 3, rel=0.05)


def quiet_imu(**kw) -> Imu:
    base = {"gyro_bias_sigma": 0.0, "gyro_bias_walk": 0.0, "accel_bias_sigma": 0.0, "accel_bias_walk": 0.0}
    return Imu(**{**base, **kw})


@pytest.mark.parametrize("rate", [200.0, 400.0, 800.0])
def test_imu_white_noise_matches_density(rate):
    imu = ImuModel(quiet_imu(rate_hz=rate), np.random.default_rng(7))
    s = [imu.sample((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, G)) for _ in range(20000)]
    gyro = np.array([x.rate for x in s])
    acc = np.array([x.accel for x in s]) - [0.0, 0.0, G]
    att = np.array([x.attitude for x in s])
    band = math.sqrt(rate / 2)  # σ = ND √(f_s/2)
    np.testing.assert_allclose(gyro.std(axis=0), 6.1e-5 * band, rtol=0.03)
    np.testing.assert_allclose(acc.std(axis=0), 1.37e-3 * band, rtol=0.03)
    np.testing.assert_allclose(att.std(axis=0), math.radians(0.05), rtol=0.03)
    assert np.abs(gyro.mean(axis=0)).max() < 4 * 6.1e-5 * band / math.sqrt(len(s))


def test_imu_heading_wraps_like_an_ahrs():
    # However far the robot has turned, the yaw an AHRS reports stays in [-π, π) (the DBC's range: a value
    # beyond it would saturate on the wire and read as frozen).
    imu = ImuModel(quiet_imu(), np.random.default_rng(1))
    for turned in (0.5, 3.0, 4.0, -4.0, 40.0):
        yaw = imu.sample((0.0, 0.0, turned), (0.0, 0.0, 0.0), (0.0, 0.0, 9.81)).attitude[2]
        assert -math.pi <= yaw < math.pi
        assert math.remainder(yaw - turned, 2 * math.pi) == pytest.approx(0.0, abs=1e-2)


def test_imu_bias_turn_on_and_random_walk():
    walk, steps, rate = 1e-3, 400, 400.0
    finals, initial = [], []
    for seed in range(300):
        imu = ImuModel(
            quiet_imu(rate_hz=rate, gyro_noise_density=0.0, gyro_bias_sigma=0.01, gyro_bias_walk=walk),
            np.random.default_rng(seed),
        )
        initial.append(imu.gyro_bias[0])
        for _ in range(steps):
            imu.sample((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, G))
        finals.append(imu.gyro_bias[0] - initial[-1])
    assert np.std(initial) == pytest.approx(0.01, rel=0.15)
    assert np.var(finals) == pytest.approx(walk**2 * steps / rate, rel=0.2)  # variance grows as walk² t


@pytest.mark.parametrize(("pitch", "roll"), [(5.0, 0.0), (0.0, 5.0), (-8.0, 3.0)])
def test_imu_reads_gravity_at_rest(pitch, roll):
    # Tilted at rest: acc_bx = −g sinθ (docs/physics.md §7.1), roll toward −y puts +g sinθ_x on body y.
    plant = Plant(RobotParams(), None, sim(fixture="clamped"), initial_tilt=(deg(pitch), deg(roll)))
    plant.step()
    attitude, rate, acc = plant.imu_truth()
    p, r = deg(pitch), deg(roll)
    np.testing.assert_allclose(
        acc, [-G * math.sin(p), G * math.cos(p) * math.sin(r), G * math.cos(p) * math.cos(r)], atol=1e-12
    )
    assert attitude[:2] == pytest.approx((r, p)) and rate == (0.0, 0.0, 0.0)


def test_imu_sees_the_accelerating_robot():
    # Forward acceleration under the balancer: the body-x specific force follows r_K φ̈ + h_I θ̈ − g sinθ.
    plant = Plant(RobotParams(), None, sim())
    bal = TruthBalancer(plant)
    bal.set_velocity(1.0)
    for _ in range(100):
        bal.drive()
        plant.step()
    _, _, acc = plant.imu_truth()
    ddphi, ddth = plant._outputs()[0][:2]
    th, dth = plant.x[1], plant.x[4]
    r, h = plant.robot.ball.radius, plant.robot.body.imu_height
    ax = r * ddphi + h * (math.cos(th) * ddth - math.sin(th) * dth**2)
    az = -h * (math.sin(th) * ddth + math.cos(th) * dth**2)
    assert abs(ax) > 0.1
    assert acc[0] == pytest.approx(math.cos(th) * ax - math.sin(th) * (az + G), rel=1e-9)


def test_tes_recovers_the_wrench_and_noise_propagates():
    tes = Tes(cell_noise=0.0)
    model = TesModel(tes, 0.03, np.random.default_rng(0))
    wrench = [12.0, -7.0, -700.0, 4.0, 30.0, -3.0]
    s = model.sample(wrench)
    np.testing.assert_allclose([*s.force, *s.moment], wrench, atol=1e-9)
    np.testing.assert_allclose(load_cell_geometry(tes) @ np.array(s.cells), wrench, atol=1e-9)

    noisy = TesModel(Tes(cell_noise=2.0), 0.03, np.random.default_rng(1))
    out = np.array([[*x.force, *x.moment] for x in (noisy.sample(wrench) for _ in range(20000))])
    # Fz sums three vertical cells; Mz sums three tangential cells at radius R.
    assert out[:, 2].std() == pytest.approx(2.0 * math.sqrt(3), rel=0.03)
    assert out[:, 5].std() == pytest.approx(2.0 * 0.12 * math.sqrt(3), rel=0.03)
    np.testing.assert_allclose(out.mean(axis=0), wrench, atol=0.1)


def test_a_seat_cell_saturates_at_its_full_scale():
    # A fall's impact on the seat (18 kN through the rider's hip on the 3-D plant) reads as the cells' full
    # scale, and the payload stays one the wire's schema takes; below full scale nothing changes.
    from drivers.schemas import PayloadError, TesWrench, decode, encode

    def wire(model, wrench):
        s = model.sample(wrench)
        return s, encode(
            TesWrench(seq=1, stamp=0.0, force=s.force, moment=s.moment, cop=s.cop, cells=s.cells)
        )

    impact = [18000.0, 0.0, -9000.0, 0.0, 0.0, 0.0]
    model = TesModel(Tes(cell_noise=0.0), 0.03, np.random.default_rng(0))
    s, payload = wire(model, impact)
    assert max(abs(c) for c in s.cells) == Tes().cell_range
    assert decode(payload, TesWrench).force == s.force
    ordinary = [150.0, -20.0, -700.0, 5.0, 20.0, -3.0]
    np.testing.assert_allclose([*model.sample(ordinary).force, *model.sample(ordinary).moment], ordinary)
    # Positive control: cells that never saturate read the impact as it is, and the schema refuses it.
    boundless = TesModel(Tes(cell_noise=0.0, cell_range=1e9), 0.03, np.random.default_rng(0))
    s, payload = wire(boundless, impact)
    assert s.force[0] == pytest.approx(18000.0)
    with pytest.raises(PayloadError):
        decode(payload, TesWrench)


def test_tes_calibration_error_biases_the_wrench():
    model = TesModel(Tes(cell_noise=0.0, calibration_error=0.02), 0.03, np.random.default_rng(4))
    s = model.sample([0.0, 0.0, -700.0, 0.0, 0.0, 0.0])
    assert s.force[2] != pytest.approx(-700.0, abs=1.0)
    assert s.force[2] == pytest.approx(-700.0, rel=0.1)


def test_cop_of_a_point_load():
    # A load (Fx, Fy, Fz) applied at (x, y) on the seat surface h above P has moment r × F about P.
    x, y, h = 0.04, -0.02, 0.03
    f = np.array([15.0, -5.0, -600.0])
    m = np.cross([x, y, h], f)
    assert cop(*f, m[0], m[1], h) == pytest.approx((x, y))
    assert cop(0.0, 0.0, -5.0, 1.0, 1.0, h) == (0.0, 0.0)  # empty seat


def test_the_seats_cop_stays_on_its_footprint_and_its_payload_in_the_schema():
    """A push through the rider's hip, or a few newtons of load with a moment, gives a wrench whose AMTI
    point lies metres off the seat: a seat is only pressed, so its COP is reported at the footprint's edge,
    in the wrench's direction, and the payload is one the rig's own schema takes."""
    from drivers.schemas import TesWrench, decode, encode
    from plant.sensors import SEAT_RADIUS

    model = TesModel(Tes(cell_noise=0.0), 0.03, np.random.default_rng(0))
    for wrench in ([0.0, 0.0, -500.0, 0.0, 900.0, 0.0], [0.0, 0.0, -25.0, -30.0, 30.0, 0.0]):
        s = model.sample(wrench)
        x, y = cop(*s.force, *s.moment[:2], 0.03)
        assert math.hypot(x, y) == pytest.approx(SEAT_RADIUS)
        free = (
            (0.03 * s.force[0] - s.moment[1]) / s.force[2],
            (s.moment[0] + 0.03 * s.force[1]) / s.force[2],
        )
        assert math.hypot(*free) > 1.0, "the control: the formula alone leaves the schema's bound"
        assert math.atan2(y, x) == pytest.approx(math.atan2(free[1], free[0])), "toward where it pushes"
        payload = TesWrench(seq=1, stamp=0.0, force=s.force, moment=s.moment, cop=s.cop, cells=s.cells)
        assert decode(encode(payload), TesWrench).cop == s.cop == (x, y)


def run_sensors(seed):
    intent = RiderIntent(
        pitch=[Ramp(to=10.0, duration=0.5), Sine(amplitude=5.0, frequency_hz=1.0, duration=1.0)]
    )
    plant = Plant(RobotParams(), RIDER_75, sim(seed=seed), intent)
    bal = TruthBalancer(plant)
    out = []
    for _ in range(300):
        bal.drive()
        plant.step()
        out.append((plant.sample_drives(), plant.sample_imu(), plant.sample_tes()))
    return out


def test_sensors_are_deterministic_for_a_seed():
    a, b, c = run_sensors(11), run_sensors(11), run_sensors(12)
    assert a == b
    assert a != c
    # Changing the seed changes noise, not physics: counts agree to within noise-free quantisation.
    assert a[-1][0][1].counts == c[-1][0][1].counts


@pytest.mark.parametrize("as_array", [False, True])
def test_a_noise_streams_draws_do_not_depend_on_its_block(as_array):
    """The block is a cost (one lump per refill), never a result: every seed's noise is the same sequence
    drawn 64 rows or 1024 at a time (one numpy call per block)."""
    from plant.sensors import NoiseStream

    def draws(block):
        stream = NoiseStream(np.random.default_rng(7), 6, block=block, as_array=as_array)
        take = stream.draw_array if as_array else stream.draw
        return np.array([np.array(take()) for _ in range(2500)])

    small, large = draws(64), draws(1024)
    assert np.array_equal(small, large)
    assert not np.array_equal(small, draws(64)[::-1]), "control: the comparison sees an order"
