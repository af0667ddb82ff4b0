"""The rider: profiles, capability limits, the adversarial policy, and the seat wrench of a leaning torso."""

import itertools
import math

import msgspec
import numpy as np
import pytest

from hil.run.truth_balancer import TruthBalancer
from plant.anthropometry import seat_rider
from plant.ballbot import Plant
from plant.core import RiderIntent
from plant.params import RobotParams
from plant.rider import Adversarial, Hold, LeanStyle, Profile, Ramp, Sine, Step, Until
from tests.helpers import RIDER_75, deg, sim

G = 9.80665


def test_profile_segments():
    p = Profile(
        [
            Ramp(to=10.0, duration=2.0),
            Hold(duration=1.0),
            Step(to=-5.0),
            Sine(amplitude=2.0, frequency_hz=0.5, duration=2.0),
        ]
    )
    assert p.target(0.0, 0.0, 30.0) == 0.0
    assert p.target(1.0, 0.0, 30.0) == pytest.approx(5.0)
    assert p.target(2.5, 0.0, 30.0) == pytest.approx(10.0)
    assert p.target(3.0, 0.0, 30.0) == pytest.approx(-5.0)  # the step happened at t = 3
    assert p.target(3.5, 0.0, 30.0) == pytest.approx(-5.0 + 2.0 * math.sin(math.pi * 0.5))
    assert p.target(10.0, 0.0, 30.0) == pytest.approx(-5.0)  # after the end the last value holds
    assert Profile().target(3.0, 0.0, 30.0) == 0.0


def test_adversarial_segment_follows_the_motion_with_commitment():
    p = Profile([Adversarial(duration=5.0, direction=1, speed_threshold=0.1, reaction_time=0.5)])
    assert p.target(1.0, 0.0, 25.0) == 25.0  # at first: the preferred direction
    assert p.target(1.1, -0.05, 25.0) == 25.0  # a slow drift backward does not count
    assert p.target(1.2, -0.3, 25.0) == 25.0  # moving backward: the rider notices...
    assert p.target(1.5, -0.3, 25.0) == 25.0  # ...but a wobble shorter than the reaction time is ignored
    assert p.target(1.71, -0.3, 25.0) == -25.0  # backward for 0.5 s: lean backward to go faster
    assert p.target(1.8, 0.05, 25.0) == -25.0  # committed
    assert p.target(6.0, -0.3, 25.0) == 0.0  # after the segment


def test_until_leans_at_the_riders_rate_until_the_robot_moves_then_the_next_segment_starts_there():
    style = LeanStyle(amplitude=20.0, rate=4.0)
    p = Profile([Until(duration=8.0, speed=0.2, reaction_time=0.3), Ramp(to=0.0, duration=1.0)], style=style)
    assert p.target(1.0, 0.0, 30.0) == pytest.approx(4.0)  # 4 deg/s toward the rider's amplitude
    assert p.target(2.0, 0.15, 30.0) == pytest.approx(8.0)  # slower than 0.2 m/s: not moving yet
    assert p.target(2.5, 0.25, 30.0) == pytest.approx(10.0)  # moving: noticed, still leaning...
    assert p.target(2.7, 0.25, 30.0) == pytest.approx(10.8)  # ...for the reaction time
    assert p.target(2.81, 0.25, 30.0) == pytest.approx(11.24)  # reacted: sitting up from 11.24 deg
    assert p.target(3.31, 0.25, 30.0) == pytest.approx(5.62)  # the ramp started at 2.81, not at 8
    assert p.end_time == pytest.approx(3.81) and p.target(4.0, 0.0, 30.0) == 0.0
    # Positive control: a robot that never moves keeps the rider leaning to their amplitude, to the end.
    q = Profile([Until(duration=8.0, speed=0.2), Ramp(to=0.0, duration=1.0)], style=style)
    assert q.target(7.9, 0.1, 30.0) == pytest.approx(20.0) and q.end_time == pytest.approx(9.0)
    assert q.target(8.5, 0.1, 30.0) == pytest.approx(10.0)  # the ramp starts where the lean got to


