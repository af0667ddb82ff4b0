"""A network namespace whose only interface is lo: where python-can's `udp_multicast` may run, since
nothing sent inside it can leave the machine (docs/bench.md, "Processes at host speed"). Created with a
multicast route on lo, removed on exit, also on failure."""

from __future__ import annotations

import secrets
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager

SETUP = (
    ("link", "set", "lo", "up"),
    ("link", "set", "lo", "multicast", "on"),
    ("route", "add", "224.0.0.0/4", "dev", "lo"),
)


class NamespaceRefused(RuntimeError):
    """This machine does not let us create a network namespace (no `ip`, or not permitted)."""


@contextmanager
def loopback_namespace(prefix: str = "pure-bus") -> Iterator[str]:
    """The new namespace's name (run a command in it with `ip netns exec NAME ...`)."""
    name = f"{prefix}-{secrets.token_hex(3)}"
    try:
        subprocess.run(["ip", "netns", "add", name], check=True, capture_output=True, text=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        why = getattr(exc, "stderr", None) or str(exc)
        raise NamespaceRefused(f"cannot create a network namespace: {why.strip()}") from exc
    try:
        for step in SETUP:
            subprocess.run(["ip", "-n", name, *step], check=True, capture_output=True, text=True)
        yield name
    finally:
        subprocess.run(["ip", "netns", "del", name], capture_output=True)
