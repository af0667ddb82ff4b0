"""`pure-hil estop`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import sys

from hil.commands.common import add_bench_options, join_rig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--reset", action="store_true", help="reset a latched e-stop (at standstill only)")
    what.add_argument(
        "--cut-power",
        action="store_true",
        help="category 0: the drives' power off at once, even in motion (docs/safety.md)",
    )
    parser.add_argument("--source", default=None, help="who (default user@host)")
    parser.add_argument(
        "--timeout", type=float, default=5.0, help="s to wait for the supervisor's confirmation (default 5)"
    )
    parser.add_argument("--identity", default="operator", help="its certificate's role (secured bench)")
    add_bench_options(parser)


def handle(args: argparse.Namespace) -> int:
    """Operator e-stop or reset over zenoh; waits for the supervisor to confirm its state."""
    import getpass
    import socket

    from drivers.keys import Keys
    from drivers.vocabulary import OperatorCommand
    from drivers.zenoh_link import ZenohLink
    from hil.bench.operator import command

    action: OperatorCommand = "reset" if args.reset else "cut_power" if args.cut_power else "estop"
    source = args.source or f"{getpass.getuser()}@{socket.gethostname()}"
    bench, session, card = join_rig(args)
    rig = f"rig {card.describe()}" if card else f"bench {bench.name}"
    link = ZenohLink(session, Keys(bench.zenoh.prefix))
    try:
        answer = command(link, action, source, args.timeout)
    finally:
        link.close()
        session.close()
    if not answer.heard:
        print(f"pure-hil estop: no supervisor listens on {link.keys.safety_estop}", file=sys.stderr)
        return 1
    if answer.confirmed and action != "reset":
        print(
            f"pure-hil estop: {action} by {source} latched on {rig}: {answer.seen()}; "
            "it ends in ESTOP and waits for a reset"
        )
        return 0
    refused = answer.state is not None and bool(answer.state.reset_refused)
    if action == "reset" and (answer.confirmed or refused):
        print(f"pure-hil estop: reset by {source} on {rig}: {answer.seen()}")
        return 0 if answer.confirmed else 1
    what = "it reset" if action == "reset" else f"its {action} latched"
    print(
        f"pure-hil estop: {action} sent to {rig}, but nothing confirmed {what} within {args.timeout:g} s; "
        f"{answer.seen()}",
        file=sys.stderr,
    )
    return 1
