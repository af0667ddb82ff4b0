"""The supervisor's state machine, exhaustively: every transition and cause, latching, reset refusals, the
SC path, and properties over arbitrary observation sequences (hypothesis)."""

import math
from pathlib import Path

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.config import load_toml
from drivers.schemas import ScRequest
from drivers.vocabulary import Cause, ControllerState, State
from safety.config import SupervisorConfig
from safety.machine import SafetyMachine
from safety.observation import STREAMS, DriveReport, Finding, Observation
from safety.reactions import CONTROLLED, CUT_POWER, FINDINGS, IMMEDIATE, TAKEOVER_CAUSES


def sc_request(mode, cap, source):
    """An SC request as the supervisor takes it in (its seq and stamp do not matter to the machine)."""
    return ScRequest(seq=0, stamp=0.0, mode=mode, speed_cap=cap, source=source)


ROOT = Path(__file__).resolve().parents[1]
CFG = SupervisorConfig()
LIMIT = 3.75
HEALTHY = dict.fromkeys(STREAMS, 0.0)
FREE = sc_request("free", 0.0, "agent")
DT = 0.0025
OFF = DriveReport(enabled=False, bus_powered=True)
"""A drive that confirms it is off, on a live bus."""
OFF3 = (OFF, OFF, OFF)
CONFIRM = CFG.drives.confirm


def obs(t=1.0, speed=0.0, tilt=0.0, ages=None, **kw) -> Observation:
    kw.setdefault("controller_state", ControllerState.BALANCING)
    kw.setdefault("seat_load", 600.0)
    kw.setdefault("request", FREE)
    kw.setdefault("drives", OFF3)
    return Observation(t=t, speed=speed, tilt=tilt, ages={**HEALTHY, **(ages or {})}, **kw)


def drives(i: int, **report) -> tuple[DriveReport, ...]:
    """Three drives confirming off, except drive i (1-based) as given."""
    return tuple(
        DriveReport(**{"enabled": False, "bus_powered": True, **report}) if j == i else OFF for j in (1, 2, 3)
    )


def supervisor(config=CFG, request=FREE) -> SafetyMachine:
    s = SafetyMachine(config, LIMIT)
    s.update(obs(t=0.0, request=request))
    return s


def hold(s: SafetyMachine, start: float, duration: float, **kw):
    """Observations every tick from `start` for `duration` s; returns the last decision and the end time."""
    t, d = start, None
    while t <= start + duration + 1e-9:
        d = s.update(obs(t=t, **kw))
        t += DT
    return d, t


def to_stopping(s: SafetyMachine, speed=1.0) -> None:
    s.update(obs(t=1.0, speed=speed, operator="estop"))
    assert s.state is State.STOPPING


def to_estop(s: SafetyMachine) -> None:
    s.update(obs(t=1.0, ages={"heartbeat": 1.0}))
    assert (s.state, s.cause) == (State.ESTOP, Cause.HEARTBEAT_LOST)


def test_shipped_config_is_the_documented_defaults():
    assert load_toml(ROOT / "configs/safety/default.toml", SupervisorConfig) == SupervisorConfig()


def test_every_cause_has_a_stop_category_or_is_not_a_stop():
    not_stops = {Cause.NONE, Cause.OVER_CAP, Cause.SC_SILENT, Cause.RESET}
    assert CONTROLLED.isdisjoint(IMMEDIATE)
    assert set(Cause) == CONTROLLED | IMMEDIATE | not_stops


# ------------------------------------------------------------------------------------------- NORMAL
def test_starts_normal_and_permits_the_drives():
    d = SafetyMachine(CFG, LIMIT).update(obs(t=0.0))
    assert (d.state, d.cause, d.drives_permitted, d.cap) == (
        State.NORMAL,
        Cause.NONE,
        True,
        CFG.speed.absolute_cap,
    )


@pytest.mark.parametrize(
    "request_, expected",
    [
        (sc_request("free", 0.0, "agent"), ("limit", 2.0, "agent")),
        (sc_request("limit", 0.5, "agent"), ("limit", 0.5, "agent")),
        (sc_request("limit", 3.0, "agent"), ("limit", 2.0, "agent")),
        (sc_request("idle", 0.0, "agent"), ("idle", 0.0, "agent")),
        (sc_request("limit", 0.0, "agent"), ("idle", 0.0, "agent")),
        (None, ("limit", 2.0, "supervisor")),
    ],
)
def test_requests_are_forwarded_clamped_to_the_cap(request_, expected):
    d = supervisor().update(obs(request=request_))
    assert (d.command.mode, d.command.speed_cap, d.command.source) == expected
    assert bool(d.command.reason) == (
        expected[1] != (request_.speed_cap if request_ else -1) and expected[0] != "idle"
    )


