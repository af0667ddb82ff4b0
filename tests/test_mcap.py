"""run.mcap (hil/outputs/mcap_log.py, mcap_file.py): a short lockstep run's file read back with the `mcap`
package's reader and held against the run's other outputs: its CAN frames against can.log (python-can's
LogReader), its signals against decoding those frames, its zenoh messages against zenoh_inputs.msgpack, its
trace against trace.npy; the summary's CRC by the spec; the file after a writer error, without a CAN log,
and after a run that failed to build; and the writer's memory against its file's length."""

from __future__ import annotations

import base64
import json
import struct
import tracemalloc
import zlib
from collections import Counter, defaultdict
from pathlib import Path

import can
import msgspec
import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import Writer

from drivers.can_codec import Catalog, MessageName
from drivers.keys import Keys
from drivers.schemas import ControllerCommand, PayloadError, ScCommand, TesWrench, decode
from hil.faults import parse_fault
from hil.outputs.mcap_file import McapFile
from hil.outputs.mcap_log import McapLog
from hil.outputs.trace_log import COLUMNS, LAYOUT, TELEMETRY
from hil.pipeline import run
from hil.run.build import RunOptions
from hil.run.scenario import Intent, OperatorEntry, Scenario, ScEntry
from plant.rider import Ramp
from tests.zenoh_helpers import private_bench

DT_NS = 2_500_000
SCENARIO = Scenario(
    name="mcap",
    rider="configs/riders/s16_mwcu_52kg_167.toml",
    law="ihacs",
    duration=1.0,
    seed=3,
    intent=Intent(pitch=[Ramp(to=10.0, duration=0.5)]),
    sc=[ScEntry(mode="limit", cap=0.5)],
    operator=[OperatorEntry(at=0.5, action="enable"), OperatorEntry(at=0.9, action="estop")],
    # Five ticks of garbage in place of the seat's wrench: /zenoh/rejected.
    faults=[parse_fault({"kind": "zenoh.malformed", "at": 0.75, "duration": 0.0125})],
)
PAYLOADS = {
    "pure/tes/wrench": TesWrench,
    "pure/sc/command": ScCommand,
    "pure/controller/command": ControllerCommand,
}


def bench(**outputs):
    b = private_bench()
    return msgspec.structs.replace(b, outputs=msgspec.structs.replace(b.outputs, plots=False, **outputs))


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run")
    result = run(SCENARIO, bench(recording=False), out=out)
    assert result.trace.failure is None and result.trace.stats.ticks == 400
    return out


