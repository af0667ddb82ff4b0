"""Campaigns: scenarios x riders x fault sets x seeds, each combination a lockstep run with a verdict.

A campaign file (`configs/campaigns/*.toml`, docs/campaigns.md) names the scenarios, the riders (none: each
scenario's own), the fault sets (each a name and a list of faults with their expected reactions; a
fault-free baseline unless `baseline = false`) and the seeds. `pure-hil campaign FILE --workers N` runs the
cases in parallel processes and writes a report (worst cases first) and JUnit XML; the pytest plugin
collects the same cases as test items (hil/pytest_plugin.py).
"""

from __future__ import annotations

import logging
import time
import traceback
import xml.etree.ElementTree as ET
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Annotated

import msgspec
import numpy as np

from drivers.config import load_toml
from hil.faults import Fault
from hil.scenario import Scenario, resolve


class FaultSetEntry(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A named set of faults injected together in one run (`inject`), each with its `expect`."""

    name: Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_.-]+$")]
    inject: list[Fault] = []
    keep_criteria: bool = False
    """Judge the case by the scenario's own criteria too. By default a faulty case is judged by what its
    faults expect (the scenario's criteria describe the healthy run: an e-stop would fail them)."""

    def __post_init__(self) -> None:
        if not self.keep_criteria and self.inject and not any(f.expect for f in self.inject):
            raise ValueError(f"fault set {self.name!r}: no fault says what it expects (add `expect`)")


class Campaign(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    name: str
    description: str = ""
    scenarios: Annotated[list[str], msgspec.Meta(min_length=1)]
    riders: list[str] = []
    """Rider files; none: each scenario's own rider."""
    fault: list[FaultSetEntry] = []
    baseline: bool = True
    """Also run every combination without faults (named `none`)."""
    seeds: Annotated[list[int], msgspec.Meta(min_length=1)] = msgspec.field(default_factory=lambda: [0])
    duration: Annotated[float, msgspec.Meta(gt=0)] | None = None
    """Overrides every scenario's duration (s)."""


@dataclass(frozen=True, slots=True)
class Case:
    """One run of a campaign: a scenario file, a rider (None: the scenario's), a fault set, a seed."""

    campaign: str
    scenario: str
    rider: str | None
    faults: str
    seed: int
    scenario_text: bytes
    """The scenario to run, fully resolved (JSON): a worker process needs nothing else."""

    @property
    def id(self) -> str:
        parts = [Path(self.scenario).stem, *([Path(self.rider).stem] if self.rider else []), self.faults]
        return "-".join(parts) + f"-seed{self.seed}"

    def build(self) -> Scenario:
        return msgspec.json.decode(self.scenario_text, type=Scenario)


def load_campaign(path: Path | str) -> Campaign:
    return load_toml(path, Campaign)


def expand(campaign: Campaign) -> list[Case]:
    """Every case of the campaign, in a stable order (scenario, rider, fault set, seed)."""
    sets = ([FaultSetEntry(name="none")] if campaign.baseline else []) + list(campaign.fault)
    names = [s.name for s in sets]
    if len(set(names)) != len(names):
        raise ValueError(f"campaign {campaign.name}: fault set names repeat: {names}")
    cases = []
    for scenario_path in campaign.scenarios:
        base = load_toml(resolve(scenario_path), Scenario)
        for rider in campaign.riders or [None]:
            for fault_set in sets:
                for seed in campaign.seeds:
                    scenario = msgspec.structs.replace(
                        base,
                        rider=rider or base.rider,
                        seed=seed,
                        duration=campaign.duration or base.duration,
                        faults=[*base.faults, *fault_set.inject],
                        criteria=base.criteria if fault_set.keep_criteria or not fault_set.inject else [],
                    )
                    cases.append(
                        Case(
                            campaign.name,
                            scenario_path,
                            rider,
                            fault_set.name,
                            seed,
                            msgspec.json.encode(scenario),
                        )
                    )
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
    peak_tilt_deg: float = 0.0
    safety_events: list[str] = field(default_factory=list)

    @property
    def failed(self) -> list[dict]:
        return [v for v in self.verdicts if not v["passed"]]

    def message(self) -> str:
        """Why the case failed, one line per failed verdict (notes say what was expected instead)."""
        if self.error:
            return self.error
        lines = []
        for v in self.failed:
            line = f"{v['criterion']}: measured {v['value']:.4g} {v['units']}, limit {v['limit']}".rstrip()
            lines.append(line + (f" ({v['note']})" if v["note"] else ""))
        return "\n".join(lines)


def run_case(
    case: Case, out: Path | None = None, can: str | None = None, controller: str | None = None
) -> CaseResult:
    """Run one case in this process, lockstep, with its own zenoh hub on a free loopback port; on a private
    virtual bus unless `can` names the lab's bus (INTERFACE:CHANNEL), with the scenario's controller unless
    `controller` says otherwise (`external`: the lab's own, already on that bus)."""
    from drivers.can_bus import parse_can_spec
    from drivers.zenoh_link import free_loopback_endpoint
    from hil.runner import run_scenario, summary

    start = time.monotonic()
    try:
        result = run_scenario(
            case.build(),
            clock="lockstep",
            hub_endpoint=None if controller == "external" else free_loopback_endpoint(),
            can=None if can is None else parse_can_spec(can),
            controller=controller,
        )
    except Exception as exc:  # a broken case is a result (an error), never the end of the campaign
        detail = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        return CaseResult(case.id, case.scenario, False, time.monotonic() - start, error=detail)
    tr = result.trace
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.json").write_bytes(
            msgspec.json.format(msgspec.json.encode(summary(result)), indent=2)
        )
    return CaseResult(
        case.id,
        case.scenario,
        result.passed,
        time.monotonic() - start,
        [asdict(v) for v in result.verdicts],
        fallen=tr.fallen,
        peak_tilt_deg=float(np.degrees(np.abs(tr.tilt).max())) if len(tr.t) else 0.0,
        safety_events=[
            f"{e.t:.3f} {e.to_state}/{e.cause}" for e in tr.safety_events if e.kind == "transition"
        ],
    )


def run_campaign(
    cases: list[Case],
    workers: int = 1,
    out: Path | None = None,
    progress: Callable[[int, int, CaseResult], None] | None = None,
    can: str | None = None,
    controller: str | None = None,
) -> list[CaseResult]:
    """Every case, `workers` at a time in fresh processes (spawned: no zenoh or bus state is inherited).
    On a shared bus (`can`) cases run one at a time in this process: they would share the bus."""
    results: list[CaseResult] = []
    folder = (lambda c: out / c.id) if out is not None else (lambda c: None)
    if workers <= 1 or can is not None:
        for case in cases:
            results.append(run_case(case, folder(case), can, controller))
            if progress:
                progress(len(results), len(cases), results[-1])
        return results
    with ProcessPoolExecutor(
        max_workers=workers, mp_context=get_context("spawn"), initializer=_quiet_worker
    ) as pool:
        futures = [pool.submit(run_case, case, folder(case)) for case in cases]
        for future in as_completed(futures):
            results.append(future.result())
            if progress:
                progress(len(results), len(cases), results[-1])
    order = {c.id: i for i, c in enumerate(cases)}
    return sorted(results, key=lambda r: order[r.case_id])


def _quiet_worker() -> None:
    # Workers' warnings (every supervisor transition, every fault start) would interleave unreadably with
    # the progress lines; each case's summary.json keeps them.
    logging.basicConfig(level=logging.ERROR)


def worst_first(results: list[CaseResult]) -> list[CaseResult]:
    """Errors, then failures (most failed verdicts first), then passes closest to a fall (peak tilt)."""
    return sorted(results, key=lambda r: (not r.error, r.passed, -len(r.failed), -r.peak_tilt_deg))


def report(campaign: str, results: list[CaseResult]) -> str:
    rows = [
        (
            "ERROR" if r.error else "PASS" if r.passed else "FAIL",
            r.case_id,
            f"{r.peak_tilt_deg:.2f}",
            "fell" if r.fallen else "",
            "; ".join(r.safety_events[:2]),
            f"{r.wall:.1f}",
            r.message().replace("\n", " | ")[:160],
        )
        for r in worst_first(results)
    ]
    head = ("verdict", "case", "peak tilt deg", "fall", "supervisor", "wall s", "why")
    lines = [
        f"# Campaign {campaign}: {sum(r.passed for r in results)}/{len(results)} passed",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def junit_xml(campaign: str, results: list[CaseResult]) -> bytes:
    suite = ET.Element(
        "testsuite",
        name=campaign,
        tests=str(len(results)),
        failures=str(sum(not r.passed and not r.error for r in results)),
        errors=str(sum(bool(r.error) for r in results)),
        time=f"{sum(r.wall for r in results):.3f}",
    )
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
        elif not r.passed:
            message = r.message()
            ET.SubElement(case, "failure", message=message.splitlines()[0][:200]).text = message
    ET.indent(suite)
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)
