"""CAN buses in python-can's own terms, and a node's typed, E2E-protected view of one.

`open_bus` hands a `BusConfig` (drivers/bus_config.py: a python-can interface, channel, bitrate and extra
kwargs) to `can.Bus`, which picks and imports the backend lazily by name. `CanNode` sends catalog messages
with their alive counter and CRC filled in, and turns received frames into typed results, counting (never
raising on) unknown ids, wrong lengths, error frames and E2E events. `BusRecorder` tees all traffic of a
channel into a python-can logger (.blf, .asc, .log candump format, ... chosen by file suffix) and any further
listeners.
"""

from __future__ import annotations

import errno
import logging
import os
import queue
import socket
import sys
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import can
from mypy_extensions import mypyc_attr

from drivers.bus_config import BusConfig, BusConfigError
from drivers.can_codec import CanCodecError, Catalog, MessageCodec
from drivers.e2e import E2EChecker, E2EEvent, E2EProtector, E2EStatus, is_protected
from drivers.shared_bus import SHARED_SOCKET_INTERFACES, SharedBus, shared_socket

log = logging.getLogger(__name__)


def private_channel(prefix: str = "pure") -> str:
    """A fresh in-process channel name. It never ends in digits: python-can's log writers (BLF)
    read trailing digits as a channel number and fail on one above 65535."""
    return f"{prefix}-{uuid.uuid4().hex[:12]}-vbus"


def queued_frames(bus: can.BusABC) -> queue.SimpleQueue[can.Message] | None:
    """The receive queue of an in-process shared bus (drivers/shared_bus.py), which the tick's drains take
    from directly, without a Python `recv` call a frame, about 40 a tick (what it had queued stays there
    after a shutdown, where its `recv` would raise); None for any other bus (its own `recv(0)`)."""
    return bus.frames if isinstance(bus, SharedBus) else None


WARNED_IDS = 16
"""Frame ids a node logs at WARNING per reason (unknown id, E2E error, ...), the first time each is seen."""


class BusUnavailable(BusConfigError):
    """The configured bus cannot open on this machine (the message says why and what to do)."""


_WHY = {
    errno.EAFNOSUPPORT: (
        "this kernel has no SocketCAN",
        "load it (modprobe can-raw vcan) or use a machine with CAN; without CAN use --can pure_shared",
    ),
    errno.ENODEV: ("no such interface", "create it: ip link add dev {ch} type vcan && ip link set {ch} up"),
    errno.ENETDOWN: ("the interface is down", "ip link set {ch} up"),
    errno.EPERM: ("permission denied", "run as a user allowed to open raw CAN sockets"),
    errno.EACCES: ("permission denied", "run as a user allowed to open raw CAN sockets"),
}


RECEIVE_BUFFER = 4 * 1024 * 1024
"""Bytes of kernel receive buffer asked for on a bus with a socket (SocketCAN, udp_multicast). Linux's default
(net.core.rmem_default, ~208 KiB) holds ~300 CAN frames, under 10 ticks of a bench's traffic: a reader that
a loaded machine holds back for longer lost a burst of frames, which the 4-bit E2E counter can alias. 4 MiB
holds ~140 ticks (~0.35 s at 400 Hz)."""


_SO_RCVBUFFORCE_LINUX = 33
"""<asm-generic/socket.h>; Python's socket module does not export it."""


def enlarge_receive_buffer(sock: socket.socket, size: int = RECEIVE_BUFFER) -> int:
    """Ask for `size` bytes of receive buffer on `sock`; the bytes the kernel grants (Linux reports twice the
    request, its bookkeeping included). SO_RCVBUFFORCE (CAP_NET_ADMIN) passes net.core.rmem_max; without it,
    SO_RCVBUF is capped there."""
    force = getattr(socket, "SO_RCVBUFFORCE", _SO_RCVBUFFORCE_LINUX if sys.platform == "linux" else None)
    try:
        if force is None:
            raise PermissionError
        sock.setsockopt(socket.SOL_SOCKET, force, size)
    except PermissionError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def _enlarge_bus_buffer(bus: can.BusABC, where: str) -> None:
    try:
        fd = bus.fileno()
    except NotImplementedError:  # no socket: the in-process bus queues without bound
        return
    if fd < 0:
        return
    # The bus's own socket, through a duplicate of its descriptor: python-can's public BusABC.fileno(), not
    # a backend's private attribute.
    with socket.socket(fileno=os.dup(fd)) as sock:
        granted = enlarge_receive_buffer(sock)
    if granted < RECEIVE_BUFFER:
        log.warning(
            "CAN bus %s: receive buffer %d bytes, asked for %d; a reader held back longer loses frames "
            "(raise net.core.rmem_max, or run with CAP_NET_ADMIN)",
            where,
            granted,
            RECEIVE_BUFFER,
        )


