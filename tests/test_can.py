"""CAN catalog, codecs, E2E protection, bus load and buses (python-can `virtual`)."""

import itertools
import logging
import os
import socket
from pathlib import Path

import can
import cantools
import pytest
from crccheck.crc import Crc8SaeJ1850
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.bus_config import BusConfig, BusConfigError, parse_can_spec
from drivers.bus_load import BusLoadError, bus_load, check_bus_load, frame_bits
from drivers.can_bus import (
    RECEIVE_BUFFER,
    WARNED_IDS,
    BusRecorder,
    CanNode,
    enlarge_receive_buffer,
    open_bus,
    private_channel,
)
from drivers.can_codec import Catalog, MessageCodec, raw_range
from drivers.e2e import E2EChecker, E2EProtector, E2EStatus, counter_of, crc8, is_protected, with_counter
from drivers.shared_bus import MESSAGE_FIELDS

CATALOG = Catalog()
DB = CATALOG.database


@st.composite
def message_values(draw, message):
    return {s.name: draw(st.integers(*raw_range(s))) * s.scale + s.offset for s in message.signals}


@pytest.mark.parametrize("message", DB.messages, ids=lambda m: m.name)
def test_codec_is_identical_to_cantools(message):
    codec = CATALOG[message.name]

    @settings(max_examples=150, deadline=None)
    @given(
        values=message_values(message), payload=st.binary(min_size=message.length, max_size=message.length)
    )
    def check(values, payload):
        assert codec.encode(values) == message.encode(values, strict=True)
        ours = codec.decode(payload)
        ref = message.decode(payload, decode_choices=False)
        assert ours.keys() == ref.keys()
        for k in ours:
            assert ours[k] == pytest.approx(ref[k], rel=1e-12, abs=1e-12)

    check()


def test_out_of_range_values_saturate():
    codec = CATALOG["DRIVE1_FEEDBACK"]
    out = codec.decode(codec.encode({"Velocity": 1e6, "Position": -1e12}))
    assert out["Velocity"] == pytest.approx(327.67) and out["Position"] == -(2**31)


def test_crc8_is_sae_j1850():
    assert crc8(b"123456789") == 0x4B

    @given(st.binary(max_size=16))
    def same_as_crccheck(data):
        assert crc8(data) == Crc8SaeJ1850.calc(data)

    same_as_crccheck()


def test_every_safety_frame_is_protected():
    unprotected = {c.name for c in CATALOG if not is_protected(c)}
    assert unprotected == {"SYNC"}
    ids = sorted(c.frame_id for c in CATALOG)
    assert ids[:2] == [CATALOG["SUPERVISOR_ESTOP"].frame_id, CATALOG["OPERATOR_ESTOP"].frame_id]


def test_e2e_on_an_unprotected_message_is_refused_by_name():
    """Sealing, checking or re-countering a message without Counter and Crc is a caller's error, named as
    such (it was an AttributeError on None)."""
    sync = CATALOG["SYNC"]
    for call in (
        lambda: E2EProtector().seal(sync, 0),
        lambda: E2EChecker().check(sync, bytes(sync.length)),
        lambda: with_counter(sync, bytes(sync.length), 1),
        lambda: counter_of(sync, bytes(sync.length)),
    ):
        with pytest.raises(ValueError, match="SYNC is not E2E-protected"):
            call()


@pytest.mark.parametrize("name", [c.name for c in CATALOG if is_protected(c)])
def test_a_sealed_frame_carries_the_reference_crc_of_its_id_and_payload(name):
    """E2E works on the payload's bytes (drivers/e2e.py): its CRC is the reference CRC-8/SAE-J1850 (crccheck)
    of the frame id and the payload with the CRC byte zeroed, whatever the counter and the values."""
    codec = CATALOG[name]
    crc_at = codec.field_position("Crc")[0] // 8

    @settings(max_examples=60, deadline=None)
    @given(values=message_values(DB.get_message_by_name(name)), counter=st.integers(0, 15))
    def check(values, counter):
        payload = with_counter(codec, E2EProtector().seal(codec, codec.encode_int(values)), counter)
        zeroed = bytearray(payload)
        zeroed[crc_at] = 0
        assert payload[crc_at] == Crc8SaeJ1850.calc(codec.frame_id.to_bytes(2, "little") + bytes(zeroed))
        assert counter_of(codec, payload) == counter
        checker = E2EChecker()
        assert checker.check(codec, payload).status is E2EStatus.OK
        assert checker.check(codec, with_counter(codec, payload, counter + 1)).status is E2EStatus.OK
        corrupted = bytearray(payload)
        corrupted[0] ^= 0x01
        assert checker.check(codec, bytes(corrupted)).status is E2EStatus.CRC_ERROR

    check()


