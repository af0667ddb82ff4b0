"""A lab's own supervisor, as small as the contract allows, plugged in through an entry point
(`pure_hil.supervisors`: minimal) by tests/test_supervisor_plug.py. It imports nothing from safety/: what it
speaks is drivers/ (the frames, the vocabulary, the SC request and its cap rule), and what the rig may drive
of it is drivers.plugs.Supervisor.

It permits the drives (SUPERVISOR_ESTOP, NORMAL, contactor closed) until an operator's e-stop, which it
latches until a reset; it forwards each SC request capped by `max_speed` (its one rule). It watches nothing
else: no monitors, no recovery law.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import cast

import msgspec

from drivers.can_bus import open_bus
from drivers.can_codec import MessageName
from drivers.devices import host_node
from drivers.plugs import Supervisor, SupervisorReport, SupervisorSpec
from drivers.schemas import EstopCommand, Payload, SafetyState, ScCommand, ScRequest, encode
from drivers.vocabulary import Cause, Event, OperatorRecord, State, StateName
from drivers.zenoh_link import ZenohLink

FRAME_PERIOD = 0.01
"""s between its SUPERVISOR_ESTOP frames (the drives' permission times out at 50 ms)."""


class Rules(msgspec.Struct, frozen=True):
    max_speed: float = 1.0
    """m/s: the cap on every request it forwards (a free request is forwarded as this limit)."""


class MinimalSupervisor:
    """Driven by the rig's tick: `update` once a tick."""

    def __init__(self, spec: SupervisorSpec, link: ZenohLink) -> None:
        self.bus = open_bus(spec.can)
        self.can = host_node(self.bus, spec.devices, 1, "supervisor")
        self.link, self.keys = link, link.keys
        self.rules = msgspec.convert(spec.rules.get("minimal", {}), Rules)
        self.requests = link.subscribe(self.keys.sc_request, ScRequest)
        self.operator = link.subscribe(self.keys.safety_estop, EstopCommand)
        self.events: list[Event] = []
        self.operator_actions: list[OperatorRecord] = []
        self.operator_actions_dropped = 0
        self.fence_misses = 0
        self.on_put: Callable[[str, bytes], None] | None = None
        self.state, self.cause = State.NORMAL, Cause.NONE
        self.estop_by = ""
        """Whose e-stop is latched: the operator's tools confirm their own e-stop by it (SafetyState)."""
        self.updates = 0
        self._frame_sent = -math.inf
        self._seq = 0

    # -- drivers.plugs.Supervisor
    def update(self, t: float, fence: int | None = None) -> None:
        self.updates += 1
        while self.can.recv(timeout=0.0) is not None:  # it watches nothing on CAN, but keeps its socket read
            pass
        for cmd in self.operator.drain():
            self.operator_actions.append(OperatorRecord(t, cmd.action, cmd.source, self.state.name))
            if cmd.action in ("estop", "cut_power") and self.state is State.NORMAL:
                self.estop_by = cmd.source
                self._enter(t, State.ESTOP, Cause.OPERATOR_ESTOP)
            elif cmd.action == "reset" and self.state is State.ESTOP:
                self.estop_by = ""
                self._enter(t, State.NORMAL, Cause.NONE)
        for request in self.requests.drain():
            cap = min(request.speed_limit(), self.rules.max_speed)
            self._put(
                self.keys.sc_command,
                ScCommand(seq=self._next(), stamp=t, mode="limit", speed_cap=cap, source=request.source),
            )
        if t - self._frame_sent >= FRAME_PERIOD - 1e-9:
            estop = self.state is State.ESTOP
            signals = {
                "Estop": int(estop),
                "Contactor": int(not estop),
                "Takeover": 0,
                "State": int(self.state),
                "Reason": int(self.cause),
            }
            self.can.send(MessageName.SUPERVISOR_ESTOP, signals)
            self._frame_sent = t

    def observed_speed(self) -> float | None:
        return None  # it does not judge the speed

    def report(self) -> SupervisorReport:
        return SupervisorReport(sc_arbitration={"supervisor": "minimal", "updates": self.updates})

    # -- its own
    def _enter(self, t: float, state: State, cause: Cause) -> None:
        self.events.append(Event(t, "transition", self.state.name, state.name, cause.name))
        self.state, self.cause = state, cause
        cap = 0.0 if state is State.ESTOP else self.rules.max_speed
        self._put(
            self.keys.safety_state,
            SafetyState(
                seq=self._next(),
                stamp=t,
                state=cast(StateName, state.name),
                reason=cause.name,
                cap=cap,
                since=t,
                estop_by=self.estop_by,
            ),
        )

    def _next(self) -> int:
        self._seq += 1
        return self._seq

    def _put(self, key: str, payload: Payload) -> None:
        data = encode(payload)
        self.link.put(key, data)
        if self.on_put is not None:
            self.on_put(key, data)


class Handle:
    """What `start` returns: the rig drives `node` from its tick and calls `stop` at the end."""

    def __init__(self, spec: SupervisorSpec, link: ZenohLink | None) -> None:
        if link is None or not spec.driven:
            raise ValueError("the minimal supervisor runs embedded only (driven by the rig's tick)")
        self.node = MinimalSupervisor(spec, link)

    def stop(self) -> None:
        self.node.bus.shutdown()  # its subscriptions are the lent link's, which closes them


def start(spec: SupervisorSpec, link: ZenohLink | None = None) -> Handle:
    return Handle(spec, link)


CONTRACT: type[Supervisor] = MinimalSupervisor
"""mypy checks it against the contract the rig drives."""
