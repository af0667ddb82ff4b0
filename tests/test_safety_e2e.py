"""The supervisor with the rig in lockstep: limiting and stopping an adversarial rider, a controlled stop on
the operator's e-stop, drives off when the controller or the supervisor dies, and a reset that permits
motion without causing it. The plant's truth is the referee; the supervisor never sees it."""

import threading
import time

import msgspec
import numpy as np
import pytest

from drivers.bus_config import BusConfig
from drivers.can_bus import CanNode, open_bus, private_channel
from drivers.can_codec import Catalog, MessageName
from drivers.config import load_toml
from drivers.plugs import NodeThread
from drivers.vocabulary import State
from drivers.zenoh_link import ZenohLink, open_session
from hil.faults.processes import Kill
from hil.pipeline import run
from hil.run import build
from hil.run.build import RunOptions
from hil.run.drives_port import DrivesPort
from hil.run.rig import Rig
from hil.run.scenario import OperatorEntry, Scenario
from plant.params import RobotParams
from safety.config import SupervisorConfig
from safety.node import SupervisorNode
from tests.helpers import ROOT
from tests.zenoh_helpers import hub_endpoint, private_bench

REF = ROOT / "configs/riders/ref_60kg_180.toml"
CFG = SupervisorConfig()
DRIVE = load_toml(ROOT / "configs/robot/pure.toml", RobotParams).drive
TICK = 1.0 / 400
SYNC = Catalog()[MessageName.SYNC]


def transitions(trace):
    return [(e.to_state, e.cause) for e in trace.safety_events if e.kind == "transition"]


def first(trace, cause):
    return next(e for e in trace.safety_events if e.kind == "transition" and e.cause == cause)


def off_since(trace) -> float:
    """The time from which the drives stayed off to the end."""
    on = np.nonzero(trace.powered)[0]
    return float(trace.t[on[-1] + 1])


def quiet_run(**kw):
    """The robot standing, the rider sitting still."""
    return run(Scenario(name="quiet", rider=str(REF), **kw), private_bench()).trace


def test_adversarial_rider_is_limited_then_stopped(shipped):
    scenario = load_toml(ROOT / "configs/scenarios/overpower_cap.toml", Scenario)
    tr = shipped[0]["overpower_cap"].trace
    assert transitions(tr)[:3] == [
        ("LIMITING", "OVER_CAP"),
        ("STOPPING", "OVERPOWERED"),
        ("ESTOP", "OVERPOWERED"),
    ]
    # Reaction against the truth: from the speed first passing cap + margin to LIMITING.
    cap = scenario.sc[0].cap
    over = tr.t[np.argmax(np.abs(tr.velocity[:, 0]) > cap + CFG.speed.margin)]
    reaction = first(tr, "OVER_CAP").t - over
    print(f"\nover-cap reaction {reaction * 1e3:.1f} ms (window {CFG.speed.window * 1e3:.0f} ms)")
    assert CFG.speed.window <= reaction <= CFG.speed.window + 4 * TICK
    # While limiting, the controller is told idle; the supervisor's own speed agrees with the truth.
    assert np.nanmax(np.abs(tr.safety_speed - np.hypot(*tr.velocity.T))) < 0.01
    assert tr.fallen is None and tr.resting[-1]


def test_operator_estop_at_speed_is_a_controlled_stop(shipped):
    tr = shipped[0]["estop_at_speed"].trace
    assert transitions(tr) == [("STOPPING", "OPERATOR_ESTOP"), ("ESTOP", "OPERATOR_ESTOP")]
    stop = first(tr, "OPERATOR_ESTOP")
    speed_then = abs(tr.velocity[np.searchsorted(tr.t, stop.t), 0])
    assert speed_then > 0.8
    # Power comes off only once the robot is at standstill (truth), and it ends at rest, not fallen.
    off = off_since(tr)
    assert abs(tr.velocity[np.searchsorted(tr.t, off) - 1, 0]) < CFG.stop.standstill_speed
    assert tr.fallen is None and tr.resting[-1]


def test_controller_killed_is_taken_over_within_the_heartbeat_bound_and_powered_off_at_rest():
    tr = quiet_run(duration=3.0, faults=[Kill(at=1.5, target="controller")])
    lost = first(tr, "HEARTBEAT_LOST")
    assert 1.5 < lost.t <= 1.5 + CFG.watchdogs.heartbeat + 2 * TICK
    assert lost.to_state == "RECOVERY" and tr.stats.recovery_commands > 0
    # The recovery law holds the standing robot until it has stood still and upright, then power off.
    off = off_since(tr)
    assert lost.t + CFG.stop.standstill_time <= off <= lost.t + CFG.stop.standstill_time + 4 * TICK
    assert tr.safety_state[-1] == State.ESTOP
    assert tr.fallen is None and tr.resting[-1], "power off at standstill: it comes to rest"


