"""Running a campaign's cases: one case in this process (`run_case`: its lockstep run, measured and judged,
a faulty case's twin timed on the same worker just before it), a faulty case classed against its twin
(`judge`), and every case in parallel processes or on a Dask cluster (`run_campaign`, hil/suites/cluster.py);
each ends as a CaseResult, which the reports read (hil/suites/campaign_report.py)."""

from __future__ import annotations

import logging
import time
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context
from pathlib import Path

import msgspec

from hil.bench.bench import Bench, load_bench
from hil.run.measurements import measure, release_end, with_unit
from hil.run.scenario import Scenario
from hil.suites.campaign_file import Case
from hil.suites.coverage import Bounds, Classification, Outcome, classify, false_trip, outcome


@dataclass(slots=True)
class CaseResult:
    case_id: str
    scenario: str
    passed: bool
    wall: float
    verdicts: list[dict] = field(default_factory=list)
    error: str = ""
    fallen: str | None = None
    peak_tilt_after_release_deg: float = 0.0
    """The largest chassis tilt (either plane) from the release's end on, deg: the release's own tilt is
    the scenario's, the same in every case of it, so it would sort nothing."""
    release_end: float | None = 0.0
    """When the release ended, s (hil/run/measurements.py release_end); None: it never did, and the peak
    is the whole run's."""
    safety_events: list[str] = field(default_factory=list)
    role: str = "plain"
    twin: str = ""
    outcome: Outcome | None = None
    coverage: Classification | None = None
    """A faulty case's class (set once its twin has run)."""
    false_trip: str = ""
    """A fault-free case of a coverage campaign: why it counts as a false trip ('' if it does not)."""
    twin_wall: float = 0.0
    """A faulty case: the wall time of its fault-free twin, run on the same worker right before it (0: the
    twin could not run there). Its wall time is judged against this one, not the twin's own run, which may
    have met a quieter or a busier machine."""
    supervisor: str = ""
    """The supervisor plug that judged it (`reference`, a lab's own), `external` for one the rig did not
    start; '' when the case never ran."""
    inconclusive: list[str] = field(default_factory=list)
    """Why the run was INCONCLUSIVE (the rig itself late in real time, hil/run/judge.py); empty: not."""

    @property
    def verdict(self) -> str:
        """ERROR, INCONCLUSIVE, PASS or FAIL: the case's line in every report."""
        if self.error:
            return "ERROR"
        if self.inconclusive:
            return "INCONCLUSIVE"
        return "PASS" if self.passed else "FAIL"

    @classmethod
    def errored(cls, case: Case, why: str, wall: float = 0.0) -> CaseResult:
        """A case that could not run to a verdict (it raised, or its worker died)."""
        return cls(case.id, case.scenario, False, wall, error=why, role=case.role, twin=case.twin_id)

    @property
    def failed(self) -> list[dict]:
        return [v for v in self.verdicts if not v["passed"]]

    def message(self) -> str:
        """Why the case failed, one line per failed verdict (notes say what was expected instead)."""
        if self.error:
            return self.error
        lines = [f"INCONCLUSIVE: {why}" for why in self.inconclusive]
        if self.coverage is not None and not self.coverage.passed:
            c = self.coverage
            lines.append(f"{c.name}: {c.cause or 'no reaction of its own'}; {c.note}".rstrip("; "))
        if self.false_trip:
            lines.append(f"false trip: {self.false_trip}")
        for v in self.failed:
            measured = with_unit(f"{v['value']:.4g}", v["units"])
            line = f"{v['criterion']}: measured {measured}, limit {v['limit']}".rstrip()
            lines.append(line + (f" ({v['note']})" if v["note"] else ""))
        return "\n".join(lines)


