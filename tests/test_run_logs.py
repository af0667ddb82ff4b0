"""can.log and run.mcap written in a process of their own (hil/outputs/run_logs.py): the same bytes as on the
tick's thread, and a writer that fails or dies never fails the run but is named in its summary."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path
from types import SimpleNamespace

import can
import msgspec
import pytest
from mcap.reader import make_reader

from drivers.bus_config import BusConfig
from drivers.can_bus import CanNode, open_bus, private_channel
from drivers.can_codec import Catalog, MessageName
from drivers.keys import Keys
from drivers.schemas import TesWrench, encode
from hil.bench.bench import load_bench
from hil.outputs import run_logs
from hil.outputs.bodies import Body, Shape
from hil.outputs.run_logs import LocalLogs, LogProcess, McapSpec, open_logs
from hil.outputs.trace_log import TELEMETRY
from hil.pipeline import run
from hil.run.build import RunOptions
from hil.run.build import run_logs as build_run_logs
from tests.test_mcap import SCENARIO, bench

TICKS = 300  # more than a batch's ticks, not a multiple of them: stop() hands over the rest
BODIES = (
    Body(
        "ball",
        (Shape("sphere", (0.11, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (1.0, 0.5, 0.0, 1.0)),),
    ),
    Body(
        "torso",
        (Shape("capsule", (0.1, 0.3, 0.0), (0.0, 0.0, 0.4), (1.0, 0.0, 0.0, 0.0), (0.8, 0.5, 0.3, 1.0)),),
    ),
)


def feed(logs: LocalLogs | LogProcess) -> None:
    """A run's calls: every tick the frames the recorder takes (at that tick's time), a zenoh input now and
    then (one that does not decode), and the tick's row; the bodies first, their poses every 4th tick."""
    bus = open_bus(BusConfig(interface="pure_shared", channel=private_channel("logs")))
    node = CanNode(bus, name="rig")
    now = [0.0]
    logs.clock = lambda: now[0]
    wrench = TesWrench(seq=0, stamp=0.0, force=(0.0, 0.0, -500.0), moment=(0.0, 0.0, 0.0), cop=(0.0, 0.0))
    logs.bodies(BODIES)
    for k in range(TICKS):
        now[0] = k / 400
        frames = [
            node.message(MessageName.SYNC, {"Tick": k % 256}),
            node.message(MessageName.IMU_RATE, {"RateX": 0.01 * k, "RateY": -0.02, "RateZ": 0.0, "Valid": 1}),
            can.Message(arbitration_id=0x555, data=bytes([k % 256] * 8), is_extended_id=False, channel="x"),
            can.Message(arbitration_id=0x1ABCDE, data=b"\x01", is_extended_id=True, channel="x"),
        ]
        for i, m in enumerate(frames):
            m.timestamp = 1000.0 + k / 400 + i * 1e-6
            logs.on_message_received(m)
        if k % 7 == 0:
            key = Keys().tes_wrench
            logs.zenoh(k, key, encode(msgspec.structs.replace(wrench, seq=k)) if k % 21 else b"\xff garbage")
        logs.trace((k / 400, *[0.001 * k] * (TELEMETRY - 1)))
        if k % 4 == 0:
            logs.poses(
                k / 400, [0.001 * k, 0.0, 0.11, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.99, 0.0, 0.1, 0.0]
            )
    logs.stop()
    bus.shutdown()


def written(tmp_path: Path, name: str, logs_type) -> tuple[bytes, bytes, dict[str, str]]:
    folder = tmp_path / name
    folder.mkdir()
    logs = logs_type(folder / "can.log", McapSpec(folder / "run.mcap", 400.0, "pure", {"scenario": "x"}))
    feed(logs)
    return (folder / "can.log").read_bytes(), (folder / "run.mcap").read_bytes(), logs.failed