def messages(path: Path, topic: str | None = None) -> list[tuple[int, dict]]:
    """(log time, decoded JSON) of `topic`'s messages (every topic's: None) in log-time order."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        return [(m.log_time, json.loads(m.data)) for _, _, m in reader.iter_messages(topics=topic)]


def topics(path: Path) -> dict[str, tuple]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return {c.topic: (c, summary.schemas[c.schema_id]) for c in summary.channels.values()}


def mcap_frames(path: Path) -> list[tuple[int, bytes, float, int]]:
    """/can/frames as (id, data, can.log's stamp, log time), frame by frame."""
    return [
        (f["id"], base64.b64decode(f["data"]), f["wall"], t)
        for t, batch in messages(path, "/can/frames")
        for f in batch["frames"]
    ]


def log_frames(path: Path) -> list[tuple[int, bytes, float]]:
    return [(m.arbitration_id, bytes(m.data), m.timestamp) for m in can.LogReader(str(path))]


def mismatch(mcap: list, log: list) -> str | None:
    """Where /can/frames and can.log part, frame by frame (None: nowhere). candump keeps 6 decimals."""
    for i, (a, b) in enumerate(zip(mcap, log, strict=False)):
        if a[:2] != b[:2] or abs(a[2] - b[2]) > 1e-6:
            return f"frame {i}: {a[:3]} != {b}"
    return None if len(mcap) == len(log) else f"{len(mcap)} frames != {len(log)}"


def test_its_frames_are_can_logs_frame_for_frame_in_simulated_time(folder):
    frames, log = mcap_frames(folder / "run.mcap"), log_frames(folder / "can.log")
    assert len(log) > 400 * 12 and mismatch(frames, log) is None
    times = [t for *_, t in frames]
    assert times == sorted(times) and times[0] == 0  # the start-up's frames at t = 0
    # Each frame's own stamp is that simulated time too, as every other topic's (can.log's wall-clock
    # stamp beside it).
    stamps = [
        round(f["stamp"] * 1e9)
        for _, batch in messages(folder / "run.mcap", "/can/frames")
        for f in batch["frames"]
    ]
    assert stamps == times
    assert {t % DT_NS for t in times} == {0} and times[-1] == 400 * DT_NS  # one time per tick
    # Each SYNC at the simulated time of the tick it names.
    sync = Catalog()[MessageName.SYNC]
    ticks = [(sync.decode(data)["Tick"], t) for id_, data, _, t in frames if id_ == sync.frame_id]
    assert [k for k, _ in ticks] == list(range(1, 401)) and all(t == k * DT_NS for k, t in ticks)


def test_the_comparison_sees_a_dropped_or_altered_frame(folder, tmp_path):
    """Positive control: copies of run.mcap, rewritten with the `mcap` package's own writer, one frame
    dropped in one and one byte altered in the other, read back the same way."""
    log = log_frames(folder / "can.log")

    def doctored(name: str, edit) -> Path:
        path = tmp_path / name
        with open(folder / "run.mcap", "rb") as src, open(path, "wb") as dst:
            reader, writer = make_reader(src), Writer(dst)
            writer.start()
            ids, done = {}, False
            for schema, channel, m in reader.iter_messages(log_time_order=False):
                if channel.id not in ids:
                    s = writer.register_schema(schema.name, schema.encoding, schema.data)
                    ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, s)
                data = m.data
                if channel.topic == "/can/frames" and m.log_time == 200 * DT_NS and not done:
                    batch = json.loads(data)
                    edit(batch["frames"])
                    data, done = json.dumps(batch).encode(), True
                writer.add_message(ids[channel.id], m.log_time, data, m.publish_time)
            writer.finish()
        return path

    def alter(frames):
        data = bytearray(base64.b64decode(frames[3]["data"]))
        data[0] ^= 1
        frames[3]["data"] = base64.b64encode(bytes(data)).decode()

    dropped = mcap_frames(doctored("dropped.mcap", lambda f: f.pop(5)))
    assert len(dropped) == len(log) - 1 and mismatch(dropped, log) is not None
    assert mismatch(mcap_frames(doctored("altered.mcap", alter)), log) is not None
    assert mismatch(mcap_frames(doctored("untouched.mcap", lambda f: None)), log) is None


def test_every_channel_is_json_with_a_json_schema_viewers_read_unaided(folder):
    channels = topics(folder / "run.mcap")
    assert {"/can/frames", "/trace", "/zenoh/rejected", *(f"/zenoh/{k}" for k in PAYLOADS)} <= set(channels)
    for channel, schema in channels.values():
        assert (channel.message_encoding, schema.encoding) == ("json", "jsonschema")
        assert b"$ref" not in schema.data, "no reference for a viewer to resolve"
        assert json.loads(schema.data)["type"] == "object"


def test_each_dbc_message_has_its_channel_with_the_frames_decoded(folder):
    path, catalog = folder / "run.mcap", Catalog()
    expected = defaultdict(list)
    for id_, data, _, t in mcap_frames(path):
        codec = catalog.by_id(id_)
        if codec is not None and len(data) == codec.length:
            expected[codec.name].append((t, codec.decode(data)))
    channels = topics(path)
    assert len(expected) >= 14
    for name, values in expected.items():
        _, schema = channels[f"/can/{name}"]
        properties = json.loads(schema.data)["properties"]
        assert list(properties) == list(catalog[name].signal_names)
        assert messages(path, f"/can/{name}") == values
    assert not {t for t in channels if t.startswith("/can/")} - {
        "/can/frames",
        *(f"/can/{n}" for n in expected),
    }


