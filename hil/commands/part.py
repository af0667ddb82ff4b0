"""`pure-hil part`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import msgspec

from hil.commands.common import part_ended, stop_on_signals, until_interrupted


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("kind", choices=("controller", "supervisor"), help="which part")
    parser.add_argument("plugin", help="its entry point in pure_hil.controllers or pure_hil.supervisors")
    parser.add_argument(
        "spec", help="the part's spec as JSON (drivers/dut.py DutSpec, drivers/plugs.py SupervisorSpec)"
    )


def handle(args: argparse.Namespace) -> int:
    """A bench part's plug in this process, on a thread of its own, until SIGINT or SIGTERM (the rig
    spawns its parts so: drivers/plugs.py)."""
    from drivers.dut import DutHandle, DutSpec, start_dut
    from drivers.plugs import SupervisorHandle, SupervisorSpec, Watched, start_supervisor
    from drivers.registry import PlugNotFound

    spec_type: type[DutSpec] | type[SupervisorSpec] = DutSpec if args.kind == "controller" else SupervisorSpec
    try:
        spec: DutSpec | SupervisorSpec = msgspec.json.decode(Path(args.spec).read_bytes(), type=spec_type)
    except OSError as exc:
        print(f"pure-hil part: {args.spec}: cannot read: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except msgspec.MsgspecError as exc:
        print(f"pure-hil part: {args.spec}: {exc}", file=sys.stderr)
        return 2
    if spec.driven:
        print(
            f"pure-hil part: {args.spec}: driven = true is for a part in the rig's own process",
            file=sys.stderr,
        )
        return 2
    stop = stop_on_signals()  # before the part: a signal while it starts stops it cleanly
    try:
        handle: DutHandle | SupervisorHandle = (
            start_dut(args.plugin, spec) if isinstance(spec, DutSpec) else start_supervisor(args.plugin, spec)
        )
    except PlugNotFound as exc:
        print(f"pure-hil part: {exc}", file=sys.stderr)
        return 2
    try:
        bus = f"{spec.can.interface}:{spec.can.channel}"
        interrupted = until_interrupted(
            f"pure-hil part: {args.kind} {args.plugin} on {bus}; Ctrl-C to stop",
            alive=handle.alive if isinstance(handle, Watched) else None,
            stop=stop,
        )
    finally:
        handle.stop()
    return part_ended("part", args.kind, None, interrupted)
