"""Judge a run: the summary's measurements, a verdict per criterion of the scenario and per fault
expectation. What a measurement is lives in hil/run/measurements.py; this only applies the scenario."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hil.faults.verdicts import fault_verdicts
from hil.run.measurements import MEASUREMENTS, measure, summary_metrics, unavailable
from hil.run.scenario import Scenario, Verdict
from hil.run.trace import Trace
from safety.config import SupervisorConfig


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
    def passed(self) -> bool:
        return self.trace.failure is None and all(v.passed for v in self.verdicts)


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
