"""Bench parts as plugs (drivers/plugs.py): found by entry point, refused by name when missing, and run from
a serialised spec by `pure-hil part` (the rig's spawned parts; tests/test_netns.py runs a whole bench of
spawned parts over multicast)."""

from __future__ import annotations

import msgspec
import pytest

from drivers.bus_config import BusConfig
from drivers.can_bus import private_channel
from drivers.plugs import SupervisorSpec
from drivers.registry import SUPERVISORS, PlugNotFound, find_plug
from hil.bench.parts import BenchUnavailable, check
from hil.cli import main
from tests.zenoh_helpers import private_bench


def test_an_unknown_plug_is_refused_naming_the_group_and_what_is_there():
    with pytest.raises(
        PlugNotFound, match=r"no supervisor 'nope' in entry points 'pure_hil.supervisors' \(have: "
    ):
        find_plug(SUPERVISORS, "nope", "supervisor")
    assert find_plug(SUPERVISORS, "reference", "supervisor")  # the positive control


def test_a_bench_whose_supervisor_plug_is_not_installed_fails_before_the_run(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text('name = "x"\n[supervisor]\nplugin = "nope"\n')
    from hil.bench.bench import load_bench

    with pytest.raises(BenchUnavailable, match=r"supervisor\.plugin 'nope' is not installed"):
        check(load_bench(path))
    check(load_bench("embedded"))


def test_part_refuses_a_bad_spec_in_one_line(tmp_path, capsys):
    spec = tmp_path / "spec.json"
    spec.write_text('{"can": {"interface": "pure_shared"}}')
    assert main(["part", "supervisor", "reference", str(spec)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pure-hil part: ") and "robot" in err and "\n" not in err
    assert main(["part", "supervisor", "reference", str(tmp_path / "missing.json")]) == 2
    assert "cannot read" in capsys.readouterr().err
    driven = SupervisorSpec(can=BusConfig(channel=private_channel()), robot="x", driven=True)
    spec.write_bytes(msgspec.json.encode(driven))
    assert main(["part", "supervisor", "reference", str(spec)]) == 2
    assert "driven = true is for a part in the rig's own process" in capsys.readouterr().err


STARTED: list[SupervisorSpec] = []


def spy_start(spec, **context):
    """A supervisor plug that records its spec and starts the reference one."""
    from safety.embedded import start

    STARTED.append(spec)
    return start(spec, **context)


def test_the_rig_starts_the_supervisor_the_bench_names_through_its_plug(monkeypatch):
    from importlib.metadata import EntryPoint

    import drivers.registry
    from hil.pipeline import load_scenario, run

    spy = EntryPoint(name="spy", value=f"{__name__}:spy_start", group=SUPERVISORS)
    real = drivers.registry.entry_points
    monkeypatch.setattr(
        drivers.registry,
        "entry_points",
        lambda group: [*real(group=group), *([spy] if group == SUPERVISORS else [])],
    )
    bench = private_bench("odrive")
    bench = msgspec.structs.replace(bench, supervisor=msgspec.structs.replace(bench.supervisor, plugin="spy"))
    scenario = msgspec.structs.replace(load_scenario("balance"), duration=0.5)
    STARTED.clear()
    result = run(scenario, bench)
    assert result.trace.failure is None and result.trace.stats.ticks == 200
    [spec] = STARTED
    assert spec.driven and spec.lockstep and spec.devices.drives == "odrive" and spec.tick_hz == 400.0
    assert spec.rules["speed"]["absolute_cap"] > 0, "the bench's rules with the scenario's overrides"


class _Node:
    events = ()


class _SupervisorHandle:
    """A lab's supervisor handle: its node and stop(), nothing more."""

    def __init__(self, spec, link=None) -> None:
        self.spec, self.link, self.node, self.stopped = spec, link, _Node(), False

    def stop(self) -> None:
        self.stopped = True


class _WatchedSupervisorHandle(_SupervisorHandle):
    def alive(self) -> bool:
        return True


def test_start_supervisor_finds_the_plug_by_name_and_hands_it_the_spec_and_link(monkeypatch):
    from importlib.metadata import EntryPoint

    import drivers.registry
    from drivers.plugs import Watched, start_supervisor

    plugs = [
        EntryPoint(name="bare", value=f"{__name__}:_SupervisorHandle", group=SUPERVISORS),
        EntryPoint(name="watched", value=f"{__name__}:_WatchedSupervisorHandle", group=SUPERVISORS),
    ]
    monkeypatch.setattr(drivers.registry, "entry_points", lambda group: plugs if group == SUPERVISORS else [])
    spec = SupervisorSpec(can=BusConfig(channel=private_channel()), robot="x")
    link = object()
    bare = start_supervisor("bare", spec, link=link)
    assert isinstance(bare, _SupervisorHandle) and (bare.spec, bare.link) == (spec, link)
    assert not isinstance(bare, Watched), "a handle without alive() is not watched"
    assert isinstance(start_supervisor("watched", spec), Watched)  # the positive control
    with pytest.raises(
        PlugNotFound,
        match=r"no supervisor 'nope' in entry points 'pure_hil.supervisors' \(have: bare, watched\)",
    ):
        start_supervisor("nope", spec)


def test_every_device_profile_is_one_entry_point_with_its_settings_host_and_emulation():
    from drivers.devices import Devices, Translator
    from drivers.devices.profile import find_profile
    from drivers.registry import DEVICE_PROFILES, installed

    kinds = {"odrive": "drives", "cia402": "drives", "xsens": "imu"}
    assert installed(DEVICE_PROFILES) == sorted(kinds)
    for name, kind in kinds.items():
        profile = find_profile(name)
        assert (profile.name, profile.kind) == (name, kind)
        devices = Devices(**{kind: name})
        assert isinstance(devices.options(name), profile.options)
        assert isinstance(profile.emulation()(devices, 8192, 400.0), Translator)
        assert isinstance(profile.host(devices, 8192, "supervisor"), Translator)
    with pytest.raises(PlugNotFound, match=r"no device profile 'nope' in entry points 'pure_hil.devices'"):
        find_profile("nope")
    with pytest.raises(
        ValueError, match=r"imu: no imu device profile 'odrive' installed \(have: pure, xsens\)"
    ):
        Devices(imu="odrive")


class _BareController:
    """A lab's controller handle that only stops: not driven from the rig's tick, and it cannot hang."""

    def stop(self) -> None:
        pass


class _FullController(_BareController):
    def __init__(self) -> None:
        self.calls: list[str] = []

    def poll(self) -> None:
        self.calls.append("poll")

    def pause(self) -> None:
        self.calls.append("pause")

    def resume(self) -> None:
        self.calls.append("resume")


def test_the_rig_and_the_hang_fault_use_only_what_a_controller_handle_offers():
    from types import SimpleNamespace

    from drivers.dut import DrivenDut, PausableDut
    from hil.faults import parse_fault

    bare, full = _BareController(), _FullController()
    assert not isinstance(bare, DrivenDut) and not isinstance(bare, PausableDut)
    assert isinstance(full, DrivenDut) and isinstance(full, PausableDut)
    hang = parse_fault({"kind": "process.hang", "at": 1.0, "duration": 0.5})
    with pytest.raises(ValueError, match=r"handle has no pause\(\)/resume\(\)"):
        hang.validate(SimpleNamespace(dut=bare))
    hang.validate(SimpleNamespace(dut=full))
    hang.start(SimpleNamespace(dut=full), None)
    hang.stop(SimpleNamespace(dut=full), None)
    assert full.calls == ["pause", "resume"]