def test_zenoh_inputs_are_there_decoded_at_their_ticks(folder):
    entries = msgspec.msgpack.decode((folder / "zenoh_inputs.msgpack").read_bytes())
    path = folder / "run.mcap"
    expected, rejected = defaultdict(list), []
    for tick, key, data in entries:
        try:
            payload = msgspec.to_builtins(decode(data, PAYLOADS[key]))
            expected[key].append((tick * DT_NS, json.loads(json.dumps(payload))))  # tuples as JSON arrays
        except PayloadError:
            rejected.append((tick * DT_NS, key, data))
    assert set(expected) == set(PAYLOADS) and len(rejected) == 5
    for key, values in expected.items():
        assert messages(path, f"/zenoh/{key}") == values
    got = [(t, m["key"], base64.b64decode(m["data"])) for t, m in messages(path, "/zenoh/rejected")]
    assert got == rejected
    assert "garbage" in messages(path, "/zenoh/rejected")[0][1]["reason"]


def test_one_trace_message_per_tick_equal_to_trace_npy(folder):
    rows = np.load(folder / "trace.npy")[:, :TELEMETRY]
    got = messages(folder / "run.mcap", "/trace")
    assert len(got) == len(rows) == json.loads((folder / "summary.json").read_text())["rig"]["ticks"]

    def flat(message: dict) -> list:
        return [
            message[c] if "." not in c else message[c.split(".")[0]][c.split(".")[1]]
            for c in (column.name for column in COLUMNS[:TELEMETRY])
        ]

    values = np.array([flat(m) for _, m in got], dtype=float)  # JSON's null -> NaN
    assert np.array_equal(values, rows, equal_nan=True)
    assert [t for t, _ in got] == [round(t * 1e9) for t in rows[:, LAYOUT.span("t")]]


def test_the_events_are_the_summarys_each_at_its_time(folder):
    """Fault windows, the fault log, the supervisor's transitions with their causes and the operator's
    actions: on their own topics, each a JSON Schema, the same records as summary.json's."""
    summary = json.loads((folder / "summary.json").read_text())
    path = folder / "run.mcap"
    windows = [
        (round(f["acted"][0] * 1e9), f["number"], f["acted"][1])
        for f in summary["faults"]
        if f["acted"] is not None
    ]
    got = messages(path, "/events/fault_windows")
    assert windows and [(t, m["fault"], m["end"]) for t, m in got] == windows
    assert got[0][1]["kind"] == "zenoh.malformed" and got[0][1]["start"] == 0.75 and not got[0][1]["live"]
    log = [(round(e["t"] * 1e9), e["fault"], e["action"]) for e in summary["fault_events"]]
    assert [(t, m["fault"], m["action"]) for t, m in messages(path, "/events/faults")] == log
    transitions = [(round(e["t"] * 1e9), e["to_state"], e["cause"]) for e in summary["safety"]["events"]]
    assert ("STOPPING", "OPERATOR_ESTOP") in [(s, c) for _, s, c in transitions]
    supervisor = messages(path, "/events/supervisor")
    assert [(t, m["to_state"], m["cause"]) for t, m in supervisor] == transitions
    operator = [(round(a["t"] * 1e9), a["source"], a["scheduled"]) for a in summary["operator_actions"]]
    assert operator == [(round(0.9 * 1e9), "scenario", True)]
    assert [(t, m["source"], m["scheduled"]) for t, m in messages(path, "/events/operator")] == operator
    channels = topics(path)
    for topic in ("/events/fault_windows", "/events/faults", "/events/supervisor", "/events/operator"):
        schema = json.loads(channels[topic][1].data)
        assert schema["type"] == "object" and schema["properties"], topic


