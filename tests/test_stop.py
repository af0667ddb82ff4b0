"""`rig stop`, SIGINT and SIGTERM end any run, a babbling bus included, and its folder is written: no wait
of the rig's outlasts a stop request, a flood is bounded by what the bus carries, a refused request says so
and exits 2. No test here times anything: a run ends, or it does not (benchmarks/stop.py measures how soon).
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from drivers.zenoh_link import LOOPBACK, open_session
from hil.cli import main
from hil.service import RigService
from tests.fault_bench import Bench
from tests.helpers import serving
from tests.test_service import ask
from tests.zenoh_helpers import hub_endpoint, private_bench

ENDS = 60.0
"""s a test waits for something that ends at once when it works (and never ends, or only after minutes,
when it does not): a bound on the test, not a figure."""

LONG = """
name = "flooded"
rider = "ref_60kg_180"
duration = 600.0
[[criteria]]
metric = "fallen"
equals = false
"""


@pytest.fixture
def session():
    s = open_session(LOOPBACK, "hub", hub_endpoint())
    yield s
    s.close()


def ended(work, *args) -> bool:
    """`work(*args)` on a thread of its own returned (a wait that ignores a stop runs for minutes)."""
    thread = threading.Thread(target=work, args=args, daemon=True)
    thread.start()
    thread.join(ENDS)
    return not thread.is_alive()


def test_a_stop_ends_a_ticks_wait_for_a_silent_controller_and_the_start_ups(session):
    bench = Bench(session)
    try:
        rig = bench.rig
        # Positive control: unasked, a lockstep tick waits its guard out for a controller that never answers.
        rig.tick(deadline=time.monotonic() + 0.2, lockstep=True)
        assert rig.port.stats.guards_expired == 1
        rig.port.stop = threading.Event()
        rig.port.stop.set()
        assert ended(rig.tick, time.monotonic() + 600.0, True), "a ten-minute guard outlasted the stop"
        stats = rig.port.stats
        assert stats.ticks == 2 and stats.guards_expired == 1, "left at the stop, not at the guard"
        missing: list[str] = []
        assert ended(lambda: missing.append(rig.await_boot(600.0))), "the start-up's wait outlasted the stop"
        assert "CONTROLLER_HEARTBEAT" in missing[0], "it ended because of the stop: nobody booted"
    finally:
        bench.close()


def test_a_stop_while_the_start_up_waits_for_a_supervisors_subscription_ends_it_without_an_error(monkeypatch):
    """A supervisor elsewhere that announced itself on CAN but never subscribed to pure/sc/request: the
    start-up waits up to 10 s for it, then says so (ControllerUnavailable). A stop during that wait is a
    stop: start_up returns, and the tick loop runs no tick."""
    from contextlib import ExitStack

    import msgspec

    from drivers.bus_config import BusConfig
    from drivers.can_bus import CanNode, open_bus, private_channel
    from drivers.can_codec import MessageName
    from hil.pipeline import load_scenario
    from hil.run import build as build_module
    from hil.run.build import RunOptions, build, start_up
    from hil.run.rig import Rig

    waited: list[str] = []

    class StoppedWhileWaiting(Rig):  # a subclass: the compiled build's Rig cannot be patched
        def wait_for_subscriber(self, key, timeout=10.0):
            if key == self.keys.sc_request:
                waited.append(key)
                self.port.stop = threading.Event()
                self.port.stop.set()
            return super().wait_for_subscriber(key, timeout)

    monkeypatch.setattr(build_module, "Rig", StoppedWhileWaiting)
    bus_config = BusConfig(channel=private_channel("silent-sc"))
    bus = open_bus(bus_config)
    announcer = CanNode(bus, name="supervisor")
    done = threading.Event()

    def announce() -> None:  # a supervisor's start-up frames, and no zenoh at all
        while not done.wait(0.01):
            announcer.send(
                MessageName.SUPERVISOR_ESTOP,
                {"Estop": 0, "Contactor": 1, "Takeover": 0, "State": 0, "Reason": 0},
            )

    thread = threading.Thread(target=announce, daemon=True)
    thread.start()
    scenario = msgspec.structs.replace(load_scenario("balance"), duration=0.5)
    endpoint = hub_endpoint()
    session = open_session(role="hub", hub_endpoint=endpoint)
    outcome: list[object] = []

    def start(built, bench) -> None:
        try:
            start_up(built, bench)
            outcome.append("returned")
        except Exception as exc:  # what the run would have reported instead of a stop
            outcome.append(exc)

    try:
        bench = private_bench(can=bus_config, supervisor="external", hub=endpoint)
        with ExitStack() as stack:
            built = build(bench, scenario, scenario.seed, RunOptions(session=session), None, None, stack)
            assert ended(start, built, bench), "the start-up's wait outlasted the stop"
            assert waited == [built.rig.keys.sc_request], "it stopped in the supervisor's wait"
            assert outcome == ["returned"] and built.rig.port.stopping
    finally:
        done.set()
        thread.join()
        session.close()
        bus.shutdown()


def test_a_flood_the_bus_cannot_carry_is_refused_and_one_it_can_ends_on_rig_stop(tmp_path, capsys):
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    svc = RigService(hub, private_bench(hub=endpoint), out_root=tmp_path)
    client = open_session(role="member", hub_endpoint=endpoint)
    hub_arg = ["--hub", endpoint]
    try:
        assert main(["rig", "start", str(tmp_path / "no_such.toml"), *hub_arg]) == 2
        assert "no_such.toml: cannot read" in json.loads(capsys.readouterr().out)["error"]
        assert ask(client, "start", LONG)["ok"]
        deadline = time.monotonic() + ENDS
        while ask(client, "status")["sim_time"] < 0.5 and time.monotonic() < deadline:
            time.sleep(0.05)
        flood = ["fault", "inject", "can.babble", *hub_arg]
        assert main([*flood, "--param", "per_tick=100000000"]) == 2
        refused = json.loads(capsys.readouterr().out)
        assert (
            refused["refused"]
            and "per_tick = 100000000 is out of its bound 1 <= per_tick <= 22" in refused["error"]
        )
        assert main(flood) == 0, "as many frames as the bus carries"
        capsys.readouterr()
        while not any(f["active"] for f in ask(client, "status")["faults"]) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert main(["fault", "clear", "7", *hub_arg]) == 2
        assert "no fault 7 in this run (its faults: 0..0" in json.loads(capsys.readouterr().out)["error"]
        assert ask(client, "stop")["stopping"] is True
        assert svc.wait_idle(ENDS), "the flooded run did not end on rig stop"
        last = ask(client, "status")["last"]
    finally:
        svc.close()
        client.close()
        hub.close()
    assert (last["verdict"], last["stopped_early"]) == ("STOPPED", True)
    assert [e["action"] for e in last["fault_events"]] == ["inject", "start", "end"]
    summary = json.loads((Path(last["out"]) / "summary.json").read_text())
    babbled = [line for line in (Path(last["out"]) / "can.log").read_text().splitlines() if " 001#" in line]
    assert summary["verdict"] == "STOPPED" and len(babbled) % 22 == 0 and babbled, "22 frames a tick"
    assert summary["simulated"] < 600.0, "stopped, not run to its end"


def test_sigterm_ends_a_served_flooded_run_and_its_folder_is_written(tmp_path):
    endpoint = hub_endpoint()
    runs = tmp_path / "runs"
    with serving(tmp_path, endpoint) as serve:
        client = open_session(role="member", hub_endpoint=endpoint)
        try:
            assert ask(client, "start", LONG)["ok"]
            assert ask(client, "fault/inject", json.dumps({"kind": "can.babble"}))["ok"]
            deadline = time.monotonic() + ENDS
            while (
                not any(f["active"] for f in ask(client, "status")["faults"]) and time.monotonic() < deadline
            ):
                time.sleep(0.05)
        finally:
            client.close()
        serve.send_signal(signal.SIGTERM)
        out, _ = serve.communicate(timeout=ENDS)
    said = f"exit {serve.returncode}, it said: {out!r}"  # what a rare failure needs to be understood
    assert serve.returncode == 130 and "pure-hil serve: stopped" in out, f"stopped as `run` is: {said}"
    folders = list(runs.glob("flooded-*"))
    assert len(folders) == 1, f"{folders}; {said}"
    summary = json.loads((folders[0] / "summary.json").read_text())
    assert summary["verdict"] == "STOPPED", f"{summary['verdict']}: {summary.get('failure')}; {said}"
    assert (folders[0] / "plots.png").exists(), "the whole folder"


def next_line(process: subprocess.Popen) -> str:
    """The process's next line of output, or '' after ENDS (a bare readline waits for ever on a hung one)."""
    line: list[str] = []
    reader = threading.Thread(target=lambda: line.append(process.stdout.readline()), daemon=True)
    reader.start()
    reader.join(ENDS)
    return line[0] if line else ""


