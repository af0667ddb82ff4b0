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
from typing import Any

import can


class _Channel:
    """The buses on one channel, held weakly (a bus its owner forgot to shut down is collected, as python-can
    expects, instead of living on here): a tuple replaced, never changed in place, when one opens or goes,
    so a send iterates it without a lock."""

    def __init__(self, name: Any) -> None:
        self.name = name
        self.buses: tuple[weakref.ref[SharedBus], ...] = ()

    def add(self, bus: SharedBus) -> None:
        with _lock:
            self.buses += (weakref.ref(bus, self._remove),)

    def _remove(self, gone: weakref.ref[SharedBus] | None) -> None:
        with _lock:
            self.buses = tuple(ref for ref in self.buses if ref is not gone and ref() is not None)
            if not self.buses and _channels.get(self.name) is self:
                del _channels[self.name]

    def remove(self, bus: SharedBus) -> None:
        self._remove(next((ref for ref in self.buses if ref() is bus), None))


_channels: dict[Any, _Channel] = {}
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
        self._queue: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self._ids: frozenset[int] | None = None
        """The filters as a set of exact standard ids, when they are that (the common case); else None."""
        self._open = True
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        with _lock:
            self._channel = _channels.setdefault(channel, _Channel(channel))
            self._channel.add(self)

    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        if filters is not None and all(
            f["can_mask"] == 0x7FF and not f.get("extended", False) for f in filters
        ):
            self._ids = frozenset(f["can_id"] for f in filters)
        else:
            self._ids = None

    def _accepts(self, frame: can.Message) -> bool:
        if self._ids is not None:
            return not frame.is_extended_id and frame.arbitration_id in self._ids
        return self._matches_filters(frame)

    def _check_if_open(self) -> None:
        if not self._open:
            raise can.CanOperationError("Cannot operate on a closed bus")

    def recv(self, timeout: float | None = None) -> can.Message | None:
        # Frames were filtered when sent: BusABC.recv's filter loop and its per-frame debug log call were
        # most of a receive's cost (0.41 -> 0.09 us a frame).
        return self._recv_internal(timeout)[0]

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._check_if_open()
        try:
            if timeout is not None and timeout <= 0:
                # Every drain of the tick ends on an empty queue: not an exception raised and caught.
                return (None if self._queue.empty() else self._queue.get_nowait()), True
            return self._queue.get(timeout=timeout), True
        except queue.Empty:  # timed out, or another reader of this bus took the frame
            return None, True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        frame = can.Message(
            timestamp=time.time(),
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            is_error_frame=msg.is_error_frame,
            channel=self.channel_id,
            dlc=msg.dlc,
            data=bytes(msg.data),  # the sender may reuse its message
            is_fd=msg.is_fd,
            bitrate_switch=msg.bitrate_switch,
            error_state_indicator=msg.error_state_indicator,
            is_rx=True,
            check=False,
        )
        for ref in self._channel.buses:
            bus = ref()
            if bus is not None and (bus is not self or self.receive_own_messages) and bus._accepts(frame):
                bus._queue.put(frame)

    def shutdown(self) -> None:
        super().shutdown()
        if self._open:
            self._open = False
            self._channel.remove(self)
