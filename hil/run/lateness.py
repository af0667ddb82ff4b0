"""The rig's own lateness in real time, told apart from the controller's (docs/rig.md "When the rig is
late").

The contract (docs/contract.md "One tick") owes a controller the time from SYNC(k) to the next tick's start.
The rig promises SYNC(k) no later than `sync_allowance` after tick k's scheduled start; a tick whose SYNC went
out later is the rig's late tick, and so are the TAIL_TICKS after it (a controller whose budget the rig cut
may still be busy with that tick when the next SYNC comes). What the controller misses in those ticks
(commands missing, or answered after their tick was over) is the rig's; what it misses in the others is its
own. A pure ledger: the rig tells it what happened, tick by tick."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from drivers.schemas import TICK_MODULO

TAIL_TICKS = 2
"""Ticks after a late SYNC that are still the rig's."""
WINDOWS_KEPT = 1000
"""Late windows a run keeps (their start and end); more are counted only (a week-long service run must not
grow)."""
REACTION_AFTER = 0.1
"""s after the end of one of the rig's late windows within which a supervisor's stop is taken to be the
lateness's doing: the reference's watchdogs on the rig's and the controller's frames are 25-100 ms
(configs/safety/default.toml [watchdogs])."""
RECENT = 64
"""Late ticks remembered to judge a late command by its tag (a command later than this is lost anyway)."""


@dataclass(slots=True)
class Lateness:
    ticks: int = 0
    """Ticks whose SYNC went out after its due time."""
    missing: int = 0
    """Commands missing in the rig's late windows."""
    late: int = 0
    """Commands that came after their tick was over, for a tick of the rig's late windows."""
    windows: list[list[float]] = field(default_factory=list)
    """[start, end] in simulated time of each stretch of late ticks (their tails included)."""
    windows_dropped: int = 0
    """Late windows beyond WINDOWS_KEPT."""
    worst: float = 0.0
    """s: the latest SYNC, after its due time."""
    _recent: deque[int] = field(default_factory=lambda: deque(maxlen=RECENT))
    """The last late ticks (tick numbers, not wrapped)."""
    _open_kept: bool = False
    """The window the last late tick opened or extended is in `windows`."""

    def sync(self, k: int, t: float, dt: float, late_by: float) -> None:
        """Tick k (simulated time t, ticks of dt) sent its SYNC `late_by` seconds after its due time (<= 0:
        on time)."""
        if late_by <= 0.0:
            return
        self.ticks += 1
        self.worst = max(self.worst, late_by)
        end = t + TAIL_TICKS * dt
        if self._recent and k - self._recent[-1] <= TAIL_TICKS + 1:
            if self._open_kept:
                self.windows[-1][1] = end
        elif len(self.windows) < WINDOWS_KEPT:
            self.windows.append([t, end])
            self._open_kept = True
        else:
            self.windows_dropped += 1
            self._open_kept = False
        self._recent.append(k)

    def owns(self, k: int) -> bool:
        """Tick k is in one of the rig's late windows (a late tick or its tail)."""
        return any(0 <= k - late <= TAIL_TICKS for late in self._recent)

    def owns_tag(self, k: int, tag: int) -> bool:
        """A command tagged `tag` (a tick mod TICK_MODULO) that arrives in tick k answered one of the rig's
        late ticks."""
        behind = (k - tag) % TICK_MODULO
        return self.owns(k - behind)

    @property
    def cost(self) -> int:
        """Commands the rig's lateness cost the controller."""
        return self.missing + self.late

    def covers(self, t: float, after: float) -> bool:
        """Simulated time t falls in a late window or within `after` seconds of one's end."""
        return any(start - 1e-9 <= t <= end + after for start, end in self.windows)

    def as_dict(self) -> dict[str, object]:
        return {
            "late_ticks": self.ticks,
            "windows": [[round(a, 4), round(b, 4)] for a, b in self.windows],
            "commands_missing": self.missing,
            "commands_late": self.late,
            "windows_dropped": self.windows_dropped,
            "worst_ms": round(self.worst * 1e3, 3),
        }