def test_until_slower_brakes_until_the_robot_stops_and_leans_no_further_than_the_rider_can():
    p = Profile(
        [Until(duration=5.0, direction=-1, amplitude=12.0, rate=40.0, when="slower", speed=0.15)], value=0.0
    )
    assert p.target(0.2, 1.2, 30.0) == pytest.approx(-8.0)
    assert p.target(1.0, 0.5, 30.0) == pytest.approx(-12.0)  # its amplitude
    assert p.target(1.1, 0.1, 30.0) == pytest.approx(-12.0)  # stopped: noticed
    assert p.target(1.41, 0.1, 30.0) == pytest.approx(-12.0)  # reacted; nothing follows: where it got to
    assert p.end_time == pytest.approx(1.41)
    clipped = Profile([Until(duration=5.0, rate=40.0)], style=LeanStyle(amplitude=35.0, rate=40.0))
    assert clipped.target(2.0, 0.0, 22.0) == pytest.approx(22.0)  # a rider's max_lean bounds the trial


def held_lean(lean_deg, rider=RIDER_75, fixture="clamped", seconds=4.0):
    intent = RiderIntent(pitch=[Ramp(to=lean_deg, duration=1.0)])
    plant = Plant(RobotParams(), rider, sim(fixture=fixture), intent)
    for _ in range(int(seconds * 400)):
        plant.step()
    return plant


@pytest.mark.parametrize(("lean", "moment"), [(5.0, 13.7), (10.0, 27.3), (20.0, 53.8)])
def test_forward_lean_produces_the_seat_moment_of_physics_md(lean, moment):
    # docs/physics.md §4.3 (75 kg / 1.75 m): τ_py ≈ m_HAT g d_HAT sin β, on top of the upright tare.
    upright = held_lean(0.0).seat_wrench()
    plant = held_lean(lean)
    wrench = plant.seat_wrench()
    assert math.degrees(plant.truth().lean[0]) == pytest.approx(lean, abs=0.01)
    assert wrench[4] - upright[4] == pytest.approx(moment, abs=0.05)
    hat = seat_rider(RobotParams(), RIDER_75).hat
    assert wrench[4] - upright[4] == pytest.approx(
        hat.mass * G * hat.com_distance * math.sin(deg(lean)), rel=1e-6
    )
    # Statically the seat carries the torso and thighs: Fz = −(m_HAT + 2 m_thigh) g, no shear.
    assert wrench[2] == pytest.approx(-(0.678 + 0.2) * 75.0 * G, rel=1e-9)
    assert abs(wrench[0]) < 1e-6 and abs(wrench[3]) < 1e-9


def test_sideways_lean_moves_the_roll_moment():
    intent = RiderIntent(roll=[Ramp(to=10.0, duration=1.0)])  # toward −y
    plant = Plant(RobotParams(), RIDER_75, sim(fixture="clamped"), intent)
    for _ in range(1600):
        plant.step()
    hat = seat_rider(RobotParams(), RIDER_75).hat
    assert plant.seat_wrench()[3] == pytest.approx(
        hat.mass * G * hat.com_distance * math.sin(deg(10.0)), rel=1e-6
    )


def test_lean_is_clipped_to_capability_and_rate_limited():
    rider = msgspec.structs.replace(RIDER_75, max_lean_deg=15.0, max_lean_rate_deg=10.0)
    intent = RiderIntent(pitch=[Step(to=40.0)])
    plant = Plant(RobotParams(), rider, sim(fixture="clamped"), intent)
    for _ in range(400):
        plant.step()
    # 1 s at 10 deg/s, less what the acceleration limit costs getting up to speed: v² / 2a.
    speed_up = 10.0**2 / (2.0 * rider.max_lean_accel_deg)
    assert math.degrees(plant.torso[0].lean_cmd) == pytest.approx(10.0 - speed_up, abs=0.02)
    for _ in range(800):
        plant.step()
    assert math.degrees(plant.truth().lean[0]) == pytest.approx(15.0, abs=0.05)
    assert math.degrees(plant.torso[0].lean_rate_cmd) == 0.0, "at rest on the target"


