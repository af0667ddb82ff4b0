"""`pure-controller` as its own process: it joins zenoh over loopback, stops cleanly on SIGTERM/SIGINT,
and refuses bad configuration with exit code 2."""

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.keys import Keys
from drivers.zenoh_link import ZenohLink, open_session
from tests.helpers import ROOT
from tests.zenoh_helpers import hub_endpoint, wait_matching

SCRIPT = str(Path(sys.executable).with_name("pure-controller"))
RIDER = str(ROOT / "configs/riders/s04_abi_50kg_164.toml")


def _run_until_signalled(argv: list[str], sig: int, while_running=lambda pid: None) -> str:
    """Start a controller process on its own hub, wait until it subscribes to the seat wrench (our publisher
    sees the match over loopback), call `while_running(pid)`, send `sig`, and return what it printed (it
    must exit 0)."""
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    proc = subprocess.Popen(
        [*argv, "--hub", endpoint, "--rider", RIDER, "--law", "ihacs"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert wait_matching(ZenohLink(hub).publisher(Keys().tes_wrench), timeout=30.0)
        while_running(proc.pid)
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=15)
        assert proc.returncode == 0, out
        return out
    finally:
        if proc.poll() is None:
            proc.kill()
        hub.close()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_runs_as_its_own_process_and_stops_cleanly(sig):
    out = _run_until_signalled([SCRIPT, "--can", "virtual"], sig)
    assert "running" in out and "stopped" in out


def test_bad_config_exits_2(tmp_path):
    bad = tmp_path / "controller.toml"
    bad.write_text("[lqr]\nq_tilt = -1.0\n")
    proc = subprocess.run(
        [SCRIPT, "--rider", RIDER, "--config", str(bad)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 2
    assert str(bad) in proc.stderr and "$.lqr.q_tilt" in proc.stderr


def _children(pid: int) -> list[int]:
    kids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                kids.append(int(entry.name))
    return kids


def test_pure_hil_controller_is_the_controller_so_a_signal_stops_it():
    # Whoever started it (a lab's script, a bench's controller.command) stops it with SIGINT to the process
    # it started: a wrapper that ran the controller as its child would exit and leave it running on the bus.
    # `pure-hil controller` starts the bench's plug in its own process, from the spec a run uses
    # (hil.run.build.controller_spec).
    def no_wrapper(pid: int) -> None:
        assert _children(pid) == [], "no controller process under a wrapper"

    argv = [str(Path(sys.executable).with_name("pure-hil")), "controller", "--can", "virtual:exec-check"]
    out = _run_until_signalled(argv, signal.SIGINT, no_wrapper)
    assert "reference (ihacs)" in out and "stopped" in out, out


def test_pure_hil_controller_refuses_a_plug_that_is_not_installed(tmp_path):
    bench = tmp_path / "bench.toml"
    bench.write_text('name = "x"\n[controller]\nplugin = "nobody"\n')
    argv = [str(Path(sys.executable).with_name("pure-hil")), "controller", "--bench", str(bench)]
    proc = subprocess.run([*argv, "--rider", RIDER], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "'nobody'" in proc.stderr and "reference" in proc.stderr


def test_a_part_whose_thread_ends_ends_its_command_instead_of_idling():
    """`pure-hil controller|supervisor|part` and `pure-controller` wait for a signal or for the part's thread
    to end (an error in it), whichever comes first: never a process left idle with its part dead."""
    from controller.embedded import start
    from drivers.bus_config import BusConfig
    from drivers.dut import DutSpec
    from drivers.zenoh_access import ZenohAccess
    from hil.commands.common import until_interrupted

    looks = []
    assert until_interrupted("waiting", alive=lambda: looks.append(1) or len(looks) < 3) is False
    assert len(looks) == 3

    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    spec = DutSpec(
        can=BusConfig(interface="virtual", channel="alive-check"),
        zenoh=ZenohAccess(endpoint=endpoint),
        robot=str(ROOT / "configs/robot/pure.toml"),
        rider=RIDER,
        lockstep=False,
    )
    handle = start(spec)
    try:
        assert handle.alive()
        assert handle.thread is not None
        handle.thread.stop_event.set()  # its loop returns, as it does when an error ends it
        handle.thread.thread.join(5.0)
        assert not handle.alive()
    finally:
        handle.stop()
        hub.close()
