"""Fail-operational (docs/safety.md "Fail-operational"): the supervisor's recovery law takes the drives when
the controller cannot be trusted to stop the robot, and power goes off in motion only when balance is lost,
the drives are the fault, or the operator asks for category 0. The state machine's rules, then whole lockstep
runs with the reference controller, the plant's truth the referee and the CAN log the wire's."""

import dataclasses
import math

import can
import msgspec
import numpy as np
import pytest

from drivers.can_codec import Catalog, MessageName
from drivers.config import load_toml
from drivers.robot import RobotModel
from drivers.vocabulary import Cause, ControllerState, State
from hil import pipeline
from hil.faults import parse_fault
from hil.run.scenario import Scenario
from safety.config import SupervisorConfig
from safety.reactions import CUT_POWER, IMMEDIATE, TAKEOVER_CAUSES
from safety.recovery import plane_gain
from tests.helpers import ROOT
from tests.test_safety_machine import CONTROLLED_CASES, DT, IMMEDIATE_CASES, LIMIT, hold, obs, supervisor
from tests.zenoh_helpers import private_bench

CFG = SupervisorConfig()
STANDSTILL_TILT = math.radians(CFG.stop.standstill_tilt_deg)


# ------------------------------------------------------------------------------------------ decisions
@pytest.mark.parametrize("cause", list(IMMEDIATE_CASES), ids=lambda c: c.name)
def test_a_cause_the_controller_cannot_stop_from_hands_the_drives_to_the_recovery_law(cause):
    s = supervisor()
    d = s.update(obs(t=5.0, speed=1.4, recoverable=True, **IMMEDIATE_CASES[cause]))
    if cause in CUT_POWER:
        assert (d.state, d.drives_permitted, d.takeover) == (State.ESTOP, False, False)
    else:
        assert (d.state, d.cause, d.drives_permitted, d.takeover) == (State.RECOVERY, cause, True, True)
        assert (d.command.mode, d.alert) == ("idle", 2)


def test_only_balance_lost_the_drives_or_the_operator_cut_power_in_motion():
    assert {Cause.TILT, Cause.DRIVE_NOT_DISABLED, Cause.CONTACTOR_FAULT} < CUT_POWER
    assert Cause.OPERATOR_CUT in CUT_POWER and CUT_POWER <= IMMEDIATE
    s = supervisor()
    d = s.update(obs(t=2.0, speed=1.4, recoverable=True, operator="cut_power", operator_source="op"))
    assert (d.state, d.cause, d.drives_permitted) == (State.ESTOP, Cause.OPERATOR_CUT, False)
    s = supervisor()
    d = s.update(obs(t=2.0, speed=1.4, recoverable=True, operator="estop"))
    assert (d.state, d.drives_permitted) == (State.STOPPING, True), "an e-stop alone is category 1"


@pytest.mark.parametrize("cause", sorted(TAKEOVER_CAUSES), ids=lambda c: c.name)
def test_a_lying_sensor_is_taken_over_at_once_not_stopped_through_the_controller_that_uses_it(cause):
    d = supervisor().update(obs(speed=1.0, recoverable=True, **CONTROLLED_CASES[cause]))
    assert (d.state, d.cause, d.takeover) == (State.RECOVERY, cause, True)
    # Without the inputs to balance on, power goes off (the positive control of the rule above).
    d = supervisor().update(obs(speed=1.0, recoverable=False, **CONTROLLED_CASES[cause]))
    assert (d.state, d.takeover) == (State.ESTOP, False)


def test_a_stop_that_does_not_take_escalates_to_the_recovery_law_not_to_power_off():
    s = supervisor()
    s.update(obs(t=1.0, speed=1.0, operator="estop", recoverable=True))
    d, _ = hold(s, 1.0 + DT, CFG.stop.escalation_time + 2 * DT, speed=1.5, recoverable=True)
    assert (d.state, d.cause, d.drives_permitted) == (State.RECOVERY, Cause.STOP_INEFFECTIVE, True)


