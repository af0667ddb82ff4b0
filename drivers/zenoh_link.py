"""zenoh sessions opened only from the project's configs, declared-once publishers, non-blocking subscribers.

Network rule: a session opens from a config file of `configs/zenoh/`; multicast scouting must be off and,
unless the caller passes allow_network=True (a multi-host bench with a router), every endpoint must be on
loopback. zenoh's built-in default config (multicast scouting on, listening on all interfaces) is never used.

Roles: the *hub* (the rig) listens on the config's endpoint; *members* (controller, supervisor, operator
tools) listen on an ephemeral loopback port and connect to the hub; gossip then introduces members to
each other over those loopback sessions.

Secured bench (docs/security.md): `bench-router.json5` and `bench-client.json5` hold `@CERTS@` (the folder
of `pure-hil certs init`) and `@ROLE@` (the client's certificate, hence its ACL identity); private keys and
credential files must not be readable by group or others.
"""

from __future__ import annotations

import json
import logging
import re
import socket
import stat
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Generic, Literal, ParamSpec, TypeVar, cast

import zenoh

from drivers.keys import Keys
from drivers.resources import SHIPPED
from drivers.schemas import TICK_MODULO, Payload, PayloadError, RigTick, decode, encode, tick_after

log = logging.getLogger(__name__)

CONFIG_DIR = SHIPPED / "zenoh"
LOOPBACK = CONFIG_DIR / "loopback.json5"
Role = Literal["hub", "member"]
Where = ParamSpec("Where")
"""Where a session connects and as whom: `load_config`'s parameters."""
MEMBER_LISTEN = "tcp/127.0.0.1:0"
LOOPBACK_PREFIXES = ("tcp/127.", "tcp/[::1]", "tls/127.", "udp/127.", "unixsock-stream/")
SECRET_KEYS = (
    "transport/link/tls/listen_private_key",
    "transport/link/tls/connect_private_key",
    "transport/auth/usrpwd/dictionary_file",
)


class ZenohConfigError(ValueError):
    pass


def _get(config: zenoh.Config, key: str) -> Any:
    return json.loads(config.get_json(key))


def _endpoints(value: list[str] | dict[str, list[str] | None] | None) -> list[str]:
    # listen/connect endpoints are a list, or a per-mode map {"peer": [...], "router": [...]}.
    if isinstance(value, dict):
        return [e for v in value.values() for e in (v or [])]
    return list(value or [])


def is_loopback(endpoint: str) -> bool:
    return endpoint.startswith(LOOPBACK_PREFIXES)