# ----------------------------------------------------------------------------------- immediate causes
IMMEDIATE_CASES = {
    Cause.HEARTBEAT_LOST: dict(ages={"heartbeat": CFG.watchdogs.heartbeat + DT}),
    Cause.CONTROLLER_FAULT: dict(controller_state=ControllerState.FAULT),
    Cause.DRIVES_SILENT: dict(ages={"drives": CFG.watchdogs.drives + DT}),
    Cause.IMU_SILENT: dict(ages={"imu": CFG.watchdogs.imu + DT}),
    Cause.TILT: dict(tilt=math.radians(CFG.motion.tilt_limit_deg) + 1e-3),
    Cause.TORQUE_RANGE: dict(torque_peak=LIMIT * CFG.motion.torque_range + 0.01),
}


@pytest.mark.parametrize("cause", list(IMMEDIATE_CASES), ids=lambda c: c.name)
@pytest.mark.parametrize("start", ["normal", "limiting", "stopping"])
def test_immediate_causes_turn_the_drives_off_from_any_running_state(cause, start):
    s = supervisor()
    if start == "limiting":
        hold(s, 0.0, CFG.speed.window + DT, speed=2.3)
        assert (s.state, s.cause) == (State.LIMITING, Cause.OVER_CAP)
    elif start == "stopping":
        to_stopping(s)
    d = s.update(obs(t=5.0, speed=0.5, **IMMEDIATE_CASES[cause]))
    assert (d.state, d.cause, d.drives_permitted) == (State.ESTOP, cause, False)
    assert (d.command.mode, d.cap) == ("idle", 0.0)


def test_below_each_immediate_threshold_nothing_happens():
    s = supervisor()
    w = CFG.watchdogs
    d = s.update(
        obs(
            ages={"heartbeat": w.heartbeat, "drives": w.drives, "imu": w.imu},
            tilt=math.radians(CFG.motion.tilt_limit_deg) - 1e-6,
            torque_peak=LIMIT * CFG.motion.torque_range - 0.01,
        )
    )
    assert d.state is State.NORMAL


def test_saturation_counts_only_when_continuous():
    s = supervisor()
    saturated = LIMIT * CFG.motion.saturation_fraction
    d, t = hold(s, 1.0, CFG.motion.saturation_time - 0.01, torque_peak=saturated)
    assert d.state is State.NORMAL
    s.update(obs(t=t, torque_peak=1.0))  # one unsaturated tick restarts the timer
    d, t = hold(s, t + DT, CFG.motion.saturation_time - 0.01, torque_peak=saturated)
    assert d.state is State.NORMAL
    d, _ = hold(s, t, 0.02, torque_peak=saturated)
    assert (d.state, d.cause) == (State.ESTOP, Cause.TORQUE_SATURATED)


# ---------------------------------------------------------------------------------- controlled causes
CONTROLLED_CASES = {
    Cause.OPERATOR_ESTOP: dict(operator="estop"),
    Cause.BUTTON_ESTOP: dict(button=True),
    Cause.HARD_SPEED: dict(speed=CFG.speed.hard_limit + 0.01),
    Cause.E2E_ERRORS: dict(e2e_invalid=("DRIVE1_FEEDBACK",)),
    Cause.WRENCH_SILENT: dict(ages={"wrench": CFG.watchdogs.wrench + DT}),
    Cause.DRIVE_FAULT: dict(drives=drives(2, enabled=False, watchdog=True)),
    **{cause: dict(findings=(Finding(cause, "test"),)) for cause in FINDINGS},
}


@pytest.mark.parametrize(
    "cause", [c for c in CONTROLLED_CASES if c not in TAKEOVER_CAUSES], ids=lambda c: c.name
)
def test_controlled_causes_stop_under_control_while_the_controller_balances(cause):
    s = supervisor()
    kw = {"speed": 1.0, **CONTROLLED_CASES[cause]}
    d = s.update(obs(**kw))
    assert (d.state, d.cause, d.drives_permitted) == (State.STOPPING, cause, True)
    assert d.command.mode == "idle"