def test_the_summary_crc_is_the_specs(folder):
    """Foxglove's reader refuses a file whose summary CRC is wrong; the `mcap` package's does not check it:
    crc32 of the summary section through the footer's summary_offset_start (mcap.dev/spec, Footer)."""
    data = (folder / "run.mcap").read_bytes()
    summary_start, _, crc = struct.unpack("<QQI", data[-8 - 20 : -8])
    assert summary_start and crc == zlib.crc32(data[summary_start : -8 - 4])
    assert json.loads((folder / "summary.json").read_text())["outputs_failed"] == {}


def test_a_writer_error_keeps_the_file_up_to_it_and_is_named_in_the_summary(tmp_path, monkeypatch):
    calls = Counter()
    messages = McapFile.messages  # every message goes through it (message() too)

    def failing_batch(self, time, channels, data):  # the 3000th message fails, in its batch
        before = 3000 - 1 - calls["n"]
        calls["n"] += len(channels)
        if 0 <= before < len(channels):
            messages(self, time, channels[:before], data[:before])
            raise OSError(28, "No space left on device")
        messages(self, time, channels, data)

    monkeypatch.setattr(McapFile, "messages", failing_batch)  # here: the writer on the tick's thread
    short = msgspec.structs.replace(SCENARIO, duration=0.5, faults=[])
    options = RunOptions(logs_in_process=True)
    result = run(short, bench(recording=False), out=tmp_path, options=options)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert result.trace.failure is None and result.trace.stats.ticks == 200, "the run goes on"
    assert "No space left on device" in summary["outputs_failed"]["run.mcap"]
    sync = Catalog()[MessageName.SYNC].frame_id
    assert sum(m.arbitration_id == sync for m in can.LogReader(str(tmp_path / "can.log"))) == 200
    with open(tmp_path / "run.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert [m.name for m in reader.iter_metadata()] == ["pure-hil", "failed"]
        assert sum(1 for _ in reader.iter_messages()) == 2999  # every message before the error


def test_events_that_fail_lose_themselves_never_the_run(tmp_path, monkeypatch):
    import hil.pipeline

    def broken(trace, scenario):
        raise KeyError("a record the events cannot read")

    monkeypatch.setattr(hil.pipeline, "events", broken)
    short = msgspec.structs.replace(SCENARIO, duration=0.25, faults=[], operator=[])
    result = run(short, bench(recording=False), out=tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert result.trace.failure is None and result.trace.stats.ticks == 100
    assert "its events: KeyError" in summary["outputs_failed"]["run.mcap"]
    assert len(messages(tmp_path / "run.mcap", "/trace")) == 100, "the rest of the file is there"


def test_without_a_can_log_or_without_mcap(tmp_path):
    short = msgspec.structs.replace(SCENARIO, duration=0.25, faults=[], operator=[])
    run(short, bench(can_log=False, recording=False), out=tmp_path / "no-log")
    assert not (tmp_path / "no-log/can.log").exists()
    assert len(messages(tmp_path / "no-log/run.mcap", "/can/SYNC")) == 100
    run(short, bench(mcap=False, recording=False), out=tmp_path / "no-mcap")
    assert not (tmp_path / "no-mcap/run.mcap").exists() and (tmp_path / "no-mcap/can.log").exists()
    assert json.loads((tmp_path / "no-mcap/summary.json").read_text())["outputs_failed"] == {}


def test_a_run_that_fails_to_build_still_leaves_a_complete_file(tmp_path):
    broken = msgspec.structs.replace(SCENARIO, rider="configs/riders/no_such_rider.toml")
    result = run(broken, bench(), out=tmp_path)
    assert result.trace.failure.stage == "build"
    assert json.loads((tmp_path / "summary.json").read_text())["outputs_failed"] == {}
    with open(tmp_path / "run.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary().statistics.message_count == 0
        assert next(reader.iter_metadata()).metadata["scenario"] == "mcap"


def test_frames_that_are_not_a_dbc_message_stay_raw_among_those_that_are(tmp_path):
    """An unknown id, a wrong length and an extended id, before and after a message's first good frame (which
    opens its channel mid-tick): every frame on /can/frames, only the good ones decoded, in order, each
    channel's records before its first message (read as a stream)."""
    catalog = Catalog()
    sync, imu = catalog[MessageName.SYNC], catalog[MessageName.IMU_RATE]
    good_sync = sync.encode({"Tick": 7})
    good_imu = bytes(range(imu.length))
    ticks = [
        [
            can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False),
            can.Message(arbitration_id=sync.frame_id, data=good_sync + b"\0", is_extended_id=False),
            can.Message(arbitration_id=sync.frame_id, data=good_sync, is_extended_id=True),
            can.Message(arbitration_id=sync.frame_id, data=good_sync, is_extended_id=False),
            can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False),
            can.Message(arbitration_id=imu.frame_id, data=good_imu, is_extended_id=False),
        ],
        [
            can.Message(arbitration_id=imu.frame_id, data=good_imu[:-1], is_extended_id=False),
            can.Message(arbitration_id=sync.frame_id, data=good_sync, is_extended_id=False),
            can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False),
        ],
    ]
    path, now = tmp_path / "run.mcap", [0.0]
    with McapLog(path, 400.0, Keys()) as log:
        log.clock = lambda: now[0]
        for i, frames in enumerate(ticks):
            now[0] = i / 400
            for m in frames:
                log.on_message_received(m)
            log.trace([now[0]] + [0.0] * (TELEMETRY - 1))
    got = [(id_, data, t) for id_, data, _, t in mcap_frames(path)]
    assert got == [(m.arbitration_id, bytes(m.data), i * DT_NS) for i, f in enumerate(ticks) for m in f]
    assert messages(path, "/can/SYNC") == [(0, {"Tick": 7}), (DT_NS, {"Tick": 7})]
    assert messages(path, "/can/IMU_RATE") == [(0, imu.decode(good_imu))]
    with open(path, "rb") as f:
        streamed = [c.topic for _, c, _ in NonSeekingReader(f, validate_crcs=True).iter_messages()]
    assert streamed == [
        *("/can/frames", "/can/SYNC", "/can/IMU_RATE", "/trace"),
        *("/can/frames", "/can/SYNC", "/trace"),
    ]