def test_supervisor_killed_the_controller_stops_on_its_own_and_turns_the_drives_off_at_rest():
    from controller.node import REST_TIME

    tr = quiet_run(duration=3.0, faults=[Kill(at=1.5, target="supervisor")])
    # The last frame was sent at most one period before the kill; the drives wait permission_timeout.
    (lost,) = tr.stats.supervisor_lost_at
    assert 1.5 + DRIVE.permission_timeout - CFG.output.estop_frame_period - TICK <= lost
    assert lost <= 1.5 + DRIVE.permission_timeout + 2 * TICK
    # Not cut by the drives (their grace is far longer): the controller, standing, turns them off itself.
    off = off_since(tr)
    assert tr.stats.permission_lost == 0
    assert lost + REST_TIME - TICK <= off <= lost + REST_TIME + 4 * TICK
    assert tr.fallen is None and tr.resting[-1]


def test_reset_permits_motion_but_never_causes_it():
    tr = quiet_run(
        duration=5.0,
        operator=[
            OperatorEntry(at=1.0, action="estop"),
            OperatorEntry(at=2.0, action="reset"),
            OperatorEntry(at=3.0, action="enable"),
        ],
    )
    assert transitions(tr) == [
        ("STOPPING", "OPERATOR_ESTOP"),
        ("ESTOP", "OPERATOR_ESTOP"),
        ("NORMAL", "RESET"),
    ]
    reset = first(tr, "RESET")
    assert 2.0 <= reset.t < 2.0 + 2 * TICK
    between = (tr.t > reset.t) & (tr.t < 3.0)
    assert tr.safety_state[between].max() == State.NORMAL, "permitted"
    assert not tr.powered[between].any() and tr.resting[between].all(), "but nothing moved"
    after = tr.t > 3.1
    assert tr.powered[after].all() and not tr.resting[after].any(), "the operator's enable starts it"
    assert tr.fallen is None
    assert np.abs(tr.velocity[tr.t > 4.0]).max() < 0.1


def external_supervisor_run(scenario: Scenario, stall_at: int | None = None, rx_hook=None):
    """A lockstep run with the supervisor on a thread of its own on the SYNC time base; `stall_at`: at that
    SYNC tick it stalls for 0.2 s of wall time (a supervisor slower than the loop, not a dead one);
    `rx_hook`: the supervisor's CAN receive hook, for other ways of holding it up."""
    endpoint = hub_endpoint()
    session = open_session(role="hub", hub_endpoint=endpoint)
    link = ZenohLink(session)
    bus_config = BusConfig(channel=private_channel("ext"))
    bus = open_bus(bus_config)
    can = CanNode(bus, name="supervisor")
    node = SupervisorNode(can, link)
    if stall_at is not None:
        # Through the node's receive hook (the compiled build's SupervisorNode cannot be patched): the
        # supervisor's thread stalls as it takes in SYNC(stall_at), before that tick's update.
        def stalling(msg):
            if msg.arbitration_id == SYNC.frame_id and SYNC.decode(msg.data)["Tick"] == stall_at:
                time.sleep(0.2)
            return msg

        can.rx_hook = stalling
    if rx_hook is not None:
        can.rx_hook = rx_hook
    thread = NodeThread(node.run_on_sync, "supervisor").start()
    try:
        bench = private_bench(can=bus_config, supervisor="external", hub=endpoint)
        return run(scenario, bench, options=RunOptions(session=session))
    finally:
        thread.stop()
        link.close()
        session.close()
        bus.shutdown()


class NotWaitingPort(DrivesPort):
    """A drives' port that never waits for a supervisor elsewhere (a subclass: the compiled build's cannot
    be patched)."""

    def await_supervisor(self, k, deadline):
        pass


def test_a_lockstep_rig_waits_for_a_slow_supervisor_instead_of_taking_it_for_dead(monkeypatch):
    """0.2 s of wall time is many ticks of a lockstep loop: the rig waits for the supervisor's next frame
    once the last is half the permission timeout old, so the drives never take it for lost."""
    scenario = msgspec.structs.replace(
        load_toml(ROOT / "configs/scenarios/balance.toml", Scenario), duration=1.5
    )
    result = external_supervisor_run(scenario, stall_at=200)
    assert result.trace.stats.supervisor_lost_at == []
    assert transitions(result.trace) == []  # and the supervisor saw nothing wrong either
    monkeypatch.setattr(build, "DrivesPort", NotWaitingPort)  # control: no waiting
    assert external_supervisor_run(scenario, stall_at=200).trace.stats.supervisor_lost_at


