"""Campaigns: scenarios x riders x control laws x fault sets x seeds, each combination a lockstep run with a
verdict.

A campaign file (`configs/campaigns/*.toml`, docs/campaigns.md) names the scenarios, the riders (none: each
scenario's own), the control laws (none: each scenario's own), the fault sets (each a name, a list of faults
with their expected reactions and operator actions; a fault-free baseline unless `baseline = false`) and the
seeds. With a `[coverage]` table it is a diagnostic coverage campaign (hil/suites/coverage.py): each faulty
case is classed against its fault-free twin (DETECTED, BENIGN, MISSED, LATE), fault sets need no expectations,
and every fault-free case, including the `[[fault_free]]` runs, counts a false trip if the supervisor acts.
`pure-hil campaign FILE --workers N` runs the cases in parallel processes and writes a report (worst cases
first, also as JSON) and JUnit XML; the pytest plugin collects the same cases as test items
(hil/suites/pytest_plugin.py).
"""

from __future__ import annotations

import logging
import time
import traceback
import xml.etree.ElementTree as ET
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Annotated, Literal, TypeVar

import msgspec
import numpy as np

from drivers.config import ConfigError, load_toml
from drivers.resources import find
from hil.bench.bench import Bench, load_bench
from hil.faults import Fault, load_with_faults
from hil.run.measurements import measure, release_end, with_unit
from hil.run.scenario import OperatorEntry, Scenario
from hil.suites.coverage import Bounds, Classification, Outcome, classify, false_trip, outcome
from plant.params import RiderParams

Law = Literal["hacs", "ihacs"]
Role = Literal["plain", "faulty", "twin", "fault_free"]


