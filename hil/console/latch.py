"""The operator's e-stop latch as a console knows it: the supervisor's own word while it is heard, and this
console's memory of it once that supervisor is gone (pure: no I/O, no clock; rig_link.py feeds it).

The supervisor latches an operator's e-stop (`SafetyState.estop_by`) until a valid reset. On a bench whose
supervisor runs with each run, that supervisor ends with the run, and its latch with it: the next run's
supervisor starts NORMAL with the drives permitted. So a latch whose supervisor went silent without a reset
is kept here (held by the console), and the console refuses to start a run until an operator resets it, on
the supervisor when one listens, else on the console itself (ISO 13850: a reset is a deliberate act of its
own; it permits a start and never causes one).

    heard(word)          the supervisor's state: estop_by set -> held by the supervisor; '' -> cleared, if it
                         was that supervisor's (never silent meanwhile, the same run)
    (silence)            no word for SILENT s: the supervisor is gone; a latch it held is the console's now
    run_ended(...)       a run this console never heard ended ESTOPPED: held by the console
    reset()              an operator's reset: clears what is held (the caller decides when it may)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

SILENT = 2.0
"""s without a state from the supervisor after which it is gone. It speaks every 0.1 s of simulated time,
and a state changes at once; 2 s of wall time is a lockstep run at 1/20 of real time, or none at all."""

Holder = Literal["supervisor", "console"]


@dataclass(frozen=True, slots=True)
class Word:
    """A state the supervisor published, as this console heard it."""

    state: str
    reason: str
    estop_by: str
    run: int | None
    """The service's run going when it was heard (None: none, or not known)."""
    at: float
    """When it was heard, s on the console's clock."""


@dataclass(frozen=True, slots=True)
class Held:
    """An operator's e-stop known to be latched."""

    by: str
    run: int | None
    since: float
    """When this console learned of it."""


class Latch:
    def __init__(self) -> None:
        self.word: Word | None = None
        """The supervisor's last word (None: never heard)."""
        self.held: Held | None = None
        self.orphaned = False
        """The supervisor that held it went silent: only a reset clears it now (a supervisor that comes back
        latched takes it back)."""
        self.why_orphaned = ""

    # ------------------------------------------------------------------------------------------ inputs
    def heard(self, word: Word) -> None:
        held, last = self.held, self.word
        if held is not None and not self.orphaned:
            if last is None or word.at - last.at > SILENT:
                self._orphan("never heard" if last is None else f"silent after {last.state} ({last.reason})")
            elif held.run is not None and word.run is not None and word.run != held.run:
                self._orphan(f"run {held.run}'s supervisor ended with it; run {word.run}'s never saw it")
        if word.estop_by:
            if self.held is None or (self.held.by, self.held.run) != (word.estop_by, word.run):
                self.held = Held(word.estop_by, word.run, word.at)
            self.orphaned, self.why_orphaned = False, ""
        elif self.held is not None and not self.orphaned:
            self.held = None  # the supervisor's own word: a valid reset took
        self.word = word

    def run_ended(self, run: int, verdict: str, now: float) -> None:
        """The service says run `run` ended with `verdict`. An operator's e-stop ended it (ESTOPPED) and
        this console never heard that run's supervisor: whether a reset followed is unknown, so it is held."""
        heard_it = self.word is not None and self.word.run == run
        if self.held is None and verdict == "ESTOPPED" and not heard_it:
            self.held = Held(f"an operator (run {run}'s summary.json names them)", run, now)
            self.orphaned = True
            self.why_orphaned = f"run {run} ended ESTOPPED before this console heard its supervisor"

    def reset(self) -> Held | None:
        """An operator's reset (on the supervisor, or on this console when no supervisor listens): what it
        cleared."""
        cleared, self.held = self.held, None
        self.orphaned, self.why_orphaned = False, ""
        return cleared

    # ----------------------------------------------------------------------------------------- queries
    def silent(self, now: float) -> bool:
        return self.word is None or now - self.word.at > SILENT

    def holder(self, now: float) -> Holder | None:
        if self.held is None:
            return None
        return "console" if self.orphaned or self.silent(now) else "supervisor"

    def start_refusal(self, now: float) -> str:
        """Why a start is refused now ('' when it is not)."""
        held, holder = self.held, self.holder(now)
        if held is None:
            return ""
        if holder == "supervisor":
            return f"the supervisor holds an e-stop by {held.by}: reset it first"
        return (
            f"the e-stop by {held.by}{_of(held.run)} was never reset and the supervisor that held it is gone "
            f"({self._why_gone(now)}): press Reset to clear it on this console before a start"
        )

    def view(self, now: float) -> dict:
        """What a page shows: the supervisor's last word and its age, and the latch and who holds it."""
        word, held = self.word, self.held
        return {
            "now": now,
            "supervisor": None
            if word is None
            else {
                "state": word.state,
                "reason": word.reason,
                "estop_by": word.estop_by,
                "run": word.run,
                "at": word.at,
                "age": round(now - word.at, 3),
            },
            "silent": self.silent(now),
            "latched": None
            if held is None
            else {
                "by": held.by,
                "run": held.run,
                "since": held.since,
                "age": round(now - held.since, 3),
                "held_by": self.holder(now),
                "why": "" if self.holder(now) == "supervisor" else self._why_gone(now),
            },
            "start_refusal": self.start_refusal(now),
        }

    # ----------------------------------------------------------------------------------------- helpers
    def _orphan(self, why: str) -> None:
        self.orphaned, self.why_orphaned = True, why

    def _why_gone(self, now: float) -> str:
        if self.orphaned:
            return self.why_orphaned
        if self.word is None:
            return "never heard"
        return f"silent for {now - self.word.at:.0f} s"


def _of(run: int | None) -> str:
    return "" if run is None else f" in run {run}"
