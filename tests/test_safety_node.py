"""The standalone supervisor on its own timer (as `pure-hil supervisor` runs it), fed healthy traffic by a
stand-in robot on a virtual bus, driven by `pure-hil estop` over zenoh on loopback."""

import os
import threading
import time

import msgspec
import pytest

from drivers.bus_config import BusConfig
from drivers.can_bus import CanNode, open_bus, private_channel
from drivers.plugs import NodeThread
from drivers.schemas import EstopCommand, ScCommand, ScRequest, TesWrench
from drivers.vocabulary import ControllerState
from drivers.zenoh_link import ZenohLink, open_session
from hil.bench.rigs import HUB_VARIABLE, announce
from hil.cli import main
from safety.config import SupervisorConfig, Watchdogs
from safety.node import SupervisorNode
from tests.helpers import wait_for
from tests.zenoh_helpers import hub_endpoint, wait_matching


class StandInRobot:
    """Drives, IMU, controller heartbeat and SYNC at 400 Hz on the bus; the seat wrench on zenoh. The drives
    obey the supervisor's frame: off while it asserts e-stop, their DC bus live while the contactor is
    commanded closed."""

    def __init__(self, bus_config: BusConfig, link: ZenohLink):
        self.bus = open_bus(bus_config)
        self.node = CanNode(self.bus, name="robot")
        self.link = link
        self.heartbeat = True
        self.permitted, self.bus_powered = True, True
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.frames: list = []
        self.thread.start()

    def _run(self):
        tick = 0
        send = self.node.send
        while not self.stop.is_set():
            tick += 1
            for i in (1, 2, 3):
                send(
                    f"DRIVE{i}_FEEDBACK",
                    {
                        "Position": 0,
                        "Velocity": 0.0,
                        "Enabled": int(self.permitted),
                        "BusPowered": int(self.bus_powered),
                    },
                )
            send("IMU_ATTITUDE", {"Roll": 0.0, "Pitch": 0.0, "Yaw": 0.0, "Valid": 1})
            send("IMU_RATE", {"RateX": 0.0, "RateY": 0.0, "RateZ": 0.0, "Valid": 1})
            if self.heartbeat:
                send("CONTROLLER_HEARTBEAT", {"State": ControllerState.BALANCING, "Mode": 0, "FaultCode": 0})
            send("SYNC", {"Tick": tick % 65536})
            self.link.put(
                self.link.keys.tes_wrench,
                TesWrench(seq=tick, stamp=tick / 400, force=(0, 0, -600.0), moment=(0, 0, 0), cop=(0, 0)),
            )
            while (rx := self.node.recv(timeout=0.0)) is not None:
                if rx.name == "SUPERVISOR_ESTOP":
                    self.frames.append((time.monotonic(), rx.signals))
                    self.permitted = not rx.signals["Estop"]
                    self.bus_powered = bool(rx.signals["Contactor"])
            time.sleep(0.0025)

    def estop_frames_since(self, t0: float):
        return [s for t, s in self.frames if t >= t0]

    def close(self):
        self.stop.set()
        self.thread.join(2)
        self.bus.shutdown()


@pytest.fixture
def bench():
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    hub_link = ZenohLink(hub)
    bus_config = BusConfig(channel=private_channel("safety"))
    sup_bus = open_bus(bus_config)
    # The stand-in robot is a Python thread paced by sleep, not a 400 Hz source: on a loaded machine it can
    # stall for 50 ms. These tests are about the operator's paths, so the stream watchdogs get room.
    watchdogs = Watchdogs(drives=0.3, imu=0.3, heartbeat=0.3, wrench=0.5)
    config = msgspec.structs.replace(SupervisorConfig(), watchdogs=watchdogs)
    node = SupervisorNode(CanNode(sup_bus, name="supervisor"), hub_link, config)
    thread = NodeThread(node.run, "supervisor").start()
    robot = StandInRobot(bus_config, hub_link)
    # As `pure-hil supervisor --role hub` does: operators' clients ask the hub which rig it is.
    try:
        with announce(hub, "pure", "embedded", endpoint, "supervisor"):
            yield endpoint, node, robot, hub_link
    finally:
        robot.close()
        thread.stop()
        hub_link.close()
        hub.close()
        sup_bus.shutdown()