def test_the_recovery_law_powers_off_only_at_rest_and_upright_and_latches_until_a_reset():
    s = supervisor()
    s.update(obs(t=1.0, speed=1.4, ages={"heartbeat": 1.0}, recoverable=True))
    assert s.state is State.RECOVERY
    # At standstill but tilted (a rider still leaning): it keeps balancing, however long.
    d, t = hold(s, 1.0 + DT, 5.0, speed=0.0, tilt=STANDSTILL_TILT + 0.01, recoverable=True)
    assert (d.state, d.drives_permitted) == (State.RECOVERY, True)
    d, t = hold(s, t, CFG.stop.standstill_time - 2 * DT, speed=0.0, tilt=0.0, recoverable=True)
    assert d.state is State.RECOVERY
    d, t = hold(s, t, 3 * DT, speed=0.0, tilt=0.0, recoverable=True)
    expected = (State.ESTOP, Cause.HEARTBEAT_LOST, False, True)
    assert (d.state, d.cause, d.drives_permitted, d.takeover) == expected
    d = s.update(obs(t=t + 1.0, operator="reset", operator_source="op"))
    assert (d.state, d.takeover) == (State.NORMAL, False)


def test_in_recovery_balance_lost_the_operators_cut_or_lost_inputs_cut_power():
    for kw in (
        {"tilt": math.radians(CFG.motion.tilt_limit_deg) + 0.01},
        {"operator": "cut_power"},
        {"recoverable": False},
    ):
        s = supervisor()
        s.update(obs(t=1.0, speed=1.4, controller_state=4, recoverable=True))
        assert s.state is State.RECOVERY
        d = s.update(obs(t=1.1, speed=1.0, **{"recoverable": True, **kw}))
        assert (d.state, d.drives_permitted) == (State.ESTOP, False), kw
    # The controller's own faults no longer matter once its commands are not followed.
    s = supervisor()
    s.update(obs(t=1.0, speed=1.4, controller_state=4, recoverable=True))
    d, _ = hold(s, 1.1, 1.0, speed=1.0, controller_state=4, torque_peak=LIMIT * 2, recoverable=True)
    assert d.state is State.RECOVERY


# ------------------------------------------------------------------------------------- the law itself
@pytest.mark.parametrize("rider_mass", [0.0, 45.0, 75.0, 120.0])
def test_the_recovery_law_stabilises_its_plane_model_for_riders_from_none_to_heavy(rider_mass):
    robot = load_toml(ROOT / "configs/robot/pure.toml", RobotModel)
    rules = CFG.recovery
    gain = plane_gain(robot, rules, rider_mass, robot.body.inertia_pitch)
    # An upright tilt pushes the ball under the body (the sign a balancing law must have): τ on the ball
    # relative to the body accelerates the ball forward for a forward tilt.
    assert gain[0] < 0
    assert all(np.isfinite(gain))


@pytest.mark.parametrize("dead", [0, 1, 2])
def test_a_pairs_free_axis_brakes_without_yaw_and_its_coupled_axis_turns_the_robot_in_a_fixed_ratio(dead):
    from safety.diagnostics import motor_jacobian
    from safety.recovery import pair

    robot = load_toml(ROOT / "configs/robot/pure.toml", RobotModel)
    g = motor_jacobian(robot)
    p = pair(g, dead)
    assert dead not in p.drives and len(p.drives) == 2
    for axis, yaw in ((p.free, 0.0), (p.coupled, p.yaw_per_torque)):
        torques = np.zeros(3)
        torques[p.drives] = p.to_motor @ np.array(axis)
        assert g.T @ torques == pytest.approx([axis[0], axis[1], yaw], abs=1e-9)
    assert np.dot(p.free, p.coupled) == pytest.approx(0.0, abs=1e-12)
    # Two wheels 120 deg apart at zenith angle α: the yaw torque is 2 tan α the torque across the free axis.
    assert p.yaw_per_torque == pytest.approx(2 * math.tan(math.radians(robot.drivetrain.zenith_deg)))
    # Drive 1 sits on +x: without it, the free axis is y (straight-line motion along x brakes without yaw).
    if dead == 0:
        assert abs(p.free[1]) == pytest.approx(1.0)


