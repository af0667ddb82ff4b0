"""A controller the rig did not write, on the wire contract alone: examples/balance_controller.py (python-can,
cantools, numpy; no zenoh) against the lockstep rig, the start-up handshake, a run that always writes its
folder, and two rigs on one machine."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import can
import msgspec
import pytest

from drivers.bus_config import BusConfig
from drivers.can_bus import private_channel
from drivers.config import load_toml
from hil.pipeline import run
from hil.run.scenario import Scenario
from tests.helpers import ROOT, load_example
from tests.zenoh_helpers import private_bench

BALANCE = load_toml(ROOT / "configs/scenarios/balance.toml", Scenario)


def example():
    return load_example("balance_controller")


class ExampleController:
    """The example on a thread, on the rig's in-process bus (its own python-can handle)."""

    def __init__(self, channel: str, start_after: float = 0.0, ex=None):
        ex = ex or example()
        self.bus = can.Bus(interface="pure_shared", channel=channel)
        self.controller = ex.BalanceController(ex.Wire(self.bus, ex.DBC))
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(start_after,), daemon=True)
        self.thread.start()

    def _run(self, start_after: float) -> None:
        if self.stop.wait(start_after):
            return
        self.controller.run(self.stop)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2)
        self.bus.shutdown()


def test_the_example_imports_nothing_of_this_project():
    source = (ROOT / "examples/balance_controller.py").read_text()
    imported = {
        line.split()[1].split(".")[0] for line in source.splitlines() if line.startswith(("import ", "from "))
    }
    assert imported <= {
        "__future__",
        "argparse",
        "math",
        "signal",
        "threading",
        "time",
        "collections",
        "pathlib",
        "can",
        "cantools",
        "numpy",
    }


def test_a_controller_on_can_alone_runs_a_shipped_scenario_to_a_written_summary(tmp_path):
    channel = private_channel("contract")
    controller = ExampleController(channel)
    try:
        result = run(
            BALANCE, private_bench(controller="external", can=BusConfig(channel=channel)), out=tmp_path
        )
    finally:
        controller.close()
    assert result.passed, [v for v in result.verdicts if not v.passed]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["rig"]["missing_commands"] == 0 and summary["failure"] is None
    assert summary["rig"]["controller_telemetry_missing"] == summary["rig"]["ticks"]
    assert summary["metrics"]["pitch.rmse"] is None
    assert summary["metrics_unavailable"]["pitch.rmse"] == "unavailable (no controller telemetry)"
    assert summary["outputs_failed"] == {}
    assert all((tmp_path / f).stat().st_size > 0 for f in ("can.log", "plots.png", "recording.rrd"))
    assert controller.controller.wire.rejected == 0, (
        "every frame of the rig passes the example's own E2E check"
    )


def test_the_rig_waits_for_a_late_controller_and_starts_on_its_boot_up_without_losing_a_tick():
    channel = private_channel("late")
    controller = ExampleController(channel, start_after=1.0)
    try:
        t0 = time.monotonic()
        result = run(BALANCE, private_bench(controller="external", can=BusConfig(channel=channel)))
        waited = time.monotonic() - t0
    finally:
        controller.close()
    assert waited > 1.0, "the rig waited for the boot-up"
    stats = result.trace.stats
    assert result.passed and stats.missing_commands == 0 and stats.ticks == round(BALANCE.duration * 400)


def test_without_a_controller_the_rig_says_what_it_waited_for_and_still_writes_its_folder(tmp_path):
    channel = private_channel("nobody")
    bench = private_bench(controller="external", can=BusConfig(channel=channel))
    bench = msgspec.structs.replace(
        bench, controller=msgspec.structs.replace(bench.controller, boot_timeout=0.5)
    )
    result = run(BALANCE, bench, out=tmp_path)
    assert not result.passed and result.trace.failure.stage == "start-up"
    assert "the controller's boot-up (CONTROLLER_HEARTBEAT)" in result.trace.failure.error
    assert "examples/balance_controller.py" in result.trace.failure.error
    assert "since contract 2 a controller announces itself" in result.trace.failure.error
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["failure"]["stage"] == "start-up" and summary["passed"] is False
    assert (tmp_path / "can.log").exists()


def test_a_controller_of_an_older_contract_is_told_in_one_line_what_changed(monkeypatch):
    from drivers.contract import CONTRACT_VERSION

    ex = example()
    monkeypatch.setitem(ex.HEARTBEAT, "Contract", 0)  # as a controller written before versions sends
    channel = private_channel("old")
    controller = ExampleController(channel, ex=ex)
    try:
        result = run(BALANCE, private_bench(controller="external", can=BusConfig(channel=channel)))
    finally:
        controller.close()
    assert not result.passed and result.trace.failure.stage == "start-up"
    error = result.trace.failure.error
    assert f"speaks contract 1, this rig contract {CONTRACT_VERSION}" in error and "\n" not in error
    assert "what changed since 1: 2: the boot-up heartbeat" in error and "SUPERVISOR_RECOVERY" in error
    # Positive control: the example as shipped speaks this contract and runs.
    monkeypatch.setitem(ex.HEARTBEAT, "Contract", CONTRACT_VERSION)
    controller = ExampleController(channel, ex=ex)
    short = msgspec.structs.replace(BALANCE, duration=0.5)
    try:
        result = run(short, private_bench(controller="external", can=BusConfig(channel=channel)))
        assert result.trace.failure is None and result.trace.stats.ticks == 200
    finally:
        controller.close()


def test_a_run_that_breaks_mid_way_keeps_what_ran_and_says_where(tmp_path, monkeypatch):
    from hil.run import build
    from hil.run.rig import Rig

    class BreakingRig(Rig):  # a subclass: the compiled build's Rig cannot be patched
        def tick(self, *args, **kwargs):
            if self.plant.tick == 400:
                raise RuntimeError("a bug in the tick")
            return super().tick(*args, **kwargs)

    monkeypatch.setattr(build, "Rig", BreakingRig)
    result = run(BALANCE, private_bench(), out=tmp_path)
    assert (
        result.trace.failure.stage.startswith("tick 400")
        and "a bug in the tick" in result.trace.failure.error
    )
    assert len(result.trace.t) == 400 and not result.passed
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["failure"]["stage"].startswith("tick 400") and summary["simulated"] == pytest.approx(1.0)
    assert (tmp_path / "plots.png").exists() and (tmp_path / "recording.rrd").exists()


def test_two_runs_at_once_on_one_machine_both_pass(tmp_path):
    # Both ask for the default hub port; the second finds it taken and moves (every part is in-process).
    command = [
        sys.executable,
        "-m",
        "hil.cli",
        "run",
        str(ROOT / "configs/scenarios/bench_smoke.toml"),
        "--quiet",
    ]
    runs = [
        subprocess.Popen(
            [*command, "--out", str(tmp_path / name)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name in ("a", "b")
    ]
    outputs = [run.communicate(timeout=300) for run in runs]
    assert [run.returncode for run in runs] == [0, 0], outputs
    assert all(json.loads((tmp_path / n / "summary.json").read_text())["passed"] for n in ("a", "b"))


def test_a_taken_hub_port_moves_a_self_contained_run_and_stops_a_bench_with_one_line():
    import socket

    from drivers.zenoh_link import ZenohConfigError, open_hub

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        with pytest.raises(ZenohConfigError, match=r"is in use .* --hub tcp/127.0.0.1:PORT"):
            open_hub(endpoint=endpoint)
        session, moved = open_hub(endpoint=endpoint, fallback=True)
        session.close()
        assert moved != endpoint and moved.startswith("tcp/127.0.0.1:")
