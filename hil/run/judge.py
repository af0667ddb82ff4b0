"""Judge a run: the summary's measurements, a verdict per criterion of the scenario and per fault
expectation, and the two rules every run is held to, whatever its criteria: a fall fails it (unless the
scenario expects one), and so does a stop of the supervisor's that the scenario did not plan. What a
measurement is lives in hil/run/measurements.py; this only applies the scenario."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from drivers.rules import JudgedRules
from drivers.vocabulary import OPERATOR_STOPS, RUNNING_STATES, STOP_COMMANDS, State
from hil.run.agents import SCENARIO_SOURCE
from hil.run.fault_verdicts import fault_verdicts
from hil.run.lateness import REACTION_AFTER
from hil.run.measurements import MEASUREMENTS, measure, summary_metrics, unavailable
from hil.run.scenario import Scenario, Verdict
from hil.run.trace import Trace

LIVE_STOPS = frozenset(c.name for c in OPERATOR_STOPS)
SCRIPTED_WITHIN = 0.5
"""s after a scripted e-stop within which the supervisor's transition is that e-stop's (a supervisor in
another process takes it in on its own clock)."""
STOPS = frozenset({"STOPPING", "RECOVERY", "ESTOP"})
"""States a stop is in."""
SUPERVISOR_LOST = "SUPERVISOR_LOST"
"""The stop of a supervisor gone silent: the drives lose their permission with nobody deciding it."""
EXIT_CODES = {"PASSED": 0, "FAILED": 1, "ESTOPPED": 3, "INCONCLUSIVE": 4, "STOPPED": 130}
"""Each verdict and the exit code `pure-hil run` ends with (2 is a usage or configuration error's)."""
NO_FALL, EXPECTED_FALL, NO_UNPLANNED_STOP = "no fall", "expected fall", "no unplanned stop"
RUN_RULES = frozenset({NO_FALL, EXPECTED_FALL, NO_UNPLANNED_STOP})
"""The verdicts every run has besides its scenario's criteria and fault expectations."""


@dataclass(slots=True)
class RunResult:
    scenario: Scenario
    law: str
    """The control law the reference controller ran (hacs, ihacs), or `external`."""
    clock: str
    seed: int
    trace: Trace
    metrics: dict[str, float]
    verdicts: list[Verdict] = field(default_factory=list)
    ball_radius: float = math.nan
    """Of the plant's robot (measurements in rad/s need it)."""
    safety: JudgedRules = field(default_factory=JudgedRules)
    """The limits it is judged by (drivers/rules.py), from the supervisor's rules the run had."""
    bench: dict = field(default_factory=dict)
    """Where each part ran (the bench's name and parts, as the summary reports them)."""

    @property
    def verdict(self) -> str:
        """How the run ended: STOPPED (ended early: Ctrl-C, SIGTERM, `rig stop`), ESTOPPED (an operator's
        e-stop the scenario did not script: `pure-hil estop`, a button, in whatever state the supervisor
        was), FAILED (the run could not finish), INCONCLUSIVE (in real time the rig itself was late and that
        cost the controller commands or set off a supervisor's stop: nothing can be said of the controller),
        FAILED (a verdict failed), else PASSED. Only PASSED passes."""
        if self.trace.stopped_early:
            return "STOPPED"
        if self.live_estop() is not None:
            return "ESTOPPED"
        if self.trace.failure is not None:
            return "FAILED"
        if self.rig_was_late():
            return "INCONCLUSIVE"
        if not all(v.passed for v in self.verdicts):
            return "FAILED"
        return "PASSED"

    def rig_was_late(self) -> list[str]:
        """Why the rig's own lateness makes the run inconclusive, one line each (empty: it does not)."""
        return rig_lateness(self.trace, self.scenario)

    @property
    def passed(self) -> bool:
        return self.verdict == "PASSED"

    def operator_actions(self) -> list[dict]:
        return operator_actions(self.trace, self.scenario)

    def live_estop(self) -> float | None:
        """When the first operator e-stop or cut that the scenario did not schedule came (None: none did):
        as the supervisor took it in, whatever its state, or as a stop it entered for an operator's cause
        (a wired button beside a supervisor in another process)."""
        for action in self.operator_actions():
            if action["action"] in STOP_COMMANDS and not action["scheduled"]:
                return action["t"]
        scripted = [e.at for e in self.scenario.operator if e.action == "estop"]
        for event in self.trace.safety_events:
            # A stop's entry (a stop under way keeps its cause into ESTOP).
            entry = event.kind == "transition" and event.from_state in RUNNING_STATES
            if not entry or event.cause not in LIVE_STOPS:
                continue
            if not any(0.0 <= event.t - at <= SCRIPTED_WITHIN for at in scripted):
                return event.t
        return None


def operator_actions(trace: Trace, scenario: Scenario) -> list[dict]:
    """The run's operator actions as summary.json and run.mcap record them: `t` (s), `action` (estop,
    cut_power, reset), `source`, `supervisor_state` (when it came) and `scheduled` (one of the scenario's
    own `[[operator]]` steps: sent by the rig as `scenario` at that step's tick, taken in within
    SCRIPTED_WITHIN)."""
    steps = [(scenario.tick_of(e.at) / scenario.tick_hz, e.action) for e in scenario.operator]
    used: set[int] = set()
    out = []
    for a in trace.operator_actions:
        scheduled = False
        if a.source == SCENARIO_SOURCE:
            for i, (at, action) in enumerate(steps):
                if i not in used and action == a.action and -1e-9 <= a.t - at <= SCRIPTED_WITHIN:
                    used.add(i)
                    scheduled = True
                    break
        out.append(
            {
                "t": round(a.t, 6),
                "action": a.action,
                "source": a.source,
                "supervisor_state": a.supervisor_state,
                "scheduled": scheduled,
            }
        )
    return out


def judge(result: RunResult) -> RunResult:
    """Fill in the result's measurements and verdicts from its trace."""
    trace, radius = result.trace, result.ball_radius
    result.metrics = summary_metrics(trace, radius)
    for c in result.scenario.criteria:
        value = measure(trace, c.metric, c.plane, c.after, c.cause, radius)
        note = unavailable(trace, c.metric) if math.isnan(value) else ""
        unit = MEASUREMENTS[c.metric].unit
        result.verdicts.append(Verdict(c.label, value, c.describe(), unit, c.check(value), note or c.note))
    result.verdicts += fault_verdicts(trace, result.scenario)
    result.verdicts += fall_verdicts(trace, result.scenario)
    result.verdicts.append(stop_verdict(trace, result.scenario))
    return result


def rig_lateness(trace: Trace, scenario: Scenario) -> list[str]:
    """What the rig's own lateness in real time cost (hil/run/lateness.py): the controller's commands in its
    late windows, and the supervisor's stops the scenario did not plan that came in or just after one."""
    late = trace.lateness
    why = []
    if late.cost:
        windows = ", ".join(f"{a:.3f}-{b:.3f} s" for a, b in late.windows[:3])
        more = f" and {len(late.windows) - 3} more" if len(late.windows) > 3 else ""
        why.append(
            f"the rig sent {late.ticks} SYNCs late (windows {windows}{more}; up to "
            f"{late.worst * 1e3:.2f} ms), which cost the controller {late.missing} missing and {late.late} "
            "late commands"
        )
    for t, state, cause in stops(trace):
        ours = cause not in LIVE_STOPS and not planned(trace, scenario, t, cause)
        if ours and late.covers(t, REACTION_AFTER):
            why.append(f"the supervisor's stop {state}/{cause} at {t:.3f} s came in or just after a late one")
    return why


def fall_verdicts(trace: Trace, scenario: Scenario) -> list[Verdict]:
    """A fall fails every run (`no fall`), unless the scenario expects one (`expected fall`: then staying up
    fails). A criterion of the scenario's own that already fails a fall stands for `no fall`."""
    fell = trace.fallen is not None
    if scenario.fall == "expected":
        note = "" if fell else 'the scenario expects a fall (fall = "expected") and the robot stayed up'
        return [Verdict(EXPECTED_FALL, float(fell), "== 1", "", fell, note)]
    if any(c.metric == "fallen" and not c.check(1.0) for c in scenario.criteria):
        return []
    note = (
        f'the robot fell: {trace.fallen} (a fall fails every run unless its scenario says fall = "expected")'
    )
    return [Verdict(NO_FALL, float(fell), "== 0", "", not fell, note if fell else "")]


def stop_verdict(trace: Trace, scenario: Scenario) -> Verdict:
    """The supervisor's stops the scenario did not plan: none may happen (an operator's are the ESTOPPED
    verdict's, scheduled or not)."""
    unplanned = [
        f"{state}/{cause} at {t:.3f} s"
        for t, state, cause in stops(trace)
        if cause not in LIVE_STOPS and not planned(trace, scenario, t, cause)
    ]
    note = ""
    if unplanned:
        note = (
            f"the supervisor stopped ({', '.join(unplanned[:3])}) and the scenario plans no such stop: no "
            "scheduled fault had started, no live fault expected a supervisor reaction, no criterion "
            "measures it"
        )
    return Verdict(NO_UNPLANNED_STOP, float(len(unplanned)), "== 0", "", not unplanned, note)


def stops(trace: Trace) -> list[tuple[float, str, str]]:
    """(t, state, cause) of each stop's entry: the supervisor leaving NORMAL or LIMITING for a stopping
    state, or its frame going silent (the drives lose their permission with nobody deciding)."""
    out = [
        (e.t, e.to_state, e.cause)
        for e in trace.safety_events
        if e.kind == "transition" and e.from_state in RUNNING_STATES and e.to_state in STOPS
    ]
    out += [(t, "silent", SUPERVISOR_LOST) for t in trace.stats.supervisor_lost_at]
    return sorted(out)


def planned(trace: Trace, scenario: Scenario, t: float, cause: str) -> bool:
    """A stop at `t` for `cause` is the scenario's plan: a fault it schedules had started by then, a live
    fault that expects a supervisor reaction had (its expectation judges which), or a criterion measures
    such a stop (the reaction for that cause, the drives going off, a stopped final state, ending at
    rest)."""
    scheduled = len(scenario.faults)
    for n, window in enumerate(trace.fault_windows):
        if window is None or window[0] > t + 1e-9:
            continue
        expect = trace.faults[n].expect if n < len(trace.faults) else None
        if n < scheduled or (expect is not None and expect.supervisor):
            return True
    stopped = [float(s) for s in State if s.name in STOPS]
    for c in scenario.criteria:
        if (
            (c.metric == "safety_reaction" and c.cause == cause)
            or c.metric == "drives_off_after"
            or (c.metric == "safety_state" and any(c.check(code) for code in stopped))
            or (c.metric == "resting" and c.check(1.0) and not c.check(0.0))
        ):
            return True
    return False