def test_the_chassis_takes_the_pairs_torque_reversed_with_a_riders_legs_and_more_so_tilted_back():
    from safety.recovery import RecoveryLaw

    robot = load_toml(ROOT / "configs/robot/pure.toml", RobotModel)
    alone = RecoveryLaw(robot, msgspec.structs.replace(CFG.recovery, rider_roll_yaw_product=0.0))
    alone.design(0.0)
    assert alone.chassis_factor(0, 0.0, 0.0) == pytest.approx(1.0), "a plane of its own, level"
    law = RecoveryLaw(robot, CFG.recovery)
    law.design(73.0 * 9.80665)
    # Drive 1 dead: the pair's roll torque comes with twice its size in yaw, and the legs' product of
    # inertia turns the chassis' roll response around; pitched back under a forward-leaning rider, further.
    level, back = law.chassis_factor(0, 0.0, 0.0), law.chassis_factor(0, 0.0, math.radians(-4.0))
    assert level < 0.0 and back < level


def two_wheel_run(rules, lean, dead=0, fault=1.0, end=7.0, speed=0.25, turn=0.0, heeds=False):
    """The 3-D plant and a 73 kg rider leaning `lean` deg forward, held by the truth balancer rolling at
    `speed` m/s (reached over 1.5 s) and turning at `turn` rad/s; at `fault` drive `dead` (0-2) stops making
    torque and the recovery law, its estimator fed the sensors' samples (the wire's values), balances on the
    other two, its command applied the next tick; a rider who `heeds` sits up after their reaction time.
    Returns how it ended, the peak yaw rate after the fault and the final speed."""
    from hil.run.truth_balancer import TruthBalancer
    from plant.ballbot3d import Plant3D
    from plant.core import RiderIntent
    from plant.params import RiderParams, RobotParams, SimParams
    from plant.rider import Ramp
    from safety.estimator import IsolatedEstimator
    from safety.recovery import RecoveryLaw

    rider = load_toml(ROOT / "configs/riders/s07_abi_73kg_176.toml", RiderParams)
    robot = load_toml(ROOT / "configs/robot/pure.toml", RobotParams)
    plant = Plant3D(robot, rider, SimParams(), RiderIntent(pitch=[Ramp(to=lean, duration=0.5)]))
    plant.heeds_alert = heeds
    geometry = load_toml(ROOT / "configs/robot/pure.toml", RobotModel)
    estimate, law = IsolatedEstimator(geometry, rules, plant.sim.dt), RecoveryLaw(geometry, rules)
    law.design(rider.mass * 9.80665)
    balancer = TruthBalancer(plant)
    peak, command = 0.0, (0.0, 0.0, 0.0)
    while plant.t < end and not plant.fallen:
        imu, drives = plant.sample_imu(), plant.sample_drives()
        estimate.update(
            plant.t, imu.attitude[:2], imu.rate, [d.velocity for d in drives], frozenset(), imu.accel
        )
        if plant.t < fault:
            ramp = min(plant.t / 1.5, 1.0)
            balancer.set_velocity(speed * ramp)
            balancer.yaw_rate_command = turn * ramp
            balancer.drive()
        else:
            if plant.drives.motors[dead].gain:
                plant.drives.motors[dead].gain = 0.0
                estimate.engage()
                plant.alert(2)
            plant.drives.set_commands(command, True, plant.t)
            command = law.torques(estimate, dead)
            peak = max(peak, abs(plant.truth().yaw_rate))
        plant.step()
    return plant.fallen, peak, math.hypot(*plant.velocity)


def test_on_two_wheels_a_coupled_plane_that_follows_the_chassis_and_the_yaw_keeps_the_robot_up():
    """Drive 2 dead at 1.0 m/s in a 0.8 rad/s turn, the rider (leaning 8 deg) heeding the alert (3-D plant):
    the law brings the robot to rest. Positive control: the same law with the coupled plane as a plane of
    its own (no product of inertia, no yaw in its velocity feedback) falls."""
    case = {"lean": 8.0, "dead": 1, "fault": 3.0, "end": 10.0, "speed": 1.0, "turn": 0.8, "heeds": True}
    fallen, _, speed = two_wheel_run(CFG.recovery, **case)
    assert fallen is None and speed < CFG.stop.standstill_speed
    own = msgspec.structs.replace(CFG.recovery.two_wheels, coupled_velocity_share=1.0)
    control = msgspec.structs.replace(CFG.recovery, two_wheels=own, rider_roll_yaw_product=0.0)
    assert two_wheel_run(control, **case)[0] is not None