def test_e2e_fields_off_their_bytes_are_refused_by_name():
    counter = cantools.database.can.Signal("Counter", start=3, length=4)
    crc = cantools.database.can.Signal("Crc", start=9, length=8)
    odd = MessageCodec(cantools.database.can.Message(0x300, "ODD", 4, [counter, crc]))
    with pytest.raises(ValueError, match="ODD: E2E needs its Crc on a byte"):
        is_protected(odd)


# ------------------------------------------------------------------------------------------ buses
@pytest.fixture
def pair():
    config = BusConfig(channel=private_channel("test"))
    a, b = open_bus(config), open_bus(config)
    yield CanNode(a, CATALOG, "a"), CanNode(b, CATALOG, "b"), config
    a.shutdown()
    b.shutdown()


@pytest.mark.parametrize("message", DB.messages, ids=lambda m: m.name)
def test_round_trip_over_the_virtual_bus(pair, message):
    tx, rx, _ = pair

    @settings(max_examples=20, deadline=None)
    @given(values=message_values(message))
    def check(values):
        values = {k: v for k, v in values.items() if k not in ("Counter", "Crc")}
        tx.send(message.name, values)
        got = rx.recv(timeout=1.0)
        assert got is not None and got.name == message.name and got.ok
        for k, v in values.items():
            assert got.signals[k] == pytest.approx(v, abs=1e-9)

    check()
    assert rx.stats.e2e == {} and rx.stats.malformed == {}


@pytest.mark.parametrize("name", ["SYNC", "DRIVE1_COMMAND", "IMU_RATE"])
def test_a_nodes_frame_is_the_one_python_cans_constructor_makes(pair, name):
    """CanNode.message sets a Message's fields one by one (its __init__ is Python): every field must be what
    `can.Message(arbitration_id=..., is_extended_id=False, data=...)` gives."""
    tx, _, _ = pair
    msg = tx.message(name, {})
    made = can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, data=bytes(msg.data))
    assert {f: getattr(msg, f) for f in MESSAGE_FIELDS} == {f: getattr(made, f) for f in MESSAGE_FIELDS}
    assert type(msg.data) is bytearray and msg.equals(made, timestamp_delta=None)


def frames(tx, name, n):
    return [tx.message(name, {"Torque": 0.1 * i, "Tick": i, "Enable": 1}) for i in range(n)]


def statuses(rx, msgs):
    return [rx.decode(m).e2e.status for m in msgs]


def test_e2e_detects_loss_repeat_reorder_and_corruption(pair):
    tx, rx, _ = pair
    m = frames(tx, "DRIVE1_COMMAND", 8)
    assert statuses(rx, [m[0], m[1]]) == [E2EStatus.OK, E2EStatus.OK]
    lost = rx.decode(m[4])  # m[2], m[3] never arrive
    assert lost.e2e.status is E2EStatus.LOST and lost.e2e.lost == 2 and lost.ok
    assert statuses(rx, [m[4]]) == [E2EStatus.REPEATED]
    assert statuses(rx, [m[6], m[5]]) == [E2EStatus.LOST, E2EStatus.OUT_OF_ORDER]
    flipped = m[7].data[:]
    flipped[0] ^= 0x04
    bad = rx.decode(can.Message(arbitration_id=m[7].arbitration_id, is_extended_id=False, data=flipped))
    assert bad.e2e.status is E2EStatus.CRC_ERROR and not bad.ok
    assert statuses(rx, [m[7]]) == [E2EStatus.OK]  # a CRC failure does not disturb the counter
    assert rx.stats.e2e == {
        ("DRIVE1_COMMAND", "LOST"): 2,
        ("DRIVE1_COMMAND", "REPEATED"): 1,
        ("DRIVE1_COMMAND", "OUT_OF_ORDER"): 1,
        ("DRIVE1_COMMAND", "CRC_ERROR"): 1,
    }
    assert rx.stats.lost_frames["DRIVE1_COMMAND"] == 3


