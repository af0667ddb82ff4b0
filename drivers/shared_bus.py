"""An in-process CAN bus whose receivers share one frame: python-can interface `pure_shared`.

python-can's `virtual` bus deep-copies every frame for every receiver (about 5 us each; with the rig, the
controller, the supervisor and the log recorder on one channel that is most of a frame's cost). Here a send
makes one frame (stamped, marked received) and hands that same object to every other bus on the channel
whose receive filters accept it. Receivers must treat frames as read-only, as a node does anyway (a fault
that alters a frame builds a new one).

Registered under python-can's `can.interface` entry point, so any python-can user in the process opens it
by name: `can.Bus(interface="pure_shared", channel="bench", can_filters=[...])`. Filters are applied when
a frame is sent, so a node never wakes for (or decodes) a frame it does not read; exact standard ids take
a set lookup. (Where python-can filters in software, as on `virtual`, `recv(timeout=0)` returns None at
the first frame a filter rejects, even with accepted frames queued behind it: a drain loop stops early.)
"""

from __future__ import annotations

import queue
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any, Generic, TypeVar

import can

B = TypeVar("B", bound=can.BusABC)


class _Buses(Generic[B]):
    """The buses on one shared thing (a channel, a socket), held weakly (a bus its owner forgot to shut down
    is collected, as python-can expects, instead of living on here): a tuple replaced, never changed in
    place, when one opens or goes, so a send or a read iterates it without a lock. The last one gone takes
    this out of `registry`, under `key`."""

    def __init__(self, key: Any, registry: dict[Any, Any]) -> None:
        self.key, self._registry = key, registry
        self.buses: tuple[weakref.ref[B], ...] = ()

    def add(self, bus: B) -> None:
        with _lock:
            self.buses += (weakref.ref(bus, self._remove),)

    def remove(self, bus: B) -> None:
        self._remove(next((ref for ref in self.buses if ref() is bus), None))

    def _remove(self, gone: weakref.ref[B] | None) -> None:
        with _lock:
            self.buses = tuple(ref for ref in self.buses if ref is not gone and ref() is not None)
            if self.buses or self._registry.get(self.key) is not self:
                return
            del self._registry[self.key]
        self._emptied()

    def _emptied(self) -> None:
        """The last bus has gone."""


_channels: dict[Any, _Buses[SharedBus]] = {}
_lock = threading.RLock()


class SharedBus(can.BusABC):
    def __init__(
        self,
        channel: Any = "channel-0",
        receive_own_messages: bool = False,
        can_filters: can.typechecking.CanFilters | None = None,
        **kwargs: Any,
    ):
        self.channel_id = channel
        self.channel_info = f"shared in-process bus channel {channel}"
        self.receive_own_messages = receive_own_messages
        self.frames: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        """What this bus received and nobody has taken yet, in order. A reader on the hot path may take from
        it directly (`empty()`, then `get_nowait()`: what `recv(0)` does, without a Python call per frame;
        drivers/can_bus.py's nodes do)."""
        self._ids: frozenset[int] | None = None
        """The filters as a set of exact standard ids, when they are that (the common case); else None."""
        self._open = True
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        with _lock:
            self._channel = _channels.setdefault(channel, _Buses(channel, _channels))
            self._channel.add(self)

    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        if filters is not None and all(
            f["can_mask"] == 0x7FF and not f.get("extended", False) for f in filters
        ):
            self._ids = frozenset(f["can_id"] for f in filters)
        else:
            self._ids = None

    def _check_if_open(self) -> None:
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")

    def recv(self, timeout: float | None = None) -> can.Message | None:
        # Frames were filtered when sent: BusABC.recv's filter loop and its per-frame debug log call were
        # most of a receive's cost (0.41 -> 0.09 us a frame). The tick's drains (timeout 0) take the short
        # path: about 40 a tick, each ending on an empty queue (a check, not an exception raised and caught).
        if timeout is not None and timeout <= 0 and self._open:
            frames = self.frames
            return None if frames.empty() else frames.get_nowait()
        return self._recv_internal(timeout)[0]

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._check_if_open()
        try:
            if timeout is not None and timeout <= 0:
                return (None if self.frames.empty() else self.frames.get_nowait()), True
            return self.frames.get(timeout=timeout), True
        except queue.Empty:  # timed out, or another reader of this bus took the frame
            return None, True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        frame = _received_copy(msg, self.channel_id)
        extended, frame_id = frame.is_extended_id, frame.arbitration_id
        for ref in self._channel.buses:
            bus = ref()
            if bus is None or (bus is self and not self.receive_own_messages):
                continue
            ids = bus._ids  # exact ids (a set look-up), no filters (every frame) or python-can's own matching
            if ids is not None:
                if extended or frame_id not in ids:
                    continue
            elif bus._filters is not None and not bus._matches_filters(frame):
                continue
            bus.frames.put(frame)

    def shutdown(self) -> None:
        super().shutdown()
        if self._open:
            self._open = False
            self._channel.remove(self)