def test_a_rider_who_leans_on_after_a_dead_drive_is_held_without_spinning_the_robot_up():
    """Drive 1 dead under a rider who holds a 12 deg lean at 0.25 m/s and does not heed: the law stays up and
    the chassis turns at under 2 rad/s."""
    fallen, peak, _ = two_wheel_run(CFG.recovery, 12.0)
    assert fallen is None and peak < 2.0


# ------------------------------------------------------------------------------------------ whole runs
BRAKING = load_toml(ROOT / "configs/scenarios/braking.toml", Scenario)
SPEED_LIMITING = load_toml(ROOT / "configs/scenarios/speed_limiting.toml", Scenario)


def run(base, faults, tmp_path, safety=None, duration=None, bench="embedded"):
    scenario = msgspec.structs.replace(
        base,
        duration=duration or base.duration,
        faults=[parse_fault(f) for f in faults],
        safety={**base.safety, **(safety or {})},
        criteria=[],
    )
    return pipeline.run(scenario, private_bench(bench), out=tmp_path).trace


def frames(folder):
    catalog = Catalog()
    out = []
    for msg in can.LogReader(str(folder / "can.log")):
        codec = catalog.by_id(msg.arbitration_id)
        if codec is not None and codec.name in (
            MessageName.SUPERVISOR_ESTOP,
            MessageName.SUPERVISOR_RECOVERY,
            MessageName.SUPERVISOR_DIAGNOSIS,
        ):
            out.append((codec.name, codec.decode(bytes(msg.data))))
    return out


def at_rest_upright(trace) -> bool:
    speed = np.hypot(trace.velocity[-1, 0], trace.velocity[-1, 1])
    return trace.fallen is None and speed < CFG.stop.standstill_speed and np.abs(trace.tilt[-1]).max() < 0.09


KILL_AT_SPEED = [{"kind": "process.kill", "target": "controller", "at": 4.5}]
"""braking: the rider has leaned the robot to ~1.4 m/s by 4.5 s."""
HANG_AT_SPEED = [{"kind": "process.hang", "target": "controller", "at": 4.5, "duration": 2.0}]
"""The controller hangs for 2 s and then works through what queued up: the takeover has latched."""


@pytest.mark.parametrize("fault", [KILL_AT_SPEED, HANG_AT_SPEED], ids=["killed", "hung"])
def test_a_controller_killed_at_speed_ends_at_rest_and_upright_under_the_recovery_law(fault, tmp_path):
    tr = run(BRAKING, fault, tmp_path)
    i = np.searchsorted(tr.t, 4.5)
    assert np.hypot(*tr.velocity[i]) > 1.2, "the fault comes at speed"
    takeover = next(e for e in tr.safety_events if e.to_state == "RECOVERY")
    assert takeover.cause == "HEARTBEAT_LOST" and takeover.t - 4.5 < 0.05
    assert at_rest_upright(tr), "upright and at rest at the end"
    assert not tr.powered[-1], "power off, at rest"
    assert tr.stats.recovery_commands > 0
    # The wire: a recovery command only while the last SUPERVISOR_ESTOP announces the takeover.
    announced = False
    for name, signals in frames(tmp_path):
        if name == MessageName.SUPERVISOR_ESTOP:
            announced = bool(signals["Takeover"])
        elif name == MessageName.SUPERVISOR_RECOVERY:
            assert announced, "SUPERVISOR_RECOVERY without the takeover announced"
    # Positive control (once: the hang's takeover is the same): without its recovery law the supervisor
    # cuts power at speed, and the robot falls.
    if fault is KILL_AT_SPEED:
        tr = run(BRAKING, fault, tmp_path / "control", safety={"recovery": {"enabled": False}})
        assert tr.fallen is not None


