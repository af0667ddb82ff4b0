"""`pure-hil` command line. Exit codes: 0 pass, 1 fail (e.g. the robot fell), 2 usage or config error.

One table, COMMANDS, names each command's module (hil/commands/) and its one-line summary; the parser's
sub-commands are made from it, and a command's module (its options beside its handler) is imported only when
that command runs, so `pure-hil --help` imports none (pip's `commands_dict` does the same). Every command that
touches the bench reads one bench file (`--bench`, default `embedded`; hil/bench/bench.py) and takes the same
few overrides: --can, --controller, --law, --supervisor, --hub, --certs (and --clock where a scenario runs;
hil/commands/common.py).
"""

from __future__ import annotations

import os

# Tiny LAPACK calls (LQR, ARE) are 10-20x slower with OpenBLAS's thread pool on small machines.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import importlib
import sys
from typing import NamedTuple, NoReturn


class Command(NamedTuple):
    module: str  # its add_arguments(parser) and handle(args) -> exit code
    summary: str  # its line in `pure-hil --help`


COMMANDS: dict[str, Command] = {
    "simulate": Command("hil.commands.simulate", "plant-only run: PURE + rider on the ideal balancer"),
    "run": Command("hil.commands.run", "run a scenario on the bench; exit 0 pass, 1 fail, 2 usage/config"),
    "compare": Command("hil.commands.compare", "HACS vs iHACS over scenarios and riders: the paper's table"),
    "calibrate": Command(
        "hil.commands.calibrate", "fit unknown parameters to a target table (bounded least squares)"
    ),
    "adversary": Command("hil.commands.adversary", "search the worst rider for an STL requirement"),
    "campaign": Command(
        "hil.commands.campaign", "scenarios x riders x faults x seeds in parallel; report + JUnit"
    ),
    "replay": Command(
        "hil.commands.replay", "replay a run's CAN log and zenoh inputs into a fresh controller"
    ),
    "serve": Command(
        "hil.commands.serve", "the long-running rig service, controlled over zenoh (pure/rig/*)"
    ),
    "supervisor": Command(
        "hil.commands.supervisor", "the safety supervisor as its own process, on the bench's bus"
    ),
    "controller": Command(
        "hil.commands.controller", "the bench's controller plug as its own process, from the spec a run uses"
    ),
    "part": Command(
        "hil.commands.part",
        "a bench part's plug in a process of its own, from the spec the rig wrote (the rig's spawned "
        "parts run so)",
    ),
    "estop": Command("hil.commands.estop", "operator e-stop (or --reset) to the supervisor over zenoh"),
    "rig": Command(
        "hil.commands.rig", "talk to a running `pure-hil serve`: status, start FILE, stop, intent JSON"
    ),
    "fault": Command(
        "hil.commands.fault", "the fault catalog (list), or inject/clear a fault in a running serve"
    ),
    "console": Command(
        "hil.commands.console", "the rig's screen in a browser: a client of `pure-hil serve` (docs/rig.md)"
    ),
    "accounts": Command(
        "hil.commands.accounts", "who may log in to a console: names, roles, scrypt hashes (docs/security.md)"
    ),
    "certs": Command("hil.commands.certs", "certificates for the secured bench router (docs/security.md)"),
    "router": Command("hil.commands.router", "the secured bench router: mutual TLS + ACL (docs/security.md)"),
}
"""Every `pure-hil` command, in the order `--help` and docs/cli.md list them."""


def package_version() -> str:
    """pure-hil's installed version (`--version`)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pure-hil")
    except PackageNotFoundError:
        return "unknown (run from a source tree that is not installed)"


class _Parser(argparse.ArgumentParser):
    """argparse's, its errors in one line (the usage is a --help away); its sub-commands' parsers too."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _give_options(name: str, parser: argparse.ArgumentParser) -> None:
    """The command's options and handler, from its module (imported now), once."""
    if parser.get_default("func") is None:
        module = importlib.import_module(COMMANDS[name].module)
        module.add_arguments(parser)
        parser.set_defaults(func=module.handle)


class _Commands(argparse._SubParsersAction):
    """argparse's sub-commands; the one chosen gets its options just before it parses the rest."""

    def __call__(self, parser, namespace, values, option_string=None):
        if values and values[0] in COMMANDS:
            _give_options(values[0], self._name_parser_map[values[0]])
        super().__call__(parser, namespace, values, option_string)


def build_parser(every: bool = False) -> argparse.ArgumentParser:
    """The parser, a sub-command for each entry of COMMANDS; `every`: all their options now (docs/cli.md),
    not only the chosen one's when it parses."""
    parser = _Parser(prog="pure-hil", description="Hardware-in-the-loop rig for the PURE ballbot")
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, action=_Commands)
    for name, command in COMMANDS.items():
        subparser = sub.add_parser(name, help=command.summary)
        if every:
            _give_options(name, subparser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Every command ends in one line, never a traceback: 2 for what the user can fix (a config, a bus, a
    port, a bench part), 1 for a failure; an unexpected error leaves its traceback in a file, named."""
    args = build_parser().parse_args(argv)

    import zenoh  # after parsing: `--help` and a usage error need none of these (~1 s of imports)

    from hil.bench.parts import BenchUnavailable
    from hil.bench.rigs import WrongRig
    from hil.run.trace import CONFIG_ERRORS

    try:
        return args.func(args)
    except (*CONFIG_ERRORS, BenchUnavailable) as exc:
        print(f"pure-hil {args.command}: {exc}", file=sys.stderr)
        return 2
    except WrongRig as exc:
        print(f"pure-hil {args.command}: {exc}", file=sys.stderr)
        return 1
    except zenoh.ZError as exc:  # an endpoint taken or unreachable, a certificate refused
        print(f"pure-hil {args.command}: zenoh: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        import tempfile
        import traceback

        with tempfile.NamedTemporaryFile("w", prefix="pure-hil-error-", suffix=".txt", delete=False) as f:
            traceback.print_exc(file=f)
        print(
            f"pure-hil {args.command}: unexpected {type(exc).__name__}: {exc} (traceback: {f.name})",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
