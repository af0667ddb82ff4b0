"""Before a run: open every part of the bench once, and name the one that cannot open, why, and the fix.

A bench whose bus is missing (no SocketCAN in the kernel, no vcan0, no permission), whose router is down or
whose certificates are not there fails here in one line, not minutes into a run or as a traceback.
"""

from __future__ import annotations

import shutil
import socket
from pathlib import Path

from drivers.can_bus import open_bus
from drivers.registry import CONTROLLERS, SUPERVISORS, installed
from hil.bench.bench import Bench


class BenchUnavailable(RuntimeError):
    """A part of the bench cannot be used here (the message names the part, the cause and the fix)."""


def check(bench: Bench) -> None:
    """Raise BenchUnavailable (or the bus's BusUnavailable) for the first part that cannot open."""
    if bench.can.in_process and bench.separate():
        # (In one Python process a test may run its own controller on an in-process bus; a command cannot.)
        raise BenchUnavailable(
            f"bench {bench.name}: {' and '.join(bench.separate())} in another process needs a bus shared "
            f"between processes, e.g. --can socketcan:vcan0 ({bench.can.interface!r} is in-process only)"
        )
    if not bench.can.in_process:
        open_bus(bench.can).shutdown()  # BusUnavailable says which bus, why, and what to do
    controller = bench.controller
    if controller.where != "external" and not controller.command:
        _check_plug(bench, "controller", CONTROLLERS, controller.plugin)
    if bench.supervisor.where != "external":
        _check_plug(bench, "supervisor", SUPERVISORS, bench.supervisor.plugin)
    if controller.where == "spawned" and controller.command and shutil.which(controller.command[0]) is None:
        raise BenchUnavailable(f"bench {bench.name}: controller.command {controller.command[0]!r} not found")
    if bench.zenoh.mode == "router":
        _check_router(bench)


def _check_plug(bench: Bench, part: str, group: str, plugin: str) -> None:
    """The part's plug is installed (drivers/plugs.py), embedded or spawned alike."""
    known = installed(group)
    if plugin not in known:
        raise BenchUnavailable(
            f"bench {bench.name}: {part}.plugin {plugin!r} is not installed (entry points {group}: "
            f"{', '.join(known)})"
        )


def _check_router(bench: Bench) -> None:
    zenoh = bench.zenoh
    if zenoh.certs is None:
        raise BenchUnavailable(
            f"bench {bench.name}: zenoh.certs: the router needs certificates; pass --certs DIR"
        )
    folder = Path(zenoh.certs)
    missing = [f"{role}.pem" for role in ("ca", "rig") if not (folder / f"{role}.pem").is_file()]
    if missing:
        raise BenchUnavailable(
            f"bench {bench.name}: zenoh.certs {folder}: no {', '.join(missing)}; "
            f"create them with pure-hil certs init {folder}"
        )
    endpoint = zenoh.endpoint or "tls/127.0.0.1:7448"
    host, _, port = endpoint.split("/", 1)[1].rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=2.0).close()
    except OSError as exc:
        raise BenchUnavailable(
            f"bench {bench.name}: zenoh router {endpoint} unreachable ({exc.strerror or exc}); "
            f"start it: pure-hil router --certs {folder}"
        ) from None