def test_a_sign_flipped_wheel_in_motion_is_named_and_ridden_to_rest_without_it(tmp_path):
    fault = [{"kind": "sensor.sign_flip", "channel": "drive2.velocity", "at": 4.0}]
    tr = run(BRAKING, fault, tmp_path)
    assert tr.fallen is None
    named = [s for name, s in frames(tmp_path) if name == MessageName.SUPERVISOR_DIAGNOSIS and s["Encoder2"]]
    assert named, "the diagnosis names encoder 2"
    assert not any(s["Encoder1"] or s["Encoder3"] or s["RateZ"] for s in named)
    assert any(e.to_state == "RECOVERY" for e in tr.safety_events)
    assert at_rest_upright(tr)


def test_a_drive_dead_at_speed_is_named_and_the_recovery_law_commands_only_the_other_two(tmp_path):
    """Drive 2 stops making torque at 1.46 m/s in `braking` (motor 1 is the lenient case: in straight-line
    motion along +x wheels 2 and 3 brake without turning the robot). The controller's torques on the other
    two no longer balance in yaw: the ball spins on the floor at once, and the yaw check sees the encoders
    disagree with the gyro (22 ms) before the torque check names Drive2 (30 ms); a named drive explains the
    disagreement, so no gyro is blamed, and the recovery law commands only drives 1 and 3. On the 3-D plant
    the robot still falls here: braking across the pair's free axis spins it up, the ball spins on the
    floor until the wheels' speed passes what DRIVEn_FEEDBACK can carry (docs/safety.md "A dead drive").
    This holds the diagnosis and the wiring; the planar plant once called it ridden to rest."""
    fault = [{"kind": "plant.drive_torque", "motor": 2, "scale": 0.0, "at": 4.5}]
    tr = run(BRAKING, fault, tmp_path)
    assert np.hypot(*tr.velocity[np.searchsorted(tr.t, 4.5)]) > 1.2, "the fault comes at speed"
    takeover = next(e for e in tr.safety_events if e.to_state == "RECOVERY")
    assert takeover.cause in ("SENSOR_DISAGREE", "ACTUATOR_MISMATCH") and takeover.t - 4.5 < 0.05
    named_drive2, recovery, blamed_after = False, [], []
    for name, signals in frames(tmp_path):
        if name == MessageName.SUPERVISOR_DIAGNOSIS:
            assert not (signals["Drive1"] or signals["Drive3"])
            if named_drive2:
                blamed_after.append(signals["RateZ"])
            named_drive2 = named_drive2 or bool(signals["Drive2"])
        elif name == MessageName.SUPERVISOR_RECOVERY and named_drive2:
            recovery.append(signals)
    assert named_drive2 and not any(blamed_after), "Drive2 named; the ball's spin then blames no gyro"
    assert recovery and all(s["Torque2"] == 0.0 for s in recovery), "nothing asked of the dead drive"
    assert max(abs(s["Torque1"]) + abs(s["Torque3"]) for s in recovery) > 0.5, "the other two balance"


CRUISING = {
    name: load_toml(ROOT / f"configs/scenarios/{name}.toml", Scenario)
    for name in ("cruising", "cruising_turn")
}
"""s07 cruising at about 1 m/s with a sideways sway, straight or turning, heeding the alert."""


def off_in_motion(trace) -> bool:
    """The drives were powered off while the robot still moved and had not fallen."""
    speed = np.hypot(trace.velocity[:, 0], trace.velocity[:, 1])
    return bool(np.any(~trace.powered.astype(bool) & (speed > CFG.stop.standstill_speed)))