def test_the_writer_holds_one_chunk_however_long_the_file(tmp_path):
    """Many chunks (small ones here), read back by the package's reader, indexes and all; memory does not
    grow with the file (a positive control keeps what it writes)."""

    def write(n: int, keep: list | None = None) -> int:
        tracemalloc.start()
        f = McapFile(tmp_path / f"{n}.mcap", "test", chunk_size=4096)
        a = f.channel("/a", "json", f.schema("A", "jsonschema", b'{"type": "object"}'))
        b = f.channel("/b", "json", f.schema("B", "jsonschema", b'{"type": "object"}'))
        for i in range(n):
            data = b'{"i": %d}' % i
            f.message(a if i % 3 else b, i * 1000, data)
            if keep is not None:
                keep.append(data)
        peak = tracemalloc.get_traced_memory()[1]  # as the file is written (close() reads in blocks)
        tracemalloc.stop()
        f.close()
        return peak

    small, large = write(5_000), write(50_000)
    assert large - small < 20_000, (small, large)
    assert write(50_000, []) - small > 1_000_000  # the control: memory that does grow is seen
    with open(tmp_path / "50000.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 50_000 and len(summary.chunk_indexes) > 100
        got = [(m.log_time, json.loads(m.data)["i"]) for _, _, m in reader.iter_messages(topics=["/b"])]
    assert got == [(i * 1000, i) for i in range(0, 50_000, 3)]
    with open(tmp_path / "50000.mcap", "rb") as f:  # read as a stream (a pipe), chunk CRCs checked
        assert sum(1 for _ in NonSeekingReader(f, validate_crcs=True).iter_messages()) == 50_000