def test_intended_lean_rate_never_jumps():
    # A trunk cannot change its angular velocity at once: from rest to full rate, into a reversal and to a
    # stop, the intended lean's rate changes by at most max_lean_accel per second, and arrives without
    # overshooting.
    intent = RiderIntent(pitch=[Step(to=20.0), Hold(duration=0.3), Step(to=-20.0), Hold(duration=2.0)])
    plant = Plant(RobotParams(), RIDER_75, sim(fixture="clamped"), intent)
    torso, dt = plant.torso[0], plant.dt
    limit = math.radians(RIDER_75.max_lean_accel_deg) * dt + 1e-12
    rates, leans = [0.0], []
    for _ in range(1200):
        plant.step()
        rates.append(torso.lean_rate_cmd)
        leans.append(math.degrees(torso.lean_cmd))
    assert max(abs(b - a) for a, b in itertools.pairwise(rates)) <= limit
    assert max(abs(r) for r in rates) == pytest.approx(math.radians(RIDER_75.max_lean_rate_deg))
    assert min(leans) >= -20.0 - 1e-9 and leans[-1] == pytest.approx(-20.0)


def test_hip_torque_saturates_at_capability():
    # A rider too weak for the lean they want cannot hold it: the torso sinks past the target.
    weak = msgspec.structs.replace(RIDER_75, max_hip_torque=30.0, max_lean_deg=40.0)
    plant = held_lean(0.0, rider=weak, seconds=0.0)
    plant.set_intent(RiderIntent(pitch=[Ramp(to=30.0, duration=1.0)]))
    deepest = 0.0
    for _ in range(3 * 400):
        plant.step()
        deepest = max(deepest, math.degrees(plant.truth().lean[0]))
    assert max(abs(u) for u in plant.truth().hip_torque) == pytest.approx(30.0)
    assert deepest > 35.0


def test_twist_is_measured_on_the_seat_within_capability():
    rider = msgspec.structs.replace(RIDER_75, max_twist_torque=12.0)
    intent = RiderIntent(twist=[Ramp(to=8.0, duration=0.5), Hold(duration=0.5), Step(to=-30.0)])
    plant = Plant(RobotParams(), rider, sim(fixture="clamped"), intent)
    for _ in range(300):
        plant.step()
    assert plant.seat_wrench()[5] == pytest.approx(8.0)
    for _ in range(200):
        plant.step()
    assert plant.seat_wrench()[5] == pytest.approx(-12.0)


def test_adversarial_rider_drives_a_balanced_robot():
    # Against a balancer that holds zero speed, leaning as far as possible in the direction of motion
    # pushes the robot along (the paper's motivation for iHACS).
    intent = RiderIntent(pitch=[Adversarial(duration=6.0, direction=-1)])
    plant = Plant(RobotParams(), RIDER_75, sim(), intent)
    bal = TruthBalancer(plant)
    for _ in range(6 * 400):
        bal.drive()
        plant.step()
    assert plant.fallen is None
    assert math.degrees(plant.truth().lean[0]) == pytest.approx(-30.0, abs=1.0)
    assert plant.truth().velocity[0] < -0.3