@pytest.mark.parametrize("ride", list(CRUISING))
@pytest.mark.parametrize("motor", [1, 2, 3])
def test_a_drive_lost_at_riding_speed_under_a_rider_who_heeds_ends_upright_at_rest_without_a_cut_in_motion(
    motor, ride, tmp_path
):
    """Issue 47's goal on the 3-D plant, through the rig: s07 cruises at 0.9-1.0 m/s, straight or turning,
    and drive `motor` stops making torque; the supervisor names it, its two-wheel law brings the robot to
    rest, and only then powers off.
    Positive controls: the same law with the three-drive law's weights and the old coupled share on two
    wheels (the law before issue 47's but for the world-fixed tilt rates) falls, and without a recovery law
    the power goes off at speed, which `off_in_motion` sees."""
    fault = [{"kind": "plant.drive_torque", "motor": motor, "scale": 0.0, "at": 4.0}]
    tr = run(CRUISING[ride], fault, tmp_path / "law")
    assert np.hypot(*tr.velocity[np.searchsorted(tr.t, 4.0)]) > 0.9, "the fault comes at riding speed"
    assert any(e.to_state == "RECOVERY" for e in tr.safety_events)
    assert at_rest_upright(tr) and not tr.powered[-1]
    assert not off_in_motion(tr)
    if motor == 2 and ride == "cruising":
        three = CFG.recovery
        weights = {k: getattr(three, k) for k in ("q_tilt", "q_position", "q_tilt_rate", "q_ball_rate", "r")}
        weights |= {"position_limit": three.position_limit, "coupled_velocity_share": 0.3}
        old = run(CRUISING[ride], fault, tmp_path / "old", safety={"recovery": {"two_wheels": weights}})
        assert old.fallen, "three wheels' weights fall"
        cut = run(CRUISING[ride], fault, tmp_path / "cut", safety={"recovery": {"enabled": False}})
        assert off_in_motion(cut)


def test_a_cia402_drive_held_in_fault_is_named_once_it_stays_off_under_the_recovery_law(tmp_path):
    """On cia402 a drive held in FAULT (a manufacturer's code: neither `Fault` nor `WatchdogTripped` on the
    host) reads as off although permitted: DRIVE_FAULT, which names no drive by itself. Once it stays off
    for drives.confirm while the recovery law commands it, the diagnosis names it and the law balances on
    the other two (it kept commanding the dead drive, and the robot fell at 4.08 s, before)."""
    fault = [{"kind": "cia402.fault", "motor": 2, "at": 3.0}]
    tr = run(SPEED_LIMITING, fault, tmp_path, duration=6.0, bench="cia402")
    takeover = next(e for e in tr.safety_events if e.to_state == "RECOVERY")
    assert takeover.cause == "DRIVE_FAULT" and takeover.t - 3.0 < 0.05
    named = [s for name, s in frames(tmp_path) if name == MessageName.SUPERVISOR_DIAGNOSIS and s["Drive2"]]
    assert named and not any(s["Drive1"] or s["Drive3"] for s in named)
    assert tr.fallen is None


def test_a_controller_that_balances_at_standstill_on_healthy_inputs_is_never_taken_over(tmp_path):
    tr = run(BRAKING, [], tmp_path)
    assert tr.stats.recovery_commands == 0 and tr.stats.overridden_commands == 0
    assert not any(e.to_state == "RECOVERY" for e in tr.safety_events)
    assert ControllerState.BALANCING in tr.stats.controller_states


# ------------------------------------------------------------------------------------------ isolation
def _estimator():
    from safety.diagnostics import motor_jacobian
    from safety.estimator import IsolatedEstimator

    robot = load_toml(ROOT / "configs/robot/pure.toml", RobotModel)
    return IsolatedEstimator(robot, CFG.recovery, DT), motor_jacobian(robot)


@pytest.mark.parametrize("faulty", ["Encoder1", "Encoder2", "Encoder3", "RateZ"])
@pytest.mark.parametrize("kind", ["sign_flip", "step"])
def test_a_yaw_disagreement_is_blamed_on_the_one_sensor_whose_exclusion_keeps_the_ball_rates_smooth(
    faulty, kind
):
    est, g = _estimator()
    rng = np.random.default_rng(1)
    for k in range(160):  # the yaw check fires within its 25 ms window (10 ticks) of the fault
        t = k * DT
        # A robot accelerating forward and turning, with the drives' velocity noise (robot file: 0.05 rad/s).
        rel = np.array([0.2 * math.sin(t), 5.0 + 2.0 * t, -0.4])
        motors = g @ rel + rng.normal(0.0, 0.05, 3)
        yaw = -rel[2]
        if k >= 150:  # the fault
            if faulty == "RateZ":
                yaw = -yaw if kind == "sign_flip" else yaw + 0.3
            else:
                i = int(faulty[-1]) - 1
                motors[i] = -motors[i] if kind == "sign_flip" else motors[i] + 3.0
        est.update(t, (0.0, 0.0), (0.0, 0.0, yaw), list(motors), frozenset())
    assert est.odd_one_out() == faulty


