"""The xsens IMU profile (docs/devices.md): an emulated Xsens MTi 600-series on its CAN output.

The emulated frames decode with the project's DBC (configs/devices/xsens_mti.dbc) to the plant's values
within the protocol's resolution; the host side passes a data group on only while SampleTime and
GroupCounter advance. Then the whole rig: the reference controller and the supervisor read the Xsens
frames, deterministic in lockstep, replayed byte for byte; a frozen sample counter is seen and the robot
does not fall; the fault is refused on a bench without the xsens IMU.

Benches are loaded by file path, so the tests run whether or not the worktree's entry points are installed
(the run itself still needs `pure_hil.devices` to name `xsens`).
"""

from __future__ import annotations

import math
from pathlib import Path

import can
import cantools
import msgspec
import pytest

from drivers.can_codec import Catalog, MessageName
from drivers.config import ConfigError
from drivers.devices import XSENS_XCIDS, Devices, ProfileNode
from drivers.devices.xsens import XsensHost, dbc_path
from hil.devices.xsens import XsensImu

BENCH = str(Path(__file__).resolve().parents[1] / "configs" / "benches" / "xsens.toml")
DEVICES = Devices(imu="xsens")
BASE = DEVICES.xsens.base_id
ATTITUDE = {"Roll": 0.0123, "Pitch": -0.2345, "Yaw": 2.5, "Valid": 1}
RATE = {"RateX": 0.5, "RateY": -1.25, "RateZ": 0.003, "Valid": 1}
ACCEL = {"AccX": 0.2, "AccY": -0.7, "AccZ": 9.81, "Valid": 1}


def _tick(imu: XsensImu, k: int) -> list[can.Message]:
    frames = []
    for name, values in (
        (MessageName.IMU_ATTITUDE, ATTITUDE),
        (MessageName.IMU_RATE, RATE),
        (MessageName.IMU_ACCEL, ACCEL),
    ):
        frames += imu.outgoing(name, values)
    imu.on_sync(k)
    return frames


def _has_entry_point() -> bool:
    from importlib.metadata import entry_points

    return "xsens" in {ep.name for ep in entry_points(group="pure_hil.devices")}


needs_entry_point = pytest.mark.skipif(
    not _has_entry_point(), reason="pure_hil.devices does not name xsens here (reinstall the package)"
)


# ------------------------------------------------------------------------------------------ the wire
def test_the_emulated_frames_decode_with_the_dbc_to_the_plants_values_within_its_resolution():
    imu = XsensImu(DEVICES, 8192, 400.0)
    db = cantools.database.load_file(str(dbc_path()))
    by_id = {BASE + m.frame_id: m for m in db.messages}
    frames = _tick(imu, 1)
    names = [by_id[f.arbitration_id].name for f in frames]
    assert names == ["SampleTime", "GroupCounter", "StatusWord", "EulerAngles", "RateOfTurn", "Acceleration"]
    d = {by_id[f.arbitration_id].name: by_id[f.arbitration_id].decode(f.data) for f in frames}
    half = {"deg": 2**-8, "rad/s": 2**-10, "m/s^2": 2**-9}  # half a count of each
    for key, sig in (("Roll", "Roll"), ("Pitch", "Pitch"), ("Yaw", "Yaw")):
        assert d["EulerAngles"][sig] == pytest.approx(math.degrees(ATTITUDE[key]), abs=half["deg"])
    for key, sig in (("RateX", "gyrX"), ("RateY", "gyrY"), ("RateZ", "gyrZ")):
        assert d["RateOfTurn"][sig] == pytest.approx(RATE[key], abs=half["rad/s"])
    for key, sig in (("AccX", "accX"), ("AccY", "accY"), ("AccZ", "accZ")):
        assert d["Acceleration"][sig] == pytest.approx(ACCEL[key], abs=half["m/s^2"])
    assert d["StatusWord"]["StatusWord"] & 0b11 == 0b11  # self test, filter valid
    # Big-endian, as Xsens sends all binary data: Roll = round(0.0123 rad in deg * 128) = 90 = 0x005A.
    euler = next(f for f in frames if f.arbitration_id == BASE + XSENS_XCIDS["EulerAngles"])
    assert euler.data[:2] == bytes([0x00, 0x5A])
    # SampleTime counts 100 us: 25 a tick at 400 Hz; GroupCounter one a group.
    later = _tick(imu, 2)
    times = [by_id[f.arbitration_id].decode(f.data) for f in (frames[0], later[0])]
    assert times[1]["SampleTime"] - times[0]["SampleTime"] == 25
    assert by_id[later[1].arbitration_id].decode(later[1].data)["GroupCounter"] == 1


