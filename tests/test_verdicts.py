"""Verdicts a lab can sign (issue 36; docs/rig.md "Verdicts", docs/scenarios.md, docs/faults.md):

1. a fall never passes, unless the scenario says it expects one; a start state beyond the fall bound, or
   not a number, is a usage error (exit 2) naming the file, the field and the bound;
2. every operator e-stop, reset and cut is recorded with its source, time and the supervisor's state, in
   summary.json, run.mcap and the service's result, and a run an operator stopped is ESTOPPED whatever
   state the supervisor was in (here: already stopping for a silent seat, and holding the drives under its
   recovery law after the IMU's rate frames were lost);
3. a stop of the supervisor's that the scenario did not plan is never PASSED; a live fault may say which
   reaction it expects (`pure-hil fault inject ... --expect CAUSE --within S`), and the verdict judges it.

The rules are held on synthetic traces first (fast, every branch), then end to end on the embedded bench and
through `pure-hil serve` and the CLI as the issue reported them.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import msgspec
import numpy as np
import pytest
from mcap.reader import make_reader

from drivers.keys import Keys
from drivers.schemas import SafetyState
from drivers.vocabulary import Event, OperatorRecord
from drivers.zenoh_link import ZenohLink, open_session
from hil.cli import main
from hil.faults import parse_fault
from hil.history import History
from hil.pipeline import run
from hil.run.judge import EXPECTED_FALL, NO_FALL, NO_UNPLANNED_STOP, RunResult, judge
from hil.run.lateness import Lateness
from hil.run.scenario import Criterion, OperatorEntry, Scenario, ScEntry
from hil.run.trace import Trace
from hil.service import RigService
from plant.params import RobotParams
from tests.helpers import RIDER_75, ROOT, wait_for
from tests.zenoh_helpers import hub_endpoint, private_bench

FELL = "tilt beyond 30 deg at t=0.800 s"
DROPOUT = parse_fault({"kind": "zenoh.wrench_dropout", "at": 1.0})


def trace(n: int = 800, **changes) -> Trace:
    """A run of n ticks at 400 Hz, standing still and powered, with `changes`."""
    empty = Trace.empty(None)  # type: ignore[arg-type]  # a run that ended as planned
    columns = {
        f.name: np.zeros((n, *column.shape[1:]), column.dtype)
        for f in dataclasses.fields(empty)
        if isinstance(column := getattr(empty, f.name), np.ndarray)
    }
    columns.update(t=np.arange(1, n + 1) / 400.0, powered=np.ones(n, bool), safety_state=np.zeros(n, np.int8))
    return dataclasses.replace(empty, **{**columns, **changes})


def judged(tr: Trace, **scenario) -> RunResult:
    return judge(RunResult(Scenario(name="synthetic", **scenario), "hacs", "lockstep", 0, tr, {}))


def verdict_of(result: RunResult, name: str):
    return next(v for v in result.verdicts if v.criterion == name)


def stop(t: float, cause: str, state: str = "STOPPING", before: str = "NORMAL") -> Event:
    return Event(t, "transition", before, state, cause)


# ----------------------------------------------------------------------------------- 1. falls never pass
def test_a_fall_fails_a_run_without_criteria_and_one_whose_criteria_all_pass():
    upright = judged(trace())
    assert upright.verdict == "PASSED" and verdict_of(upright, NO_FALL).passed  # the positive control
    fell = judged(trace(fallen=FELL))
    assert (fell.verdict, fell.passed) == ("FAILED", False)
    assert FELL in verdict_of(fell, NO_FALL).note
    criteria = [Criterion(metric="max_speed", max=1.0)]
    assert judged(trace(fallen=FELL), criteria=criteria).verdict == "FAILED"


def test_a_scenario_that_expects_a_fall_passes_only_when_the_robot_falls():
    assert judged(trace(fallen=FELL), fall="expected").verdict == "PASSED"
    stayed_up = judged(trace(), fall="expected")
    assert stayed_up.verdict == "FAILED" and "stayed up" in verdict_of(stayed_up, EXPECTED_FALL).note


def test_a_criterion_that_already_fails_a_fall_stands_for_the_rule_and_one_that_admits_it_does_not():
    own = judged(trace(fallen=FELL), criteria=[Criterion(metric="fallen", equals=False)])
    assert own.verdict == "FAILED" and not any(v.criterion == NO_FALL for v in own.verdicts)
    lenient = judged(trace(fallen=FELL), criteria=[Criterion(metric="fallen", max=1.0)])
    assert lenient.verdict == "FAILED" and not verdict_of(lenient, NO_FALL).passed


def documented_push() -> str:
    """docs/scenarios.md's push-limit scenario, as the page shows it."""
    page = (ROOT / "docs/scenarios.md").read_text()
    return next(block for block in page.split("```toml\n")[1:] if 'fall = "expected"' in block).split("```")[
        0
    ]


