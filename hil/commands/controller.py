"""`pure-hil controller`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse

import msgspec

from hil.commands.common import add_bench_options, bench_from, part_ended, stop_on_signals, until_interrupted


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bench_options(parser)
    parser.add_argument("--rider", required=True, help="rider file or shipped name (iHACS uses its model)")
    parser.add_argument(
        "--robot", default=None, help="the controller's robot model (default: the bench's, or pure)"
    )
    parser.add_argument("--lockstep", action="store_true", help="beside a lockstep rig")


def handle(args: argparse.Namespace) -> int:
    """The bench's controller plug as its own process (what runs beside a rig on a shared bus), started from
    the spec a run starts it from (hil.run.build.controller_spec). It runs in this process, so a signal to
    it (whoever started it stopping it) stops the controller itself, never a wrapper around it."""
    from drivers.dut import start_dut
    from drivers.plugs import Watched
    from hil.run.build import Placement, controller_spec
    from hil.run.scenario import Scenario

    bench = bench_from(args)
    if args.robot:  # its model, over the bench's: a model mismatch on purpose
        bench = msgspec.structs.replace(
            bench, controller=msgspec.structs.replace(bench.controller, robot=args.robot)
        )
    scenario = Scenario(name="controller", rider=args.rider)
    at = Placement(bench.can, bench.zenoh, scenario.tick_hz, args.lockstep)
    spec = controller_spec(bench, scenario, at)
    # A plug not installed, a bus that cannot open: one line and exit 2 (hil/cli.py main). Not the whole
    # bench's check: the supervisor's plug or the rig's certificate need not be on a controller's host.
    stop = stop_on_signals()  # before the plug: a signal while it starts stops it cleanly
    handle = start_dut(bench.controller.plugin, spec)
    try:
        interrupted = until_interrupted(
            f"pure-hil controller: {bench.controller.plugin} ({spec.mode}) on {bench.can.interface}:"
            f"{bench.can.channel}, zenoh {bench.zenoh.mode}; Ctrl-C to stop",
            alive=handle.alive if isinstance(handle, Watched) else None,
            stop=stop,
        )
    finally:
        handle.stop()
    code = part_ended("controller", "controller", getattr(handle, "node", None), interrupted)
    if code == 0:
        print("pure-hil controller: stopped", flush=True)
    return code
