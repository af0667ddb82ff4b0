"""Nodes of one DBC share its codecs, and a payload every reader decodes is decoded once
(MessageCodec.decode_shared): each receiver still gets signals of its own and checks E2E for itself, a
changed payload is decoded afresh, and a node on another DBC is never served the default DBC's signals."""

import can
import pytest

from drivers.can_bus import CanNode, private_channel
from drivers.can_codec import DEFAULT_DBC, Catalog, MessageName
from drivers.e2e import E2EStatus

FEEDBACK = MessageName.DRIVE1_FEEDBACK


def feedback(tx: CanNode, position: int) -> can.Message:
    return tx.message(FEEDBACK, {"Position": position, "Velocity": 1.25, "Enabled": 1})


def test_catalogs_of_one_dbc_share_its_codecs():
    assert Catalog()[FEEDBACK] is Catalog(str(DEFAULT_DBC))[FEEDBACK]


def test_a_frame_read_by_two_nodes_on_the_shared_bus_is_decoded_once():
    channel = private_channel("decode")
    with (
        can.Bus(interface="pure_shared", channel=channel) as tx_bus,
        can.Bus(interface="pure_shared", channel=channel) as a_bus,
        can.Bus(interface="pure_shared", channel=channel) as b_bus,
    ):
        tx, a, b = CanNode(tx_bus, name="tx"), CanNode(a_bus, name="a"), CanNode(b_bus, name="b")
        tx.send(FEEDBACK, {"Position": 7, "Velocity": 1.25})
        got_a, got_b = a.recv(0.0), b.recv(0.0)
        assert got_a is not None and got_b is not None
        assert got_a.signals == got_b.signals
        assert got_a.signals["Position"] == 7 and got_a.signals["Velocity"] == pytest.approx(1.25)
        assert got_a.e2e == got_b.e2e and got_a.ok
        got_a.signals["Position"] = 99  # a reader (a controller under test) that changes what it got
        assert got_b.signals["Position"] == 7, "the other reader's signals are its own"
        tx.send(FEEDBACK, {"Position": 7, "Velocity": 1.25})  # the same payload, the codec's copy reused
        assert b.recv(0.0).signals["Position"] == 7


def test_each_reader_checks_e2e_for_itself():
    tx, a, b = CanNode(None, name="tx"), CanNode(None, name="a"), CanNode(None, name="b")
    m = [feedback(tx, i) for i in range(3)]
    assert [a.decode(f).e2e.status for f in m] == [E2EStatus.OK] * 3
    # b never saw m[1]: the payload a decoded last is b's next, and b alone finds the loss.
    assert b.decode(m[0]).e2e.status is E2EStatus.OK
    lost = b.decode(m[2])
    assert lost.signals == a.decode(m[2]).signals
    assert lost.e2e.status is E2EStatus.LOST and lost.e2e.lost == 1
    assert b.stats.e2e == {(FEEDBACK, "LOST"): 1} and b.stats.lost_frames[FEEDBACK] == 1
    assert a.stats.e2e == {(FEEDBACK, "REPEATED"): 1}, "a's repeat of m[2] is a's own"
    assert b.decode(m[2]).e2e.status is E2EStatus.REPEATED
    assert b.stats.e2e == {(FEEDBACK, "LOST"): 1, (FEEDBACK, "REPEATED"): 1}
    assert a.stats.e2e == {(FEEDBACK, "REPEATED"): 1}


def test_a_changed_payload_is_decoded_afresh():
    tx, a, b = CanNode(None, name="tx"), CanNode(None, name="a"), CanNode(None, name="b")
    first = feedback(tx, 100)
    seen = a.decode(first).signals
    assert seen["Position"] == 100
    second = feedback(tx, 200)  # a new frame
    assert b.decode(second).signals["Position"] == 200
    altered = feedback(tx, 300)
    before = a.decode(altered).signals
    altered.data[0] ^= 0x01  # the same frame object, one bit changed in place
    after = b.decode(altered)
    assert after.signals["Position"] == 301 and before["Position"] == 300
    assert after.e2e.status is E2EStatus.CRC_ERROR
    assert seen["Position"] == 100, "a served dict never changes afterwards"


def test_an_equal_payload_in_another_frame_is_served_the_same_signals():
    codec = Catalog()[FEEDBACK]
    data = feedback(CanNode(None), 5).data
    first, again = codec.decode_shared(bytes(data)), codec.decode_shared(bytearray(data))
    assert first == again and first is not again
    assert codec.decode_shared(data) == codec.decode(data)


def test_a_wrong_length_is_rejected_not_cached():
    tx, rx = CanNode(None, name="tx"), CanNode(None, name="rx")
    good = feedback(tx, 9)
    assert rx.decode(good) is not None
    short = can.Message(arbitration_id=good.arbitration_id, is_extended_id=False, data=good.data[:7])
    assert rx.decode(short) is None and rx.stats.malformed["wrong_length"] == 1


def _other_dbc(path, velocity_scale: str):
    """The default DBC with DRIVE1_FEEDBACK's Velocity at another scale."""
    text = DEFAULT_DBC.read_text(encoding="cp1252")
    line = ' SG_ Velocity : 32|16@1- (0.01,0) [-327.68|327.67] "rad/s" CONTROLLER,SUPERVISOR'
    assert text.count(line) == 3  # every drive's feedback; only the first is DRIVE1_FEEDBACK's
    path.write_text(
        text.replace(line, line.replace("(0.01,0)", f"({velocity_scale},0)"), 1), encoding="cp1252"
    )
    return path


def test_a_node_on_another_dbc_is_not_served_the_default_dbcs_signals(tmp_path):
    other = Catalog(_other_dbc(tmp_path / "other.dbc", "0.1"))
    assert other[FEEDBACK] is not Catalog()[FEEDBACK]
    tx, default_rx = CanNode(None, name="tx"), CanNode(None, name="default")
    other_rx = CanNode(None, other, name="other")
    frame = tx.message(FEEDBACK, {"Velocity": 1.25})
    assert default_rx.decode(frame).signals["Velocity"] == pytest.approx(1.25)
    assert other_rx.decode(frame).signals["Velocity"] == pytest.approx(12.5)
    assert default_rx.decode(frame).signals["Velocity"] == pytest.approx(1.25)


def test_a_dbc_rewritten_in_place_is_loaded_afresh(tmp_path):
    path = _other_dbc(tmp_path / "other.dbc", "0.1")
    before = Catalog(path)
    _other_dbc(path, "0.5")
    after = Catalog(path)
    assert after[FEEDBACK] is not before[FEEDBACK]
    data = CanNode(None).message(FEEDBACK, {"Velocity": 1.25}).data
    assert before[FEEDBACK].decode_shared(data)["Velocity"] == pytest.approx(12.5)
    assert after[FEEDBACK].decode_shared(data)["Velocity"] == pytest.approx(62.5)
