"""The console's zenoh side: what it reads of the rig service and the supervisor, and the actions it takes
with its role's session (its certificate on the secured bench).

Read: the service's live stream (PREFIX/rig/live, 20 Hz while a run goes), the supervisor's state
(PREFIX/safety/state) and the service's status (asked once a second), all handed to the pages through a
Broadcast; the history and run files on request. Acted: start, stop, faults as queries to the service, like
`pure-hil rig` and `pure-hil fault`; e-stop and reset as `pure-hil estop` does them (an EstopCommand put
on PREFIX/safety/estop, confirmed by the supervisor's own `estop_by`).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator

import msgspec
import zenoh

from drivers.keys import Keys
from drivers.schemas import PayloadError, SafetyState, SafetyStateName, decode
from drivers.zenoh_link import ZenohLink
from hil.bench.operator import Action, command
from hil.console.events import Broadcast
from hil.faults import parse_fault

STATUS_EVERY = 1.0
"""s between the console's status questions to the service."""
ASK_TIMEOUT = 10.0
"""s a query to the service may take (a start loads the scenario before it answers)."""
CONFIRM_TIMEOUT = 5.0
"""s an e-stop or reset waits for the supervisor's word (pure-hil estop's default --timeout)."""
SAFETY_REPEAT = 0.5
"""s of wall time between the pages' copies of an unchanged supervisor state (it repeats every 0.1 s
simulated)."""


class Refused(Exception):
    """An action the console cannot take as asked: its HTTP status and one line saying why."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


class RigLink:
    def __init__(self, session: zenoh.Session, keys: Keys, role: str, source: str, events: Broadcast):
        """`source`: who the console's e-stops and resets say they are from (the supervisor echoes it in
        `estop_by`)."""
        self.session, self.keys, self.role, self.source = session, keys, role, source
        self.events = events
        self.status: dict | None = None
        """The service's last status reply (None: it has not answered yet)."""
        self._safety_sent: tuple[tuple[SafetyStateName, str, float, str] | None, float] = (None, 0.0)
        """The supervisor's state the pages were last sent (state, reason, cap, estop_by), and when."""
        self._closed = threading.Event()
        self._subscribers = [
            session.declare_subscriber(keys.rig_live, self._on_live),
            session.declare_subscriber(keys.safety_state, self._on_safety),
        ]
        self._poller = threading.Thread(target=self._poll_status, name="console-status", daemon=True)
        self._poller.start()

    # ------------------------------------------------------------------------------------------ reading
    def _on_live(self, sample: zenoh.Sample) -> None:
        self.events.publish("live", sample.payload.to_string())

    def _on_safety(self, sample: zenoh.Sample) -> None:
        try:
            state = decode(sample.payload.to_bytes(), SafetyState)
        except PayloadError:
            return
        shown = (state.state, state.reason, state.cap, state.estop_by)
        last, at = self._safety_sent
        now = time.monotonic()
        if shown != last or now - at >= SAFETY_REPEAT:
            self._safety_sent = (shown, now)
            self.events.publish("safety", msgspec.json.encode(state).decode())

    def _poll_status(self) -> None:
        previous = None
        while not self._closed.is_set():
            reply = self.ask("status", timeout=2.0)
            self.status = reply if reply.get("ok") else None
            self.events.publish("status", json.dumps({"reachable": self.status is not None, **reply}))
            ended = (reply.get("run"), reply.get("state"))
            if previous is not None and ended != previous:
                self.events.publish("history", json.dumps({"changed": True}))  # pages ask for the new rows
            previous = ended
            self._closed.wait(STATUS_EVERY)

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
        """Start one of the scenarios the service offers, by name: never a path from a browser."""
        offered = (self.status or {}).get("scenarios") or []
        if scenario not in offered:
            raise Refused(400, f"scenario {scenario!r} is not one the service offers: {', '.join(offered)}")
        return self.ask("start", scenario)

    def stop(self) -> dict:
        return self.ask("stop")

    def inject(self, fault: dict) -> dict:
        # One read of the status: the poller may set it to None (the service stopped answering) meanwhile.
        bench = (self.status or {}).get("bench") or {}
        if bench.get("rider_on_board"):
            name = bench["name"]
            raise Refused(409, f"bench {name} says a person is on the robot: fault injection is refused")
        try:
            parse_fault(fault, "fault")  # the check the service makes, before anything is sent
        except ValueError as exc:
            raise Refused(400, str(exc)) from None
        return self.ask("fault/inject", json.dumps(fault))

    def clear(self, number: int | None) -> dict:
        return self.ask("fault/clear", "" if number is None else str(number))

    def estop(self, action: Action) -> dict:
        """`pure-hil estop` from the page (hil/bench/operator.py): the operator's EstopCommand (estop,
        cut_power or reset), and the supervisor's word: its `estop_by` naming this console, or NORMAL."""
        link = ZenohLink(self.session, self.keys)
        try:
            answer = command(link, action, self.source, CONFIRM_TIMEOUT)
        finally:
            link.close()
        if not answer.heard:
            raise Refused(409, f"no supervisor listens on {self.keys.safety_estop} (is a run going?)")
        if answer.confirmed or (answer.state is not None and "reset refused" in answer.state.reason):
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