MESSAGE_FIELDS = (
    "timestamp",
    "arbitration_id",
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "channel",
    "dlc",
    "data",
    "is_fd",
    "is_rx",
    "bitrate_switch",
    "error_state_indicator",
)
"""Every field of a python-can Message (its __slots__ but __weakref__): _received_copy sets each one, the
run's log writer process rebuilds frames from them (tests/test_shared_bus.py holds this list to
python-can's)."""


def _received_copy(msg: can.Message, channel: Any) -> can.Message:
    """The frame the receivers get: `msg` stamped now, on this channel, marked received, with its own data
    (the sender may reuse its message). Built field by field: Message.__init__ with every keyword was a
    third of a shared send (1.8 of ~5 us)."""
    frame = can.Message.__new__(can.Message)
    frame.timestamp = time.time()
    frame.arbitration_id = msg.arbitration_id
    frame.is_extended_id = msg.is_extended_id
    frame.is_remote_frame = msg.is_remote_frame
    frame.is_error_frame = msg.is_error_frame
    frame.channel = channel
    frame.dlc = msg.dlc
    frame.data = bytearray(msg.data)
    frame.is_fd = msg.is_fd
    frame.is_rx = True
    frame.bitrate_switch = msg.bitrate_switch
    frame.error_state_indicator = msg.error_state_indicator
    return frame


# ------------------------------------------------------------------------------ one socket per process
SHARED_SOCKET_INTERFACES = frozenset({"udp_multicast"})
"""Interfaces whose every socket in the group receives every frame, its own sends included (python-can's
udp_multicast: multicast loop-back): a process's nodes share one socket (`SocketView`), each frame read
once. SocketCAN keeps a socket per node (the kernel does not echo a frame to the socket that sent it)."""

WAIT_SLICE = 0.05
"""s a blocking reader waits on the shared socket at most before it looks at its own queue again (another
thread may have read its frame meanwhile)."""


class _Socket(_Buses["SocketView"]):
    """One real bus of this process and the views reading it: whoever reads hands each frame to every view
    whose filters take it (one `recvmsg` and one unpack a frame, not one per node)."""

    def __init__(self, key: tuple[Any, ...], bus: can.BusABC) -> None:
        super().__init__(key, _sockets)
        self.bus = bus
        self.reading = threading.Lock()

    def read(self, timeout: float) -> None:
        """Everything the socket holds now, waiting up to `timeout` for the first frame; the caller holds
        `reading`."""
        msg = self.bus.recv(timeout)
        while msg is not None:
            for ref in self.buses:
                view = ref()
                if view is not None and (view._filters is None or view._matches_filters(msg)):
                    view.frames.put(msg)
            msg = self.bus.recv(0.0)

    def _emptied(self) -> None:
        self.bus.shutdown()


_sockets: dict[tuple[Any, ...], _Socket] = {}


class SocketView(can.BusABC):
    """A node's bus on a socket this process shares (`shared_socket`). Receives what the socket receives, its
    own sends included, as a socket of its own on that interface would; frames are shared read-only, as on
    SharedBus. Sends go out on the shared socket."""

    def __init__(self, shared: _Socket, can_filters: can.typechecking.CanFilters | None = None) -> None:
        self._socket = shared
        self.frames: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self.channel_info = f"{shared.bus.channel_info} (shared by this process's nodes)"
        self._open = True
        super().__init__(channel=shared.key[1], can_filters=can_filters)
        shared.add(self)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")
        frames = self.frames
        if not frames.empty():  # the hot path: a frame another view's read brought
            return frames.get_nowait()
        shared = self._socket
        deadline = None if timeout is None else time.monotonic() + max(timeout, 0.0)
        while frames.empty():
            wait = WAIT_SLICE if deadline is None else min(max(deadline - time.monotonic(), 0.0), WAIT_SLICE)
            if shared.reading.acquire(timeout=wait):  # one reader at a time; 0: only if nobody reads
                try:
                    if frames.empty():  # else another reader brought it while this one waited
                        shared.read(wait)
                finally:
                    shared.reading.release()
            if deadline is not None and time.monotonic() >= deadline:
                break
        return None if frames.empty() else frames.get_nowait()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(timeout), True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")
        self._socket.bus.send(msg, timeout)

    def fileno(self) -> int:
        return -1  # the shared socket is its owner's (its receive buffer was set when it opened)

    def shutdown(self) -> None:
        super().shutdown()
        if self._open:
            self._open = False
            self._socket.remove(self)


def shared_socket(key: tuple[Any, ...], opened: Callable[[], can.BusABC]) -> SocketView:
    """A view on this process's socket for `key` (interface, channel, options), opened by `opened()` the first
    time."""
    with _lock:
        shared = _sockets.get(key)
        if shared is None:
            shared = _sockets[key] = _Socket(key, opened())
    return SocketView(shared)
