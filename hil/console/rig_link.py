"""The console's zenoh side: what it reads of the rig service and the supervisor, and the actions it takes
with its role's session (its certificate on the secured bench).

Read: the service's live stream (PREFIX/rig/live, 20 Hz while a run goes), the supervisor's state
(PREFIX/safety/state) and the service's status (asked once a second), each stamped with when the console
heard it (its own monotonic clock; a page ages them by it), all handed to the pages through a Broadcast; the
history and run files on request. Acted: start, stop, faults as queries to the service, like `pure-hil rig`
and `pure-hil fault`; e-stop and reset as `pure-hil estop` does them (an EstopCommand put on
PREFIX/safety/estop, confirmed by the supervisor's own `estop_by`).

Pinned: the console belongs to the rig it was opened for, by that rig's card (id, bench, pid: the one
`pure-hil serve` announces and puts in its status). Every action first asks the status again and is refused
when another rig answers on the endpoint (409) or none does (502): nothing is sent then.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator

import msgspec
import zenoh

from drivers.keys import Keys
from drivers.schemas import PayloadError, SafetyState, decode
from drivers.vocabulary import OperatorCommand, StateName
from drivers.zenoh_link import ZenohLink
from hil.bench.operator import command
from hil.console.events import Broadcast
from hil.console.latch import Latch, Word
from hil.faults import parse_fault

STATUS_EVERY = 1.0
"""s between the console's status questions to the service."""
STATUS_TIMEOUT = 2.0
"""s a status question may take (a zenoh query nobody serves ends at once)."""
ASK_TIMEOUT = 10.0
"""s a query to the service may take (a start loads the scenario before it answers)."""
CONFIRM_TIMEOUT = 5.0
"""s an e-stop or reset waits for the supervisor's word (pure-hil estop's default --timeout)."""
LISTEN_WAIT = 0.5
"""s an e-stop waits to learn that a supervisor listens (a session knows its peers' subscriptions at once)."""
SAFETY_REPEAT = 0.5
"""s of wall time between the pages' copies of an unchanged supervisor state (it repeats every 0.1 s
simulated)."""
CARD_FIELDS = ("id", "bench", "pid")
"""What makes a rig the one a console was opened for (hil/bench/rigs.py RigCard)."""


