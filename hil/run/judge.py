"""Judge a run: the summary's measurements, a verdict per criterion of the scenario and per fault
expectation. What a measurement is lives in hil/run/measurements.py; this only applies the scenario."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hil.run.fault_verdicts import fault_verdicts
from hil.run.measurements import MEASUREMENTS, measure, summary_metrics, unavailable
from hil.run.scenario import Scenario, Verdict
from hil.run.trace import Trace
from safety.config import SupervisorConfig
from safety.machine import OPERATOR_STOPS

LIVE_STOPS = frozenset(c.name for c in OPERATOR_STOPS)
SCRIPTED_WITHIN = 0.5
"""s after a scripted e-stop within which the supervisor's transition is that e-stop's (a supervisor in
another process takes it in on its own clock)."""
RUNNING = frozenset({"NORMAL", "LIMITING"})
"""States a stop starts from."""


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
    safety: SupervisorConfig = field(default_factory=SupervisorConfig)
    """The supervisor's rules the run had (the bench's config with the scenario's overrides)."""
    bench: dict = field(default_factory=dict)
    """Where each part ran (the bench's name and parts, as the summary reports them)."""

    @property
    def verdict(self) -> str:
        """How the run ended: STOPPED (ended early: Ctrl-C, SIGTERM, `rig stop`), ESTOPPED (an operator's
        e-stop the scenario did not script: `pure-hil estop`, a button), FAILED (a criterion, or the run
        could not finish), else PASSED. Only PASSED passes."""
        if self.trace.stopped_early:
            return "STOPPED"
        if self.live_estop() is not None:
            return "ESTOPPED"
        if self.trace.failure is not None or not all(v.passed for v in self.verdicts):
            return "FAILED"
        return "PASSED"

    @property
    def passed(self) -> bool:
        return self.verdict == "PASSED"

    def live_estop(self) -> float | None:
        """When an operator's e-stop that the scenario did not schedule came (None: none did)."""
        scripted = [e.at for e in self.scenario.operator if e.action == "estop"]
        for event in self.trace.safety_events:
            # A stop's entry (a stop under way keeps its cause into ESTOP).
            if event.kind != "transition" or event.cause not in LIVE_STOPS or event.from_state not in RUNNING:
                continue
            if not any(0.0 <= event.t - at <= SCRIPTED_WITHIN for at in scripted):
                return event.t
        return None


def judge(result: RunResult) -> RunResult:
    """Fill in the result's measurements and verdicts from its trace."""
    trace, radius = result.trace, result.ball_radius
    result.metrics = summary_metrics(trace, radius)
    for c in result.scenario.criteria:
        value = measure(trace, c.metric, c.plane, c.after, c.cause, radius)
        note = unavailable(trace, c.metric) if math.isnan(value) else ""
        unit = MEASUREMENTS[c.metric].unit
        result.verdicts.append(Verdict(c.label, value, c.describe(), unit, c.check(value), note or c.note))
    result.verdicts += fault_verdicts(trace)
    return result