@pytest.mark.parametrize("cause", list(CONTROLLED_CASES), ids=lambda c: c.name)
@pytest.mark.parametrize("controller_state", [0, 1, 2, None])
def test_controlled_causes_turn_the_drives_off_when_the_controller_is_not_balancing(cause, controller_state):
    s = supervisor()
    d = s.update(obs(controller_state=controller_state, **{"speed": 0.5, **CONTROLLED_CASES[cause]}))
    assert (d.state, d.cause, d.drives_permitted) == (State.ESTOP, cause, False)


# ------------------------------------------------------------------------------- drives and root cause
def test_a_tripped_drive_watchdog_is_the_controllers_fault_when_its_heartbeat_is_as_old():
    # A dead controller trips the drives' 20 ms watchdog before the 50 ms heartbeat watchdog: the event
    # still names the root cause (and acts on it at once), HEARTBEAT_LOST.
    tripped = drives(1, watchdog=True)
    d = supervisor().update(obs(t=2.0, speed=0.5, drives=tripped, ages={"heartbeat": 0.0225}))
    assert (d.state, d.cause) == (State.ESTOP, Cause.HEARTBEAT_LOST)
    # Positive control: with the heartbeat fresh the same report is the drive's (lost commands): the
    # recovery law, which reaches the drives on a frame of its own, takes over.
    d = supervisor().update(
        obs(t=2.0, speed=0.5, drives=tripped, ages={"heartbeat": 0.0025}, recoverable=True)
    )
    assert (d.state, d.cause) == (State.RECOVERY, Cause.DRIVE_FAULT)


def test_a_drive_that_stays_off_when_permitted_and_told_to_enable_is_a_drive_fault():
    s = supervisor()
    off_yet_commanded = drives(3, enabled=False, commanded_for=CONFIRM - DT)
    assert s.update(obs(t=1.0, drives=off_yet_commanded)).state is State.NORMAL, "within the bound"
    d = s.update(obs(t=1.0 + DT, drives=drives(3, enabled=False, commanded_for=CONFIRM), recoverable=True))
    assert (d.state, d.cause) == (State.RECOVERY, Cause.DRIVE_FAULT), "the recovery law balances on two"
    assert "drive 3" in s.events[-1].detail
    # Not commanded to enable: off is right.
    assert supervisor().update(obs(t=1.0, drives=drives(3, enabled=False))).state is State.NORMAL


def test_simultaneous_findings_name_the_most_upstream_cause():
    both = (Finding(Cause.SENSOR_DISAGREE, "yaw"), Finding(Cause.SENSOR_STUCK, "pitch frozen"))
    d = supervisor().update(obs(speed=0.5, findings=both))
    assert (d.cause, supervisor().update(obs(speed=0.5, findings=both[::-1])).cause) == (
        Cause.SENSOR_STUCK,
    ) * 2


def test_controlled_stop_waits_for_the_chassis_to_come_upright_before_power_off():
    # A rider still leaning holds the chassis tilted at standstill: power off would tip it.
    s = supervisor()
    to_stopping(s, speed=0.5)
    tilted = math.radians(CFG.stop.standstill_tilt_deg) + 0.01
    d, t = hold(s, 1.0 + DT, 2.0 * CFG.stop.standstill_time + CFG.stop.timeout, speed=0.01, tilt=tilted)
    assert (d.state, d.drives_permitted) == (State.STOPPING, True), "no timeout while stopped and tilted"
    d, t = hold(s, t, CFG.stop.standstill_time + 2 * DT, speed=0.01, tilt=0.0)
    assert (d.state, d.drives_permitted) == (State.ESTOP, False)


# --------------------------------------------------------------------------------- the second path
def test_a_drive_that_does_not_confirm_off_opens_the_main_contactor():
    s = supervisor()
    to_estop(s)  # at t = 1.0
    stuck = drives(2, enabled=True)
    d = s.update(obs(t=1.0 + CONFIRM - DT, drives=stuck))
    assert (d.state, d.contactor_closed) == (State.ESTOP, True), "within the bound"
    d = s.update(obs(t=1.0 + CONFIRM, drives=stuck))
    assert (d.state, d.cause, d.contactor_closed) == (State.ESTOP, Cause.DRIVE_NOT_DISABLED, False)
    assert "drive 2" in s.events[-1].detail and "contactor opened" in s.events[-1].detail
    # It stays open, and a reset is refused while the drive still reports itself on.
    d = s.update(obs(t=2.0, drives=stuck, operator="reset"))
    assert (d.state, d.contactor_closed) == (State.ESTOP, False)
    assert "drive 2 still enabled" in s.events[-1].detail


