"""The console's fan-out of live events to its pages (Server-Sent Events).

zenoh's threads publish (never blocking: a lock held for an append); every page's request thread waits on
one condition for events newer than the last it wrote. Nothing is kept per page, so a page that goes away
leaves nothing behind, and a page that falls behind by more than KEEP events skips to the newest.
"""

from __future__ import annotations

import threading
from collections import deque

KEEP = 256
"""Events kept for pages that are behind (about 10 s of the 20 Hz live stream)."""


LIVE = b"event: live\n"


def encode(event: str, data: str) -> bytes:
    """One SSE message; `data` is one line of JSON (json.dumps never writes a raw newline)."""
    return f"event: {event}\ndata: {data}\n\n".encode()


class Broadcast:
    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._log: deque[tuple[int, bytes]] = deque(maxlen=KEEP)
        self._latest: dict[str, tuple[int, bytes]] = {}
        self._seq = 0
        self.closed = False

    def publish(self, event: str, data: str) -> None:
        message = encode(event, data)
        with self._changed:
            self._seq += 1
            self._log.append((self._seq, message))
            self._latest[event] = (self._seq, message)
            self._changed.notify_all()

    def snapshot(self) -> tuple[int, list[bytes]]:
        """A new page's first picture, and the sequence number it is at: the kept live samples (its charts
        start with the last seconds of the run) and the newest event of every other kind."""
        with self._changed:
            kept = [(seq, m) for seq, m in self._log if m.startswith(LIVE)]
            others = [(seq, m) for seq, m in self._latest.values() if not m.startswith(LIVE)]
            return self._seq, [m for _, m in sorted(kept + others)]

    def latest(self, event: str) -> bytes | None:
        with self._changed:
            found = self._latest.get(event)
            return None if found is None else found[1]

    def wait(self, after: int, timeout: float) -> tuple[int, list[bytes]]:
        """Events newer than `after`, waiting up to `timeout` s for one; ([]) on timeout or close."""
        with self._changed:
            self._changed.wait_for(lambda: self._seq > after or self.closed, timeout)
            newer = [m for seq, m in self._log if seq > after]
            return self._seq, newer

    def close(self) -> None:
        with self._changed:
            self.closed = True
            self._changed.notify_all()
