"""The supervisor's diagnostics and second shutdown path in the lockstep rig, with the reference controller:
a drive stuck on during an e-stop, conflicting SC agents, the root cause of a dead controller, and faulty
runs that never wait out the wall-clock guard tick after tick. The plant's truth is the referee."""

import msgspec
import numpy as np
import pytest

from drivers.config import load_toml
from drivers.schemas import ScCommand, decode
from hil import pipeline
from hil.faults import parse_fault
from hil.run.scenario import OperatorEntry, Scenario
from safety.config import SupervisorConfig
from tests.helpers import ROOT
from tests.zenoh_helpers import private_bench

BENCH = load_toml(ROOT / "configs/scenarios/bench_smoke.toml", Scenario)
CFG = SupervisorConfig()


def run(faults=(), operator=(), safety=None, duration=2.5, bench="embedded"):
    scenario = msgspec.structs.replace(
        BENCH,
        duration=duration,
        faults=[parse_fault(f) for f in faults],
        operator=list(operator),
        safety=safety or {},
        criteria=[],
    )
    return pipeline.run(scenario, private_bench(bench)).trace


def causes(trace):
    return [(round(e.t, 4), e.to_state, e.cause) for e in trace.safety_events if e.kind == "transition"]


STUCK = [{"kind": "plant.drive_stuck_enabled", "motor": 2, "at": 1.0}]
ESTOP = [OperatorEntry(at=1.0, action="estop")]


def test_a_drive_stuck_on_during_an_estop_ends_unpowered_and_at_rest():
    tr = run(STUCK, ESTOP)
    estop = next(t for t, state, _ in causes(tr) if state == "ESTOP")
    cut = next(t for t, _, cause in causes(tr) if cause == "DRIVE_NOT_DISABLED")
    assert cut - estop <= CFG.drives.confirm + 0.0025, "within the drives' confirm bound"
    assert tr.stats.contactor_opened == 1
    after = tr.t > cut + 0.005
    assert not tr.powered[after].any(), "every drive unpowered from the contactor on"
    assert tr.fallen is None and tr.resting[-1]
    # Positive control: without the second path in time the stuck drive stays powered to the end.
    tr = run(STUCK, ESTOP, safety={"drives": {"confirm": 100.0}})
    assert tr.powered[-1] and tr.stats.contactor_opened == 0


@pytest.mark.parametrize("bench", ["odrive", "cia402"])
def test_a_drive_stuck_on_that_its_firmware_calls_off_is_cut_by_the_contactor_every_estop(bench):
    """On ODrive and CiA 402 the drive's state says off whatever its power stage does: nothing sees the
    stuck stage, so the contactor opens on every e-stop (docs/safety.md "The second shutdown path")."""
    tr = run(STUCK, ESTOP, bench=bench)
    estop = next(t for t, state, _ in causes(tr) if state == "ESTOP")
    assert "DRIVE_NOT_DISABLED" not in {cause for *_, cause in causes(tr)}, "the firmware's state hides it"
    opened = next(e.t for e in tr.safety_events if e.kind == "contactor_opened")
    assert opened - estop <= CFG.drives.confirm + 0.0025
    # Positive control within the run: the stuck drive was still powered after the drives' own stop.
    assert tr.powered[(tr.t > estop + 0.005) & (tr.t < opened)].all()
    assert not tr.powered[tr.t > opened + 0.005].any(), "every drive unpowered from the contactor on"
    assert tr.stats.contactor_opened == 1 and tr.fallen is None and tr.resting[-1]


@pytest.mark.parametrize("bench", ["odrive", "cia402"])
def test_after_a_reset_the_drives_clear_the_open_contactors_error_and_balance_again(bench):
    """The contactor opened on the e-stop leaves every drive with a DC-bus error: a reset closes it and the
    controller's next enable clears the error and arms the drives."""
    operator = [
        OperatorEntry(at=1.0, action="estop"),
        OperatorEntry(at=2.0, action="reset"),
        OperatorEntry(at=2.1, action="enable"),
    ]
    tr = run(operator=operator, bench=bench, duration=3.5)
    assert [e.kind for e in tr.safety_events].count("contactor_opened") == 1
    assert tr.resting[(tr.t > 1.5) & (tr.t < 2.0)].all(), "at rest, unpowered, before the reset"
    assert tr.powered[tr.t > 2.6].all() and tr.fallen is None and not tr.resting[-1]


def sc_commands(trace, after: float) -> list[ScCommand]:
    return [
        decode(data, ScCommand)
        for tick, key, data in trace.zenoh_inputs
        if key.endswith("sc/command") and tick * 0.0025 > after
    ]


def flood(mode, source, cap=0.0):
    return {"kind": "zenoh.sc_flood", "mode": mode, "cap": cap, "source": source, "per_tick": 20, "at": 1.0}


def test_two_floods_of_conflicting_sc_requests_never_lift_a_cap():
    tr = run([flood("free", "a"), flood("limit", "b", cap=0.5)])
    forwarded = sc_commands(tr, 1.0 + 0.0025)
    assert forwarded and max(c.speed_cap for c in forwarded) <= 0.5
    assert {c.mode for c in forwarded} == {"limit"}
    arbitration = tr.sc_arbitration
    assert arbitration["conflicts"] > 0
    assert all(arbitration["sources"][s]["refused_rate"] > 1000 for s in ("a", "b")), "rate-limited"
    # Positive control: one free flood alone is forwarded at the absolute cap, so a lifted cap would show.
    alone = sc_commands(run([flood("free", "a")]), 1.0 + 0.0025)
    assert max(c.speed_cap for c in alone) == CFG.speed.absolute_cap


def test_a_dead_controller_is_named_the_root_cause_before_its_heartbeat_watchdog():
    # The drives' 20 ms command watchdog trips first; the event still says HEARTBEAT_LOST, at once, and the
    # recovery law takes the drives (their watchdog re-arms on its first command).
    tr = run([{"kind": "process.kill", "target": "controller", "at": 1.0}])
    t, state, cause = causes(tr)[0]
    assert (state, cause) == ("RECOVERY", "HEARTBEAT_LOST")
    assert t - 1.0 < CFG.watchdogs.heartbeat, "before the heartbeat's own watchdog"
    assert "watchdog tripped" in tr.safety_events[0].detail


def test_faulty_runs_never_wait_out_the_guard_tick_after_tick():
    # What makes a faulty lockstep run slow is waiting: the rig for commands that will not come, the
    # supervisor and the controller for inputs a fault withheld. Counted, not timed.
    for fault in (
        {"kind": "zenoh.malformed", "at": 1.0},
        {"kind": "can.drop", "message": "DRIVE1_COMMAND", "at": 1.0},
        {"kind": "process.kill", "target": "controller", "at": 1.0},
        {"kind": "process.hang", "at": 1.0, "duration": 0.5},
        {"kind": "zenoh.wrench_dropout", "at": 1.0},
    ):
        tr = run([fault])
        assert tr.stats.guards_expired <= 1, fault
        assert tr.fence_misses == 0, fault
    assert np.isfinite(tr.t[-1])
