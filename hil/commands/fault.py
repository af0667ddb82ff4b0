"""`pure-hil fault`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import json
import re
import sys
import typing

import msgspec

from drivers.bounds import MAX_DURATION
from hil.commands.common import DURATION, add_bench_options, ask_service, number


def _parameter(value: str) -> object:
    """A --param value: JSON (a number, true, a list: force=[100,0]), values separated by commas as a list
    (force=100,0: a shell needs no quotes for it), a number however Python spells it (nan, inf: refused by
    name later, not taken for words), else the word itself (a channel, a message)."""
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        pass
    if "," in value:
        return [_parameter(part.strip()) for part in value.split(",")]
    try:
        return float(value)
    except ValueError:
        return value


def _form(kind: str, name: str) -> str:
    """How parameter `name` of fault `kind` is written on the command line when it takes several values (a
    tuple: msgspec's 'Expected `array`' names neither that form nor the parameter); '' for any other."""
    from hil.faults import CATALOG

    field = next((f for f in msgspec.structs.fields(CATALOG[kind]) if f.name == name), None)
    if field is None or typing.get_origin(field.type) is not tuple:
        return ""
    n = len(typing.get_args(field.type))
    example = ",".join(["100"] + ["0"] * (n - 1))
    return f"expected {n} numbers, as {name}={example} or {name}=[{example}]"


def _expectation(text: str, within: float | None) -> dict:
    """`--expect` as a fault's `expect` (docs/faults.md): none, STATE, CAUSE or STATE/CAUSE; the fault's
    own check names what is wrong with it."""
    from drivers.vocabulary import State

    if text.lower() == "none":
        return {"reaction": "none"}
    state, _, cause = text.upper().rpartition("/")
    if not state and cause in State.__members__:
        state, cause = cause, ""
    expect: dict = {"state": state} if state else {}
    expect |= {"cause": cause} if cause else {}
    return expect if within is None else {**expect, "within": within}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "action", choices=("list", "inject", "clear"), help="the catalog, or a live fault (docs/faults.md)"
    )
    parser.add_argument("kind", nargs="?", default=None, help="inject: the fault's kind; clear: its number")
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a fault parameter; several values as a list: force=100,0 or force=[100,0]",
    )
    parser.add_argument(
        "--at", type=number(float, 0.0, MAX_DURATION), default=0.0, help="seconds from now (simulated)"
    )
    parser.add_argument("--duration", type=DURATION, default=None, help="seconds (default: until cleared)")
    parser.add_argument(
        "--expect",
        default=None,
        metavar="CAUSE",
        help="the supervisor's reaction the run's verdict expects: a cause (WRENCH_SILENT), a state "
        "(RECOVERY), STATE/CAUSE, or none (ridden through); without it a stop the fault causes fails the run",
    )
    parser.add_argument(
        "--within", type=DURATION, default=None, help="seconds from the fault's start for --expect (0.1)"
    )
    parser.add_argument("--identity", default="fault-injector", help="its certificate's role (secured bench)")
    add_bench_options(parser)


def handle(args: argparse.Namespace) -> int:
    """The fault catalog, or live injection into a running `pure-hil serve` over its zenoh API."""
    from hil.faults import describe_catalog, parse_fault

    if args.action == "list":
        print(describe_catalog())
        return 0
    if args.action == "inject":
        if not args.kind:
            print("pure-hil fault inject: which fault? (pure-hil fault list)", file=sys.stderr)
            return 2
        fault: dict = {"kind": args.kind, "at": args.at}
        if args.duration is not None:
            fault["duration"] = args.duration
        for item in args.param:
            name, sep, value = item.partition("=")
            if not sep:
                print(f"pure-hil fault inject: --param {item!r}: expected NAME=VALUE", file=sys.stderr)
                return 2
            fault[name] = _parameter(value)
        if args.within is not None and (args.expect or "none").lower() == "none":
            print("pure-hil fault inject: --within times the reaction --expect names", file=sys.stderr)
            return 2
        if args.expect is not None:
            fault["expect"] = _expectation(args.expect, args.within)
        try:
            parse_fault(fault, "pure-hil fault inject")  # the same check the service makes, before sending
        except ValueError as exc:
            at = re.search(r"at `\$\.(\w+)`", str(exc))
            form = _form(args.kind, at.group(1)) if at else ""
            if form and at:
                given = next((p for p in args.param if p.partition("=")[0] == at.group(1)), at.group(1))
                print(f"pure-hil fault inject: {args.kind}: --param {given}: {form}", file=sys.stderr)
            else:
                print(exc, file=sys.stderr)
            return 2
        key, payload = "fault/inject", json.dumps(fault)
    else:
        if args.kind is not None and not args.kind.isdigit():
            print(
                f"pure-hil fault clear: {args.kind!r}: expected a fault's number (pure-hil rig status)",
                file=sys.stderr,
            )
            return 2
        key, payload = "fault/clear", "" if args.kind is None else args.kind
    return ask_service(args, key, payload, f"pure-hil fault {args.action}")