def test_e2e_detects_a_masquerading_node(pair):
    # A valid DRIVE1 command replayed under DRIVE2's id fails the CRC (the data id is part of it).
    tx, rx, _ = pair
    m = tx.message("DRIVE1_COMMAND", {"Torque": 1.0, "Tick": 5, "Enable": 1})
    fake = rx.decode(
        can.Message(arbitration_id=CATALOG["DRIVE2_COMMAND"].frame_id, is_extended_id=False, data=m.data)
    )
    assert fake.name == "DRIVE2_COMMAND" and fake.e2e.status is E2EStatus.CRC_ERROR


frame_strategy = st.builds(
    lambda fid, ext, data, err, rtr: can.Message(
        arbitration_id=fid if ext else fid & 0x7FF,
        is_extended_id=ext,
        data=b"" if rtr else data,
        is_error_frame=err,
        is_remote_frame=rtr,
        dlc=len(data),
    ),
    st.one_of(st.sampled_from([c.frame_id for c in CATALOG]), st.integers(0, 0x1FFFFFFF)),
    st.booleans(),
    st.binary(max_size=8),
    st.booleans(),
    st.booleans(),
)


def test_a_drain_reads_past_a_rejected_frame_in_the_same_tick(pair):
    """A malformed frame ahead of good ones must not hold them back until the next drain."""
    tx, rx, _ = pair
    tx.bus.send(can.Message(arbitration_id=0x7F0, is_extended_id=False, data=bytes(8)))  # not in the DBC
    tx.send("SYNC", {"Tick": 7})
    frame = rx.recv(timeout=0.0)
    assert frame is not None and frame.name == "SYNC" and frame.signals["Tick"] == 7
    assert rx.stats.malformed["unknown_id"] == 1 and rx.recv(timeout=0.0) is None


def test_a_flood_of_random_ids_is_counted_but_logged_and_remembered_only_so_far(pair, caplog):
    """A babbling node's random ids: every frame counted; at WARNING only the first WARNED_IDS ids per
    reason (then DEBUG), and the node remembers no more than that (2^29 extended ids would grow it)."""
    tx, rx, _ = pair
    caplog.set_level(logging.DEBUG, logger="drivers.can_bus")
    extended = [0x1000 + 7919 * i for i in range(3000)]
    for frame_id in extended:
        tx.bus.send(can.Message(arbitration_id=frame_id, is_extended_id=True, data=bytes(8)))
    for _ in range(2):  # seen twice: the second time never at WARNING
        tx.bus.send(can.Message(arbitration_id=0x7F0, is_extended_id=False, data=bytes(8)))
    while rx.recv(timeout=0.0) is not None:
        pass
    assert rx.stats.malformed == {"extended_id": 3000, "unknown_id": 2}
    warned = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len([r for r in warned if "extended_id" in r.getMessage()]) == WARNED_IDS
    assert "further ones at DEBUG" in warned[WARNED_IDS - 1].getMessage()
    assert len([r for r in warned if "unknown_id" in r.getMessage()]) == 1, "another reason has its own"
    assert sum(r.levelno == logging.DEBUG for r in caplog.records) == 3000 - WARNED_IDS + 1
    assert sum(map(len, rx._warned.values())) == WARNED_IDS + 1


