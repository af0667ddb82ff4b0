"""pytest plugin (entry point `pytest11`): HIL runs as tests, campaigns as test items.

- Marker `hil`: a test that runs the rig (campaign items carry it; `-m "not hil"` skips them).
- Fixtures: `hil_bench` (the bench of `--hil-bench`, default embedded; `--hil-can` overrides its bus),
  `hil_scenario` (load a scenario by name or path, with overrides), `hil_rig` (run it on that bench in
  lockstep: the same pipeline as `pure-hil run`).
- Campaign files (`*.toml` in a folder named `campaigns`) are collected: one item per case (a long
  campaign's `pytest_select` subset unless `--hil-full`), so `pytest -n auto` (pytest-xdist) spreads them
  over cores and `--junitxml` reports them; a failing case says which verdict failed and what was expected
  instead. A coverage campaign's faulty case is classed against its fault-free twin (run once per process).
- Assertion helpers: hil/suites/testing.py (`assert_passed`, `assert_supervisor`, `assert_metric`, ...).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import pytest

if TYPE_CHECKING:  # imported where used: pytest loads this plugin in every session, HIL or not
    from hil.suites.campaign import CaseResult

MARKER = "hil: a hardware-in-the-loop run on the rig (lockstep unless the scenario says otherwise)"


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("hil", "PURE hardware-in-the-loop rig")
    group.addoption("--hil-out", default=None, help="write each HIL case's run folder under this folder")
    group.addoption(
        "--hil-bench",
        default=None,
        help="the bench HIL runs and campaign cases run on: a bench file or shipped name (default embedded; "
        "a campaign's cases: the campaign's own bench, else embedded)",
    )
    group.addoption("--hil-can", default=None, help="override the bench's bus: INTERFACE:CHANNEL")
    group.addoption(
        "--hil-full",
        action="store_true",
        help="collect every case of a campaign, not its pytest_select subset",
    )


def bench_of(config: pytest.Config, default: str | None = None):
    """The bench of --hil-bench; without it `default` (a campaign's own), else the embedded bench."""
    from drivers.bus_config import parse_can_spec
    from hil.bench.bench import EMBEDDED, load_bench

    can = config.getoption("--hil-can")
    return load_bench(config.getoption("--hil-bench") or default or EMBEDDED).with_overrides(
        can=None if can is None else parse_can_spec(can)
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", MARKER)


def pytest_collect_file(file_path: Path, parent: pytest.Collector):
    if file_path.suffix == ".toml" and file_path.parent.name == "campaigns":
        return CampaignFile.from_parent(parent, path=file_path)
    return None


class HilCaseFailed(Exception):
    """A campaign case whose verdicts failed (the message lists them)."""


class CampaignFile(pytest.File):
    def collect(self):
        from hil.suites.campaign import expand, load_campaign

        campaign = load_campaign(self.path)
        select = None if self.config.getoption("--hil-full") else campaign.pytest_select
        for case in expand(campaign, select or None):
            item = CampaignItem.from_parent(self, name=case.id, case=case, bench=campaign.bench)
            item.add_marker(pytest.mark.hil)
            yield item


_twins: dict[str, CaseResult] = {}
"""Fault-free twins already run in this process, by case id (a coverage campaign judges against them)."""


class CampaignItem(pytest.Item):
    def __init__(self, *, case, bench=None, **kwargs):
        super().__init__(**kwargs)
        self.case = case
        self.bench = bench
        """The campaign's own bench (None: the embedded one), unless --hil-bench names another."""

    def runtest(self) -> None:
        from hil.suites.campaign import expand, judge, load_campaign, run_case

        config = self.config
        root = config.getoption("--hil-out")

        bench = bench_of(config, self.bench)

        def run(case):
            return run_case(case, None if root is None else Path(root) / case.id, bench)

        result = run(self.case)
        if self.case.role == "twin":
            _twins[self.case.id] = result
        if self.case.role == "faulty":
            twin = _twins.get(self.case.twin_id)
            if twin is None:  # its twin ran in another worker, or was not selected
                case = next(c for c in expand(load_campaign(self.path)) if c.id == self.case.twin_id)
                twin = _twins[case.id] = run(case)
            judge(result, twin, self.case.bounds)
        for v in result.verdicts:
            self.user_properties.append((v["criterion"], v["value"]))
        if result.inconclusive and not result.error:
            # The rig itself was late in real time: neither a pass nor a fail of the controller.
            pytest.skip(f"{self.case.id}: {result.message()}")
        if not result.passed:
            raise HilCaseFailed(result.message())

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, HilCaseFailed):
            return f"{self.case.id} failed:\n{excinfo.value}"
        return super().repr_failure(excinfo, style)

    def reportinfo(self):
        return self.path, None, f"hil campaign {self.case.campaign}: {self.case.id}"


@pytest.fixture
def hil_bench(request: pytest.FixtureRequest):
    """The bench of this session (`--hil-bench`, `--hil-can`)."""
    return bench_of(request.config)


@pytest.fixture
def hil_scenario():
    """`hil_scenario(name_or_path, **overrides)` -> Scenario (a short name is a shipped scenario)."""
    from drivers.resources import find
    from hil.faults import load_with_faults, parse_fault
    from hil.run.scenario import Scenario

    def load(name: str | Path, **overrides):
        scenario = load_with_faults(find(name, "scenarios"), Scenario)
        if "faults" in overrides:
            overrides["faults"] = [
                f if not isinstance(f, dict) else parse_fault(f) for f in overrides["faults"]
            ]
        return msgspec.structs.replace(scenario, **overrides)

    return load


class HilRig:
    """Runs scenarios for a test on its bench, in lockstep, with a zenoh hub of its own per run."""

    def __init__(self, bench):
        self.bench = bench

    def run(self, scenario, **kwargs):
        """`hil.pipeline.run(scenario, bench, **kwargs)` -> RunResult."""
        from drivers.zenoh_link import free_loopback_endpoint
        from hil.pipeline import run

        bench = self.bench.with_overrides(clock="lockstep")
        if bench.self_contained and bench.zenoh.mode == "loopback" and bench.zenoh.endpoint is None:
            bench = bench.with_overrides(hub=free_loopback_endpoint())
        return run(scenario, bench, **kwargs)


@pytest.fixture
def hil_rig(hil_bench) -> HilRig:
    """A rig for this test: `hil_rig.run(scenario, out=..., seed=...)` -> RunResult."""
    return HilRig(hil_bench)
