"""A controller that stays up serves run after run (issue 46; docs/contract.md "Between runs"): a SYNC silent
for RUN_OVER ends its run, it starts over in INIT and announces its boot-up again, and the rig's next run
starts on that boot-up as on the first. Here the contract's own example (examples/balance_controller.py,
written from docs/contract.md alone) on a thread of this process, on the in-process bus of a service's
bench with `controller = external`, three runs in a row through `pure-hil serve`'s service."""

from __future__ import annotations

import json
import threading

import can
import msgspec
import pytest

from drivers.bus_config import BusConfig
from drivers.can_bus import private_channel
from drivers.keys import Keys
from drivers.zenoh_link import open_session
from hil.service import RigService
from tests.helpers import load_example
from tests.zenoh_helpers import hub_endpoint, private_bench

RUN = """
name = "between_runs"
rider = "configs/riders/ref_60kg_180.toml"
law = "hacs"
duration = 1.0
initial_tilt_deg = [2.0, 0.0]
[[criteria]]
metric = "fallen"
equals = false
[[criteria]]
metric = "missing_commands"
equals = 0
"""


BOOT_TIMEOUT = 6.0
"""s the rig waits for a boot-up: more than RUN_OVER (2 s), so a controller that starts over is in time."""


def external(bench, timeout: float = BOOT_TIMEOUT):
    return msgspec.structs.replace(
        bench, controller=msgspec.structs.replace(bench.controller, boot_timeout=timeout)
    )


@pytest.fixture
def served(tmp_path):
    """A service whose bench's controller is external, on an in-process channel of its own."""
    channel = private_channel("between")
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    bench = external(private_bench(hub=endpoint, controller="external", can=BusConfig(channel=channel)))
    svc = RigService(hub, bench, out_root=tmp_path)
    client = open_session(role="member", hub_endpoint=endpoint)
    yield svc, client, channel
    svc.close()
    client.close()
    hub.close()


def ask(client, action, payload=""):
    replies = list(client.get(Keys().rig(action), payload=payload, timeout=10.0))
    return json.loads(replies[0].ok.payload.to_string())


def runs_in_a_row(served, n: int, run_over: float | None = None) -> list[tuple[str, dict | None]]:
    """n runs through the service with the example controller up throughout; `run_over`: its RUN_OVER."""
    svc, client, channel = served
    module = load_example("balance_controller")
    if run_over is not None:
        module.RUN_OVER = run_over
    bus = can.Bus(interface="pure_shared", channel=channel)
    controller = module.BalanceController(module.Wire(bus, module.DBC))
    stop = threading.Event()
    thread = threading.Thread(target=controller.run, args=(stop,), daemon=True)
    thread.start()
    try:
        return serve_runs(svc, client, n)
    finally:
        stop.set()
        thread.join(5.0)
        bus.shutdown()


def serve_runs(svc, client, n: int) -> list[tuple[str, dict | None]]:
    """n runs of RUN through the service, one after another: each one's (verdict, failure)."""
    verdicts = []
    for _ in range(n):
        assert ask(client, "start", RUN)["ok"]
        assert svc.wait_idle(120), "a run did not end"
        last = ask(client, "status")["last"]
        verdicts.append((last["verdict"], last.get("failure")))
    return verdicts


def test_one_external_controller_serves_three_runs_in_a_row(served):
    assert runs_in_a_row(served, 3) == [("PASSED", None)] * 3


def test_a_controller_that_never_starts_over_cannot_serve_a_second_run(served):
    """The positive control, the issue's case: without the contract's rule it stays silent after its run."""
    first, second = runs_in_a_row(served, 2, run_over=1e9)
    assert first == ("PASSED", None)
    assert second[0] == "FAILED" and "CONTROLLER_HEARTBEAT" in second[1]["error"], second


def test_the_reference_controller_serves_runs_in_a_row(served):
    """The reference as `pure-hil controller` runs it (its own thread, real time: not driven by the rig)."""
    from drivers.dut import start_dut
    from hil.run.build import Placement, controller_spec
    from hil.run.scenario import Scenario

    svc, client, _ = served
    bench = svc.bench
    at = Placement(bench.can, bench.zenoh, 400.0, lockstep=False)
    handle = start_dut(
        bench.controller.plugin, controller_spec(bench, Scenario(name="c", rider="ref_60kg_180"), at)
    )
    try:
        assert serve_runs(svc, client, 2) == [("PASSED", None)] * 2
    finally:
        handle.stop()


def test_a_controller_that_never_answers_still_fails_naming_the_wait(tmp_path):
    """The positive control: nobody on the external controller's bus, a short boot timeout."""
    from hil.pipeline import load_scenario, run

    bench = private_bench(controller="external", can=BusConfig(channel=private_channel("nobody")))
    bench = msgspec.structs.replace(
        bench, controller=msgspec.structs.replace(bench.controller, boot_timeout=1.0)
    )
    scenario = load_scenario("bench_smoke")
    result = run(scenario, bench, out=tmp_path / "run")
    failure = result.trace.failure
    assert result.verdict == "FAILED" and failure is not None and failure.stage == "start-up"
    assert "CONTROLLER_HEARTBEAT" in failure.error, failure.error


@pytest.mark.parametrize(
    ("profile", "example_name", "address"),
    [
        ("odrive", "odrive_controller", [1, 2, 3]),
        ("cia402", "cia402_controller", [1, 2, 3]),
        ("xsens", "xsens_controller", 0x100),
    ],
)
def test_each_device_example_serves_runs_in_a_row(tmp_path, profile, example_name, address):
    """The device profiles' examples stay up too: the second run's drives (or IMU) boot again, and the
    example starts over with them (a CiA 402 master configures and starts its drives again). Positive
    control, seen: the CiA 402 example before its `start_over` passed the first run and FAILED the second
    (its drives never configured again: silent, the supervisor's DRIVES_SILENT e-stop at 0.5 s)."""
    import asyncio

    from hil.pipeline import load_scenario, run

    example = load_example(example_name)
    channel = private_channel(f"{profile}-runs")
    stop = threading.Event()
    if profile == "odrive":
        target = lambda: asyncio.run(example.run(channel, "pure_shared", address, stop))  # noqa: E731
    else:
        target = lambda: example.run(channel, "pure_shared", address, stop)  # noqa: E731
    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    scenario_file = tmp_path / "between_runs.toml"
    scenario_file.write_text(RUN)
    verdicts = []
    try:
        bench = external(private_bench(profile, controller="external", can=BusConfig(channel=channel)))
        for i in range(2):
            result = run(load_scenario(scenario_file), bench, out=tmp_path / f"run{i}")
            failure = result.trace.failure
            verdicts.append((result.verdict, failure and failure.error))
    finally:
        stop.set()
        thread.join(timeout=10)
    assert verdicts == [("PASSED", None)] * 2
    assert not thread.is_alive()