@pytest.mark.parametrize(("expected", "code", "verdict"), [(False, 1, "FAILED"), (True, 0, "PASSED")])
def test_the_issues_push_fails_unless_its_scenario_expects_the_fall(
    tmp_path, capsys, expected, code, verdict
):
    """The issue's 3 s scenario: no criteria, one push at the rider's chest, and the robot falls at 2.35 s.
    Without `fall = "expected"` (the issue's own text) it fails; with it (docs/scenarios.md) it passes."""
    text = documented_push()
    scenario = tmp_path / "push.toml"
    scenario.write_text(text if expected else text.replace('fall = "expected"\n', ""))
    bench = tmp_path / "bench.toml"  # the embedded bench, the verdict's outputs only (no plots, no recording)
    bench.write_text('name = "embedded"\n[outputs]\nplots = false\nrecording = false\n')
    out = tmp_path / "run"
    command = ["run", str(scenario), "--bench", str(bench), "--hub", hub_endpoint(), "--out", str(out)]
    assert main([*command, "--quiet"]) == code
    assert f"; {verdict}" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["verdict"], summary["passed"], summary["fallen"]) == (verdict, expected, True)
    rule = next(v for v in summary["verdicts"] if v["criterion"] in (NO_FALL, EXPECTED_FALL))
    assert (rule["criterion"], rule["passed"]) == (EXPECTED_FALL if expected else NO_FALL, expected)