class Refused(Exception):
    """An action the console cannot take as asked: its HTTP status and one line saying why."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def describe_card(card: dict | None) -> str:
    if not card:
        return "no rig"
    return f"{card.get('runs')} on bench {card.get('bench')}, pid {card.get('pid')}, id {card.get('id')}"


class RigLink:
    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        role: str,
        source: str,
        events: Broadcast,
        card: dict | None = None,
    ):
        """`source`: who the console's e-stops and resets say they are from (the supervisor echoes it in
        `estop_by`); `card`: the rig it was opened for (None: the first whose status it hears, on a bench
        whose router hides the rigs' cards)."""
        self.session, self.keys, self.role, self.source = session, keys, role, source
        self.events = events
        self.clock = time.monotonic
        self.pinned: dict | None = card
        self.card: dict | None = None
        """The card of the rig answering now (None: none answered yet)."""
        self.status: dict | None = None
        """The pinned service's last status reply (None: it has not answered)."""
        self.answered: float | None = None
        """When a status answer last came (the console's clock)."""
        self.run: int | None = None
        """The pinned service's run going now (None: idle, or not known)."""
        self.latch = Latch()
        self._lock = threading.Lock()  # the latch: zenoh's threads, the poller and the pages' requests
        self._safety_sent: tuple[tuple[StateName, str, float, str] | None, float] = (None, 0.0)
        """The supervisor's state the pages were last sent (state, reason, cap, estop_by), and when."""
        self._latch_sent: tuple | None = None
        self._closed = threading.Event()
        self._subscribers = [
            session.declare_subscriber(keys.rig_live, self._on_live),
            session.declare_subscriber(keys.safety_state, self._on_safety),
        ]
        self._poller = threading.Thread(target=self._poll_status, name="console-status", daemon=True)
        self._poller.start()

    # ------------------------------------------------------------------------------------------ reading
    def pinned_here(self) -> bool:
        """The rig answering now is the one this console was opened for."""
        card, pinned = self.card, self.pinned
        return (
            card is not None and pinned is not None and all(card.get(f) == pinned.get(f) for f in CARD_FIELDS)
        )

    def _on_live(self, sample: zenoh.Sample) -> None:
        try:
            live = json.loads(sample.payload.to_string())
        except ValueError:
            return
        if not isinstance(live, dict):
            return
        live["received"] = self.clock()
        live["foreign"] = not self.pinned_here()
        if not live["foreign"] and isinstance(live.get("run"), int):
            self.run = live["run"]
        self.events.publish("live", json.dumps(live))

    def _on_safety(self, sample: zenoh.Sample) -> None:
        try:
            state = decode(sample.payload.to_bytes(), SafetyState)
        except PayloadError:
            return
        now = self.clock()
        foreign = not self.pinned_here()
        if not foreign:  # another rig's supervisor says nothing of this rig's latch
            with self._lock:
                self.latch.heard(Word(state.state, state.reason, state.estop_by, self.run, now))
        shown = (state.state, state.reason, state.cap, state.estop_by)
        last, at = self._safety_sent
        if shown != last or now - at >= SAFETY_REPEAT:
            self._safety_sent = (shown, now)
            body = {**msgspec.to_builtins(state), "received": now, "foreign": foreign}
            self.events.publish("safety", json.dumps(body))
        self._publish_latch()

    def latch_view(self) -> dict:
        with self._lock:
            return self.latch.view(self.clock())

    def _publish_latch(self, always: bool = False) -> None:
        view = self.latch_view()
        latched = view["latched"]
        shape = (latched["by"], latched["run"], latched["held_by"]) if latched else None
        if always or shape != self._latch_sent:
            self._latch_sent = shape
            self.events.publish("latch", json.dumps(view))

    def _poll_status(self) -> None:
        previous = None
        while not self._closed.is_set():
            reply = self._take_status(self.ask("status", timeout=STATUS_TIMEOUT))
            here = self.pinned_here()
            now = self.clock()
            self.events.publish(
                "status",
                json.dumps(
                    {
                        **reply,
                        "reachable": bool(reply.get("ok")),
                        "now": now,
                        "answered": self.answered,
                        "rig": "pinned" if here else "different" if self.card else "none",
                        "pinned": self.pinned,
                    }
                ),
            )
            ended = (reply.get("run"), reply.get("state"))
            if here and ended[1] == "idle" and ended != previous and ended[0] is not None:
                last = reply.get("last") or {}
                with self._lock:
                    self.latch.run_ended(ended[0], str(last.get("verdict")), now)
            if previous is not None and ended != previous:
                self.events.publish("history", json.dumps({"changed": True}))  # pages ask for the new rows
            previous = ended
            self._publish_latch(always=True)  # its ages, and a supervisor gone silent
            self._closed.wait(STATUS_EVERY)

    def _take_status(self, reply: dict) -> dict:
        """Note a status reply: who answers (the pin), when, and the run going."""
        if reply.get("ok"):
            self.answered = self.clock()
            card = reply.get("card")
            self.card = card if isinstance(card, dict) else None
            if self.pinned is None and self.card is not None:
                self.pinned = self.card  # the first rig heard (a router hides the cards until then)
            if self.pinned_here():
                self.status = reply
                self.run = reply.get("run") if reply.get("state") == "running" else None
        else:
            self.status = None
        return reply

    def check_rig(self) -> dict:
        """The pinned rig's status, asked now; Refused (nothing is sent) when it does not answer (502) or
        another rig answers on its endpoint (409)."""
        reply = self._take_status(self.ask("status", timeout=STATUS_TIMEOUT))
        if not reply.get("ok"):
            raise Refused(
                502,
                f"no answer from the rig this console was opened for ({describe_card(self.pinned)}): "
                f"{reply.get('error')}; nothing was sent",
            )
        if not self.pinned_here():
            raise Refused(
                409,
                f"a different rig answers on this endpoint ({describe_card(self.card)}), not the one this "
                f"console was opened for ({describe_card(self.pinned)}): nothing was sent; open a console "
                "for that rig",
            )
        return reply

    def ask(self, name: str, payload: str = "", timeout: float = ASK_TIMEOUT) -> dict:
        """The service's JSON reply to PREFIX/rig/NAME, or {ok: false, error} when none came (the service is
        not running, or the router refused this role the question: a denied query just goes unanswered)."""
        replies = list(self.session.get(self.keys.rig(name), payload=payload, timeout=timeout))
        for reply in replies:
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_string())
        return {
            "ok": False,
            "error": f"no answer on {self.keys.rig(name)} (is `pure-hil serve` running, and may "
            f"{self.role} ask it?)",
        }

    def history(self, limit: int, before: int | None) -> dict:
        asked = {"limit": limit, **({"before": before} if before is not None else {})}
        return self.ask("history", json.dumps(asked))

    def file(self, run: int, name: str) -> tuple[int, Iterator[bytes]]:
        """A run file's size and its bytes in the service's chunks. Refused(404) when the service does not
        serve it, Refused(502) when it does not answer."""
        first = self._chunk(run, name, 0)
        size = first[0]

        def chunks() -> Iterator[bytes]:
            offset, data = 0, first[1]
            while data:
                yield data
                offset += len(data)
                if offset >= size:
                    return
                data = self._chunk(run, name, offset)[1]

        return size, chunks()

    def _chunk(self, run: int, name: str, offset: int) -> tuple[int, bytes]:
        asked = json.dumps({"run": run, "name": name, "offset": offset})
        for reply in self.session.get(self.keys.rig_file, payload=asked, timeout=ASK_TIMEOUT):
            if reply.ok is not None:
                if reply.ok.attachment is None:  # the service always attaches it: another program answered
                    raise Refused(502, f"the answer on {self.keys.rig_file} does not say the file's size")
                told = json.loads(reply.ok.attachment.to_string())
                return int(told["size"]), reply.ok.payload.to_bytes()
            if reply.err is not None:
                raise Refused(404, json.loads(reply.err.payload.to_string())["error"])
        raise Refused(502, f"no answer on {self.keys.rig_file} (is `pure-hil serve` running?)")

    # ------------------------------------------------------------------------------------------- acting
    def start(self, scenario: str) -> dict:
        """Start one of the scenarios the service offers, by name (never a path from a browser), unless an
        e-stop is latched."""
        status = self.check_rig()
        offered = status.get("scenarios") or []
        if scenario not in offered:
            raise Refused(400, f"scenario {scenario!r} is not one the service offers: {', '.join(offered)}")
        with self._lock:
            refusal = self.latch.start_refusal(self.clock())
        if refusal:
            raise Refused(409, refusal)
        return self.ask("start", scenario)

    def stop(self) -> dict:
        self.check_rig()
        return self.ask("stop")

    def inject(self, fault: dict) -> dict:
        try:
            parse_fault(fault, "fault")  # the check the service makes, before anything is sent
        except ValueError as exc:
            raise Refused(400, str(exc)) from None
        bench = self.check_rig().get("bench") or {}
        if bench.get("rider_on_board"):
            name = bench["name"]
            raise Refused(409, f"bench {name} says a person is on the robot: fault injection is refused")
        return self.ask("fault/inject", json.dumps(fault))

    def clear(self, number: int | None) -> dict:
        self.check_rig()
        return self.ask("fault/clear", "" if number is None else str(number))

    def estop(self, action: OperatorCommand, source: str | None = None) -> dict:
        """`pure-hil estop` from the page (hil/bench/operator.py): the operator's EstopCommand (estop,
        cut_power or reset) to the pinned rig's supervisor, and the supervisor's word: its `estop_by`
        naming `source` (default: the console's), or NORMAL. A reset with no supervisor listening clears a
        latch whose supervisor is gone (hil/console/latch.py)."""
        source = source or self.source
        self.check_rig()
        link = ZenohLink(self.session, self.keys)
        try:
            if not link.wait_for_subscriber(self.keys.safety_estop, LISTEN_WAIT):
                return self._no_supervisor(action, source)
            answer = command(link, action, source, CONFIRM_TIMEOUT)
        finally:
            link.close()
        if not answer.heard:  # it went between the two looks
            return self._no_supervisor(action, source)
        if action == "reset" and answer.confirmed:
            with self._lock:
                self.latch.reset()
            self._publish_latch()
        if answer.confirmed or (answer.state is not None and answer.state.reset_refused):
            return {
                "ok": answer.confirmed,
                "action": action,
                "confirmed": True,
                "state": msgspec.to_builtins(answer.state),
            }
        return {
            "ok": False,
            "action": action,
            "confirmed": False,
            "error": f"{action} sent, but the supervisor did not confirm it within {CONFIRM_TIMEOUT:g} s; "
            f"{answer.seen()}",
        }

    def _no_supervisor(self, action: OperatorCommand, source: str) -> dict:
        """No supervisor listens on the e-stop key: nothing was sent. A reset then clears a latch held for a
        supervisor that is gone, on this console."""
        where = self.keys.safety_estop
        with self._lock:  # a supervisor that does not listen can never be reset: its latch is the console's
            cleared = self.latch.reset() if action == "reset" else None
        if cleared is None:
            raise Refused(
                502,
                f"no supervisor listens on {where}: no run goes (the bench's supervisor runs with each run); "
                "nothing was sent",
            )
        self._publish_latch()
        run = "" if cleared.run is None else f" in run {cleared.run}"
        return {
            "ok": True,
            "action": action,
            "confirmed": False,
            "cleared": {"by": cleared.by, "run": cleared.run},
            "message": f"no supervisor listens on {where}: the e-stop by {cleared.by}{run} ended with the "
            f"supervisor that held it; cleared on this console by {source}",
        }

    def close(self) -> None:
        self._closed.set()
        self._poller.join(5.0)
        for subscriber in self._subscribers:
            subscriber.undeclare()


def fault_catalog() -> list[dict]:
    """The fault kinds a page offers: kind, family, parameters with their defaults (null: required), what
    it does."""
    from hil.faults import FAMILIES

    faults = []
    for family, classes in FAMILIES.items():
        for cls in classes:
            params = {
                f.name: None if f.default is msgspec.NODEFAULT else msgspec.to_builtins(f.default)
                for f in msgspec.structs.fields(cls)
                if f.name not in ("kind", "at", "duration", "expect")
            }
            doc = " ".join((cls.__doc__ or "").split())
            faults.append({"kind": cls.__struct_config__.tag, "family": family, "params": params, "doc": doc})
    return faults
