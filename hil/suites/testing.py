"""Assertion helpers for HIL tests (the pytest plugin's fixtures hand out results these check).

Each helper raises AssertionError with what was expected and what the run did, so a failing HIL test
reads on its own in a CI log or a JUnit report.
"""

from __future__ import annotations

import math

from drivers.vocabulary import Event
from hil.run.judge import RunResult
from hil.run.measurements import measure


def assert_passed(result: RunResult) -> None:
    """Every criterion and fault expectation of the run passed. A run the rig itself made late in real time
    says nothing of the controller: the test is skipped, saying why (INCONCLUSIVE)."""
    late = result.rig_was_late()
    if late:
        import pytest

        pytest.skip(f"{result.scenario.name}: INCONCLUSIVE: " + "; ".join(late))
    failed = [v for v in result.verdicts if not v.passed]
    if failed:
        lines = [
            f"{v.criterion}: measured {v.value:.4g} {v.units}, limit {v.limit}"
            + (f" ({v.note})" if v.note else "")
            for v in failed
        ]
        raise AssertionError(
            f"{result.scenario.name}: {len(failed)} verdict(s) failed:\n  " + "\n  ".join(lines)
        )


def metric(result: RunResult, name: str, plane: str = "pitch", after: float = 0.0, cause: str = "") -> float:
    """A measurement of the run (hil/run/measurements.py), as a scenario's criterion would take it."""
    return measure(result.trace, name, plane, after, cause, result.ball_radius)


def assert_metric(
    result: RunResult,
    name: str,
    *,
    min: float | None = None,
    max: float | None = None,
    plane: str = "pitch",
    after: float = 0.0,
) -> float:
    """`min <= metric <= max`; returns the value."""
    value = metric(result, name, plane, after)
    if math.isnan(value) or (min is not None and value < min) or (max is not None and value > max):
        raise AssertionError(f"{name} [{plane}] = {value:.4g}, expected within [{min}, {max}]")
    return value


def supervisor_transitions(result: RunResult, after: float = 0.0) -> list[Event]:
    return [e for e in result.trace.safety_events if e.kind == "transition" and e.t >= after - 1e-9]


def assert_supervisor(
    result: RunResult,
    *,
    state: str | None = None,
    cause: str | None = None,
    after: float = 0.0,
    within: float | None = None,
) -> Event:
    """The supervisor entered `state` with `cause` at or after `after` (and within `within` s of it)."""
    seen = supervisor_transitions(result, after)
    for e in seen:
        if (state is None or e.to_state == state) and (cause is None or e.cause == cause):
            if within is not None and e.t - after > within + 1e-9:
                break
            return e
    bound = "" if within is None else f" within {within:g} s"
    got = ", ".join(f"{e.to_state}/{e.cause} at {e.t:.3f} s" for e in seen) or "no transition"
    raise AssertionError(
        f"expected the supervisor to enter {state or '*'}/{cause or '*'}{bound} after {after:g} s; got {got}"
    )


def assert_no_reaction(result: RunResult, after: float = 0.0) -> None:
    seen = supervisor_transitions(result, after)
    if seen:
        e = seen[0]
        raise AssertionError(
            f"expected no supervisor reaction after {after:g} s; "
            f"it entered {e.to_state}/{e.cause} at {e.t:.3f} s"
        )
