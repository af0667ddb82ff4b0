"""Judge a run against what its faults expected: each field of a fault's `expect` becomes a Verdict.

A missed reaction fails with a message that says what was expected, by when, and what the supervisor did
instead, so a campaign report or a pytest failure reads on its own.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from hil.faults.base import Expect, FaultSpec
from hil.run.scenario import Verdict

if TYPE_CHECKING:
    from hil.run.trace import Trace


def fault_verdicts(trace: Trace) -> list[Verdict]:
    out = []
    for n, spec in enumerate(trace.faults):
        if spec.expect is not None:
            out += _judge(trace, n, spec, spec.expect)
    return out


def _judge(trace: Trace, n: int, spec: FaultSpec, e: Expect) -> list[Verdict]:
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
        note = ""
        if after:
            first = after[0]
            note = (
                f"expected no supervisor reaction to {spec.describe()}, but it entered "
                f"{first.to_state}/{first.cause} at {first.t:.3f} s"
            )
        verdicts.append(
            Verdict(f"{label}: no reaction", float(len(after)), "== 0 transitions", "", not after, note)
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