@pytest.mark.parametrize("interface", ["pure_shared", "virtual"])
def test_a_drain_and_the_recorder_take_the_same_frames_from_either_bus(interface):
    """On the in-process shared bus a node's drain and the recorder take frames from its queue directly;
    on any other bus (python-can's virtual here) through recv: the same frames, in order, hooks applied."""
    channel = private_channel("drain")
    with (
        can.Bus(interface=interface, channel=channel) as a,
        can.Bus(interface=interface, channel=channel) as b,
        can.Bus(interface=interface, channel=channel) as c,
    ):
        tx, rx = CanNode(a, CATALOG, "tx"), CanNode(b, CATALOG, "rx")
        rx.rx_hook = lambda msg: None if msg.arbitration_id == 0x080 and msg.data[0] == 2 else msg
        for tick in (1, 2, 3):
            tx.send("SYNC", {"Tick": tick})
        tx.bus.send(can.Message(arbitration_id=0x7F0, is_extended_id=False, data=bytes(8)))  # not in the DBC
        tx.send("SYNC", {"Tick": 4})
        ticks = []
        while (frame := rx.recv(timeout=0.0)) is not None:
            ticks.append(frame.signals["Tick"])
        assert ticks == [1, 3, 4], "the hook dropped tick 2; the unknown id is counted, not returned"
        assert rx.stats.malformed["unknown_id"] == 1
        seen: list[int] = []

        class Seen(can.Listener):
            def on_message_received(self, msg: can.Message) -> None:
                seen.append(msg.arbitration_id)

        recorder = BusRecorder(BusConfig(interface=interface, channel=channel), None, [Seen()])
        try:
            tx.send("SYNC", {"Tick": 5})
            recorder.poll()
        finally:
            recorder.stop(settle=0.0)
        assert seen == [0x080]
        assert c.recv(0) is not None, "every reader has its own queue"