def open_bus(config: BusConfig) -> can.BusABC:
    """python-can's bus for `config`, with a receive buffer of RECEIVE_BUFFER where it has a socket;
    BusUnavailable (one line: the bus, the cause, the fix) when it cannot open here. On an interface whose
    sockets each receive every frame (SHARED_SOCKET_INTERFACES), the nodes of one process share one socket."""
    if config.interface in SHARED_SOCKET_INTERFACES:
        key = (config.interface, config.channel, config.bitrate, repr(sorted(config.kwargs.items())))
        return shared_socket(key, lambda: _open_bus(config))
    return _open_bus(config)


def _open_bus(config: BusConfig) -> can.BusABC:
    try:
        bus = can.Bus(
            interface=config.interface, channel=config.channel, bitrate=config.bitrate, **config.kwargs
        )
    except (OSError, can.CanError, ImportError, ValueError) as exc:
        where = f"{config.interface}:{config.channel}"
        code = getattr(exc, "errno", None) or getattr(exc, "error_code", None)
        if code in _WHY:
            why, fix = _WHY[code]
            raise BusUnavailable(
                f"CAN bus {where} cannot open: {why}; {fix.format(ch=config.channel)}"
            ) from exc
        raise BusUnavailable(f"CAN bus {where} cannot open: {exc}") from exc
    _enlarge_bus_buffer(bus, f"{config.interface}:{config.channel}")
    return bus


class Received:
    """A decoded frame (a plain class, not a NamedTuple: one is made for every frame a node reads, and the
    compiled build gives a plain class a native constructor)."""

    def __init__(
        self, name: str, signals: dict[str, float | int], timestamp: float, e2e: E2EEvent | None
    ) -> None:
        self.name = name
        self.signals = signals
        """This node's own (MessageCodec.decode_shared copies a payload's decode for each reader)."""
        self.timestamp = timestamp
        self.e2e = e2e
        """None for unprotected messages (SYNC)."""

    @property
    def ok(self) -> bool:
        """Content can be trusted (unprotected, or E2E OK or LOST: a fresh frame after a gap)."""
        return self.e2e is None or self.e2e.status in (E2EStatus.OK, E2EStatus.LOST)

    def __repr__(self) -> str:
        return f"Received({self.name!r}, {self.signals!r}, {self.timestamp!r}, {self.e2e!r})"


