"""`pure-hil console`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import sys

from hil.commands.common import add_bench_options, join_rig, until_interrupted


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--listen",
        default="127.0.0.1:0",
        metavar="IP:PORT",
        help="where the page is served (port 0: a free one); off loopback it needs --tls-cert and --tls-key",
    )
    parser.add_argument(
        "--tls-cert", default=None, metavar="PEM", help="serve HTTPS with this certificate (chain)"
    )
    parser.add_argument("--tls-key", default=None, metavar="PEM", help="the private key of --tls-cert")
    parser.add_argument(
        "--identity",
        default="operator",
        help="its certificate's role (secured bench); the page offers that role's actions only: operator "
        "(start, stop, e-stop, reset), fault-injector (faults), any other watches",
    )
    parser.add_argument(
        "--source",
        default=None,
        help="who its e-stops say they are from (default: console ROLE user@host; with --accounts: "
        "console ROLE NAME, the person logged in)",
    )
    parser.add_argument(
        "--accounts",
        default=None,
        metavar="FILE",
        help="who may log in, each with a bench role (pure-hil accounts); needed off loopback",
    )
    add_bench_options(parser)


def handle(args: argparse.Namespace) -> int:
    """The rig's screen in a browser: a zenoh client of `pure-hil serve` that serves one page over HTTP."""
    import getpass
    import socket
    from dataclasses import asdict

    from drivers.keys import Keys
    from hil.console import accounts
    from hil.console.events import Broadcast
    from hil.console.rig_link import RigLink, fault_catalog
    from hil.console.server import Console, ListenError, check_exposure, parse_listen, tls_context

    try:  # the options first: a mistake costs no zenoh session
        listen = parse_listen(args.listen)
        tls = tls_context(args.tls_cert, args.tls_key)
        people = accounts.load(args.accounts) if args.accounts else None
        check_exposure(listen, tls, bool(people))
    except (ListenError, accounts.AccountsError) as exc:
        print(f"pure-hil console: {exc}", file=sys.stderr)
        return 2
    source = (args.source or f"console {args.identity} {getpass.getuser()}@{socket.gethostname()}")[:64]
    bench, session, card = join_rig(args)
    link = RigLink(
        session,
        Keys(bench.zenoh.prefix),
        args.identity,
        source,
        Broadcast(),
        None if card is None else asdict(card),
    )
    info = {"bench": bench.name, "faults": fault_catalog()}
    try:  # its output is its audit log: who did what, from where, and the answer
        console = Console(link, info, listen, tls, people, audit=lambda line: print(line, flush=True))
        console.start()
    except ListenError as exc:
        link.close()
        session.close()
        print(f"pure-hil console: {exc}", file=sys.stderr)
        return 2
    rig = card.describe() if card else f"bench {bench.name} through its router"
    login = f", {len(people)} accounts" if people else ""
    until_interrupted(
        f"pure-hil console: {rig}, role {args.identity}{login}; Ctrl-C to stop\nconsole: {console.url}"
    )
    console.close()
    link.close()
    session.close()
    return 0
