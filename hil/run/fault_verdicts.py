"""Judge a run against what its faults expected: each field of a fault's `expect` becomes a Verdict.

A missed reaction fails with a message that says what was expected, by when, and what the supervisor did
instead, so a campaign report or a pytest failure reads on its own.

A fault that expects no reaction is judged on what it caused (docs/faults.md "Attribution"): a transition
of the supervisor's after its start is held against it unless something else in the run explains it
(`explained_by`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from drivers.vocabulary import OPERATOR_STOPS, RUNNING_STATES, Cause, Event
from hil.faults.base import Expect, FaultSpec
from hil.run.lateness import REACTION_AFTER
from hil.run.scenario import Scenario, Verdict

if TYPE_CHECKING:
    from hil.run.trace import Trace

AFTERMATH = 2.0
"""s after another fault's end within which a transition may still be its doing: the supervisor's slowest
watchdog (the SC's, 1 s) and a stop's first step after it."""
OPERATORS = frozenset(c.name for c in OPERATOR_STOPS)


def fault_verdicts(trace: Trace, scenario: Scenario | None = None) -> list[Verdict]:
    out = []
    for n, spec in enumerate(trace.faults):
        if spec.expect is not None:
            out += _judge(trace, n, spec, spec.expect, scenario)
    return out


def explained_by(trace: Trace, n: int, ev: Event, scenario: Scenario | None) -> str:
    """What in the run other than fault n explains transition `ev` ('' : nothing, the fault is blamed):
    a stop already under way (the transition does not start from a running state), an operator's e-stop,
    the scenario's own SC cap in force, another fault acting then or AFTERMATH before, the rig's own
    lateness in real time."""
    if ev.from_state not in RUNNING_STATES:
        return "a stop already under way"
    if ev.cause in OPERATORS:
        return "an operator's e-stop"
    if ev.cause == Cause.OVER_CAP.name and scenario is not None:
        steps = [s for s in scenario.sc if s.at <= ev.t + 1e-9]
        if steps and steps[-1].mode == "limit":
            return "the scenario's SC cap"
    for m, window in enumerate(trace.fault_windows):
        if m != n and window is not None and window[0] - 1e-9 <= ev.t <= window[1] + AFTERMATH:
            return f"fault {m} {trace.faults[m].kind}"
    if trace.lateness.covers(ev.t, REACTION_AFTER):
        return "the rig's own lateness"
    return ""


def _judge(trace: Trace, n: int, spec: FaultSpec, e: Expect, scenario: Scenario | None) -> list[Verdict]:
    label = f"fault {n} {spec.kind} @{spec.at:g}s"
    window = trace.fault_windows[n] if n < len(trace.fault_windows) else None
    end = float(trace.t[-1]) if len(trace.t) else 0.0
    if window is None:
        why = f"the fault never started (the run ended at {end:.3f} s)"
        return [Verdict(f"{label}: started", math.nan, "started", "", False, why)]
    start = window[0]
    after = [ev for ev in trace.safety_events if ev.kind == "transition" and ev.t >= start - 1e-9]
    verdicts = []
    if e.supervisor:
        wanted = "/".join(x for x in (e.state, e.cause) if x)
        hit = next(
            (
                ev
                for ev in after
                if (e.state is None or ev.to_state == e.state) and (e.cause is None or ev.cause == e.cause)
            ),
            None,
        )
        delay = math.nan if hit is None else hit.t - start
        passed = hit is not None and delay <= e.within + 1e-9
        note = ""
        if not passed:
            seen = ", ".join(f"{ev.to_state}/{ev.cause} at {ev.t:.3f} s" for ev in after[:3]) or "none"
            note = (
                f"expected the supervisor to enter {wanted} within {e.within:g} s of {spec.describe()} "
                f"starting at {start:.3f} s; its transitions from then on: {seen}"
            )
        verdicts.append(Verdict(f"{label}: {wanted}", delay, f"<= {e.within:g} s", "s", passed, note))
    if e.reaction == "none":
        causes = [explained_by(trace, n, ev, scenario) for ev in after]
        blamed = [ev for ev, cause in zip(after, causes, strict=True) if not cause]
        note = ""
        if blamed:
            first = blamed[0]
            note = (
                f"expected no supervisor reaction to {spec.describe()}, but it entered "
                f"{first.to_state}/{first.cause} at {first.t:.3f} s and nothing else in the run explains it"
            )
        elif after:
            pairs = zip(after, causes, strict=True)
            note = "not this fault's: " + "; ".join(
                f"{ev.to_state}/{ev.cause} at {ev.t:.3f} s ({c})" for ev, c in pairs
            )
        verdicts.append(
            Verdict(f"{label}: no reaction", float(len(blamed)), "== 0 transitions", "", not blamed, note)
        )
    if e.fall is not None:
        fell = trace.fallen is not None
        note = "" if fell == e.fall else f"expected fall={e.fall}, fallen: {trace.fallen}"
        verdicts.append(Verdict(f"{label}: fall", float(fell), f"== {e.fall}", "", fell == e.fall, note))
    if e.max_speed is not None:
        since = trace.t >= start - 1e-9
        speed = np.hypot(trace.velocity[since, 0], trace.velocity[since, 1])
        top = float(speed.max()) if len(speed) else math.nan
        passed = top <= e.max_speed
        note = "" if passed else f"ground speed reached {top:.3f} m/s after {spec.describe()}"
        verdicts.append(Verdict(f"{label}: max_speed", top, f"<= {e.max_speed:g} m/s", "m/s", passed, note))
    return verdicts