def test_estop_frame_at_100_hz_and_sc_requests_clamped(bench):
    _endpoint, _node, robot, link = bench
    t0 = time.monotonic()
    assert wait_for(lambda: len(robot.estop_frames_since(t0)) >= 10, 5.0)
    frames = robot.estop_frames_since(t0)
    assert all(f["Estop"] == 0 and f["State"] == 0 for f in frames)
    commands = link.subscribe(link.keys.sc_command, ScCommand)
    pub = link.publisher(link.keys.sc_request)
    link.put(link.keys.sc_request, ScRequest(seq=1, stamp=0.0, mode="limit", speed_cap=3.0, source="agent"))
    assert wait_matching(pub)
    assert wait_for(lambda: any(c.source == "agent" for c in commands.drain()), 3.0)
    last = commands.latest()
    assert (last.mode, last.speed_cap, last.source) == ("limit", 2.0, "agent")


def test_supervisor_estop_goes_out_every_frame_period_of_the_supervisors_own_time():
    """The 100 Hz of SUPERVISOR_ESTOP in the supervisor's time: updates at the 400 Hz tick, counted
    frames, no wall clock (its own timer's pace is a benchmark's: benchmarks/supervisor.py)."""
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    link = ZenohLink(hub)
    bus_config = BusConfig(channel=private_channel("period"))
    sup_bus, listener = open_bus(bus_config), open_bus(bus_config)
    try:
        # Nothing trips within its 1 s: every frame counted is a periodic one.
        quiet = Watchdogs(drives=10.0, imu=10.0, heartbeat=10.0, wrench=10.0, startup_grace=10.0)
        config = msgspec.structs.replace(SupervisorConfig(), watchdogs=quiet)
        node = SupervisorNode(CanNode(sup_bus, name="supervisor"), link, config)
        reader = CanNode(listener, name="robot")
        for k in range(400):  # 1 s at 2.5 ms
            node.update(k * 0.0025)
        names = []
        while (rx := reader.recv(timeout=0.0)) is not None:
            names.append(rx.name)
        assert not node.events
        assert names.count("SUPERVISOR_ESTOP") == round(1.0 / config.output.estop_frame_period) == 100
    finally:
        link.close()
        hub.close()
        sup_bus.shutdown()
        listener.shutdown()


def test_operator_estop_and_reset_through_the_cli(bench, capsys):
    endpoint, node, robot, _ = bench
    time.sleep(0.7)  # past the start-up grace
    assert main(["estop", "--hub", endpoint, "--source", "alice"]) == 0
    assert "STOPPING" in capsys.readouterr().out
    # At standstill the controlled stop ends with the drives off after standstill_time.
    assert wait_for(lambda: robot.frames and robot.frames[-1][1]["Estop"] == 1, 3.0)
    assert robot.frames[-1][1]["State"] == 3
    assert main(["estop", "--reset", "--hub", endpoint, "--source", "alice"]) == 0
    assert "NORMAL" in capsys.readouterr().out
    assert node.machine.reset_by and node.machine.reset_by[-1][1] == "alice"
    assert wait_for(lambda: robot.frames[-1][1]["Estop"] == 0, 2.0)


def test_reset_refused_while_the_controller_is_silent(bench, capsys):
    endpoint, node, robot, _ = bench
    time.sleep(0.7)
    robot.heartbeat = False
    assert wait_for(lambda: node.machine.cause.name == "HEARTBEAT_LOST", 2.0)
    assert robot.frames and wait_for(lambda: robot.frames[-1][1]["Estop"] == 1, 1.0)
    assert main(["estop", "--reset", "--hub", endpoint]) == 1
    out = capsys.readouterr().out
    # The refusal is the state's typed field (SafetyState.reset_refused), answered at once, not a timeout.
    assert "reset refused: heartbeat silent" in out and "nothing confirmed" not in out, out
    robot.heartbeat = True
    time.sleep(0.2)
    assert main(["estop", "--reset", "--hub", endpoint]) == 0