def test_intent_changes_live_from_where_the_rider_is():
    plant = Plant(
        RobotParams(), RIDER_75, sim(fixture="clamped"), RiderIntent(pitch=[Ramp(to=10.0, duration=1.0)])
    )
    for _ in range(800):  # 2 s: holding 10°
        plant.step()
    plant.set_intent(RiderIntent(pitch=[Ramp(to=-10.0, duration=2.0)]))
    plant.step()
    assert math.degrees(plant.torso[0].lean_cmd) == pytest.approx(10.0, abs=0.05)  # no jump
    for _ in range(399):  # 1 s into the new 2 s ramp: halfway from 10° to −10°, behind by v² / 2a
        plant.step()
    lag = 10.0**2 / (2.0 * RIDER_75.max_lean_accel_deg)
    assert math.degrees(plant.torso[0].lean_cmd) == pytest.approx(lag, abs=0.05)


def _leaning_rider(heeds: bool, intent: RiderIntent) -> Plant:
    plant = Plant(RobotParams(), RIDER_75, sim(fixture="clamped"), intent)
    plant.heeds_alert = heeds
    return plant


def test_a_rider_who_heeds_the_alert_sits_up_as_they_would_by_script_after_their_reaction_time():
    # Physics against physics: after the alert and the rider's reaction time, the torso goes upright exactly
    # as it does for a rider scripted to sit up at that moment (the same rate limits, the same PD hip torque
    # on the same body); before it, nothing differs from a rider who ignores the alert.
    lean_then_hold = [Ramp(to=20.0, duration=1.0)]
    reaction = RIDER_75.alert_reaction_time
    alert_at, end = 1.5, 1.5 + reaction + 3.0
    scripted_sit_up = RiderIntent(
        pitch=[*lean_then_hold, Hold(duration=alert_at + reaction - 1.0), Step(to=0.0)]
    )
    heeding, heedless = (_leaning_rider(h, RiderIntent(pitch=lean_then_hold)) for h in (True, False))
    reference = _leaning_rider(False, scripted_sit_up)
    leans: dict[str, list[float]] = {"heeding": [], "heedless": [], "reference": []}
    times = []
    for tick in range(round(end * 400)):
        for name, plant in (("heeding", heeding), ("heedless", heedless), ("reference", reference)):
            if tick == round(alert_at * 400):
                plant.alert(2)  # the heedless rider and the scripted reference are told too
            plant.step()
            leans[name].append(math.degrees(plant.truth().lean[0]))
        times.append(heeding.t)
    t = np.asarray(times)
    heeding_lean, heedless_lean, reference_lean = (np.asarray(leans[k]) for k in leans)
    before = t < alert_at + reaction - 1e-9
    assert np.array_equal(heeding_lean[before], heedless_lean[before]), "nothing changes before the reaction"
    assert heeding_lean[before][-1] == pytest.approx(20.0, abs=0.05)
    assert np.abs(heeding_lean - reference_lean).max() < 1e-9, "sitting up is the rider's own torso motion"
    assert abs(heeding_lean[-1]) < 0.05, "upright and still at the end"
    assert heedless_lean[-1] == pytest.approx(20.0, abs=0.05), "the scripted rider ignores the alert"
    # Sitting up takes the rider's time, not a jump: at least 20 deg at the rider's fastest lean rate.
    upright = t[np.argmax((t > alert_at + reaction) & (np.abs(heeding_lean) < 1.0))]
    assert upright - (alert_at + reaction) >= 19.0 / RIDER_75.max_lean_rate_deg


def test_a_bad_heeds_alert_or_reaction_time_names_the_field():
    from drivers.config import ConfigError, decode_toml
    from hil.run.scenario import Scenario
    from plant.params import RiderParams

    with pytest.raises(
        ConfigError, match=r"^s\.toml: Expected `bool`, got `str` - at `\$\.intent\.heeds_alert`$"
    ):
        decode_toml('name = "s"\n[intent]\nheeds_alert = "yes"\n', Scenario, "s.toml")
    with pytest.raises(ConfigError, match=r"Expected `float` > 0.0 - at `\$\.alert_reaction_time`$"):
        decode_toml('name = "x"\nmass = 70.0\nheight = 1.7\nalert_reaction_time = 0\n', RiderParams, "r.toml")
