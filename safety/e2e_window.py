"""One protected stream's E2E checks judged over a window: a corrupted or lost frame is transient until the
window says otherwise (the state machine of AUTOSAR's E2E profiles, in this project's terms; no I/O, no
clock: the monitors feed it each frame's E2E status as it is read).

Every frame slot is a check. A frame that passes E2E is an OK check; one that fails it (CRC, repeated, out
of order) is an error check; a frame that arrives after a gap (LOST) is an OK check after one error check
per frame missing, less the frames of that gap already counted as corrupted (a corrupted frame's slot is one
the gap reports: counted once). Over the last `window` checks at most `max_errors` errors are tolerated:

    NODATA ──any check──▶ INIT ──at least window − max_errors OK, at most max_errors errors──▶ VALID
                            │                                                                  │ ▲
                            └──more than max_errors errors──▶ INVALID ◀──more than max_errors──┘ │
                                                                 └──── window checks all OK ─────┘

INVALID clears the window (a stream is trusted again only on a whole window of its own clean checks, not on
the clean ones before its errors). A trusted stream rides through a burst of at most `max_errors` errors
within a window; it is named (INVALID) only when its errors persist. Silence is not a check: E2E cannot
count frames it never saw beyond its counter's gap, and the stream watchdogs judge time (safety/machine.py).
"""

from __future__ import annotations

from collections import deque
from enum import IntEnum

from drivers.e2e import E2EStatus


class WindowState(IntEnum):
    NODATA = 0
    """No check yet."""
    INIT = 1
    """Checks have begun, not yet a window's worth of OK ones, and no more errors than tolerated."""
    VALID = 2
    INVALID = 3
    """More errors than tolerated in the window: the stream is not trusted until a whole window is clean."""


class E2EWindow:
    """The last `window` checks of one stream and the state they put it in."""

    def __init__(self, window: int, max_errors: int) -> None:
        if not 0 <= max_errors < window:
            raise ValueError(f"max_errors ({max_errors}) must be at least 0 and below window ({window})")
        self.window, self.max_errors = window, max_errors
        self.state = WindowState.NODATA
        self._count = 0
        """Checks since the window began (start-up, or the entry to INVALID)."""
        self._errors: deque[int] = deque()
        """The numbers (of `_count`) of the error checks among the last `window`."""
        self._corrupted = 0
        """Frames that failed their CRC since the last one whose counter was read (their slots are the
        ones the next LOST reports)."""

    @property
    def errors(self) -> int:
        """Error checks among the last `window` (since the window began)."""
        return len(self._errors)

    def frame(self, status: E2EStatus, lost: int = 0) -> WindowState:
        """One frame's E2E status (`lost`: the frames missing before it, LOST only); the state after it."""
        if status is E2EStatus.OK:
            self._corrupted = 0
            if self.state is WindowState.VALID:  # most frames: a clean check cannot change VALID
                self._count += 1
                errors = self._errors
                if errors and errors[0] <= self._count - self.window:
                    errors.popleft()
                return WindowState.VALID
            self._check(error=False)
        elif status is E2EStatus.LOST:
            for _ in range(lost - self._corrupted):
                self._check(error=True)
            self._corrupted = 0
            self._check(error=False)
        else:
            if status is E2EStatus.CRC_ERROR:
                self._corrupted += 1
            self._check(error=True)
        return self.state

    def _check(self, error: bool) -> None:
        self._count += 1
        errors = self._errors
        if error:
            errors.append(self._count)
        while errors and errors[0] <= self._count - self.window:
            errors.popleft()
        state = self.state
        if state is WindowState.NODATA:
            state = self.state = WindowState.INIT
        if state is WindowState.INVALID:
            if self._count >= self.window and not errors:
                self.state = WindowState.VALID
        elif len(errors) > self.max_errors:
            self.state = WindowState.INVALID
            self._count = 0
            errors.clear()
        elif state is WindowState.INIT and min(self._count, self.window) - len(errors) >= (
            self.window - self.max_errors
        ):
            self.state = WindowState.VALID