def test_the_wired_estop_frame_trips_it(bench):
    _endpoint, node, robot, _ = bench
    time.sleep(0.7)
    robot.node.send("OPERATOR_ESTOP", {"Request": 1})
    assert wait_for(lambda: node.machine.cause.name == "BUTTON_ESTOP", 2.0)


def test_an_estop_without_a_hub_never_reaches_another_rig(bench, tmp_path, monkeypatch, capsys):
    endpoint, node, _robot, _ = bench
    time.sleep(0.7)
    monkeypatch.delenv(HUB_VARIABLE, raising=False)
    other = hub_endpoint()
    second = open_session(role="hub", hub_endpoint=other)
    try:
        with announce(second, "pure", "embedded", other, "run speed_limiting"):
            # Two rigs of the bench on this machine: the client names both and sends nothing.
            assert main(["estop", "--source", "alice"]) == 1
            err = capsys.readouterr().err
            assert "2 rigs of bench embedded" in err and endpoint in err and other in err
            assert node.machine.estop_by == ""
            # Named by the environment, it reaches that one and says which rig it was.
            monkeypatch.setenv(HUB_VARIABLE, endpoint)
            assert main(["estop", "--source", "alice"]) == 0
            out = capsys.readouterr().out
            assert f"latched on rig supervisor on bench embedded, pid {os.getpid()}, at {endpoint}" in out
            assert node.machine.estop_by == "alice"
            monkeypatch.delenv(HUB_VARIABLE)
        # A bench file that points at a hub where another bench's rig runs: refused, both benches named.
        bench_file = tmp_path / "lab.toml"
        bench_file.write_text(f'name = "lab"\n[zenoh]\nendpoint = "{other}"\n')
        with announce(second, "pure", "embedded", other, "serve"):
            assert main(["estop", "--bench", str(bench_file), "--source", "bob"]) == 1
        assert f"the rig at {other} runs bench embedded, not lab" in capsys.readouterr().err
        # The one live rig of the bench is found without --hub.
        assert main(["estop", "--source", "carol"]) == 0
        assert f"at {endpoint}" in capsys.readouterr().out
    finally:
        second.close()
    assert node.machine.estop_by == "carol"


def test_estop_confirms_its_own_latch_when_a_stop_is_already_under_way(bench, capsys):
    endpoint, node, robot, link = bench
    time.sleep(0.7)
    robot.heartbeat = False  # the supervisor stops for its own cause first
    assert wait_for(lambda: node.machine.cause.name == "HEARTBEAT_LOST", 2.0)
    assert main(["estop", "--hub", endpoint, "--source", "dave"]) == 0
    out = capsys.readouterr().out
    assert "estop by dave latched" in out and "HEARTBEAT_LOST" in out
    # Positive control: a supervisor that takes in no operator command confirms nothing (its operator
    # subscription swapped for one on a key nobody puts to: a compiled Subscription cannot be patched).
    node.operator = link.subscribe(link.keys.rig("deaf"), EstopCommand)
    assert main(["estop", "--hub", endpoint, "--source", "erin", "--timeout", "1"]) == 1
    assert "nothing confirmed its estop latched" in capsys.readouterr().err


def test_a_rigs_announcement_starts_no_python_thread():
    """A lockstep tick yields the GIL whenever a second Python thread exists (hil/run/clock.py): the hello
    queryable must answer on zenoh's own thread, not on a Python thread zenoh would start for it."""
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    client = open_session(role="member", hub_endpoint=endpoint)
    try:
        # New threads, not a count: a thread an earlier test left may end meanwhile.
        before = set(threading.enumerate())
        with announce(hub, "pure", "embedded", endpoint, "run balance"):
            assert not set(threading.enumerate()) - before
            replies: list = []

            def answered() -> bool:  # the declaration reaches the client a moment after it is made
                replies.extend(r for r in client.get("pure/rig/hello", timeout=0.5) if r.ok is not None)
                return bool(replies)

            assert wait_for(answered, 10.0)
            assert '"bench": "embedded"' in replies[0].ok.payload.to_string()
        # Positive control: zenoh's default callback does start one.
        queryable = hub.declare_queryable("pure/rig/other", lambda query: None)
        assert len(set(threading.enumerate()) - before) == 1
        queryable.undeclare()
    finally:
        client.close()
        hub.close()