def test_serve_stopped_by_ctrl_c_exits_130_as_run_does(tmp_path):
    """`run` stopped by Ctrl-C exits 130 (README's exit codes); `serve` exited 0."""
    with serving(tmp_path, hub_endpoint()) as serve:
        serve.send_signal(signal.SIGINT)
        out, _ = serve.communicate(timeout=ENDS)
    assert serve.returncode == 130 and out.rstrip().endswith("pure-hil serve: stopped"), out


def test_a_second_ctrl_c_leaves_at_once_and_the_runs_history_row_is_completed(tmp_path):
    """The second Ctrl-C of a serve writing its run's folder ends it at once; its history row said RUNNING
    until the next start. Now it is completed as the process leaves: INTERRUPTED (or STOPPED, had the folder
    been written first), with its end."""
    import sqlite3

    endpoint = hub_endpoint()
    with serving(tmp_path, endpoint) as serve:
        client = open_session(role="member", hub_endpoint=endpoint)
        try:
            run_id = ask(client, "start", LONG)["run"]
            deadline = time.monotonic() + ENDS
            while ask(client, "status")["sim_time"] <= 0.0 and time.monotonic() < deadline:
                time.sleep(0.05)
        finally:
            client.close()
        serve.send_signal(signal.SIGINT)
        said = next_line(serve)
        assert "stopping the run" in said, f"{said!r}: the run had not started, or the stop hung"
        serve.send_signal(signal.SIGINT)
        out, _ = serve.communicate(timeout=ENDS)
    assert serve.returncode == 130, out
    # Read as the file is (hil.history.History itself would complete a dead process's row on opening).
    db = sqlite3.connect(tmp_path / "runs" / "history.sqlite")
    try:
        verdict, error, ended = db.execute(
            "SELECT verdict, error, ended FROM runs WHERE id = ?", (run_id,)
        ).fetchone()
    finally:
        db.close()
    assert verdict in ("INTERRUPTED", "STOPPED") and ended is not None, (verdict, out)
    if verdict == "INTERRUPTED":
        assert error == "serve ended at once by a second SIGINT" and "stopped at once" in out, (error, out)