def test_the_host_passes_a_group_on_only_while_its_sample_counter_advances():
    imu, host = XsensImu(DEVICES, 8192, 400.0), XsensHost(DEVICES, 8192, "supervisor")

    def read(frames):
        return {rx.name: rx for f in frames if (rx := host.incoming(f)) is not None}

    got = read(_tick(imu, 1))
    assert set(got) == {MessageName.IMU_ATTITUDE, MessageName.IMU_RATE, MessageName.IMU_ACCEL}
    assert all(rx.signals["Valid"] == 1 for rx in got.values())
    assert got[MessageName.IMU_ATTITUDE].signals["Pitch"] == pytest.approx(ATTITUDE["Pitch"], abs=1.4e-4)
    assert got[MessageName.IMU_RATE].signals["RateY"] == pytest.approx(RATE["RateY"], abs=2**-10)
    assert got[MessageName.IMU_ACCEL].signals["AccZ"] == pytest.approx(ACCEL["AccZ"], abs=2**-9)
    assert all(rx.signals["Valid"] == 1 for rx in read(_tick(imu, 2)).values())  # the positive control
    imu.sample_counter_frozen(True)
    frozen = read(_tick(imu, 3))
    assert frozen and all(rx.signals["Valid"] == 0 for rx in frozen.values())
    assert host.stale == 3
    imu.sample_counter_frozen(False)
    assert all(rx.signals["Valid"] == 1 for rx in read(_tick(imu, 4)).values())
    # A data frame repeated within its group is not fresh either (no E2E: the group is the alive counter).
    frames = _tick(imu, 5)
    read(frames)
    assert read(frames[3:4])[MessageName.IMU_ATTITUDE].signals["Valid"] == 0


def test_a_frame_of_the_family_that_does_not_decode_is_counted_not_raised():
    bus = can.Bus(interface="virtual", channel="xsens-malformed", receive_own_messages=False)
    node = ProfileNode(bus, [XsensHost(DEVICES, 8192, "controller")], name="controller")
    try:
        bad = can.Message(
            arbitration_id=BASE + XSENS_XCIDS["EulerAngles"], data=b"\x00\x01", is_extended_id=False
        )
        assert node.decode(bad) is None
        assert node.stats.malformed["malformed_device_frame"] == 1
    finally:
        bus.shutdown()


def test_xsens_ids_that_own_a_contract_or_drive_frame_are_refused_naming_the_field(tmp_path):
    from hil.bench.bench import load_bench

    path = tmp_path / "bench.toml"
    path.write_text('name = "x"\n[devices]\nimu = "xsens"\n[devices.xsens]\nbase_id = 0\n')
    with pytest.raises(ConfigError, match=r"xsens\.base_id: 0x000 .*StatusWord 0x011 on OPERATOR_ESTOP"):
        load_bench(path)
    # The drives' profile owns ids too: ODrive nodes 1-3 own 0x020-0x07F, CANopen node 1 its heartbeat 0x701.
    path.write_text(
        'name = "x"\n[devices]\nimu = "xsens"\ndrives = "odrive"\n[devices.xsens]\nbase_id = 0x010\n'
    )
    with pytest.raises(ConfigError, match=r"EulerAngles 0x032 on ODrive node 1's frames"):
        load_bench(path)
    path.write_text(
        'name = "x"\n[devices]\nimu = "xsens"\ndrives = "cia402"\n[devices.xsens]\nbase_id = 0x700\n'
    )
    with pytest.raises(ConfigError, match=r"Error 0x701 on CANopen node 1's COB-IDs"):
        load_bench(path)
    path.write_text('name = "x"\n[devices]\nimu = "xsens"\n[devices.xsens]\nbase_id = 0x170\n')
    with pytest.raises(ConfigError, match=r"StatusWord 0x181 on DRIVE1_FEEDBACK"):
        load_bench(path)
    # The shipped base is free on every drive profile (the positive control).
    for drives in ("pure", "odrive", "cia402"):
        Devices(imu="xsens", drives=drives)
    assert Catalog()[MessageName.OPERATOR_ESTOP].frame_id == 0x011