def test_drives_that_confirm_off_leave_the_contactor_closed_and_silence_opens_it():
    s = supervisor()
    to_estop(s)
    d, _ = hold(s, 1.0 + DT, 1.0)
    assert (d.state, d.contactor_closed) == (State.ESTOP, True)
    s = supervisor()
    to_estop(s)
    d = s.update(obs(t=1.0 + CONFIRM, drives=drives(1, enabled=None)))  # no fresh feedback: unconfirmed
    assert (d.cause, d.contactor_closed) == (Cause.DRIVE_NOT_DISABLED, False)


def test_drives_that_cannot_confirm_their_stage_off_get_the_contactor_opened_on_every_estop():
    """ODrive's and CiA 402's Enabled is the firmware's state: a power stage stuck on still reads off, so
    both paths act on every e-stop (docs/safety.md "The second shutdown path")."""
    cut = tuple(DriveReport(enabled=False, bus_powered=False) for _ in range(3))
    for read_back in (False, True):
        s = SafetyMachine(CFG, LIMIT, stage_read_back=read_back)
        s.update(obs(t=0.0))
        to_estop(s)
        assert s.update(obs(t=1.0 + CONFIRM - DT)).contactor_closed, "within the bound"
        d = s.update(obs(t=1.0 + CONFIRM))
        if read_back:  # positive control: drives confirmed off leave it closed
            assert d.contactor_closed and s.events[-1].kind == "transition"
            continue
        assert (d.state, d.cause, d.contactor_closed) == (State.ESTOP, Cause.HEARTBEAT_LOST, False), (
            "the e-stop keeps its cause: an opened contactor is no finding about the drives"
        )
        assert s.events[-1].kind == "contactor_opened" and "20.0 ms after the e-stop" in s.events[-1].detail
        # The contactor is still checked, and a reset closes it again.
        assert s.update(obs(t=1.0 + 2 * CONFIRM, drives=cut)).cause is Cause.HEARTBEAT_LOST
        d = s.update(obs(t=2.0, drives=cut, operator="reset"))
        assert (d.state, d.contactor_closed) == (State.NORMAL, True)


def test_a_contactor_that_does_not_cut_the_bus_is_a_fault_of_its_own():
    s = supervisor()
    to_estop(s)
    s.update(obs(t=1.0 + CONFIRM, drives=drives(1, enabled=True)))
    live = tuple(DriveReport(enabled=False, bus_powered=True) for _ in range(3))
    d = s.update(obs(t=1.0 + 2 * CONFIRM, drives=live))
    assert (d.cause, d.contactor_closed) == (Cause.CONTACTOR_FAULT, False)
    cut = tuple(DriveReport(enabled=False, bus_powered=False) for _ in range(3))
    d = s.update(obs(t=2.0, drives=cut, operator="reset"))
    assert d.state is State.ESTOP and "contactor did not open" in s.events[-1].detail
    # Positive control: a contactor that cut the bus is no fault, and a reset closes it again.
    s = supervisor()
    to_estop(s)
    s.update(obs(t=1.0 + CONFIRM, drives=drives(1, enabled=True)))
    assert s.update(obs(t=1.0 + 2 * CONFIRM, drives=cut)).cause is Cause.DRIVE_NOT_DISABLED
    d = s.update(obs(t=2.0, drives=cut, operator="reset"))
    assert (d.state, d.contactor_closed) == (State.NORMAL, True)


def test_rider_absent_stops_only_when_moving_for_the_window():
    s = supervisor()
    d, t = hold(s, 1.0, 2.0, seat_load=50.0, speed=0.0)
    assert d.state is State.NORMAL, "an empty seat at standstill is not a hazard"
    d, t = hold(s, t, CFG.motion.rider_absent_time - 0.01, seat_load=50.0, speed=0.5)
    assert d.state is State.NORMAL
    d, _ = hold(s, t, 0.02, seat_load=50.0, speed=0.5)
    assert (d.state, d.cause) == (State.STOPPING, Cause.RIDER_ABSENT)


