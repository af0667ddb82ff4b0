"""`pure-hil rig`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse

from hil.commands.common import add_bench_options, ask_service


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "action",
        choices=("status", "start", "stop", "intent"),
        help="what to ask the service (docs/rig.md)",
    )
    parser.add_argument("arg", nargs="?", default=None, help="scenario (start) or intent JSON (intent)")
    parser.add_argument("--identity", default="operator", help="its certificate's role (secured bench)")
    add_bench_options(parser)


def handle(args: argparse.Namespace) -> int:
    return ask_service(args, args.action, args.arg or "", f"pure-hil rig {args.action}")