def load_config(
    path: Path | str = LOOPBACK,
    role: Role = "member",
    hub_endpoint: str | None = None,
    allow_network: bool = False,
    certs: Path | str | None = None,
    identity: str | None = None,
) -> zenoh.Config:
    """A zenoh Config from a project file, with the role applied and the network rule checked.

    hub_endpoint replaces the file's hub endpoint (tests use a free port per test); certs and identity
    fill a secured bench file's @CERTS@ and @ROLE@. Router and client files keep their own roles.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ZenohConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    for placeholder, value, what in (("@CERTS@", certs, "certs"), ("@ROLE@", identity, "identity")):
        if placeholder in text:
            if value is None:
                raise ZenohConfigError(f"{path}: needs {what} (the file uses {placeholder})")
            text = text.replace(placeholder, str(value))
    try:
        config = zenoh.Config.from_json5(text)
    except Exception as exc:  # zenoh raises its own ZError for invalid files
        raise ZenohConfigError(f"{path}: cannot load zenoh config: {exc}") from exc
    if hub_endpoint is not None:
        config.insert_json5("listen/endpoints", json.dumps([hub_endpoint]))
        config.insert_json5("connect/endpoints", json.dumps([hub_endpoint]))
    mode = _get(config, "mode")
    if mode == "router":
        config.insert_json5("connect/endpoints", "[]")
    elif mode == "client":  # no listener: a client reachable directly would bypass the router's ACL
        config.insert_json5("listen/endpoints", "[]")
    elif mode == "peer":
        if role == "hub":
            config.insert_json5("connect/endpoints", "[]")
        else:
            config.insert_json5("listen/endpoints", json.dumps([MEMBER_LISTEN]))
    check_config(config, path, allow_network)
    check_secrets(config, path)
    return config


def check_secrets(config: zenoh.Config, origin: Path | str = "<config>") -> None:
    """Private keys and credential files must exist and be readable by their owner only."""
    for key in SECRET_KEYS:
        value = _get(config, key)
        if not value:
            continue
        secret = Path(value)
        try:
            mode = secret.stat().st_mode
        except OSError as exc:
            raise ZenohConfigError(f"{origin}: {key} = {secret}: {exc.strerror or exc}") from exc
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise ZenohConfigError(
                f"{origin}: {key} = {secret} is readable by group or others (mode {stat.S_IMODE(mode):04o}); "
                f"chmod 600 {secret}"
            )


def check_config(config: zenoh.Config, origin: Path | str = "<config>", allow_network: bool = False) -> None:
    if _get(config, "scouting/multicast/enabled") is not False:
        raise ZenohConfigError(
            f"{origin}: scouting/multicast/enabled must be false (multicast leaves the machine)"
        )
    # zenoh fills missing endpoints with its defaults (listen on tcp/[::]: all interfaces): refused below.
    endpoints = _endpoints(_get(config, "listen/endpoints")) + _endpoints(_get(config, "connect/endpoints"))
    outside = [e for e in endpoints if not is_loopback(e)]
    if outside and not allow_network:
        raise ZenohConfigError(
            f"{origin}: endpoints {outside} are not on loopback "
            "(allow_network=True is for a bench network with a router only)"
        )


ENDPOINT = re.compile(r"(tcp|tls|udp|quic)/(\[[0-9A-Fa-f:.]+\]|[^/:\[\]\s]+):(\d{1,5})|unixsock-stream/\S+")
"""An endpoint a bench's process may name: PROTOCOL/HOST:PORT, or a Unix socket's path."""


def check_endpoint(endpoint: str, origin: str, allow_network: bool = False) -> str:
    """`endpoint` if it is one (PROTOCOL/HOST:PORT, on this machine unless `allow_network`); else a
    ZenohConfigError naming `origin`, the option or the variable it came from."""
    form = ENDPOINT.fullmatch(endpoint)
    if form is None or (form.group(3) is not None and not 0 < int(form.group(3)) < 65536):
        raise ZenohConfigError(
            f"{origin} {endpoint!r}: not a zenoh endpoint: expected PROTOCOL/HOST:PORT (port 1-65535), e.g. "
            "tcp/127.0.0.1:7447"
        )
    if not allow_network and not is_loopback(endpoint):
        raise ZenohConfigError(
            f"{origin} {endpoint}: not on this machine (tcp/127.0.0.1:PORT); a bench across hosts joins its "
            "router (docs/security.md)"
        )
    return endpoint


def free_loopback_endpoint() -> str:
    """A hub endpoint on a port free right now on 127.0.0.1 (parallel runs must not share a hub)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def hub_endpoints(path: Path | str) -> list[str]:
    """Where a hub opened from the config at `path` listens."""
    return _endpoints(_get(load_config(path, "hub"), "listen/endpoints"))


def _opened(config: Callable[Where, zenoh.Config]) -> Callable[Where, zenoh.Session]:
    def open_session(*args: Where.args, **kwargs: Where.kwargs) -> zenoh.Session:
        return zenoh.open(config(*args, **kwargs))

    return open_session


open_session = _opened(load_config)
"""A session on `load_config`'s Config: the same arguments, declared once there (mypy checks each call)."""


def open_hub(
    path: Path | str = LOOPBACK,
    endpoint: str | None = None,
    fallback: bool = False,
    allow_network: bool = False,
) -> tuple[zenoh.Session, str | None]:
    """The rig's hub session and the endpoint it listens on. A port already taken (another rig on this
    machine) moves a self-contained run (`fallback`: nobody else has to find it) to a free loopback port;
    otherwise it is a ZenohConfigError naming the port and the option, never a traceback."""
    try:
        return open_session(path, "hub", endpoint, allow_network), endpoint
    except zenoh.ZError as exc:
        if "Address already in use" not in str(exc):
            raise ZenohConfigError(f"{path}: cannot open the rig's zenoh hub: {exc}") from None
        taken = endpoint or ", ".join(hub_endpoints(path))
        if not fallback:
            raise ZenohConfigError(
                f"{taken} is in use (another rig on this machine?): give this rig and every process of its "
                "bench another hub endpoint, --hub tcp/127.0.0.1:PORT"
            ) from None
    free = free_loopback_endpoint()
    log.warning(
        "%s is in use (another rig on this machine?): this run's hub listens on %s (its clients: --hub %s)",
        taken,
        free,
        free,
    )
    return open_session(path, "hub", free, allow_network), free


BENCH_CLIENT = CONFIG_DIR / "bench-client.json5"


class LentSession:
    """The rig's hub session lent to another node of the same process (the embedded controller on a
    loopback bench): its puts and subscriptions never leave the process (zenoh delivers inside one session
    at once, no loopback TCP hop and no wake-up per sample); closing it is its owner's business."""

    def __init__(self, session: zenoh.Session):
        self._session = session

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)

    def close(self) -> None:
        pass


