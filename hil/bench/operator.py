"""The operator's e-stop, category-0 cut and reset over zenoh, confirmed by the supervisor's own word
(`pure-hil estop` and the console's buttons alike)."""

from __future__ import annotations

import time
from dataclasses import dataclass

from drivers.schemas import EstopCommand, SafetyState
from drivers.vocabulary import OperatorCommand
from drivers.zenoh_link import ZenohLink


@dataclass(frozen=True, slots=True)
class Answer:
    heard: bool
    """A supervisor listens on the e-stop key (False: nothing was sent)."""
    confirmed: bool
    """An e-stop or cut latched under this source (`SafetyState.estop_by`), or a reset took (NORMAL)."""
    state: SafetyState | None
    """The state that decided it, or the last one seen."""

    def seen(self) -> str:
        return f"supervisor {self.state.state} ({self.state.reason})" if self.state else "no supervisor state"


def command(link: ZenohLink, action: OperatorCommand, source: str, timeout: float) -> Answer:
    """Put the operator's command and wait up to `timeout` s for the supervisor's state to confirm it: an
    e-stop by `estop_by` naming `source`, a reset by NORMAL (or its refusal, which is unconfirmed)."""
    states = link.subscribe(link.keys.safety_state, SafetyState)
    deadline = time.monotonic() + timeout
    if not link.wait_for_subscriber(link.keys.safety_estop, timeout):
        return Answer(heard=False, confirmed=False, state=None)
    link.put(link.keys.safety_estop, EstopCommand(seq=1, stamp=time.time(), action=action, source=source))
    last = None
    while time.monotonic() < deadline:
        states.wait(max(deadline - time.monotonic(), 0.0))
        for state in states.drain():
            last = state
            if action != "reset" and state.estop_by == source:
                return Answer(heard=True, confirmed=True, state=state)
            if action == "reset" and (state.state == "NORMAL" or state.reset_refused):
                return Answer(heard=True, confirmed=state.state == "NORMAL", state=state)
    return Answer(heard=True, confirmed=False, state=last)
