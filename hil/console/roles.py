"""What a console may do, by the role it was started with (`--identity`): the same least privilege as the
secured bench router's ACL (configs/zenoh/bench-router.json5, docs/security.md), so the page offers only
what the router would let through. On a loopback bench (no router) these rules are the only check.
"""

from __future__ import annotations

ACTIONS: dict[str, frozenset[str]] = {
    "operator": frozenset({"start", "stop", "estop", "reset"}),
    "fault-injector": frozenset({"inject", "clear"}),
}
"""Role -> the actions its console offers; every other role (monitor, ...) only watches."""

EVERY_ACTION = ("start", "stop", "estop", "reset", "inject", "clear")


def allowed(role: str) -> frozenset[str]:
    return ACTIONS.get(role, frozenset())