_lent: dict[str | None, zenoh.Session] = {}


def lent_session(endpoint: str | None) -> zenoh.Session | None:
    """A proxy of the hub session lent to this process for `endpoint` (see `lend`), if any: all but
    close() is the hub's."""
    hub = _lent.get(endpoint)
    return None if hub is None else cast(zenoh.Session, LentSession(hub))


@contextmanager
def lend(session: zenoh.Session, endpoint: str | None) -> Iterator[None]:
    """While inside, nodes of this process that join the loopback hub at `endpoint` share `session`."""
    _lent[endpoint] = session
    try:
        yield
    finally:
        if _lent.get(endpoint) is session:
            del _lent[endpoint]


P = TypeVar("P", bound=Payload)


POLL = 20e-6
"""s between looks while waiting for samples: zenoh fills a subscription's channel from its own threads
without taking the GIL, so a wait looks again instead of being woken by a Python callback."""


def poll_until(ready: Callable[[], object], timeout: float) -> bool:
    """Look until `ready()` is true (True) or `timeout` seconds have passed (False)."""
    deadline = time.monotonic() + timeout
    while not ready():
        if time.monotonic() >= deadline:
            return bool(ready())
        time.sleep(POLL)
    return True


TICK_TAG_BYTES = 2
"""A put's tick tag: the tick modulo TICK_MODULO, little-endian (zenoh attachment)."""


class Subscription(Generic[P]):
    """Samples land in a zenoh ring channel (filled by zenoh's threads without the GIL; the oldest drop
    when full); the consumer takes and decodes them on its own thread with `drain()` (all new) or
    `latest()`, and can wait in `wait()` until something arrives."""

    def __init__(self, session: zenoh.Session, key: str, payload_type: type[P], capacity: int = 256):
        self.key, self.type = key, payload_type
        self._buffer: deque[tuple[bytes, int | None]] = deque(maxlen=capacity)
        """Undrained samples with the tick a lockstep rig tagged them with (None: untagged)."""
        self._received = 0
        self._sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
        self.accepted = 0
        self.rejected: Counter[str] = Counter()
        self.last_rejection = ""
        self._latest: P | None = None

    def _take(self) -> None:
        while (sample := self._sub.try_recv()) is not None:
            tag = sample.attachment
            tagged = tag is not None and len(tag_bytes := tag.to_bytes()) == TICK_TAG_BYTES
            tick = int.from_bytes(tag_bytes, "little") if tagged else None
            self._buffer.append((sample.payload.to_bytes(), tick))
            self._received += 1

    @property
    def received(self) -> int:
        """Samples that arrived so far, decodable or not (a lockstep fence counts them)."""
        self._take()
        return self._received

    def wait(self, timeout: float) -> bool:
        """Wait until at least one undrained sample is here (True) or the timeout passes (False)."""

        def arrived() -> bool:
            self._take()
            return bool(self._buffer)

        return poll_until(arrived, timeout)

    def drain(self, tick: int | None = None) -> list[P]:
        """Everything new; given the reader's tick, samples a lockstep rig tagged with a later tick stay
        queued (a reader behind the rig judges each input at the tick it was put)."""
        self._take()
        pending: list[bytes] = []
        buffer = self._buffer
        while buffer and (tick is None or (tag := buffer[0][1]) is None or not tick_after(tag, tick)):
            pending.append(buffer.popleft()[0])
        out: list[P] = []
        for data in pending:
            try:
                out.append(decode(data, self.type))
            except PayloadError as exc:
                self._reject(exc)
        self.accepted += len(out)
        if out:
            self._latest = out[-1]
        return out

    def latest(self) -> P | None:
        """The newest valid payload received so far (draining what is pending)."""
        self.drain()
        return self._latest

    def _reject(self, exc: PayloadError) -> None:
        level = logging.DEBUG if self.rejected[exc.kind] else logging.WARNING
        self.rejected[exc.kind] += 1
        self.last_rejection = str(exc)
        log.log(level, "rejected payload on %s: %s", self.key, exc)

    def close(self) -> None:
        self._sub.undeclare()