def test_a_sockets_receive_buffer_is_enlarged_past_the_kernels_default():
    """What open_bus does to a SocketCAN or udp_multicast bus's socket (tests/socketcan checks it on vcan0),
    here on an unbound UDP socket (no traffic): the default holds a few ticks of frames, too few for a
    reader a loaded machine holds back."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        default = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        assert default < RECEIVE_BUFFER, "control: the kernel's default is smaller than what open_bus asks"
        granted = enlarge_receive_buffer(sock)
        assert granted == sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) > default
        limit = int(Path("/proc/sys/net/core/rmem_max").read_text())
        if os.geteuid() == 0:  # past net.core.rmem_max: SO_RCVBUFFORCE, which Python's socket lacks
            assert granted >= RECEIVE_BUFFER
            assert enlarge_receive_buffer(sock, 2 * limit) >= 2 * limit
        else:
            assert granted >= min(RECEIVE_BUFFER, limit)


def test_an_in_process_bus_has_no_socket_and_opens_as_before():
    bus = open_bus(BusConfig(channel=private_channel("rcvbuf")))
    try:
        with pytest.raises(NotImplementedError):
            bus.fileno()
    finally:
        bus.shutdown()


@settings(max_examples=400, deadline=None)
@given(st.lists(frame_strategy, max_size=30))
def test_fuzzed_frames_never_raise_and_are_all_counted(frames_in):
    node = CanNode(None, CATALOG, "fuzz")  # decode only: no bus needed
    results = [node.decode(f) for f in frames_in]
    decoded = sum(r is not None for r in results)
    assert decoded == sum(node.stats.received.values())
    assert len(frames_in) - decoded == sum(node.stats.malformed.values())
    e2e_bad = sum(1 for r in results if r is not None and not r.ok)
    assert e2e_bad <= sum(node.stats.e2e.values())


# --------------------------------------------------------------------------------------- bus load
def test_frame_bits_by_hand():
    # 8 data bytes, 11-bit id: 44 + 64 + 3 = 111 bits + worst stuffing floor((34 + 64 − 1)/4) = 24 -> 135.
    assert frame_bits(8) == 135
    assert frame_bits(0) == 55
    assert frame_bits(8, extended=True) == 160
    with pytest.raises(ValueError):
        frame_bits(9)


def test_catalog_load_at_400_hz_by_hand():
    # Per tick: SYNC(2 B) 75 + 3 feedback 135 + 3 IMU 135 + 3 commands(6 B) 115 + heartbeat(4 B) 95
    # + the recovery law's command (8 B) 135 (worst case: it is sent only during a takeover) = 1460 bits;
    # periodic: e-stop(4 B) 95 and diagnosis(4 B) 95 @ 100 Hz, 3 torque(4 B) 95 @ 100 Hz, operator
    # e-stop(3 B) 85 @ 10 Hz.
    expected = 1460 * 400 + 2 * 95 * 100 + 3 * 95 * 100 + 85 * 10
    load = bus_load(CATALOG, 400.0, 1_000_000)
    assert load.bits_per_second == expected
    assert check_bus_load(CATALOG, 400.0, 1_000_000).fraction == pytest.approx(0.63235)


def test_overloaded_configuration_is_refused_with_the_figure():
    with pytest.raises(
        BusLoadError, match=r"worst-case bus load 92\.4% at 600 Hz tick on 1000 kbit/s exceeds the 70%"
    ):
        check_bus_load(CATALOG, 600.0, 1_000_000)
    with pytest.raises(BusLoadError, match="exceeds the 50% bound"):
        check_bus_load(CATALOG, 400.0, 1_000_000, max_fraction=0.5)


# ---------------------------------------------------------------------------------------- config
def test_can_specs():
    assert parse_can_spec("socketcan:vcan0") == BusConfig(interface="socketcan", channel="vcan0")
    assert parse_can_spec("virtual").interface == "virtual"
    with pytest.raises(BusConfigError, match="only inside a network namespace whose only interface is lo"):
        parse_can_spec("udp_multicast:239.74.163.2")
    with pytest.raises(BusConfigError, match="expected INTERFACE"):
        parse_can_spec(":vcan0")


@pytest.mark.parametrize("suffix", [".log", ".blf", ".asc"])
def test_recorder_tees_all_traffic_into_python_can_logs(pair, tmp_path, suffix):
    tx, rx, config = pair
    path = tmp_path / f"can{suffix}"
    with BusRecorder(config, path) as recorder:
        sent = [tx.message("SYNC", {"Tick": i}) for i in range(5)] + frames(tx, "DRIVE2_COMMAND", 5)
        for m in sent:
            tx.bus.send(m)
        for _ in sent:
            assert rx.bus.recv(1.0) is not None
        recorder.poll()
        assert recorder.frames == len(sent)
    logged = [m for m in can.LogReader(str(path)) if not m.is_error_frame]
    assert [(m.arbitration_id, bytes(m.data)) for m in logged] == [
        (m.arbitration_id, bytes(m.data)) for m in sent
    ]
    if suffix == ".log":  # candump -L format: "(time) channel ID#DATA"
        first = path.read_text().splitlines()[0]
        assert first.startswith("(") and " 080#0000" in first
    assert list(itertools.islice(can.LogReader(str(path)), 1))


class FullQueueBus(can.BusABC):
    """A bus whose transmit queue is full, as SocketCAN reports it with a real qdisc (ENOBUFS)."""

    def __init__(self):
        super().__init__(channel="full")

    def send(self, msg, timeout=None):
        raise can.CanOperationError("Failed to transmit: No buffer space available", error_code=105)

    def _recv_internal(self, timeout):
        return None, False


def test_a_refused_frame_is_counted_not_raised():
    node = CanNode(FullQueueBus(), name="tx")
    assert node.send("SYNC", {"Tick": 1}) is False
    assert node.send("SYNC", {"Tick": 2}) is False
    assert node.stats.send_errors["SYNC"] == 2 and node.stats.sent["SYNC"] == 0
    assert node.stats.as_dict()["send_errors"] == {"SYNC": 2}


def test_private_channels_never_end_in_digits():
    # python-can's BLF writer reads trailing digits as a channel number (and fails above 65535).
    names = {private_channel("x") for _ in range(200)}
    assert len(names) == 200 and not any(n[-1].isdigit() for n in names)
    assert can.util.channel2int(private_channel()) is None


def test_message_names_are_exactly_the_dbcs():
    from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MessageName

    assert {m.value for m in MessageName} == {codec.name for codec in Catalog()}
    for kind, group in (("COMMAND", DRIVE_COMMAND), ("FEEDBACK", DRIVE_FEEDBACK), ("TORQUE", DRIVE_TORQUE)):
        assert [str(m) for m in group] == [f"DRIVE{i}_{kind}" for i in (1, 2, 3)]


def test_diagnosis_parts_are_exactly_the_dbcs_flags():
    from drivers.can_codec import ENCODERS, PARTS, TILT_INPUTS, MessageName

    signals = Catalog()[MessageName.SUPERVISOR_DIAGNOSIS].signal_names
    assert list(PARTS) == [name for name in signals if name not in ("Alert", "Counter", "Crc")]
    assert set(ENCODERS) | {name for plane in TILT_INPUTS for name in plane} <= set(PARTS)
