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
PERSON_ROLES = ("operator", "fault-injector", "monitor")
"""The bench's roles a person logged in to a console may have (hil/console/accounts.py)."""


def allowed(role: str) -> frozenset[str]:
    return ACTIONS.get(role, frozenset())


def allowed_to(person_role: str, console_role: str) -> frozenset[str]:
    """What a person may do on a console: their role's actions, never more than the console's own role
    (its certificate: on the secured bench the router would refuse the rest anyway)."""
    return allowed(person_role) & allowed(console_role)