@pytest.mark.parametrize(
    ("tilt", "bound"),
    [("[95.0, 0.0]", "within ±30 deg, the fall bound (fall_tilt_deg of"), ("[0.0, 30.0]", "±30 deg")],
)
def test_a_start_beyond_the_fall_bound_is_exit_2_naming_the_file_the_field_and_the_bound(
    tmp_path, capsys, tilt, bound
):
    scenario = tmp_path / "fallen_at_start.toml"
    scenario.write_text(f'name = "fallen_at_start"\nduration = 1.0\ninitial_tilt_deg = {tilt}\n')
    out = tmp_path / "run"
    assert main(["run", str(scenario), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(scenario) in err and "initial_tilt_deg" in err and bound in err, err
    assert not (out / "summary.json").exists(), "refused before anything ran"
    # Just inside the bound, sideways or backward, is a start the robot can be released in (the positive
    # control): no foot and not the rim on the floor there (forward the feet are: test_config_bounds.py).
    for tilt in ((0.0, -29.9), (-29.9, 0.0)):
        Scenario(name="x", initial_tilt_deg=tilt).check_start(30.0, "sim", RobotParams(), RIDER_75, "x")


@pytest.mark.parametrize("tilt", ["[nan, 0.0]", "[0.0, inf]"])
def test_a_start_tilt_that_is_not_a_number_is_exit_2(tmp_path, capsys, tilt):
    scenario = tmp_path / "nonsense.toml"
    scenario.write_text(f'name = "nonsense"\ninitial_tilt_deg = {tilt}\n')
    assert main(["run", str(scenario), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(scenario) in err and "initial_tilt_deg" in err and "finite" in err, err


def test_every_entry_point_refuses_a_start_beyond_the_bench_fall_bound(tmp_path):
    """Not only `pure-hil run`: the pipeline itself (a campaign, the pytest plugin) ends such a run as a
    configuration failure before its first tick, its folder written."""
    result = run(
        Scenario(name="fallen", duration=1.0, initial_tilt_deg=(95.0, 0.0)), private_bench(), out=tmp_path
    )
    failure = result.trace.failure
    assert failure is not None and failure.config and "initial_tilt_deg" in failure.error
    assert result.verdict == "FAILED" and (tmp_path / "summary.json").exists()


# ------------------------------------------------------------------------ 2. every e-stop, in any state
@pytest.mark.parametrize("state", ["NORMAL", "LIMITING", "STOPPING", "RECOVERY", "ESTOP"])
def test_an_operators_estop_in_any_state_is_estopped_with_its_source(state):
    # The supervisor was already stopping for a cause of its own: no transition of its names the operator.
    events = [] if state in ("NORMAL", "LIMITING") else [stop(0.5, "WRENCH_SILENT", state)]
    action = OperatorRecord(1.2, "estop", "lab-operator-A", state)
    result = judged(trace(safety_events=events, operator_actions=[action]), faults=[DROPOUT])
    assert (result.verdict, result.passed) == ("ESTOPPED", False)
    assert result.operator_actions() == [
        {
            "t": 1.2,
            "action": "estop",
            "source": "lab-operator-A",
            "supervisor_state": state,
            "scheduled": False,
        }
    ]
    cut = OperatorRecord(1.2, "cut_power", "lab-operator-A", state)
    assert judged(trace(safety_events=events, operator_actions=[cut]), faults=[DROPOUT]).verdict == "ESTOPPED"


def test_the_scenarios_own_estop_is_scheduled_and_a_reset_stops_nothing():
    scripted = [
        OperatorRecord(1.0, "estop", "scenario", "NORMAL"),
        OperatorRecord(1.5, "reset", "lab-a", "ESTOP"),
    ]
    result = judged(
        trace(safety_events=[stop(1.0, "OPERATOR_ESTOP")], operator_actions=scripted),
        operator=[OperatorEntry(at=1.0, action="estop")],
    )
    assert result.verdict == "PASSED", result.verdicts
    assert [a["scheduled"] for a in result.operator_actions()] == [True, False]
    # Positive control: the scenario's name at a time it schedules nothing is somebody's e-stop.
    spoofed = [OperatorRecord(3.0, "estop", "scenario", "NORMAL")]
    result = judged(trace(operator_actions=spoofed), operator=[OperatorEntry(at=1.0, action="estop")])
    assert result.verdict == "ESTOPPED" and not result.operator_actions()[0]["scheduled"]


# ------------------------------------------------------------------------------------ 3. unplanned stops
def no_unplanned_stop(result: RunResult) -> bool:
    return verdict_of(result, NO_UNPLANNED_STOP).passed


def test_a_stop_the_scenario_did_not_plan_fails_it():
    assert no_unplanned_stop(judged(trace()))  # the positive control: no stop at all
    result = judged(trace(safety_events=[stop(1.1, "WRENCH_SILENT")]))
    assert result.verdict == "FAILED"
    rule = verdict_of(result, NO_UNPLANNED_STOP)
    assert (rule.value, rule.passed) == (1.0, False) and "STOPPING/WRENCH_SILENT at 1.100 s" in rule.note
    # A supervisor gone silent stops the drives with nobody deciding it: a stop too.
    lost = dataclasses.replace(Trace.empty(None).stats, supervisor_lost_at=[1.0])  # type: ignore[arg-type]
    silent = judged(trace(stats=lost))
    assert silent.verdict == "FAILED" and "SUPERVISOR_LOST" in verdict_of(silent, NO_UNPLANNED_STOP).note


def test_a_stop_is_planned_by_a_scheduled_fault_a_live_fault_that_expects_it_or_a_criterion():
    events = [stop(1.1, "WRENCH_SILENT")]

    def with_fault(fault, start=1.0, scheduled=False):
        tr = trace(safety_events=events, faults=[fault], fault_windows=[(start, 2.0)])
        return judged(tr, faults=[fault] if scheduled else [])

    assert no_unplanned_stop(with_fault(DROPOUT, scheduled=True))
    assert not no_unplanned_stop(with_fault(DROPOUT, start=1.5, scheduled=True)), "it started after the stop"
    # Live (not among the scenario's faults): planned only when it expects a supervisor reaction, which
    # its own verdict then judges.
    assert not no_unplanned_stop(with_fault(DROPOUT))
    expecting = {"kind": "zenoh.wrench_dropout", "expect": {"cause": "WRENCH_SILENT", "within": 0.15}}
    result = with_fault(parse_fault(expecting))
    assert result.verdict == "PASSED" and any(
        v.criterion.endswith(": WRENCH_SILENT") for v in result.verdicts
    )
    wrong = with_fault(parse_fault({"kind": "zenoh.wrench_dropout", "expect": {"cause": "IMU_SILENT"}}))
    assert wrong.verdict == "FAILED" and no_unplanned_stop(wrong), "its expectation fails, not the rule"
    fall_only = parse_fault({"kind": "zenoh.wrench_dropout", "expect": {"fall": False}})
    assert not no_unplanned_stop(with_fault(fall_only))
    # A criterion that measures such a stop plans it; one on another cause does not.
    reaction = Criterion(metric="safety_reaction", cause="WRENCH_SILENT", max=1.2)
    assert no_unplanned_stop(judged(trace(safety_events=events), criteria=[reaction]))
    other = Criterion(metric="safety_reaction", cause="OVER_CAP", min=0.0)
    assert not no_unplanned_stop(judged(trace(safety_events=events), criteria=[other]))
    for planning in (Criterion(metric="safety_state", equals=3), Criterion(metric="resting", equals=True)):
        assert no_unplanned_stop(judged(trace(safety_events=events), criteria=[planning]))
    assert not no_unplanned_stop(
        judged(trace(safety_events=events), criteria=[Criterion(metric="safety_state", equals=0)])
    )


# ---------------------------------------------------- 4. a fault is judged on what it caused (issue 46)
NOISE = {
    "kind": "sensor.noise",
    "channel": "imu.pitch",
    "at": 1.0,
    "expect": {"reaction": "none", "fall": False},
}


def no_reaction(result: RunResult):
    return next(v for v in result.verdicts if v.criterion.endswith(": no reaction"))


def test_a_transition_something_else_explains_is_not_the_faults_and_one_nothing_explains_is():
    noise = parse_fault({**NOISE, "sigma": 0.001})
    flood = parse_fault({"kind": "zenoh.sc_flood", "at": 0.5, "duration": 0.4})

    def judged_with(events, faults=(noise,), windows=((1.0, 2.0),), **scenario):
        tr = trace(safety_events=events, faults=list(faults), fault_windows=list(windows))
        return no_reaction(judged(tr, faults=list(faults), **scenario))

    assert not judged_with([stop(1.2, "SENSOR_DISAGREE")]).passed  # the positive control: nothing explains it
    operator = judged_with([stop(1.5, "OPERATOR_ESTOP"), stop(1.8, "OPERATOR_ESTOP", "ESTOP", "STOPPING")])
    assert (
        operator.passed
        and "an operator's e-stop" in operator.note
        and "a stop already under way" in operator.note
    )
    # Another fault's window and its aftermath: the SC silence an earlier flood left.
    aftermath = judged_with([stop(1.3, "SC_SILENT")], faults=(flood, noise), windows=((0.5, 0.9), (1.0, 2.0)))
    assert aftermath.passed and "fault 0 zenoh.sc_flood" in aftermath.note
    long_after = judged_with(
        [stop(3.5, "SC_SILENT")], faults=(flood, noise), windows=((0.5, 0.9), (1.0, 4.0))
    )
    assert not long_after.passed, "AFTERMATH is bounded"
    # The scenario's own SC cap, in force then; without it, OVER_CAP is the fault's.
    limiting = [Event(1.4, "transition", "NORMAL", "LIMITING", "OVER_CAP")]
    capped = judged_with(limiting, sc=[ScEntry(at=0.0, mode="limit", cap=0.5)])
    assert capped.passed and not judged_with(limiting, sc=[ScEntry(at=0.0, mode="free")]).passed
    # The rig's own lateness in real time.
    late = Lateness()
    late.sync(500, 1.25, 0.0025, 0.002)
    tr = trace(
        safety_events=[stop(1.3, "IMU_SILENT")], faults=[noise], fault_windows=[(1.0, 2.0)], lateness=late
    )
    assert no_reaction(judged(tr, faults=[noise])).passed


def scheduled_noise(sigma: float) -> RunResult:
    """The issue's case: noise the robot should ride through, then the scenario's own e-stop."""
    from hil.pipeline import load_scenario

    scenario = msgspec.structs.replace(
        load_scenario("balance"),
        duration=3.0,
        faults=[parse_fault({**NOISE, "sigma": sigma})],
        operator=[OperatorEntry(at=2.0, action="estop")],
    )
    return run(scenario, private_bench())


def test_ride_through_this_noise_then_check_the_estop_passes_and_noise_that_trips_fails_on_its_line():
    ridden = scheduled_noise(0.001)
    assert ridden.verdict == "PASSED", [v for v in ridden.verdicts if not v.passed]
    assert "STOPPING/OPERATOR_ESTOP at 2.000 s (an operator's e-stop)" in no_reaction(ridden).note
    tripped = scheduled_noise(0.05)
    assert tripped.verdict == "FAILED"
    assert [v.criterion for v in tripped.verdicts if not v.passed] == [
        "fault 0 sensor.noise @1s: no reaction"
    ]


# ------------------------------------------------------------------- end to end, through `pure-hil serve`
SEAT = """
name = "seat_then_estop"
rider = "configs/riders/ref_60kg_180.toml"
duration = {duration}
[[sc]]
mode = "idle"
"""
MOVING = """
name = "imu_then_estop"
rider = "configs/riders/s07_abi_73kg_176.toml"
law = "ihacs"
duration = 5.0
[[sc]]
mode = "limit"
cap = 0.5
[intent]
pitch = [{ kind = "hold", duration = 0.5 }, { kind = "ramp", to = 12.0, duration = 1.0 }]
"""


@pytest.fixture
def serve(tmp_path):
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    bench = private_bench(hub=endpoint)  # the verdicts' outputs only: no plots, no recording
    bench = msgspec.structs.replace(
        bench, outputs=msgspec.structs.replace(bench.outputs, plots=False, recording=False)
    )
    svc = RigService(hub, bench, out_root=tmp_path)
    client = open_session(role="member", hub_endpoint=endpoint)
    states = ZenohLink(client).subscribe(Keys().safety_state, SafetyState, capacity=4096)
    yield svc, endpoint, client, states
    svc.close()
    client.close()
    hub.close()


def start(client, text: str, after: float) -> None:
    """Start `text` on the service and wait until its run has simulated `after` seconds."""
    reply = json.loads(
        next(iter(client.get(Keys().rig("start"), payload=text, timeout=10.0))).ok.payload.to_string()
    )
    assert reply["ok"], reply

    def sim_time() -> float:
        replies = list(client.get(Keys().rig("status"), timeout=10.0))
        return json.loads(replies[0].ok.payload.to_string())["sim_time"]

    assert wait_for(lambda: sim_time() >= after, 60, step=0.02)


def reached(states, wanted: set[str]) -> str:
    """The supervisor's first announced state among `wanted` (waits for it)."""
    seen = wait_for(lambda: next((s.state for s in states.drain() if s.state in wanted), None), 30)
    assert seen, f"the supervisor never announced {wanted}"
    return seen


def mcap_operator(folder: Path) -> list[tuple[int, dict]]:
    """run.mcap's operator actions but the scenario's own: (log time, message)."""
    with open(folder / "run.mcap", "rb") as f:
        messages = make_reader(f).iter_messages(topics=["/events/operator"])
        return [(m.log_time, json.loads(m.data)) for _, _, m in messages if b'"scenario"' not in m.data]


@pytest.mark.parametrize(
    ("scenario", "fault", "stopping"),
    [
        (SEAT.format(duration=5.0), ["zenoh.wrench_dropout"], {"STOPPING", "ESTOP"}),
        (MOVING, ["can.drop", "--param", "message=IMU_RATE"], {"RECOVERY", "ESTOP"}),
    ],
    ids=["seat_silent", "imu_rate_lost"],
)
def test_an_estop_while_the_supervisor_is_already_stopping_is_estopped_with_its_source(
    serve, tmp_path, capsys, scenario, fault, stopping
):
    """The issue's report: the e-stop latched, `pure-hil estop` said so, and the run still PASSED."""
    svc, endpoint, client, states = serve
    start(client, scenario, 1.5)
    assert main(["fault", "inject", *fault, "--hub", endpoint]) == 0
    reached(states, stopping)
    assert main(["estop", "--source", "lab-operator-A", "--hub", endpoint]) == 0
    assert "latched" in capsys.readouterr().out
    assert svc.wait_idle(60)
    last = svc.last
    assert last is not None and (last["verdict"], last["passed"]) == ("ESTOPPED", False), last
    ours = [a for a in last["operator_actions"] if a["source"] == "lab-operator-A"]
    assert len(ours) == 1 and ours[0]["action"] == "estop" and not ours[0]["scheduled"]
    assert ours[0]["supervisor_state"] in stopping, "it came while the supervisor was stopping already"
    folder = Path(last["out"])
    summary = json.loads((folder / "summary.json").read_text())
    assert (summary["verdict"], summary["operator_actions"]) == ("ESTOPPED", last["operator_actions"])
    # run.mcap's /events/operator: the same record, each at its time.
    assert mcap_operator(folder) == [
        (round(a["t"] * 1e9), {k: v for k, v in a.items() if k != "t"}) for a in ours
    ]
    assert History(tmp_path).runs(1)[0]["verdict"] == "ESTOPPED"


def test_a_live_faults_unplanned_stop_fails_and_an_expected_one_is_judged(serve, capsys):
    svc, endpoint, client, _ = serve
    start(client, SEAT.format(duration=3.0), 0.5)
    assert main(["fault", "inject", "zenoh.wrench_dropout", "--hub", endpoint]) == 0
    assert svc.wait_idle(60)
    unplanned = svc.last
    assert unplanned is not None and unplanned["verdict"] == "FAILED", unplanned
    summary = json.loads((Path(unplanned["out"]) / "summary.json").read_text())
    rule = next(v for v in summary["verdicts"] if v["criterion"] == NO_UNPLANNED_STOP)
    assert not rule["passed"] and "WRENCH_SILENT" in rule["note"]
    # The same fault, saying what it expects: the verdict judges the reaction, and the run passes.
    start(client, SEAT.format(duration=3.0), 0.5)
    expect = ["--expect", "STOPPING/WRENCH_SILENT", "--within", "0.15"]
    assert main(["fault", "inject", "zenoh.wrench_dropout", *expect, "--hub", endpoint]) == 0
    capsys.readouterr()
    assert svc.wait_idle(60)
    expected = svc.last
    assert expected is not None and expected["verdict"] == "PASSED", expected
    summary = json.loads((Path(expected["out"]) / "summary.json").read_text())
    judged_reaction = [v for v in summary["verdicts"] if v["criterion"].endswith("STOPPING/WRENCH_SILENT")]
    assert len(judged_reaction) == 1 and judged_reaction[0]["passed"] and judged_reaction[0]["value"] <= 0.15


def test_fault_inject_refuses_a_bad_expectation_before_sending(capsys):
    assert main(["fault", "inject", "zenoh.wrench_dropout", "--expect", "WRENCH_QUIET"]) == 2
    assert "unknown cause 'WRENCH_QUIET'" in capsys.readouterr().err
    assert main(["fault", "inject", "zenoh.wrench_dropout", "--within", "0.2"]) == 2
    assert "--within times the reaction --expect names" in capsys.readouterr().err
    assert main(["fault", "inject", "zenoh.wrench_dropout", "--expect", "NORMAL"]) == 2
    assert "NORMAL" in capsys.readouterr().err