def run_case(case: Case, out: Path | None = None, bench: Bench | None = None) -> CaseResult:
    """Run one case in this process, lockstep, on `bench` (default: embedded, a private bus and its own
    zenoh hub on a free loopback port, so cases in parallel never meet); with `out`, its whole run folder
    there (summary, CAN log, trace, recording, plots: the bench's outputs)."""
    from hil.pipeline import run
    from hil.run.build import RunOptions
    from hil.run.judge import RUN_RULES

    bench = bench or load_bench()
    twin_wall = _time_twin(case, bench)
    bench = _private(bench)
    start = time.monotonic()
    try:
        # The logs on the case's own thread: a campaign's workers fill every core already, and a writer
        # process per case would only add its hand-over (hil/outputs/run_logs.py).
        result = run(case.build(), bench, out=out, options=RunOptions(logs_in_process=True))
    except Exception as exc:  # a broken case is a result (an error), never the end of the campaign
        detail = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        return CaseResult.errored(case, detail, time.monotonic() - start)
    tr = result.trace
    if tr.failure is not None and not len(tr.t):  # it never ran: why is the case's line, not NaN verdicts
        return CaseResult.errored(case, f"{tr.failure.stage}: {tr.failure.error}", time.monotonic() - start)
    judged = case.role != "plain"
    # A faulty case's falls and stops are its classification's to judge (against its twin; a fall the fault
    # makes unrecoverable passes), not the rules every run has.
    verdicts = [v for v in result.verdicts if case.role != "faulty" or v.criterion not in RUN_RULES]
    released = release_end(tr, result.scenario.initial_tilt_deg) if len(tr.t) else 0.0
    res = CaseResult(
        case.id,
        case.scenario,
        result.passed,
        time.monotonic() - start,
        [asdict(v) for v in verdicts],
        fallen=tr.fallen,
        peak_tilt_after_release_deg=measure(tr, "max_tilt_deg", "both", released or 0.0)
        if len(tr.t)
        else 0.0,
        release_end=released,
        safety_events=[
            f"{e.t:.3f} {e.to_state}/{e.cause}" for e in tr.safety_events if e.kind == "transition"
        ],
        role=case.role,
        twin=case.twin_id,
        outcome=outcome(result) if judged else None,
        twin_wall=twin_wall,
        supervisor=bench.supervisor.plug or "external",
        inconclusive=result.rig_was_late(),
    )
    if res.outcome is not None:  # every role but plain (judged)
        res.outcome.unrecoverable = case.unrecoverable
        if case.role in ("twin", "fault_free"):
            res.false_trip = false_trip(res.outcome)
            res.passed = res.passed and not res.false_trip
    return res


def _private(bench: Bench) -> Bench:
    """The bench for one lockstep run: a self-contained one gets its own zenoh hub on a free loopback
    port, so runs side by side, or one right after another, never meet."""
    from drivers.zenoh_link import free_loopback_endpoint

    if bench.self_contained and bench.zenoh.mode == "loopback" and bench.zenoh.endpoint is None:
        bench = bench.with_overrides(hub=free_loopback_endpoint())
    return bench.with_overrides(clock="lockstep")


def _time_twin(case: Case, bench: Bench) -> float:
    """A faulty case's twin run on this worker, now, for its wall time only (no outputs): the case's own
    run follows at once, so both meet the same machine (0.0: the twin could not run)."""
    if case.role != "faulty" or not case.twin_text:
        return 0.0
    from hil.pipeline import run
    from hil.run.build import RunOptions

    twin = msgspec.json.decode(case.twin_text, type=Scenario)
    start = time.monotonic()
    try:
        result = run(twin, _private(bench), options=RunOptions(logs_in_process=True))
    except Exception:  # judged without a timing twin: its own run's errors show where it runs as a case
        return 0.0
    return 0.0 if result.trace.failure is not None else time.monotonic() - start