def test_the_process_writes_the_same_bytes_as_the_ticks_thread(tmp_path):
    here_log, here_mcap, here_failed = written(tmp_path, "here", LocalLogs)
    there_log, there_mcap, there_failed = written(tmp_path, "there", LogProcess)
    assert here_failed == there_failed == {}
    assert len(here_log.splitlines()) == 4 * TICKS
    assert there_log == here_log
    assert there_mcap == here_mcap
    with open(tmp_path / "there/run.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        topics = {channel.topic for channel in reader.get_summary().channels.values()}
    assert {"/can/SYNC", "/can/IMU_RATE", "/can/frames", "/trace", "/zenoh/rejected"} <= topics
    assert {"/scene", "/pose/ball", "/pose/torso"} <= topics


def test_the_process_is_its_own_session_reports_its_cpu_and_ends(tmp_path):
    logs = LogProcess(tmp_path / "can.log", None)
    pid = logs.pid
    assert os.getsid(pid) != os.getsid(0), "a terminal's Ctrl-C does not reach it: the run stops it"
    feed(logs)
    assert logs.failed == {} and logs.cpu_s > 0
    assert not Path(f"/proc/{pid}").exists(), "stop() waited for it"


def test_under_the_real_time_clock_the_writer_runs_in_the_background_and_hands_over_smaller_batches(tmp_path):
    """SCHED_IDLE never preempts the rig on its core when a hand-over wakes the writer (niceness did); the
    hand-overs come every REALTIME_BATCH_TICKS ticks. The lockstep writer is the control."""
    realtime = LogProcess(tmp_path / "rt.log", None, realtime=True)
    lockstep = LogProcess(tmp_path / "ls.log", None)
    try:
        assert os.sched_getscheduler(realtime.pid) == os.SCHED_IDLE
        assert os.sched_getscheduler(lockstep.pid) == os.SCHED_OTHER
        handed: list[int] = []
        hand_over = realtime._hand_over
        realtime._hand_over = lambda: handed.append(len(realtime._calls)) or hand_over()
        for tick in range(2 * run_logs.REALTIME_BATCH_TICKS):
            realtime.trace((float(tick),))
        assert handed == [run_logs.REALTIME_BATCH_TICKS] * 2
    finally:
        for logs in (realtime, lockstep):
            logs.stop()
            assert logs.failed == {}


def test_a_log_that_cannot_be_written_is_named_and_the_other_is_still_written(tmp_path):
    (tmp_path / "can.log").mkdir()  # not a file: the process cannot open it
    logs = LogProcess(tmp_path / "can.log", McapSpec(tmp_path / "run.mcap", 400.0, "pure", {}))
    feed(logs)
    assert list(logs.failed) == ["can.log"] and "IsADirectoryError" in logs.failed["can.log"]
    with open(tmp_path / "run.mcap", "rb") as f:
        assert make_reader(f, validate_crcs=True).get_summary().statistics.message_count > TICKS


def _writer_processes() -> list[int]:
    """This process's children that are a run's log writer."""
    pids = []
    for entry in Path("/proc").iterdir():
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            command = (entry / "cmdline").read_bytes()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == os.getpid() and b"hil.outputs.run_logs" in command:
            pids.append(int(entry.name))
    return pids


def test_a_writer_process_that_dies_mid_run_does_not_stop_the_run_and_is_named(tmp_path):
    killed = []

    def kill_the_writer(plant) -> None:
        if plant.tick == 100:
            pids = _writer_processes()
            for pid in pids:
                os.kill(pid, signal.SIGKILL)
            killed.extend(pids)

    short = msgspec.structs.replace(SCENARIO, duration=0.5, faults=[])
    result = run(short, bench(recording=False), out=tmp_path, options=RunOptions(on_tick=kill_the_writer))
    assert len(killed) == 1, "positive control: the run had its writer process"
    assert result.trace.failure is None and result.trace.stats.ticks == 200, "the run goes on"
    failed = json.loads((tmp_path / "summary.json").read_text())["outputs_failed"]
    assert set(failed) == {"can.log", "run.mcap"}
    assert all("the writer process stopped" in why and "SIGKILL" in why for why in failed.values())


def test_a_daemonic_process_writes_on_its_own_thread(tmp_path, monkeypatch):
    """A Dask worker is daemonic: it may not start a process of its own."""
    assert isinstance(open_logs(tmp_path / "a.log", None), LogProcess)  # positive control
    monkeypatch.setattr(run_logs.multiprocessing, "current_process", lambda: SimpleNamespace(daemon=True))
    logs = open_logs(tmp_path / "b.log", None)
    assert isinstance(logs, LocalLogs)
    logs.stop()
    assert open_logs(None, None) is None


@pytest.mark.parametrize("in_process", [False, True])
def test_a_run_writes_both_logs_either_way(tmp_path, in_process):
    short = msgspec.structs.replace(SCENARIO, duration=0.25, faults=[], operator=[])
    run(short, bench(recording=False), out=tmp_path, options=RunOptions(logs_in_process=in_process))
    sync_id = Catalog()[MessageName.SYNC].frame_id
    sync = sum(m.arbitration_id == sync_id for m in can.LogReader(str(tmp_path / "can.log")))
    with open(tmp_path / "run.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        synced = sum(1 for _ in reader.iter_messages(topics="/can/SYNC"))
    assert sync == synced == 100
    assert json.loads((tmp_path / "summary.json").read_text())["outputs_failed"] == {}


def test_the_process_imports_the_runs_pure_hil_not_the_working_directorys(tmp_path, monkeypatch):
    """Run from a folder that holds another checkout (a compiled build run from its source tree): the
    process must import what the run imported, never the folder's."""
    decoy = tmp_path / "decoy"
    (decoy / "hil").mkdir(parents=True)
    (decoy / "hil" / "__init__.py").write_text('raise ImportError("the working directory\'s hil")\n')
    monkeypatch.chdir(decoy)
    logs = LogProcess(tmp_path / "can.log", None)
    feed(logs)
    assert logs.failed == {}
    assert len((tmp_path / "can.log").read_text().splitlines()) == 4 * TICKS


def test_a_bench_with_parts_in_other_processes_writes_on_the_ticks_thread(tmp_path):
    """The lockstep tick waits on a controller or supervisor in a process of its own: no writer process
    competes with them for the CPU."""
    embedded = bench(recording=False)
    here = run_logs_of(embedded, tmp_path / "embedded")
    assert isinstance(here, LogProcess), "positive control: a rig alone in its process"
    spawned = load_bench("vcan")  # a shipped bench whose controller and supervisor are spawned
    assert isinstance(run_logs_of(spawned, tmp_path / "vcan"), LocalLogs)


def run_logs_of(b, folder: Path) -> LocalLogs | LogProcess:
    folder.mkdir()
    logs = build_run_logs(b, SCENARIO, 0, RunOptions(), folder)
    assert logs is not None
    logs.stop()
    return logs
