"""`pure-hil certs`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import sys

from hil.commands.common import COUNT


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("init",), help="make a CA and every role's certificate")
    parser.add_argument("folder", help="where the certificates go (keys 0600)")
    parser.add_argument("--days", type=COUNT, default=365, help="validity of the certificates")
    parser.add_argument("--force", action="store_true", help="replace the certificates in a non-empty folder")
    parser.add_argument(
        "--host",
        action="append",
        default=None,
        help="an address the router is reached at (default 127.0.0.1)",
    )


def handle(args: argparse.Namespace) -> int:
    from hil.bench.certs import init

    try:
        paths = init(args.folder, days=args.days, force=args.force, hosts=args.host)
    except FileExistsError as exc:
        print(f"pure-hil certs: {exc}", file=sys.stderr)
        return 2
    print(
        f"pure-hil certs: CA and {len(paths) - 1} certificates in {args.folder} "
        "(keys 0600; never commit them)"
    )
    for name, path in paths.items():
        print(f"  {name:<14} {path}")
    return 0
