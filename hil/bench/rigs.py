"""The rigs running on this machine: each one announces itself, and an operator's client finds the one it
means, never silently another.

A rig's loopback hub (a `run`, `serve`, or a hub-role `supervisor`) answers `PREFIX/rig/hello` with its
bench, endpoint, pid and what it runs, and leaves a small file in the machine's rig folder
(`$PURE_HIL_RIGS`, default `$TMPDIR/pure-hil-UID/rigs`) while it lives. A client (`estop`, `rig`, `fault`)
takes its hub from `--hub`, else `$PURE_HIL_HUB`, else the one live rig of its bench in that folder, else
the bench file's endpoint; several live rigs of one bench are refused with their endpoints. Having joined,
it asks `rig/hello` and refuses a rig of another bench (docs/rig.md "Which rig").
"""

from __future__ import annotations

import json
import os
import secrets
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass, field
from pathlib import Path

import zenoh

from drivers.keys import Keys

HUB_VARIABLE = "PURE_HIL_HUB"
FOLDER_VARIABLE = "PURE_HIL_RIGS"
HELLO = "hello"


class WrongRig(Exception):
    """The client cannot tell which rig it means, or reached another bench's: what to do instead."""


@dataclass(frozen=True, slots=True)
class RigCard:
    """What a running rig says of itself."""

    bench: str
    endpoint: str
    pid: int
    runs: str
    """'serve', 'run SCENARIO', 'supervisor'."""
    started: float
    """Wall clock, s."""
    id: str = field(default_factory=lambda: secrets.token_hex(6))
    """This rig process's own: a restarted rig may get its pid back, never its id (a console pins to it)."""
    process: str = ""
    """When its process started (`started_ticks`): with the pid, that process itself, as a pid alone is not
    once the rig died and another process got the pid ('' : not known, the pid alone)."""

    def describe(self) -> str:
        return f"{self.runs} on bench {self.bench}, pid {self.pid}, at {self.endpoint}"


def folder() -> Path:
    configured = os.environ.get(FOLDER_VARIABLE)
    return (
        Path(configured) if configured else Path(tempfile.gettempdir()) / f"pure-hil-{os.getuid()}" / "rigs"
    )


def alive(pid: int) -> bool:
    """The process `pid` still runs (a record it left behind is still its own)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def started_ticks(pid: int) -> str:
    """When process `pid` started, in clock ticks since boot (field 22 of /proc/PID/stat), '' where /proc
    does not say: a later process given the same pid has another."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return ""
    # Field 2, the command's name, is in parentheses and may hold spaces: count from its end (field 3 on).
    fields = stat[stat.rfind(")") + 2 :].split()
    return fields[19] if len(fields) > 19 else ""


def live(card: RigCard) -> bool:
    """The rig of `card` still runs: its pid alive and, where the card knows it, the same process."""
    if not alive(card.pid):
        return False
    now = started_ticks(card.pid)
    return not card.process or not now or now == card.process


def running() -> list[RigCard]:
    """The live rigs of this machine. The card of a rig that died without removing it (killed, or a
    second Ctrl-C) is removed here: a client never picks it, nor counts it among a bench's rigs."""
    cards = []
    for path in sorted(folder().glob("*.json")):
        try:
            card = RigCard(**json.loads(path.read_text()))
        except (OSError, ValueError, TypeError):
            continue  # half-written, or removed meanwhile
        if live(card):
            cards.append(card)
        else:
            with suppress(OSError):  # not ours to remove: still never picked
                path.unlink(missing_ok=True)
    return cards


@contextmanager
def announce(session: zenoh.Session, prefix: str, bench: str, endpoint: str, runs: str) -> Iterator[RigCard]:
    """While inside, the rig at `endpoint` answers rig/hello and is listed in the machine's rig folder."""
    card = RigCard(bench, endpoint, os.getpid(), runs, time.time(), process=started_ticks(os.getpid()))
    body = json.dumps({"ok": True, **asdict(card)})

    def answer(query: zenoh.Query) -> None:
        query.reply(query.key_expr, body)

    # Answered on zenoh's own thread (indirect=False): zenoh's default runs a callback on a Python thread
    # of its own, and a second Python thread makes a lockstep tick yield the GIL (~100 us a tick here).
    # `drop` given: eclipse-zenoh 1.4 requires it (positional, None: nothing to do when it is dropped).
    queryable = session.declare_queryable(
        Keys(prefix).rig(HELLO), zenoh.handlers.Callback(answer, None, indirect=False)
    )
    path = folder() / f"{card.pid}-{id(card):x}.json"
    written: Path | None = path
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        running()  # the dead rigs' cards go as a new one comes, not only when a client looks
        path.write_text(json.dumps(asdict(card)))
    except OSError:
        written = None  # an unwritable folder costs the finding by folder, not the run
    try:
        yield card
    finally:
        queryable.undeclare()
        if written is not None:
            written.unlink(missing_ok=True)


def choose_hub(bench: str, hub: str | None, bench_endpoint: str | None) -> str | None:
    """The hub a client of `bench` joins: --hub, $PURE_HIL_HUB, the one live rig of the bench, the bench
    file's endpoint (None: the zenoh config's). Raises WrongRig when several rigs of the bench run."""
    chosen = hub or os.environ.get(HUB_VARIABLE)
    if chosen:
        return chosen
    mine = [card for card in running() if card.bench == bench]
    if len(mine) > 1:
        listed = "; ".join(card.describe() for card in mine)
        raise WrongRig(
            f"{len(mine)} rigs of bench {bench} run on this machine ({listed}): "
            f"name one with --hub ENDPOINT or {HUB_VARIABLE}=ENDPOINT"
        )
    return mine[0].endpoint if mine else bench_endpoint


def greet(session: zenoh.Session, prefix: str, bench: str | None, timeout: float = 5.0) -> RigCard:
    """The card of the rig this session joined; WrongRig if none answers, or if it runs another bench
    than `bench` (None: any, the hub was named)."""
    # Asked again until `timeout`: a session just opened may not yet know the hub's queryables.
    deadline = time.monotonic() + timeout
    replies: list = []
    while not replies and time.monotonic() < deadline:
        replies = [r for r in session.get(Keys(prefix).rig(HELLO), timeout=0.5) if r.ok is not None]
    for reply in replies:
        if reply.ok is None:
            continue
        body = json.loads(reply.ok.payload.to_string())
        body.pop("ok", None)
        card = RigCard(**body)
        if bench is not None and card.bench != bench:
            raise WrongRig(
                f"the rig at {card.endpoint} runs bench {card.bench}, not {bench} ({card.describe()}): "
                f"name its bench with --bench, or the right rig with --hub or {HUB_VARIABLE}"
            )
        return card
    raise WrongRig(
        "no rig answers on this hub (is it running? a rig prints its hub endpoint when it starts; "
        f"name it with --hub or {HUB_VARIABLE})"
    )
