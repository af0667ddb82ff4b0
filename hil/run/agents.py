"""The scenario's agents (docs/rig.md "One tick"): the shared controller's requests and the operator's
actions it schedules, put on zenoh at their ticks as a person's or an SC agent's would be."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import msgspec

from drivers.schemas import ControllerCommand, EstopCommand, Payload, ScRequest
from drivers.zenoh_link import ZenohLink

SC_REPEAT_EVERY = 40  # ticks between repeats of an unchanged SC request (keeps it fresh for the supervisor)
SCENARIO_SOURCE = "scenario"
"""The source of the SC requests and operator actions the scenario schedules (a person's are theirs)."""


@dataclass(frozen=True, slots=True)
class ScStep:
    """From `tick` on, the shared controller asks for `request` (sent with its own seq and stamp)."""

    tick: int
    request: ScRequest


FREE_SCHEDULE = (ScStep(0, ScRequest(seq=0, stamp=0.0, mode="free", source=SCENARIO_SOURCE)),)
"""The schedule of a run that plans no SC request: the rider in charge throughout."""
OperatorAction = Literal["estop", "reset", "enable", "disable"]


@dataclass(frozen=True, slots=True)
class OperatorStep:
    """At `tick` the operator acts: estop or reset (pure/safety/estop), enable or disable the controller
    (pure/controller/command)."""

    tick: int
    action: OperatorAction


@dataclass(frozen=True, slots=True)
class AgentLinks:
    """The sessions the rig's scenario speaks through as the SC agent and the operator (secured bench)."""

    sc_agent: ZenohLink
    operator: ZenohLink


Put = Callable[[int, str, Payload, ZenohLink], None]
"""(tick, key, payload, link): how the rig puts a payload of tick k (and keeps it in the inputs log)."""


class ScenarioAgents:
    """The SC agent and the operator of a scenario: what they put, and at which tick."""

    def __init__(
        self,
        link: ZenohLink,
        sc_schedule: Sequence[ScStep],
        operator: Sequence[OperatorStep],
        agent_link: AgentLinks | None,
        put: Put,
    ) -> None:
        """agent_link: the sessions of those roles on a secured bench; None: the rig's own `link`."""
        self.keys = keys = link.keys
        self.sc_link = link if agent_link is None else agent_link.sc_agent
        self.operator_link = link if agent_link is None else agent_link.operator
        self.sc_link.declare_publishers([keys.sc_request])
        self.operator_link.declare_publishers([keys.safety_estop, keys.controller_command])
        self.sc_schedule = sorted(sc_schedule, key=lambda s: s.tick)
        self.operator = sorted(operator, key=lambda s: s.tick)
        self._put = put
        self._seq: Counter[str] = Counter()
        self._sc_last: ScStep | None = None
        self._sc_sent_tick = -SC_REPEAT_EVERY
        self._operator_next = 0

    def publish(self, k: int, t: float) -> None:
        """Tick k's (simulated time t) SC request, when it changed or is due again, and operator actions."""
        self._sc_request(k, t)
        self._operator(k, t)

    def _next_seq(self, key: str) -> int:
        self._seq[key] += 1
        return self._seq[key]

    def _sc_request(self, k: int, t: float) -> None:
        current = None
        for step in self.sc_schedule:
            if step.tick <= k:
                current = step
        if current is None:
            return
        if current is self._sc_last and k - self._sc_sent_tick < SC_REPEAT_EVERY:
            return
        key = self.keys.sc_request
        request = msgspec.structs.replace(current.request, seq=self._next_seq(key), stamp=t)
        self._put(k, key, request, self.sc_link)
        self._sc_last, self._sc_sent_tick = current, k

    def _operator(self, k: int, t: float) -> None:
        while self._operator_next < len(self.operator) and self.operator[self._operator_next].tick <= k:
            action = self.operator[self._operator_next].action
            self._operator_next += 1
            command: EstopCommand | ControllerCommand
            if action == "estop" or action == "reset":
                key = self.keys.safety_estop
                command = EstopCommand(
                    seq=self._next_seq(key), stamp=t, action=action, source=SCENARIO_SOURCE
                )
            else:
                key = self.keys.controller_command
                command = ControllerCommand(
                    seq=self._next_seq(key), stamp=t, action=action, source=SCENARIO_SOURCE
                )
            self._put(k, key, command, self.operator_link)
