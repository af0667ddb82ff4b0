"""`pure-hil controller`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import msgspec

from drivers.resources import find
from hil.commands.common import add_bench_options, bench_from


def controller_command(bench, rider: str, robot: str, law: str, lockstep: bool) -> list[str]:
    """`pure-controller` on this bench: its bus, its zenoh (with the controller's certificate on a router)."""
    script = Path(sys.executable).with_name("pure-controller")
    zenoh = bench.zenoh
    command = [str(script) if script.exists() else "pure-controller"]
    command += ["--can", f"{bench.can.interface}:{bench.can.channel}", "--prefix", zenoh.prefix]
    command += ["--zenoh", str(zenoh.config_path)]
    if zenoh.endpoint:
        command += ["--hub", zenoh.endpoint]
    if zenoh.mode == "router":
        command += ["--certs", str(zenoh.certs), "--identity", "controller"]
        command += ["--allow-network"] if zenoh.network else []
    command += ["--rider", str(find(rider, "riders")), "--robot", str(find(robot, "robot"))]
    command += ["--config", str(find(bench.controller.config, "controller")), "--law", law]
    if not bench.devices.pure:
        command += ["--devices", msgspec.json.encode(bench.devices).decode()]
    return command + (["--lockstep"] if lockstep else [])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bench_options(parser)
    parser.add_argument("--rider", required=True, help="rider file or shipped name (iHACS uses its model)")
    parser.add_argument(
        "--robot", default=None, help="the controller's robot model (default: the bench's, or pure)"
    )
    parser.add_argument("--lockstep", action="store_true", help="beside a lockstep rig")


def handle(args: argparse.Namespace) -> int:
    """The reference controller as its own process on this bench (the rig never imports a controller).
    This process becomes pure-controller (exec), so a signal to it (the rig stopping what it spawned)
    reaches the controller itself: a wrapper would exit and leave the controller running on the bus."""
    bench = bench_from(args)
    law = args.law or (bench.controller.law if bench.controller.law != "scenario" else "hacs")
    command = controller_command(
        bench, args.rider, args.robot or bench.controller.robot or "pure", law, args.lockstep
    )
    sys.stdout.flush()
    os.execvp(command[0], command)
