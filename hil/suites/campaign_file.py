"""A campaign file (`configs/campaigns/*.toml`, docs/campaigns.md): its schema, loading it (a rider it
names that cannot be read is refused before any case runs) and expanding it into its cases, each a fully
resolved scenario a worker runs with nothing else (hil/suites/campaign_run.py)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Literal, TypeVar

import msgspec

from drivers.config import ConfigError, load_toml
from drivers.resources import find
from hil.faults import Fault, load_with_faults
from hil.run.scenario import OperatorEntry, Scenario
from hil.suites.coverage import Bounds
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