def test_wrench_not_required_is_not_a_cause():
    config = msgspec.structs.replace(
        CFG, watchdogs=msgspec.structs.replace(CFG.watchdogs, require_wrench=False)
    )
    s = supervisor(config)
    assert s.update(obs(ages={"wrench": math.inf})).state is State.NORMAL


# ------------------------------------------------------------------------------------------ LIMITING
def test_over_cap_for_the_window_limits_then_releases_below_the_cap():
    s = supervisor(request=sc_request("limit", 0.5, "agent"))
    over = dict(speed=0.5 + CFG.speed.margin + 0.05, request=sc_request("limit", 0.5, "agent"))
    d, t = hold(s, 1.0, CFG.speed.window - 0.01, **over)
    assert d.state is State.NORMAL
    d, t = hold(s, t, 0.02, **over)
    assert (d.state, d.cause, d.command.mode, d.cap) == (State.LIMITING, Cause.OVER_CAP, "idle", 0.0)
    d, t = hold(s, t, CFG.speed.release_window - 0.01, speed=0.4, request=over["request"])
    assert d.state is State.LIMITING
    d, _ = hold(s, t, 0.02, speed=0.4, request=over["request"])
    assert (d.state, d.cause, d.command.speed_cap) == (State.NORMAL, Cause.NONE, 0.5)


def test_within_the_margin_is_not_over_cap():
    s = supervisor(request=sc_request("limit", 0.5, "a"))
    d, _ = hold(s, 1.0, 2.0, speed=0.5 + CFG.speed.margin, request=sc_request("limit", 0.5, "a"))
    assert d.state is State.NORMAL


def test_requested_cap_not_enforced_keeps_the_absolute_cap():
    config = msgspec.structs.replace(
        CFG, speed=msgspec.structs.replace(CFG.speed, enforce_requested_cap=False)
    )
    s = supervisor(config)
    d, t = hold(s, 1.0, 1.0, speed=1.5, request=sc_request("idle", 0.0, "a"))
    assert d.state is State.NORMAL and d.command.mode == "idle"
    d, _ = hold(s, t, CFG.speed.window + 0.01, speed=CFG.speed.absolute_cap + CFG.speed.margin + 0.01)
    assert (d.state, d.cause) == (State.LIMITING, Cause.OVER_CAP)


def test_speed_still_rising_while_limited_stops():
    s = supervisor(request=sc_request("limit", 0.5, "a"))
    d, t = hold(s, 1.0, CFG.speed.window + 0.01, speed=1.0, request=sc_request("limit", 0.5, "a"))
    assert d.state is State.LIMITING
    d = s.update(obs(t=t, speed=1.0 + CFG.speed.rise_margin + 0.01))
    assert (d.state, d.cause) == (State.STOPPING, Cause.OVERPOWERED)


def test_limiting_that_never_gets_under_the_cap_stops():
    req = sc_request("limit", 0.5, "a")
    s = supervisor(request=req)
    d, t = hold(s, 1.0, CFG.speed.window + 0.01, speed=1.0, request=req)
    d, t = hold(s, t, CFG.speed.limit_timeout - 0.02, speed=0.9, request=req)
    assert d.state is State.LIMITING
    d, _ = hold(s, t, 0.03, speed=0.9, request=req)
    assert (d.state, d.cause) == (State.STOPPING, Cause.OVERPOWERED)


def test_silent_sc_agent_lowers_the_cap_until_it_speaks_again():
    s = SafetyMachine(CFG, LIMIT)
    s.update(obs(t=0.0, ages={"sc": math.inf}, request=None))
    assert s.update(obs(ages={"sc": math.inf}, request=None)).state is State.NORMAL, "never heard: no agent"
    s.update(obs(t=1.0, ages={"sc": 0.0}))
    d = s.update(obs(t=3.0, ages={"sc": CFG.watchdogs.sc + 0.01}, request=sc_request("limit", 1.5, "a")))
    assert (d.state, d.cause, d.cap) == (State.LIMITING, Cause.SC_SILENT, CFG.speed.reduced_cap)
    assert (d.command.mode, d.command.speed_cap) == ("limit", CFG.speed.reduced_cap)
    d = s.update(obs(t=3.1, request=sc_request("limit", 1.5, "a")))
    assert (d.state, d.command.speed_cap) == (State.NORMAL, 1.5)