# ------------------------------------------------------------------------------------------- the rig
@needs_entry_point
def test_speed_limiting_on_xsens_passes_deterministically_and_replays_byte_for_byte(tmp_path):
    from tests.device_runs import frames, speed_limiting_on

    replayed = speed_limiting_on(BENCH, tmp_path, {"imu": "xsens"}, contract={"imu": "pure"})
    assert replayed.frames_compared >= 4 * replayed.ticks
    ids = {int(frame.split("#")[0], 16) for frame in frames(tmp_path / "whole")}
    assert {BASE + x for n, x in XSENS_XCIDS.items() if n != "Error"} <= ids, "the Xsens group on the wire"
    assert not ids & {0x18A, 0x28A, 0x38A}, "no contract IMU frame on an xsens bus"


def _balance(faults, duration: float = 2.0, bench: str = BENCH, out: Path | None = None):
    from hil.pipeline import load_scenario, run
    from tests.zenoh_helpers import private_bench

    scenario = msgspec.structs.replace(load_scenario("balance"), duration=duration, faults=faults)
    return run(scenario, private_bench(bench), out=out).trace


@needs_entry_point
def test_a_frozen_sample_counter_is_seen_and_the_robot_does_not_fall(tmp_path):
    from hil.faults import parse_fault

    clean = _balance([])
    assert clean.failure is None and clean.fallen is None
    assert not [e for e in clean.safety_events if e.kind == "transition"], "the positive control: NORMAL"
    at = 1.0
    trace = _balance([parse_fault({"kind": "xsens.sample_counter_frozen", "at": at})], out=tmp_path)
    assert trace.failure is None and trace.fallen is None
    first = next(e for e in trace.safety_events if e.kind == "transition")
    # The controller holds its last good IMU values 20 ms, then faults with SENSOR_TIMEOUT (the supervisor's
    # own IMU timeout is 25 ms): whichever comes first, the cause is the IMU's stream going invalid.
    assert first.cause in ("IMU_SILENT", "CONTROLLER_FAULT")
    assert at < first.t <= at + 0.1
    heartbeat = Catalog()[MessageName.CONTROLLER_HEARTBEAT]
    codes = {
        heartbeat.decode(bytes.fromhex(frame.split("#")[1]))["FaultCode"]
        for line in (tmp_path / "can.log").read_text().splitlines()
        if (frame := line.split()[2]).startswith(f"{heartbeat.frame_id:03X}#")
    }
    assert 1 in codes, "the controller's fault is SENSOR_TIMEOUT: its IMU went invalid"


def test_the_fault_is_refused_on_a_bench_without_the_xsens_imu():
    from hil.faults import parse_fault

    trace = _balance([parse_fault({"kind": "xsens.sample_counter_frozen", "at": 0.5})], 1.0, "embedded")
    assert trace.failure is not None and trace.failure.config
    assert "needs a bench whose IMU speak 'xsens'" in trace.failure.error


@needs_entry_point
def test_a_fault_free_run_on_xsens_keeps_the_supervisor_in_normal():
    # Near rest the gyro's 2^-9 rad/s step is over twice its noise: a live RateY reads 0 for 20 frames and
    # more. The stuck check asks a run as unlikely for a live channel at the stream's step (54 frames) as 20
    # are at the contract's; it tripped at 0.503 s when it asked 20 (docs/devices.md, xsens).
    from hil.pipeline import load_scenario, run
    from tests.zenoh_helpers import private_bench

    scenario = msgspec.structs.replace(load_scenario("speed_limiting"), duration=1.0)
    trace = run(scenario, private_bench(BENCH)).trace
    assert trace.failure is None
    assert [e for e in trace.safety_events if e.kind == "transition"] == []
