"""The wire contract's version (docs/contract.md "Versions"): a controller says in its boot-up heartbeat
which one it speaks (CONTROLLER_HEARTBEAT.Contract), and the rig refuses another with one line that names
both and what changed."""

from __future__ import annotations

CONTRACT_VERSION = 2

CHANGES = {
    2: "the boot-up heartbeat (State INIT every 100 ms until the first SYNC) says Contract = 2; "
    "SUPERVISOR_ESTOP.Takeover with SUPERVISOR_RECOVERY (the supervisor's recovery law holds the drives: "
    "stop commanding while Takeover = 1) and SUPERVISOR_DIAGNOSIS (the inputs found faulty)",
}
"""What each version changed against the one before (version 1: the first, unversioned, contract)."""


def spoken(contract: int) -> int:
    """The version a heartbeat's Contract signal names (0: a controller from before versions, i.e. 1)."""
    return contract or 1


def mismatch(contract: int) -> str:
    """'' if a controller whose heartbeat says `contract` speaks this contract, else one line saying so."""
    theirs = spoken(contract)
    if theirs == CONTRACT_VERSION:
        return ""
    if theirs > CONTRACT_VERSION:
        return (
            f"the controller speaks contract {theirs}, this rig contract {CONTRACT_VERSION}: "
            "update pure-hil (docs/contract.md, Versions)"
        )
    changed = "; ".join(f"{v}: {CHANGES[v]}" for v in range(theirs + 1, CONTRACT_VERSION + 1))
    return (
        f"the controller speaks contract {theirs}, this rig contract {CONTRACT_VERSION}; what changed since "
        f"{theirs}: {changed} (docs/contract.md, Versions)"
    )