# ------------------------------------------------------------------------------------------ STOPPING
def test_controlled_stop_ends_with_drives_off_after_standstill():
    s = supervisor()
    to_stopping(s)
    d, t = hold(s, 1.0 + DT, 1.0, speed=0.5)
    assert d.state is State.STOPPING and d.drives_permitted
    d, t = hold(s, t, CFG.stop.standstill_time - 0.01, speed=0.01)
    assert d.state is State.STOPPING
    d, _ = hold(s, t, 0.02, speed=0.01)
    assert (d.state, d.cause, d.drives_permitted) == (State.ESTOP, Cause.OPERATOR_ESTOP, False)
    assert s.events[-1].detail.startswith("standstill")


@pytest.mark.parametrize(
    "speeds, cause",
    [
        ([0.01, CFG.stop.motion_after_standstill + 0.01], Cause.MOTION_AFTER_STANDSTILL),
        ([1.0 + CFG.speed.rise_margin + 0.01], Cause.STOP_INEFFECTIVE),
    ],
)
def test_stop_escalates_to_drives_off(speeds, cause):
    # Once the stop keeps failing for the escalation time: a brief excursion (a rider rebalancing) is not.
    s = supervisor()
    to_stopping(s, speed=1.0)
    t = 1.1
    for v in speeds[:-1]:
        s.update(obs(t=t, speed=v))
        t += DT
    window = CFG.stop.escalation_time
    d, t = hold(s, t, window - 2 * DT, speed=speeds[-1])
    assert d.state is State.STOPPING
    s.update(obs(t=t, speed=0.01))  # one tick back within bounds restarts the window
    d, t = hold(s, t + DT, window - 2 * DT, speed=speeds[-1])
    assert d.state is State.STOPPING
    d, _ = hold(s, t, 2 * DT, speed=speeds[-1])
    assert (d.state, d.cause) == (State.ESTOP, cause)


def test_stop_that_does_not_reach_standstill_times_out():
    s = supervisor()
    to_stopping(s)
    d, t = hold(s, 1.0 + DT, CFG.stop.timeout - 0.02, speed=0.5)
    assert d.state is State.STOPPING
    d, _ = hold(s, t, 0.03, speed=0.5)
    assert (d.state, d.cause) == (State.ESTOP, Cause.STOP_TIMEOUT)


def test_stopping_ignores_requests_and_further_stop_causes():
    s = supervisor()
    to_stopping(s)
    d = s.update(obs(t=1.1, speed=0.8, request=sc_request("limit", 1.5, "a"), button=True))
    assert (d.state, d.cause, d.command.mode) == (State.STOPPING, Cause.OPERATOR_ESTOP, "idle")


# ---------------------------------------------------------------------------------------------- ESTOP
def test_estop_latches_until_a_valid_reset():
    s = supervisor()
    to_estop(s)
    d, t = hold(s, 1.1, 2.0)  # everything healthy again, no reset
    assert (d.state, d.drives_permitted) == (State.ESTOP, False)
    d = s.update(obs(t=t, operator="reset", operator_source="alice"))
    assert (d.state, d.cause, d.drives_permitted) == (State.NORMAL, Cause.RESET, True)
    assert s.reset_by == [(t, "alice")]
    assert s.events[-1].detail == "reset by alice"


UNSAFE_FOR_RESET = {
    "moving": dict(speed=CFG.stop.standstill_speed + 0.01),
    "no speed estimate": dict(speed=None),
    "tilted": dict(tilt=math.radians(CFG.motion.tilt_limit_deg) + 0.01),
    "button held": dict(button=True),
    "drives silent": dict(ages={"drives": 1.0}),
    "imu silent": dict(ages={"imu": 1.0}),
    "heartbeat silent": dict(ages={"heartbeat": 1.0}),
    "wrench silent": dict(ages={"wrench": 1.0}),
    "controller fault": dict(controller_state=ControllerState.FAULT),
    "bus errors": dict(e2e_invalid=("IMU_RATE",)),
    "a drive still on": dict(drives=drives(1, enabled=True)),
    "a sensor check failing": dict(findings=(Finding(Cause.SENSOR_DISAGREE, "yaw"),)),
}