# ---------------------------------------------------------------------------------------------- rider
def _leaning_plant(heeds: bool):
    from plant.ballbot import Plant
    from plant.core import RiderIntent
    from plant.params import RiderParams, RobotParams, SimParams
    from plant.rider import Ramp

    rider = load_toml(ROOT / "configs/riders/s07_abi_73kg_176.toml", RiderParams)
    plant = Plant(
        load_toml(ROOT / "configs/robot/pure.toml", RobotParams),
        rider,
        SimParams(),
        RiderIntent(pitch=[Ramp(to=20.0, duration=1.0)]),
    )
    plant.heeds_alert = heeds
    plant.clamped = True  # the chassis held upright: the rider's torso alone
    return plant, rider


def test_a_rider_who_heeds_the_alert_sits_up_after_the_reaction_time_and_a_scripted_one_does_not():
    for heeds in (True, False):
        plant, rider = _leaning_plant(heeds)
        while plant.t < 1.5:
            plant.step()
        plant.alert(2)
        alerted = plant.t
        lean = []
        while plant.t < alerted + rider.alert_reaction_time + 2.0:
            plant.step()
            lean.append((plant.t, math.degrees(plant.torso[0].lean_cmd)))
        before = [v for t, v in lean if t < alerted + rider.alert_reaction_time - 1e-9]
        assert min(before) == pytest.approx(20.0), "nothing changes before the reaction time"
        if heeds:
            assert lean[-1][1] == pytest.approx(0.0, abs=1e-6), "upright again"
            # Sitting up is the rider's own motion: never faster than their lean rate.
            rates = np.diff([v for _, v in lean]) / DT
            assert np.abs(rates).max() <= rider.max_lean_rate_deg + 1e-6
        else:
            assert lean[-1][1] == pytest.approx(20.0), "the scripted rider ignores the alert"


def test_the_drives_never_follow_two_masters_in_one_tick(tmp_path, monkeypatch):
    # Every setpoint a drive takes, by tick and by sender, through a takeover at speed while the controller
    # goes on commanding (a wheel that lies): before the announcement only the controller's, from it on
    # only the recovery law's (the controller's are counted and dropped), never both in one tick after it.
    from hil.run import build
    from hil.run.drives_port import DrivesPort
    from plant.drives import MotorDrive

    applied: list[tuple[int, str, bool]] = []
    sender: dict = {}

    class WatchedDrive(MotorDrive):  # a subclass: the compiled build's MotorDrive cannot be patched
        def set_command(self, torque, enable, now):
            port = sender["port"]
            applied.append((port.plant.tick, sender["who"], port.takeover))
            super().set_command(torque, enable, now)

    class WatchedPort(DrivesPort):  # a subclass: the compiled build's DrivesPort cannot be patched
        def __init__(self, plant, *args, **kwargs):
            drives = plant.drives
            drives.motors = tuple(
                WatchedDrive(**{f.name: getattr(m, f.name) for f in dataclasses.fields(m)})
                for m in drives.motors
            )
            super().__init__(plant, *args, **kwargs)

        def _drive(self, index, torque, enable, recovery=False):
            sender.update(port=self, who="recovery" if recovery else "controller")
            super()._drive(index, torque, enable, recovery)

    monkeypatch.setattr(build, "DrivesPort", WatchedPort)
    flip = [{"kind": "sensor.sign_flip", "channel": "drive2.velocity", "at": 4.0}]
    tr = run(BRAKING, flip, tmp_path, duration=5.0)
    assert tr.stats.overridden_commands > 0, "the controller went on commanding during the takeover"
    takeover = min(k for k, who, _ in applied if who == "recovery")
    assert all(announced for _, who, announced in applied if who == "recovery"), "only while announced"
    assert not any(who == "controller" and k > takeover for k, who, _ in applied), "one master"
    assert any(who == "controller" for _, who, _ in applied), "the controller held them before"
    by_tick: dict[int, set[str]] = {}
    for k, who, _ in applied:
        by_tick.setdefault(k, set()).add(who)
    assert all(len(who) == 1 for k, who in by_tick.items() if k > takeover)