@dataclass(slots=True)
class BusStats:
    received: Counter[str] = field(default_factory=Counter)
    """Frames decoded, per message."""
    e2e: Counter[tuple[str, str]] = field(default_factory=Counter)
    """(message, E2E status) for every status other than OK."""
    lost_frames: Counter[str] = field(default_factory=Counter)
    malformed: Counter[str] = field(default_factory=Counter)
    """Undecodable frames by reason: unknown_id, wrong_length, error_frame, remote, extended_id."""
    sent: Counter[str] = field(default_factory=Counter)
    send_errors: Counter[str] = field(default_factory=Counter)
    """Frames the bus refused (transmit queue full, bus-off), per message."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "sent": dict(self.sent),
            "received": dict(self.received),
            "e2e": {f"{m}:{s}": n for (m, s), n in self.e2e.items()},
            "lost_frames": dict(self.lost_frames),
            "malformed": dict(self.malformed),
            "send_errors": dict(self.send_errors),
        }


@mypyc_attr(allow_interpreted_subclasses=True)  # a device profile's ProfileNode (drivers/devices) is one
class CanNode:
    """One node on a bus: typed send with E2E protection, typed receive that never raises."""

    def __init__(self, bus: can.BusABC, catalog: Catalog | None = None, name: str = "node"):
        self.bus = bus
        self.catalog = catalog or Catalog()
        self.name = name
        self.stats = BusStats()
        self._protector = E2EProtector()
        self._checker = E2EChecker()
        self._codecs = {c.frame_id: (c, is_protected(c)) for c in self.catalog}
        """frame id -> (codec, E2E-protected): one lookup per received frame."""
        self._outgoing = {c.name: (c, protected) for c, protected in self._codecs.values()}
        """message name -> (codec, E2E-protected): one lookup per sent frame."""
        self._warned: dict[str, set[int]] = {}
        """Per reason, the frame ids already logged at WARNING (at most WARNED_IDS each)."""
        self.tx_hook: Callable[[str, can.Message], Iterable[can.Message]] | None = None
        """Sees every frame `send` makes and returns the frames to put on the bus instead (fault injection:
        none, altered, several)."""
        self.rx_hook: Callable[[can.Message], can.Message | None] | None = None
        """Sees every received frame before decoding; returns it (maybe altered) or None (lost)."""
        self._queued = queued_frames(bus)

    def message(self, name: str, values: Mapping[str, float]) -> can.Message:
        codec, protected = self._outgoing[name]
        raw = codec.encode_int(values)
        if protected:
            payload = self._protector.seal(codec, raw)
        else:
            payload = raw.to_bytes(codec.length, "little")
        # What can.Message(arbitration_id=..., is_extended_id=False, data=payload) makes, field by field:
        # its __init__ is Python, half a frame's making (tests/test_can.py holds the two equal).
        msg = can.Message.__new__(can.Message)
        msg.timestamp = 0.0
        msg.arbitration_id = codec.frame_id
        msg.is_extended_id = False
        msg.is_remote_frame = False
        msg.is_error_frame = False
        msg.channel = None
        msg.dlc = len(payload)
        msg.data = bytearray(payload)
        msg.is_fd = False
        msg.is_rx = True
        msg.bitrate_switch = False
        msg.error_state_indicator = False
        return msg

    def send(self, name: str, values: Mapping[str, float]) -> bool:
        """Send a frame; a full transmit queue (ENOBUFS on SocketCAN with a real qdisc) or a bus that
        refuses it loses the frame, as on a real bus: counted and logged, never raised."""
        msg = self.message(name, values)
        if self.tx_hook is None:
            return self.transmit(name, msg)
        sent = [self.transmit(name, m) for m in self.tx_hook(name, msg)]
        return all(sent)

    def transmit(self, name: str, msg: can.Message) -> bool:
        """Put one ready-made frame on the bus (counted under `name`)."""
        try:
            self.bus.send(msg)
        except can.CanOperationError as exc:
            self.stats.send_errors[name] += 1
            self._warn("send_failed", msg.arbitration_id, exc)
            return False
        self.stats.sent[name] += 1
        return True

    def decode(self, msg: can.Message) -> Received | None:
        """A received frame -> Received, or None (counted and logged) if it is not a catalog frame."""
        if msg.is_error_frame:
            self._reject("error_frame", msg)
            return None
        if msg.is_remote_frame:
            self._reject("remote", msg)
            return None
        if msg.is_extended_id:
            self._reject("extended_id", msg)
            return None
        known = self._codecs.get(msg.arbitration_id)
        if known is None:
            self._reject("unknown_id", msg)
            return None
        codec, protected = known
        try:
            signals = codec.decode_shared(msg.data)
        except CanCodecError:
            self._reject("wrong_length", msg)
            return None
        event = self._check(codec, msg.data) if protected else None
        self.stats.received[codec.name] += 1
        return Received(codec.name, signals, msg.timestamp, event)

    def recv(self, timeout: float | None = None) -> Received | None:
        """The next catalog frame within `timeout` seconds (None: wait forever), else None. With timeout 0
        (the tick's drains): the next queued catalog frame, past any rejected ones (they are counted), and
        no clock read."""
        if timeout == 0.0:
            queued = self._queued  # the shared bus's queue, read here: no call between it and the decode
            while queued is None or not queued.empty():
                msg = self.bus.recv(0.0) if queued is None else queued.get_nowait()
                if msg is None:
                    return None
                if self.rx_hook is not None and (msg := self.rx_hook(msg)) is None:
                    continue
                if (frame := self.decode(msg)) is not None:
                    return frame
            return None
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            msg = self.bus.recv(remaining)
            if msg is None:
                return None
            if self.rx_hook is not None and (msg := self.rx_hook(msg)) is None:
                if deadline is not None and remaining == 0.0:
                    return None
                continue
            frame = self.decode(msg)
            if frame is not None:
                return frame
            if deadline is not None and remaining == 0.0:
                return None

    def _check(self, codec: MessageCodec, data: bytes | bytearray) -> E2EEvent:
        event = self._checker.check(codec, data)
        if event.status is not E2EStatus.OK:
            self.stats.e2e[(codec.name, event.status.name)] += 1
            self.stats.lost_frames[codec.name] += event.lost
            self._warn(f"e2e_{event.status.name}", codec.frame_id, event)
        return event

    def _reject(self, reason: str, msg: can.Message) -> None:
        self.stats.malformed[reason] += 1
        self._warn(reason, msg.arbitration_id, msg)

    def _warn(self, reason: str, frame_id: int, detail: object) -> None:
        # The first occurrence per (reason, id) at WARNING, for WARNED_IDS ids per reason: a flood must not
        # flood the log too, and random ids (2^29 extended ones) must not grow this node's memory.
        ids = self._warned.setdefault(reason, set())
        if frame_id in ids or len(ids) >= WARNED_IDS:
            log.debug("%s: %s on 0x%03X: %s", self.name, reason, frame_id, detail)
            return
        ids.add(frame_id)
        more = len(ids) == WARNED_IDS
        log.warning(
            "%s: %s on 0x%03X: %s%s",
            self.name,
            reason,
            frame_id,
            detail,
            f" (the {WARNED_IDS}th id for {reason}: further ones at DEBUG, all counted)" if more else "",
        )


class FrameSink(Protocol):
    """What takes a recorded frame: a python-can `Listener`, or the run's logs (hil/outputs/run_logs.py)."""

    def on_message_received(self, msg: can.Message) -> None: ...


class BusRecorder:
    """Tee everything on a channel into a python-can logger and any further listeners (the run's MCAP), from
    a monitor bus of its own (like candump), written by whoever calls `poll()` (the rig, once per tick: no
    thread woken for every frame). Every listener gets the same frames in the same order. The writer streams
    to disk as the run goes; the further listeners are their owners' to close, after `stop()`."""

    def __init__(self, config: BusConfig, path: Path | str | None, listeners: Iterable[FrameSink] = ()):
        """path: the log file (None: no file, only the listeners)."""
        self.path = None if path is None else Path(path)
        self.bus = open_bus(config)
        self.writer = None if self.path is None else can.Logger(str(self.path))
        self._sinks = tuple(s.on_message_received for s in (self.writer, *listeners) if s is not None)
        self._queued = queued_frames(self.bus)
        self.frames = 0

    def poll(self) -> None:
        """Write every frame queued so far."""
        sinks, bus, queued = self._sinks, self.bus, self._queued
        while queued is None or not queued.empty():
            msg = bus.recv(0.0) if queued is None else queued.get_nowait()
            if msg is None:
                return
            for sink in sinks:
                sink(msg)
            self.frames += 1

    def stop(self, settle: float = 0.05) -> None:
        # Frames may still be on their way (from other processes): write until the traffic has settled.
        deadline = time.monotonic() + 2.0
        seen = -1
        while seen != self.frames and time.monotonic() < deadline:
            seen = self.frames
            time.sleep(settle)
            self.poll()
        if self.writer is not None:
            self.writer.stop()  # flushes and closes the file
        self.bus.shutdown()

    def __enter__(self) -> BusRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