def judge(result: CaseResult, twin: CaseResult | None, bounds: Bounds) -> None:
    """Class a faulty case against its twin (coverage campaigns); its verdict is its class's."""
    if result.role != "faulty" or result.error:
        return
    assert result.outcome is not None  # run_case measures every case that ran but a plain one
    if twin is None or twin.outcome is None:
        result.coverage = Classification("MISSED", note=f"no twin to judge against ({result.twin})")
    else:
        result.coverage = classify(result.outcome, twin.outcome, bounds)
        # Timing against the twin run back to back on the same worker (run_case), not the twin's own run.
        reference = result.twin_wall
        if reference > 0 and result.wall > bounds.wall_ratio * reference:
            result.verdicts.append(
                {
                    "criterion": "wall time vs twin",
                    "value": result.wall / reference,
                    "limit": f"<= {bounds.wall_ratio:g}x",
                    "units": "x",
                    "passed": False,
                    "note": f"{result.wall:.1f} s against its twin's {reference:.1f} s, run just before it "
                    "on the same worker",
                }
            )
    result.passed = result.coverage.passed and not result.failed


def run_campaign(
    cases: list[Case],
    workers: int = 1,
    out: Path | None = None,
    progress: Callable[[int, int, CaseResult], None] | None = None,
    bench: Bench | None = None,
    scheduler: str | None = None,
) -> list[CaseResult]:
    """Every case on `bench`, `workers` at a time in fresh processes (spawned: no zenoh or bus state is
    inherited), or as tasks on the Dask cluster at `scheduler` (hil/suites/cluster.py). A bench whose parts
    are not all in the rig's process, or whose bus is shared, runs them one at a time in this process: they
    would share the bus and the hub."""
    bench = bench or load_bench()
    parallel = distributable(bench)
    results: list[CaseResult] = []
    folder = (lambda c: out / c.id) if out is not None else (lambda c: None)
    # Coverage: twins first, so a faulty case is judged the moment it finishes.
    cases = sorted(cases, key=lambda c: c.role == "faulty")
    by_id: dict[str, CaseResult] = {}

    def done(case: Case, result: CaseResult) -> None:
        if case.bounds is not None:
            judge(result, by_id.get(case.twin_id), case.bounds)
        by_id[result.case_id] = result
        results.append(result)
        if progress:
            progress(len(results), len(cases), result)

    if scheduler is not None:
        if not parallel:
            raise ValueError(f"bench {bench.name}: on a cluster every part must be in the rig's process")
        from hil.suites.cluster import run_on_cluster

        phases = [[c for c in cases if c.role != "faulty"], [c for c in cases if c.role == "faulty"]]
        run_on_cluster(scheduler, phases, bench, out, run_case, CaseResult.errored, done)
    elif workers <= 1 or not parallel:
        with quiet_cases():
            for case in cases:
                done(case, run_case(case, folder(case), bench))
    else:
        with run_pool(workers) as pool:
            futures = {pool.submit(run_case, c, folder(c), bench): c for c in cases if c.role != "faulty"}
            for future in as_completed(futures):
                done(futures[future], future.result())
            futures = {pool.submit(run_case, c, folder(c), bench): c for c in cases if c.role == "faulty"}
            for future in as_completed(futures):
                done(futures[future], future.result())
    order = {c.id: i for i, c in enumerate(cases)}
    return sorted(results, key=lambda r: order[r.case_id])


def distributable(bench: Bench) -> bool:
    """Cases on this bench can run side by side, in any process: every part in the rig's process, on a
    private in-process bus."""
    return bench.self_contained and bench.can.in_process and not bench.can.channel


def run_pool(workers: int) -> ProcessPoolExecutor:
    """Processes for runs side by side: spawned fresh (no zenoh or bus state inherited), quiet."""
    return ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_quiet_worker)


def _quiet_worker() -> None:
    # Workers' warnings (every supervisor transition, every fault start) would interleave unreadably with
    # the progress lines; each case's summary.json keeps them.
    logging.basicConfig(level=logging.ERROR)


@contextmanager
def quiet_cases() -> Iterator[None]:
    """Cases run in this process say no more than a worker's do (`_quiet_worker`): errors only, while
    inside. Their warnings broke a campaign's progress bar up, case by case."""
    root = logging.getLogger()
    level = root.level
    root.setLevel(max(level, logging.ERROR))
    try:
        yield
    finally:
        root.setLevel(level)