def test_external_supervisor_on_the_sync_time_base():
    """The rig without its embedded supervisor, one on the same bus instead (as `pure-hil supervisor
    --clock lockstep` runs beside a lockstep rig): the same controlled stop, its transitions as announced."""
    result = external_supervisor_run(load_toml(ROOT / "configs/scenarios/estop_at_speed.toml", Scenario))
    tr = result.trace
    assert transitions(tr) == [("STOPPING", "OPERATOR_ESTOP"), ("ESTOP", "OPERATOR_ESTOP")]
    assert abs(first(tr, "OPERATOR_ESTOP").t - 4.0) < 0.01
    assert result.passed, [v for v in result.verdicts if not v.passed]


def test_a_supervisor_behind_the_rig_judges_each_zenoh_input_at_the_tick_it_was_put(monkeypatch):
    """The rig puts tick k's zenoh inputs before tick k's SYNC. A supervisor on the SYNC time base that
    is still at tick k - 1 (a busy machine) must not take the operator's e-stop of tick k a tick early: the
    rig tags each put with its tick, and the supervisor holds a later tick's input; each SYNC is its own
    update, so one far behind does not take several ticks at once either. The CI failures this fixes: the
    e-stop's STOPPING came at 3.9975 s for an e-stop put at 4.0 s, and under load at 4.0125 s."""
    k = 400  # the e-stop's tick, 1.0 s
    put = threading.Event()

    class AheadRig(Rig):
        """At tick k: the zenoh inputs are out, then the supervisor held at SYNC k - 1 is let go, and this
        tick's SYNC follows only later."""

        def _send_sensors(self, tick, *args):
            if tick == k:
                put.set()
                time.sleep(0.3)  # ordering only: the held supervisor updates before SYNC k is sent
            super()._send_sensors(tick, *args)

    def held_at_the_tick_before(msg):
        if msg.arbitration_id == SYNC.frame_id and SYNC.decode(msg.data)["Tick"] == k - 1:
            put.wait(10.0)
        return msg

    scenario = Scenario(
        name="estop", rider=str(REF), duration=1.2, operator=[OperatorEntry(at=k * TICK, action="estop")]
    )

    class AheadPort(DrivesPort):
        def await_supervisor(self, tick, deadline):
            if tick != k - 1:  # the supervisor waits for the rig here, not the other way round
                super().await_supervisor(tick, deadline)

    monkeypatch.setattr(build, "Rig", AheadRig)
    monkeypatch.setattr(build, "DrivesPort", AheadPort)
    stop = first(external_supervisor_run(scenario, rx_hook=held_at_the_tick_before).trace, "OPERATOR_ESTOP")
    assert stop.t == pytest.approx(k * TICK)

    # Control: the same puts untagged (as before the fix) are judged at whatever tick the supervisor is at
    # when they arrive: here, held at k - 1 or further behind, before their own tick.
    class UntaggedRig(AheadRig):
        def _put_bytes(self, tick, key, data, link=None):
            (link or self.link).put(key, data)
            self._record(tick, key, data)

    monkeypatch.setattr(build, "Rig", UntaggedRig)
    put.clear()
    early = first(external_supervisor_run(scenario, rx_hook=held_at_the_tick_before).trace, "OPERATOR_ESTOP")
    assert early.t < k * TICK - TICK / 2


def test_a_run_ended_by_an_operators_live_estop_is_not_passed(tmp_path):
    """An e-stop the scenario did not schedule (`pure-hil estop`, a button) ends the run ESTOPPED, not
    PASSED (exit 3); the same e-stop scheduled by the scenario is part of the test and passes."""
    from drivers.schemas import EstopCommand

    endpoint = hub_endpoint()
    session = open_session(role="hub", hub_endpoint=endpoint)
    link = ZenohLink(session)
    link.declare_publishers([link.keys.safety_estop])
    sent: list[float] = []

    def operator(plant):
        if plant.t >= 1.0 and not sent:
            stop = EstopCommand(seq=1, stamp=time.time(), action="estop", source="operator")
            link.put(link.keys.safety_estop, stop)
            sent.append(plant.t)

    balance = msgspec.structs.replace(
        load_toml(ROOT / "configs/scenarios/balance.toml", Scenario), duration=2.0, criteria=[]
    )
    try:
        live = run(
            balance,
            private_bench(hub=endpoint),
            out=tmp_path / "live",
            options=RunOptions(on_tick=operator, session=session),
        )
    finally:
        link.close()
        session.close()
    assert sent and live.live_estop() is not None
    assert (live.verdict, live.passed) == ("ESTOPPED", False)
    summary = msgspec.json.decode((tmp_path / "live" / "summary.json").read_bytes())
    assert (summary["verdict"], summary["passed"]) == ("ESTOPPED", False)
    scripted = msgspec.structs.replace(balance, operator=[OperatorEntry(at=1.0, action="estop")])
    result = run(scripted, private_bench())
    assert result.live_estop() is None and result.verdict == "PASSED"