RESCUE = 10.0
"""s after which the watchdog ends a wait the signal did not (a bound on the control, not a figure: the
signal ends the wait within a look or two, ALIVE_CHECK each)."""


@pytest.mark.parametrize("untimed", [False, True])
def test_a_signal_another_thread_takes_still_ends_the_wait_for_it(untimed, monkeypatch):
    # The kernel may hand a process's SIGINT to any thread (zenoh's, a run's); Python's handler then runs
    # only when the main thread next runs bytecode. A serve blocked for good in an untimed wait ignored
    # Ctrl-C (test_a_second_ctrl_c... hung so once). Positive control: the untimed wait, rescued only by
    # a watchdog after RESCUE, is caught.
    from hil.commands import common

    if untimed:
        monkeypatch.setattr(common, "ALIVE_CHECK", None)
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    rescued = threading.Event()
    try:
        stop = common.stop_on_signals()

        def other_thread() -> None:
            time.sleep(0.1)  # the main thread waiting by then (either way it must end)
            signal.pthread_kill(threading.get_ident(), signal.SIGINT)  # taken here, not by the main thread

        def watchdog() -> None:
            if not stop.wait(RESCUE):
                rescued.set()
                stop.set()

        threading.Thread(target=other_thread, daemon=True).start()
        threading.Thread(target=watchdog, daemon=True).start()
        assert common.until_interrupted("waiting", stop=stop)
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
    assert rescued.is_set() == untimed, "the signal ended the wait" if not untimed else "control not caught"
