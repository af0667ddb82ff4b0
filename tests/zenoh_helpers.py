"""Helpers for tests that open real zenoh sessions on 127.0.0.1."""

from __future__ import annotations

import socket

from tests.helpers import wait_for


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def hub_endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


def wait_matching(publisher, timeout: float = 5.0) -> bool:
    return wait_for(lambda: publisher.matching_status.matching, timeout)


def own_sockets() -> dict[str, list[tuple[str, int, str]]]:
    """This process's inet sockets from /proc: {'tcp': [(local ip, port, state)], 'udp': [...]}."""
    import os

    inodes = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out: dict[str, list[tuple[str, int, str]]] = {"tcp": [], "udp": []}
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        try:
            with open(f"/proc/net/{proto}") as f:
                lines = f.read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            parts = line.split()
            if parts[9] not in inodes:
                continue
            ip_hex, port_hex = parts[1].split(":")
            if len(ip_hex) == 8:
                ip = ".".join(str(int(ip_hex[i : i + 2], 16)) for i in (6, 4, 2, 0))
            else:
                ip = "::1" if ip_hex == "00000000000000000000000001000000" else ip_hex
            state = "LISTEN" if parts[3] == "0A" else parts[3]
            out[proto.rstrip("6")].append((ip, int(port_hex, 16), state))
    return out


def private_bench(name: str = "embedded", **overrides):
    """A shipped bench on a free hub port of its own (tests never take fixed ports), with a command's
    overrides (can=BusConfig, controller=, law=, supervisor=, clock=)."""
    from hil.bench.bench import load_bench

    overrides.setdefault("hub", hub_endpoint())
    return load_bench(name).with_overrides(**overrides)
