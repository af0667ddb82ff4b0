"""`pure-hil supervisor`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

import msgspec

from hil.commands.common import add_bench_options, bench_from, part_ended, stop_on_signals, until_interrupted


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bench_options(parser)
    parser.add_argument("--robot", default="pure", help="robot file or shipped name (its geometry)")
    parser.add_argument("--tick-hz", type=float, default=400.0, help="the rig's SYNC rate (time stamps)")
    parser.add_argument(
        "--clock",
        choices=("realtime", "lockstep"),
        default="realtime",
        help="realtime: its own 400 Hz timer; lockstep: the SYNC tick's time (beside a lockstep rig)",
    )
    parser.add_argument(
        "--role", choices=("member", "hub"), default="member", help="loopback: hub without a rig"
    )
    parser.add_argument("--identity", default="supervisor", help="its certificate's role (secured bench)")
    parser.add_argument("--safety", default=None, help="a scenario's [safety] overrides, as JSON")


def handle(args: argparse.Namespace) -> int:
    """The supervisor as its own process, on its own timer (what runs beside a real robot): the bench's
    supervisor plug, as the rig starts it (drivers/plugs.py)."""
    from contextlib import ExitStack

    from drivers.keys import Keys
    from drivers.plugs import Watched, start_supervisor
    from drivers.zenoh_link import ZenohLink
    from hil.bench.parts import check
    from hil.bench.rigs import announce
    from hil.run.build import Placement, supervisor_spec
    from hil.run.scenario import Scenario

    bench = bench_from(args)
    if bench.can.in_process:
        print(
            "pure-hil supervisor: needs a bus shared with other processes (e.g. --can socketcan:vcan0)",
            file=sys.stderr,
        )
        return 2
    try:  # the rules as a run would hand them over: the bench's, with a scenario's overrides
        overrides = msgspec.json.decode(args.safety or "{}", type=dict[str, dict[str, Any]])
        scenario = Scenario(name="overrides", robot=args.robot, safety=overrides)
    except (ValueError, msgspec.DecodeError) as exc:
        print(f"pure-hil supervisor: --safety: {exc}", file=sys.stderr)
        return 2
    at = Placement(bench.can, bench.zenoh, args.tick_hz, lockstep=args.clock == "lockstep")
    spec = supervisor_spec(bench, scenario, at, overrides="--safety")
    check(bench)  # the bus and the plug, before any session: a missing vcan0 is one line and exit 2
    hub = bench.zenoh.mode == "loopback" and args.role == "hub"
    # Its session as this command's role says (the rig's hub, or --identity's certificate), lent to the plug.
    session = bench.zenoh.open_rig(fallback=False)[0] if hub else bench.zenoh.open(args.identity)
    link = ZenohLink(session, Keys(bench.zenoh.prefix))
    stop = stop_on_signals()  # before the plug: a signal while it starts stops it cleanly
    try:
        handle = start_supervisor(bench.supervisor.plugin, spec, link=link)
        with ExitStack() as announced:
            where = f"zenoh {bench.zenoh.mode}"
            if hub:
                endpoint = bench.zenoh.hub_endpoint()
                announced.enter_context(
                    announce(session, bench.zenoh.prefix, bench.name, endpoint, "supervisor")
                )
                where = f"zenoh hub {endpoint}"
            interrupted = until_interrupted(
                f"pure-hil supervisor: on {bench.can.interface}:{bench.can.channel}, {where}; Ctrl-C to stop",
                alive=handle.alive if isinstance(handle, Watched) else None,
                stop=stop,
            )
        handle.stop()
    finally:
        link.close()
        session.close()
    node = handle.node
    for e in node.events:
        print(f"  t={e.t:9.3f}  {e.kind:<14} {e.from_state} -> {e.to_state} ({e.cause}) {e.detail}")
    return part_ended("supervisor", "supervisor", node, interrupted)