@pytest.mark.parametrize("condition", list(UNSAFE_FOR_RESET))
def test_reset_is_refused_in_every_unsafe_condition(condition):
    s = supervisor()
    to_estop(s)
    d = s.update(obs(t=2.0, operator="reset", **UNSAFE_FOR_RESET[condition]))
    assert d.state is State.ESTOP
    assert s.events[-1].kind == "reset_refused" and s.events[-1].detail
    assert s.reset_by == []


@pytest.mark.parametrize("cause", list(CONTROLLED_CASES), ids=lambda c: c.name)
def test_estop_outranks_any_stop_cause_and_request(cause):
    s = supervisor()
    to_estop(s)
    d = s.update(
        obs(t=2.0, request=sc_request("limit", 2.0, "a"), **{"speed": 1.0, **CONTROLLED_CASES[cause]})
    )
    assert (d.state, d.cause, d.command.mode) == (State.ESTOP, Cause.HEARTBEAT_LOST, "idle")


def test_reset_outside_estop_does_nothing():
    s = supervisor()
    to_stopping(s)
    assert s.update(obs(t=1.1, speed=0.5, operator="reset")).state is State.STOPPING


# --------------------------------------------------------------------------------------------- start
def test_never_heard_streams_are_faults_only_after_the_grace():
    s = SafetyMachine(CFG, LIMIT)
    never = dict(
        ages=dict.fromkeys(STREAMS, math.inf), speed=None, tilt=None, controller_state=None, request=None
    )
    assert s.update(obs(t=0.0, **never)).state is State.NORMAL
    assert s.update(obs(t=CFG.watchdogs.startup_grace - 0.01, **never)).state is State.NORMAL
    d = s.update(obs(t=CFG.watchdogs.startup_grace, **never))
    assert (d.state, d.cause) == (State.ESTOP, Cause.HEARTBEAT_LOST)


def test_transitions_are_logged_with_time_cause_and_values():
    s = supervisor()
    s.update(obs(t=1.25, speed=0.7, tilt=0.1, operator="estop"))
    e = s.events[-1]
    assert (e.kind, e.t, e.from_state, e.to_state, e.cause) == (
        "transition",
        1.25,
        "NORMAL",
        "STOPPING",
        "OPERATOR_ESTOP",
    )
    assert e.values["speed"] == 0.7 and e.values["tilt_deg"] == pytest.approx(math.degrees(0.1))


# ------------------------------------------------------------------------------------------ properties
requests = st.one_of(
    st.none(),
    st.builds(
        sc_request,
        st.sampled_from(["free", "idle", "limit"]),
        st.floats(0.0, 5.0),
        st.just("agent"),
    ),
)
ages = st.fixed_dictionaries(
    {k: st.sampled_from([0.0, 0.01, 0.03, 0.06, 0.2, 2.0, math.inf]) for k in STREAMS}
)
steps = st.lists(
    st.fixed_dictionaries(
        {
            "dt": st.sampled_from([DT, 0.05, 0.3, 1.0]),
            "speed": st.one_of(st.none(), st.floats(0.0, 3.0)),
            "tilt": st.one_of(st.none(), st.floats(0.0, 0.5)),
            "ages": ages,
            "controller_state": st.sampled_from([None, 0, 1, 2, 3, 3, 3, 4]),
            "torque_peak": st.sampled_from([0.0, 1.0, 3.7, 4.0]),
            "e2e_invalid": st.sampled_from([(), (), (), ("DRIVE2_FEEDBACK",)]),
            "seat_load": st.sampled_from([None, 0.0, 600.0]),
            "button": st.booleans(),
            "request": requests,
            "operator": st.sampled_from([None, None, None, "estop", "reset", "cut_power"]),
            "drives": st.sampled_from(
                [
                    OFF3,
                    OFF3,
                    (),
                    drives(1, enabled=True),
                    drives(2, watchdog=True),
                    drives(3, enabled=None),
                    tuple(DriveReport(enabled=True, bus_powered=True, commanded_for=1.0) for _ in range(3)),
                    tuple(DriveReport(enabled=False, bus_powered=False) for _ in range(3)),
                ]
            ),
            "findings": st.sampled_from([(), (), (Finding(Cause.SENSOR_STUCK, "x"),)]),
            "recoverable": st.booleans(),
        }
    ),
    max_size=60,
)