class FaultSetEntry(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A named set of faults injected together in one run (`inject`), each with its `expect`, and the
    operator actions that go with them (`operator`, e.g. an e-stop that reveals a drive stuck on)."""

    name: Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_.-]+$")]
    inject: list[Fault] = []
    operator: list[OperatorEntry] = []
    keep_criteria: bool = False
    """Judge the case by the scenario's own criteria too. By default a faulty case is judged by what its
    faults expect (the scenario's criteria describe the healthy run: an e-stop would fail them)."""
    unrecoverable: dict[str, str] = {}
    """Scenario name -> why nothing can balance the robot after this fault there (a measurement): a fall
    after the detection does not fail the case. docs/safety.md names each."""


class FaultFree(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """More fault-free runs of a coverage campaign, judged for false trips only."""

    scenarios: Annotated[list[str], msgspec.Meta(min_length=1)]
    riders: list[str] = []
    laws: list[Law] = []
    duration: Annotated[float, msgspec.Meta(gt=0)] | None = None


class Campaign(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    name: str
    description: str = ""
    scenarios: Annotated[list[str], msgspec.Meta(min_length=1)]
    riders: list[str] = []
    """Rider files; none: each scenario's own rider."""
    laws: list[Law] = []
    """The reference controller's control laws; none: each scenario's own."""
    fault: list[FaultSetEntry] = []
    baseline: bool = True
    """Also run every combination without faults (named `none`)."""
    seeds: Annotated[list[int], msgspec.Meta(min_length=1)] = msgspec.field(default_factory=lambda: [0])
    duration: Annotated[float, msgspec.Meta(gt=0)] | None = None
    """Overrides every scenario's duration (s)."""
    coverage: Bounds | None = None
    """A diagnostic coverage campaign: faulty cases classed against their fault-free twins."""
    fault_free: list[FaultFree] = []
    bench: str | None = None
    """The bench its cases need (a device profile's protocol faults: configs/benches/odrive.toml, ...); a
    command's --bench (the pytest plugin's --hil-bench) given explicitly runs them on another. None: the
    command's default bench."""
    pytest_select: list[str] = []
    """What the pytest plugin collects: the cases whose id contains one of these (and their twins); empty:
    every case. A long campaign's representative subset for CI (`pytest --hil-full` runs them all)."""

    def __post_init__(self) -> None:
        if self.coverage is not None and not self.baseline:
            raise ValueError("a coverage campaign needs its fault-free baseline (the twins)")
        if self.fault_free and self.coverage is None:
            raise ValueError("[[fault_free]] runs belong to a coverage campaign (add [coverage])")
        for s in self.fault:
            if (
                self.coverage is None
                and not s.keep_criteria
                and s.inject
                and not any(f.expect for f in s.inject)
            ):
                raise ValueError(f"fault set {s.name!r}: no fault says what it expects (add `expect`)")


@dataclass(frozen=True, slots=True)
class Case:
    """One run of a campaign: a scenario file, a rider and a control law (None: the scenario's), a fault set,
    a seed."""

    campaign: str
    scenario: str
    rider: str | None
    faults: str
    seed: int
    scenario_text: bytes
    """The scenario to run, fully resolved (JSON): a worker process needs nothing else."""
    law: str | None = None
    role: Role = "plain"
    """Coverage campaigns: a faulty case, the fault-free twin of faulty cases, or a false-trip run."""
    bounds: Bounds | None = None
    twin_faults: str = "none"
    """The fault set of this case's twin: `none`, or for a set with operator actions its own twin (the
    same actions, no faults)."""
    unrecoverable: str = ""
    """Why nothing can balance the robot after this case's fault (its set's `unrecoverable` entry)."""
    twin_text: bytes = b""
    """A faulty case: its twin's scenario (JSON), run again on the same worker right before it to time it
    (`CaseResult.twin_wall`)."""

    @property
    def id(self) -> str:
        parts = [Path(self.scenario).stem, *([Path(self.rider).stem] if self.rider else [])]
        parts += [*([self.law] if self.law else []), self.faults]
        return "-".join(parts) + f"-seed{self.seed}"

    @property
    def twin_id(self) -> str:
        """The id of this case's fault-free twin (same scenario, rider, law, seed and operator)."""
        return Case(self.campaign, self.scenario, self.rider, self.twin_faults, self.seed, b"", self.law).id

    def build(self) -> Scenario:
        return msgspec.json.decode(self.scenario_text, type=Scenario)


def load_campaign(name: Path | str) -> Campaign:
    """A campaign by path or shipped short name (`smoke`, `diagnostics`). A rider file it names that cannot
    be read or is not one is a ConfigError naming the campaign's file and the field, before any case runs
    (each case would end in the same error)."""
    path = find(name, "campaigns")
    campaign = load_with_faults(path, Campaign)
    listed = [("riders", campaign.riders)]
    listed += [(f"fault_free[{i}].riders", entry.riders) for i, entry in enumerate(campaign.fault_free)]
    for field_name, riders in listed:
        for rider in riders:
            try:
                load_toml(find(rider, "riders"), RiderParams)
            except ConfigError as exc:
                said = exc.detail if exc.path == Path(rider) else str(exc)  # its path once
                raise ConfigError(path, f'{field_name}: "{rider}": {said}') from None
    return campaign


_Choice = TypeVar("_Choice")


def _or_scenarios_own(choices: list[_Choice]) -> list[_Choice | None]:
    """The campaign's choices (riders, laws), or [None]: each scenario's own."""
    return list(choices) or [None]


def expand(campaign: Campaign, select: list[str] | None = None) -> list[Case]:
    """Every case of the campaign, in a stable order (scenario, rider, law, fault set, seed); with
    `select`, those whose id contains one of its strings (and the twins they are judged against)."""
    sets = [FaultSetEntry(name="none")] if campaign.baseline else []
    coverage = campaign.coverage
    if coverage is not None:  # a set with operator actions is judged against a twin with the same actions
        sets += [
            FaultSetEntry(name=f"{s.name}~twin", operator=s.operator) for s in campaign.fault if s.operator
        ]
    sets += campaign.fault
    names = [s.name for s in sets]
    if len(set(names)) != len(names):
        raise ValueError(f"campaign {campaign.name}: fault set names repeat: {names}")
    cases = []
    for scenario_path in campaign.scenarios:
        base = load_with_faults(find(scenario_path, "scenarios"), Scenario)
        for rider in _or_scenarios_own(campaign.riders):
            for law in _or_scenarios_own(campaign.laws):
                for fault_set in sets:
                    faulty = bool(fault_set.inject)
                    plain_baseline = not (faulty or fault_set.operator) and coverage is None
                    keep = fault_set.keep_criteria or plain_baseline
                    scenario = msgspec.structs.replace(
                        base,
                        rider=rider or base.rider,
                        law=law or base.law,
                        duration=campaign.duration or base.duration,
                        faults=[*base.faults, *fault_set.inject],
                        operator=sorted([*base.operator, *fault_set.operator], key=lambda e: e.at),
                        criteria=base.criteria if keep else [],
                    )
                    role: Role = "plain" if coverage is None else "faulty" if faulty else "twin"
                    twin = f"{fault_set.name}~twin" if fault_set.operator and faulty else "none"
                    for seed in campaign.seeds:
                        text = msgspec.json.encode(msgspec.structs.replace(scenario, seed=seed))
                        cases.append(
                            Case(
                                campaign.name,
                                scenario_path,
                                rider,
                                fault_set.name,
                                seed,
                                text,
                                law,
                                role,
                                coverage,
                                twin,
                                fault_set.unrecoverable.get(Path(scenario_path).stem, ""),
                            )
                        )
    for entry in campaign.fault_free:
        for scenario_path in entry.scenarios:
            base = load_with_faults(find(scenario_path, "scenarios"), Scenario)
            for rider in _or_scenarios_own(entry.riders):
                for law in _or_scenarios_own(entry.laws):
                    for seed in campaign.seeds:
                        scenario = msgspec.structs.replace(
                            base,
                            rider=rider or base.rider,
                            law=law or base.law,
                            duration=entry.duration or base.duration,
                            seed=seed,
                            criteria=[],
                        )
                        name = "fault_free" if entry.duration is None else f"fault_free_{entry.duration:g}s"
                        cases.append(
                            Case(
                                campaign.name,
                                scenario_path,
                                rider,
                                name,
                                seed,
                                msgspec.json.encode(scenario),
                                law,
                                "fault_free",
                                coverage,
                            )
                        )
    scenario_of = {c.id: c.scenario_text for c in cases}
    cases = [replace(c, twin_text=scenario_of[c.twin_id]) if c.role == "faulty" else c for c in cases]
    if select:
        chosen = [c for c in cases if any(text in c.id for text in select)]
        twins = {c.twin_id for c in chosen if c.role == "faulty"}
        cases = [c for c in cases if c in chosen or c.id in twins]
    return cases


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


def worst_first(results: list[CaseResult]) -> list[CaseResult]:
    """Errors, then failures (most failed verdicts first), then passes closest to a fall (peak tilt after
    the release)."""
    return sorted(
        results, key=lambda r: (not r.error, r.passed, -len(r.failed), -r.peak_tilt_after_release_deg)
    )


PEAK_TILT = (
    "peak tilt: the largest chassis tilt after the release, from the first time the robot, released "
    "tilted, came back through upright (never: the whole run's)"
)


def provenance() -> str:
    """What wrote a report: the pure-hil version, and its git commit when it runs from a checkout."""
    from hil.report.folder import commit, versions

    where = commit()
    return f"pure-hil {versions()['pure-hil']}" + (f", commit {where}" if where else " (not a git checkout)")


def supervisors(results: list[CaseResult]) -> str:
    """The supervisor plug(s) that judged the cases, for a report's head (a campaign runs on one bench)."""
    return ", ".join(sorted({r.supervisor for r in results if r.supervisor})) or "none (no case ran)"


def peak_tilt(r: CaseResult) -> str:
    """A case's peak tilt after the release for a table, deg."""
    return f"{r.peak_tilt_after_release_deg:.2f}" + (" (never upright)" if r.release_end is None else "")


def coverage_report(results: list[CaseResult]) -> str:
    """The coverage table (faulty cases by class, then fault-free runs that tripped) and its totals."""
    faulty = [r for r in results if r.role == "faulty"]
    fault_free = [r for r in results if r.role in ("twin", "fault_free")]
    if not faulty and not fault_free:
        return ""
    classes = Counter(r.coverage.label if r.coverage else "ERROR" for r in faulty)
    afters = [r.coverage.after for r in faulty if r.coverage and r.coverage.after]
    ended = Counter(a.ended for a in afters)
    excused = sum(bool(a.excused) for a in afters)
    detected, missed = classes["DETECTED"] + classes["LATE"], classes["MISSED"]
    trips = [r for r in fault_free if r.false_trip or r.error]
    ratios = [r.wall / r.twin_wall for r in faulty if r.twin_wall > 0]
    reactions = [r.coverage.reaction for r in faulty if r.coverage and r.coverage.reaction is not None]
    lines = [
        "## Diagnostic coverage",
        "",
        f"- faulty cases: {len(faulty)}: " + ", ".join(f"{k} {v}" for k, v in sorted(classes.items())),
        "- diagnostic coverage (detected / (detected + missed)): "
        + (f"{detected / (detected + missed):.1%}" if detected + missed else "n/a"),
        f"- reaction: median {np.median(reactions) * 1e3:.1f} ms, max {max(reactions) * 1e3:.1f} ms"
        if reactions
        else "- reaction: none",
        "- after the detection: "
        + ", ".join(f"{k} {v}" for k, v in sorted(ended.items()))
        + (f" ({excused} of the falls unrecoverable, named in the campaign)" if excused else ""),
        f"- false trips: {len(trips)} of {len(fault_free)} fault-free runs",
        f"- wall time of a faulty run vs its twin run just before it on the same worker: max "
        f"{max(ratios):.2f}x"
        if ratios
        else "",
        "",
        "| class | case | cause | reaction ms | departed ms | bound ms | to rest s | peak speed m/s "
        "| peak tilt deg | peak yaw rad/s | modes | drives held by | note |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    order = {"ERROR": 0, "MISSED": 1, "LATE": 2, "DETECTED": 3, "BENIGN": 4}
    for r in sorted(
        faulty,
        key=lambda r: (
            r.coverage is not None and r.coverage.passed,
            order[r.coverage.label if r.coverage else "ERROR"],
            r.case_id,
        ),
    ):
        c = r.coverage
        if c is None:
            lines.append(
                f"| ERROR | {r.case_id} |  |  |  |  |  |  |  |  |  |  "
                f"| {r.error.splitlines()[0][:120] if r.error else ''} |"
            )
            continue
        reaction = "" if c.reaction is None else f"{c.reaction * 1e3:.1f}"
        departed = "" if c.departed is None else f"{c.departed * 1e3:.1f}"
        bound = f"{r.outcome.detect_within * 1e3:.0f}" if r.outcome else ""
        a = c.after
        after = (
            f"{'' if a.to_rest is None else f'{a.to_rest:.1f}'} | {a.peak_speed:.2f} | {a.peak_tilt_deg:.1f} "
            f"| {a.peak_yaw_rate:.1f} | {a.modes} | {a.held_by}"
            if a
            else " |  |  |  |  | "
        )
        note = "; ".join(x for x in (c.note, a and a.excused and f"unrecoverable: {a.excused}") if x)
        lines.append(
            f"| {c.name} | {r.case_id} | {c.cause} | {reaction} | {departed} | {bound} | {after} | {note} |"
        )
    for r in trips:
        why = r.false_trip or r.error.splitlines()[0]
        lines.append(f"| FALSE TRIP | {r.case_id} |  |  |  |  |  |  |  |  |  |  | {why} |")
    return "\n".join(line for line in lines if line is not None) + "\n"


def inconclusive(results: list[CaseResult]) -> str:
    """', N inconclusive' for a report's headline when any case was (the rig itself late)."""
    n = sum(r.verdict == "INCONCLUSIVE" for r in results)
    return f", {n} inconclusive" if n else ""


def report(campaign: str, results: list[CaseResult]) -> str:
    rows = [
        (
            r.verdict,
            r.case_id,
            peak_tilt(r),
            "fell" if r.fallen else "",
            "; ".join(r.safety_events[:2]),
            f"{r.wall:.1f}",
            r.message().replace("\n", " | ")[:160],
        )
        for r in worst_first(results)
    ]
    head = ("verdict", "case", "peak tilt after release deg", "fall", "supervisor", "wall s", "why")
    lines = [
        f"# Campaign {campaign}: {sum(r.passed for r in results)}/{len(results)} passed"
        + inconclusive(results),
        "",
        f"{provenance()}. Judged by the supervisor {supervisors(results)}. Worst first: errors, failures, "
        f"then passes by {PEAK_TILT}.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    coverage = coverage_report(results)
    return "\n".join(lines) + "\n" + ("\n" + coverage if coverage else "")


def report_json(campaign: str, results: list[CaseResult]) -> bytes:
    """The report as data, worst first: each case's verdict and why, and for a faulty case of a coverage
    campaign its class, reaction and what followed the detection (docs/campaigns.md)."""

    def coverage(r: CaseResult) -> dict | None:
        c = r.coverage
        if c is None:
            return None
        return {
            "class": c.name,
            "passed": c.passed,
            "cause": c.cause,
            "reaction": c.reaction,
            "departed": c.departed,
            "bound": r.outcome.detect_within if r.outcome else None,
            "note": c.note,
            "after": msgspec.to_builtins(c.after) if c.after else None,
        }

    cases = [
        {
            "case": r.case_id,
            "scenario": r.scenario,
            "role": r.role,
            "passed": r.passed,
            "verdict": r.verdict,
            "error": r.error,
            "why": "" if r.passed else r.message(),
            "fallen": r.fallen is not None,
            "fall_cause": r.fallen,
            "peak_tilt_after_release_deg": r.peak_tilt_after_release_deg,
            "release_end": r.release_end,
            "safety_events": r.safety_events,
            "wall": r.wall,
            "twin_wall": r.twin_wall,
            "coverage": coverage(r),
            "false_trip": r.false_trip,
            "supervisor": r.supervisor,
        }
        for r in worst_first(results)
    ]
    from hil.report.folder import commit, versions

    summary = {
        "campaign": campaign,
        "version": versions()["pure-hil"],
        "commit": commit(),
        "supervisor": supervisors(results),
        "passed": sum(r.passed for r in results),
        "inconclusive": sum(bool(r.inconclusive) and not r.error for r in results),
        "total": len(results),
    }
    return msgspec.json.format(msgspec.json.encode({**summary, "cases": cases}), indent=2)


def junit_xml(campaign: str, results: list[CaseResult]) -> bytes:
    suite = ET.Element(
        "testsuite",
        name=campaign,
        tests=str(len(results)),
        failures=str(sum(r.verdict == "FAIL" for r in results)),
        errors=str(sum(bool(r.error) for r in results)),
        skipped=str(sum(r.verdict == "INCONCLUSIVE" for r in results)),
        time=f"{sum(r.wall for r in results):.3f}",
    )
    judged_by = ET.SubElement(suite, "properties")
    ET.SubElement(judged_by, "property", name="supervisor", value=supervisors(results))
    for r in results:
        case = ET.SubElement(
            suite,
            "testcase",
            classname=f"{campaign}.{Path(r.scenario).stem}",
            name=r.case_id,
            time=f"{r.wall:.3f}",
        )
        props = ET.SubElement(case, "properties")
        for v in r.verdicts:
            ET.SubElement(props, "property", name=v["criterion"], value=f"{v['value']:.6g}")
        if r.error:
            ET.SubElement(case, "error", message=r.error.splitlines()[0][:200]).text = r.error
        elif r.inconclusive:
            # Neither passed nor failed: JUnit's `skipped`, its message saying why.
            message = r.message()
            ET.SubElement(case, "skipped", message=message.splitlines()[0][:200]).text = message
        elif not r.passed:
            message = r.message()
            ET.SubElement(case, "failure", message=message.splitlines()[0][:200]).text = message
    ET.indent(suite)
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)