class ZenohLink:
    """A node's zenoh side: publishers declared once per key, typed subscriptions, and the lockstep fence
    (every put is counted per key; `put_fence` tells the other nodes how many there were)."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys | None = None,
        lossless: bool = False,
        puts: Counter[str] | None = None,
    ):
        """lossless: publishers block instead of dropping when zenoh's queue is full (lockstep: an input
        lost under load would make the run depend on the machine's load). puts: a counter shared by the
        links of one process (its fence counts the puts of all its sessions)."""
        self.session = session
        self.keys = keys or Keys()
        self._congestion = zenoh.CongestionControl.BLOCK if lossless else zenoh.CongestionControl.DROP
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._subscriptions: list[Subscription[Any]] = []
        self.puts: Counter[str] = Counter() if puts is None else puts
        """Payloads put on each key by this link (and the links sharing its counter)."""

    def declare_publishers(self, keys: Iterable[str]) -> None:
        for key in keys:
            self.publisher(key)

    def publisher(self, key: str) -> zenoh.Publisher:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = self.session.declare_publisher(
                key, congestion_control=self._congestion
            )
        return pub

    def wait_for_subscriber(self, key: str, timeout: float) -> bool:
        """Block until someone subscribes to `key` (a put before that reaches nobody), at most `timeout` s."""
        pub = self.publisher(key)
        matched = threading.Event()

        def on_change(status: zenoh.MatchingStatus) -> None:
            if status.matching:
                matched.set()

        listener = pub.declare_matching_listener(on_change)
        try:
            # zenoh's stub types `matching_status` as bool; it is a MatchingStatus (zenoh 1.x). Read
            # untyped: the compiled build checks an attribute is the type its stub says.
            status = getattr(pub, "matching_status")  # noqa: B009
            return bool(status.matching) or matched.wait(timeout)
        finally:
            listener.undeclare()

    def put(self, key: str, payload: Payload | bytes, tick: int | None = None) -> None:
        """`payload`: a message, or its encoding (a node that records what it puts encodes it once). `tick`:
        the rig's tick the sample belongs to, attached for readers that may lag (`drain(tick)`)."""
        data = payload if isinstance(payload, bytes) else encode(payload)
        pub = self.publisher(key)
        if tick is None:
            pub.put(data)
        else:
            pub.put(data, attachment=(tick % TICK_MODULO).to_bytes(TICK_TAG_BYTES, "little"))
        self.puts[key] += 1

    def put_fence(self, tick: int, stamp: float) -> None:
        """Lockstep: every zenoh input of `tick` is out (pure/rig/tick, with this link's put counts)."""
        self.publisher(self.keys.rig_tick).put(encode(RigTick(seq=tick, stamp=stamp, puts=dict(self.puts))))

    def subscribe(self, key: str, payload_type: type[P], capacity: int = 256) -> Subscription[P]:
        sub = Subscription(self.session, key, payload_type, capacity)
        self._subscriptions.append(sub)
        return sub

    def close(self) -> None:
        for sub in self._subscriptions:
            sub.close()
        for pub in self._publishers.values():
            pub.undeclare()
        self._subscriptions.clear()
        self._publishers.clear()


class Fence:
    """A lockstep node's wait for the rig's tick: pure/rig/tick k has arrived, and so has every payload it
    counts on the keys this node reads (zenoh may deliver a fence before an earlier put on another key).
    The counts start together only if the node's subscriptions exist before the rig's first put: declare
    them before the seat wrench's, whose subscriber the rig waits for. A wait that times out with a count
    still short takes the shortfall as lost for good, so a lost sample costs one tick, not every tick."""

    def __init__(self, link: ZenohLink, reads: list[Subscription[Any]]):
        self.link, self.reads = link, reads
        self.ticks = link.subscribe(link.keys.rig_tick, RigTick, capacity=64)
        self.tick = -1
        self._puts: dict[str, int] = {}
        self.lost: Counter[str] = Counter()
        """Per key, samples the fence counted that never arrived."""

    def _short(self, s: Subscription[Any]) -> int:
        # .get: a Counter's missing key goes through its Python __missing__ (every key, every tick).
        return self._puts.get(s.key, 0) - self.lost.get(s.key, 0) - s.received

    def _take_fences(self) -> None:
        for fence in self.ticks.drain():
            if fence.seq > self.tick:
                self.tick, self._puts = fence.seq, fence.puts

    def _ready(self, k: int) -> bool:
        self._take_fences()
        return self.tick >= k and all(self._short(s) <= 0 for s in self.reads)

    def heard(self) -> bool:
        """A lockstep rig's fence has arrived (such a rig also tags its puts with their tick): takes in the
        fences that are here, so a method, not a property."""
        self._take_fences()
        return self.tick >= 0

    def wait(self, k: int, timeout: float) -> bool:
        """Wait until tick k's inputs are all here (True) or the timeout passes (False)."""
        if self._ready(k) or poll_until(lambda: self._ready(k), timeout):
            return True
        if self.tick >= k:
            for s in self.reads:
                self.lost[s.key] += max(self._short(s), 0)
        return False