@settings(max_examples=300, deadline=None)
@given(steps, st.booleans())
def test_properties_over_any_observation_sequence(sequence, stage_read_back):
    s = SafetyMachine(CFG, LIMIT, stage_read_back=stage_read_back)
    t = 0.0
    closed, taken, latched = True, False, ""
    for step in sequence:
        t += step.pop("dt")
        o = Observation(t=t, **step)
        before = s.state
        refusal = s.reset_refusal(o)
        d = s.update(o)
        # No way out of ESTOP but a valid operator reset.
        if before is State.ESTOP and d.state is not State.ESTOP:
            assert o.operator == "reset" and refusal == ""
            assert (d.state, d.cause) == (State.NORMAL, Cause.RESET)
        # The main contactor opens only in ESTOP and never closes again while in it.
        if not d.contactor_closed:
            assert d.state is State.ESTOP
        if d.contactor_closed and not closed:
            assert before is State.ESTOP and d.state is State.NORMAL and d.cause is Cause.RESET
        closed = d.contactor_closed
        # The forwarded SC command never exceeds the active cap, and is never `free`.
        assert d.command.mode in ("idle", "limit")
        assert d.command.speed_cap <= d.cap
        if d.command.mode == "idle":
            assert d.command.speed_cap == 0.0
        # Stopping, the recovery law and e-stop forward idle; only ESTOP takes the drives' permission away.
        if d.state in (State.STOPPING, State.ESTOP, State.RECOVERY):
            assert d.command.mode == "idle"
        assert d.drives_permitted == (d.state is not State.ESTOP)
        # The recovery law holds the drives only from RECOVERY on, latched until a valid reset: the
        # controller never gets them back while it is announced.
        assert d.takeover == (d.state is State.RECOVERY or (d.state is State.ESTOP and taken))
        taken = d.takeover
        # An operator's e-stop latches whatever stop is under way: from the update that takes it in until a
        # valid reset, it is named and the robot is in a stop that ends in ESTOP.
        if o.operator in ("estop", "cut_power"):
            latched = o.operator_source or "?"
        elif d.cause is Cause.RESET and before is State.ESTOP:
            latched = ""
        assert d.estop_by == latched
        if latched:
            assert d.state in (State.STOPPING, State.RECOVERY, State.ESTOP)
        # Power is cut in motion only when balance is lost, the drives are the fault, the operator asks
        # for category 0, or the recovery law has nothing to balance on.
        moving = o.speed is not None and o.speed > CFG.stop.standstill_speed
        if before is not State.ESTOP and d.state is State.ESTOP and moving and o.recoverable:
            assert d.cause in CUT_POWER, d.cause


def test_a_dropped_cap_is_enforced_along_a_braking_ramp():
    s = supervisor()
    s.update(obs(t=1.0, speed=1.4, request=sc_request("limit", 1.5, "a")))
    idle = sc_request("idle", 0.0, "a")
    # Braking faster than the ramp: never limited, although far above the new cap for a while.
    t, v = 1.0 + DT, 1.4
    while v > 0.0:
        assert s.update(obs(t=t, speed=v, request=idle)).state is State.NORMAL
        t, v = t + DT, v - 1.0 * DT
    # Slower than the ramp: limited once the speed is above the ramp + margin for the window.
    s = supervisor()
    s.update(obs(t=1.0, speed=1.4, request=sc_request("limit", 1.5, "a")))
    t, v, d = 1.0 + DT, 1.4, None
    while v > 0.0 and (d is None or d.state is State.NORMAL):
        d = s.update(obs(t=t, speed=v, request=idle))
        t, v = t + DT, v - 0.2 * DT
    sp = CFG.speed
    ramp_crossing = (sp.margin + sp.decel * sp.brake_delay) / (sp.decel - 0.2)
    assert (d.state, d.cause) == (State.LIMITING, Cause.OVER_CAP)
    assert t - 1.0 == pytest.approx(ramp_crossing + CFG.speed.window, abs=4 * DT)


def test_the_dbc_names_every_cause_as_the_supervisor_numbers_it():
    # SUPERVISOR_ESTOP.Reason is the cause on the wire: a controller reads it by the DBC's value table.
    from drivers.can_codec import Catalog

    assert Catalog()["SUPERVISOR_ESTOP"].values("Reason") == {c.value: c.name for c in Cause}
