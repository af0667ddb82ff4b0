"""Several shared-controller agents on pure/sc/request: the most restrictive request wins.

Each source's latest accepted request is kept; the forwarded request is the one with the lowest cap (idle
is 0, free is no cap), so a conflicting or flooding agent can never lift a cap another agent set. A lease
(one source holds the channel) was the alternative: it lets whoever holds the lease refuse a legitimate
agent's stop, so merging was chosen. Each source is rate-limited by a token bucket; refusals are counted.
A source that falls silent keeps its last request (the supervisor's SC_SILENT rule lowers the cap
meanwhile), so an agent's silence never lifts its cap either.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.schemas import ScRequest
from safety.config import ScRules


@dataclass(slots=True)
class Source:
    request: ScRequest
    heard: float
    tokens: float
    accepted: int = 0
    refused: int = 0
    """Requests over the rate limit."""


class ScArbiter:
    def __init__(self, rules: ScRules):
        self.rules = rules
        self.sources: dict[str, Source] = {}
        self.refused_sources = 0
        """Requests from a source beyond `max_sources`."""
        self.conflicts = 0
        """Accepted requests whose cap differed from another source's current one."""
        self._merged: ScRequest | None = None

    def offer(self, request: ScRequest, t: float) -> bool:
        """A valid request at time t; False if refused (rate or number of sources)."""
        r = self.rules
        source = self.sources.get(request.source)
        if source is None:
            if len(self.sources) >= r.max_sources:
                self.refused_sources += 1
                return False
            source = self.sources[request.source] = Source(request, t, float(r.burst))
        source.tokens = min(float(r.burst), source.tokens + (t - source.heard) * r.rate)
        source.heard = max(source.heard, t)
        if source.tokens < 1.0:
            source.refused += 1
            return False
        source.tokens -= 1.0
        source.accepted += 1
        source.request = request
        cap = request.speed_limit()
        if any(s.request.speed_limit() != cap for name, s in self.sources.items() if name != request.source):
            self.conflicts += 1
        self._merged = min(
            (s.request for s in self.sources.values()), key=lambda q: (q.speed_limit(), q.source)
        )
        return True

    @property
    def request(self) -> ScRequest | None:
        """The most restrictive request of every source heard (None: no source yet)."""
        return self._merged

    def age(self, t: float) -> float:
        """Seconds since the stalest source was last heard (inf: none heard)."""
        return max((t - s.heard for s in self.sources.values()), default=math.inf)

    def summary(self) -> dict[str, object]:
        return {
            "sources": {
                name: {
                    "accepted": s.accepted,
                    "refused_rate": s.refused,
                    "mode": s.request.mode,
                    "cap": s.request.speed_cap,
                }
                for name, s in self.sources.items()
            },
            "refused_sources": self.refused_sources,
            "conflicts": self.conflicts,
        }
