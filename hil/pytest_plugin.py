"""pytest plugin (entry point `pytest11`): HIL runs as tests, campaigns as test items.

- Marker `hil`: a test that runs the rig (campaign items carry it; `-m "not hil"` skips them).
- Fixtures: `hil_scenario` (load a scenario by name or path, with overrides), `hil_rig` (run it on the
  virtual bus in lockstep, or on the lab's bus with `--hil-can` and `--hil-controller external`).
- Campaign files (`*.toml` in a folder named `campaigns`) are collected: one item per case (a long
  campaign's `pytest_select` subset unless `--hil-full`), so `pytest -n auto` (pytest-xdist) spreads them
  over cores and `--junitxml` reports them; a failing case says which verdict failed and what was expected
  instead. A coverage campaign's faulty case is classed against its fault-free twin (run once per process).
- Assertion helpers: hil/testing.py (`assert_passed`, `assert_supervisor`, `assert_metric`, ...).
"""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

MARKER = "hil: a hardware-in-the-loop run on the rig (lockstep unless the scenario says otherwise)"


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("hil", "PURE hardware-in-the-loop rig")
    group.addoption("--hil-out", default=None, help="write each HIL case's summary.json under this folder")
    group.addoption(
        "--hil-can",
        default=None,
        help="bus for hil_rig runs: INTERFACE:CHANNEL (default: in-process virtual)",
    )
    group.addoption(
        "--hil-full",
        action="store_true",
        help="collect every case of a campaign, not its pytest_select subset",
    )
    group.addoption(
        "--hil-controller",
        default=None,
        choices=("hacs", "ihacs", "external"),
        help="controller for HIL runs and campaign cases (external: your own, already on --hil-can)",
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
        from hil.campaign import expand, load_campaign

        campaign = load_campaign(self.path)
        select = None if self.config.getoption("--hil-full") else campaign.pytest_select
        for case in expand(campaign, select or None):
            item = CampaignItem.from_parent(self, name=case.id, case=case)
            item.add_marker(pytest.mark.hil)
            yield item


_twins: dict[str, object] = {}
"""Fault-free twins already run in this process, by case id (a coverage campaign judges against them)."""


class CampaignItem(pytest.Item):
    def __init__(self, *, case, **kwargs):
        super().__init__(**kwargs)
        self.case = case

    def runtest(self) -> None:
        from hil.campaign import expand, judge, load_campaign, run_case

        config = self.config
        root = config.getoption("--hil-out")

        def run(case):
            return run_case(
                case,
                None if root is None else Path(root) / case.id,
                config.getoption("--hil-can"),
                config.getoption("--hil-controller"),
            )

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
        if not result.passed:
            raise HilCaseFailed(result.message())

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, HilCaseFailed):
            return f"{self.case.id} failed:\n{excinfo.value}"
        return super().repr_failure(excinfo, style)

    def reportinfo(self):
        return self.path, None, f"hil campaign {self.case.campaign}: {self.case.id}"


@pytest.fixture
def hil_scenario():
    """`hil_scenario(name_or_path, **overrides)` -> Scenario (a bare name is configs/scenarios/NAME.toml)."""
    from drivers.config import load_toml
    from drivers.resources import find
    from hil.faults import parse_fault
    from hil.scenario import Scenario

    def load(name: str | Path, **overrides):
        path = Path(name)
        if path.suffix != ".toml":
            path = Path("configs/scenarios") / f"{name}.toml"
        scenario = load_toml(find(path, "scenarios"), Scenario)
        if "faults" in overrides:
            overrides["faults"] = [
                f if not isinstance(f, dict) else parse_fault(f) for f in overrides["faults"]
            ]
        return msgspec.structs.replace(scenario, **overrides)

    return load


class HilRig:
    """Runs scenarios for a test: lockstep, a private bus and a private zenoh hub per run."""

    def __init__(self, can: str | None, controller: str | None):
        self.can, self.controller = can, controller

    def run(self, scenario, **kwargs):
        from drivers.can_bus import parse_can_spec
        from drivers.zenoh_link import free_loopback_endpoint
        from hil.runner import run_scenario

        kwargs.setdefault("clock", "lockstep")
        kwargs.setdefault("hub_endpoint", free_loopback_endpoint())
        if self.can:
            kwargs.setdefault("can", parse_can_spec(self.can))
        if self.controller:
            kwargs.setdefault("controller", self.controller)
        return run_scenario(scenario, **kwargs)


@pytest.fixture
def hil_rig(request: pytest.FixtureRequest) -> HilRig:
    """A rig for this test: `hil_rig.run(scenario, **run_scenario kwargs)` -> RunResult."""
    config = request.config
    return HilRig(config.getoption("--hil-can"), config.getoption("--hil-controller"))
