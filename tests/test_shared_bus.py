"""The in-process shared bus (drivers/shared_bus.py), opened by name through python-can."""

from __future__ import annotations

import threading

import can
import pytest

from drivers.can_bus import private_channel
from drivers.shared_bus import MESSAGE_FIELDS, SharedBus


@pytest.fixture
def channel():
    return private_channel("shared")


def frame(can_id: int, data: bytes = b"\x01\x02") -> can.Message:
    return can.Message(arbitration_id=can_id, is_extended_id=False, data=data)


def test_python_can_opens_it_by_name(channel):
    with can.Bus(interface="pure_shared", channel=channel) as bus:
        assert isinstance(bus, SharedBus)


def test_every_other_bus_on_the_channel_gets_one_shared_frame(channel):
    a, b, c = (can.Bus(interface="pure_shared", channel=channel) for _ in range(3))
    other = can.Bus(interface="pure_shared", channel=private_channel("other"))
    try:
        sent = frame(0x181)
        a.send(sent)
        got_b, got_c = b.recv(0), c.recv(0)
        assert got_b is got_c  # one frame for every receiver: no copy per receiver
        assert (got_b.arbitration_id, bytes(got_b.data), got_b.is_rx) == (0x181, b"\x01\x02", True)
        assert got_b.timestamp > 0 and got_b.channel == channel
        assert a.recv(0) is None  # not its own frame
        assert other.recv(0) is None  # not another channel's
        sent.data[0] = 0xFF  # the sender reuses its message
        assert bytes(got_b.data) == b"\x01\x02"
    finally:
        for bus in (a, b, c, other):
            bus.shutdown()


def test_a_received_frame_carries_every_field_of_the_sent_one(channel):
    """The receivers' copy is built field by field (drivers/shared_bus.py): a field python-can adds to its
    Message must be copied too, so the list is held to python-can's own slots."""
    assert set(MESSAGE_FIELDS) == set(can.Message.__slots__) - {"__weakref__"}
    a, b = (can.Bus(interface="pure_shared", channel=channel) for _ in range(2))
    try:
        sent = can.Message(
            arbitration_id=0x1ABCDE,
            is_extended_id=True,
            data=bytes(range(12)),
            dlc=12,
            is_fd=True,
            bitrate_switch=True,
            error_state_indicator=True,
            is_rx=False,
        )
        a.send(sent)
        got = b.recv(0)
        assert got.equals(sent, timestamp_delta=None, check_channel=False, check_direction=False)
        assert (got.is_rx, got.channel, got.dlc) == (True, channel, 12)
        remote = can.Message(arbitration_id=0x10, is_extended_id=False, is_remote_frame=True, dlc=4)
        a.send(remote)
        assert b.recv(0).equals(remote, timestamp_delta=None, check_channel=False, check_direction=False)
    finally:
        a.shutdown()
        b.shutdown()


def test_receive_own_messages_on_request(channel):
    with can.Bus(interface="pure_shared", channel=channel, receive_own_messages=True) as bus:
        bus.send(frame(0x10))
        assert bus.recv(0).arbitration_id == 0x10


def test_filters_apply_at_send_so_a_filtered_bus_never_queues_the_frame(channel):
    tx = can.Bus(interface="pure_shared", channel=channel)
    only_sync = can.Bus(
        interface="pure_shared", channel=channel, can_filters=[{"can_id": 0x080, "can_mask": 0x7FF}]
    )
    everything = can.Bus(interface="pure_shared", channel=channel)
    try:
        tx.send(frame(0x181))
        tx.send(frame(0x080))
        assert only_sync.frames.qsize() == 1  # the 0x181 never reached its queue
        assert only_sync.recv(0).arbitration_id == 0x080
        assert [everything.recv(0).arbitration_id for _ in range(2)] == [0x181, 0x080]  # positive control
    finally:
        for bus in (tx, only_sync, everything):
            bus.shutdown()


def test_a_blocking_recv_wakes_on_a_send_from_another_thread(channel):
    tx, rx = (can.Bus(interface="pure_shared", channel=channel) for _ in range(2))
    try:
        timer = threading.Timer(0.05, tx.send, args=(frame(0x200),))
        timer.start()
        got = rx.recv(2.0)  # None had it slept through its timeout instead of waking on the send
        assert got is not None and got.arbitration_id == 0x200
        assert rx.recv(0.01) is None
    finally:
        tx.shutdown()
        rx.shutdown()


def test_a_bus_shut_down_leaves_the_channel_and_refuses_to_send(channel):
    a, b = (can.Bus(interface="pure_shared", channel=channel) for _ in range(2))
    b.shutdown()
    a.send(frame(0x1))  # nobody left to receive: not an error
    with pytest.raises(can.CanOperationError):
        b.send(frame(0x1))
    c = can.Bus(interface="pure_shared", channel=channel)
    a.send(frame(0x2))
    assert c.recv(0).arbitration_id == 0x2
    a.shutdown()
    c.shutdown()


def test_a_bus_never_shut_down_is_collected_not_kept_by_the_channel(channel):
    import gc

    from drivers import shared_bus

    kept = can.Bus(interface="pure_shared", channel=channel)
    forgotten = can.Bus(interface="pure_shared", channel=channel)
    forgotten._is_shutdown = True  # so python-can's __del__ does not shut it down: only the weak ref can go
    del forgotten
    gc.collect()
    assert len(shared_bus._channels[channel].buses) == 1
    kept.send(frame(0x3))  # the dead entry is skipped
    kept.shutdown()
    assert channel not in shared_bus._channels  # control: the last bus out removes the channel


def test_masked_filters_follow_python_cans_rule(channel):
    tx = can.Bus(interface="pure_shared", channel=channel)
    block = can.Bus(
        interface="pure_shared", channel=channel, can_filters=[{"can_id": 0x180, "can_mask": 0x7F0}]
    )
    try:
        for can_id in (0x181, 0x18F, 0x190, 0x080):
            tx.send(frame(can_id))
        assert [block.recv(0).arbitration_id for _ in range(2)] == [0x181, 0x18F]
        assert block.recv(0) is None
    finally:
        tx.shutdown()
        block.shutdown()
