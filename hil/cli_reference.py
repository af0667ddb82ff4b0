"""docs/cli.md, generated from the parser itself so the help and the docs cannot disagree.

python -m hil.cli_reference docs      # rewrite docs/cli.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil.cli import build_parser

PAGE = Path(__file__).resolve().parents[1] / "docs" / "cli.md"
HEADER = """# Command reference

Generated from `pure-hil`'s own parser (`python -m hil.cli_reference docs`); `pure-hil COMMAND --help`
says the same. Exit codes: README.md. Which rig an operator's command reaches: docs/rig.md
"Which rig".
"""


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def _option(action: argparse.Action) -> str:
    names = ", ".join(f"`{o}`" for o in action.option_strings) or f"`{action.dest}`"
    if action.choices is not None:
        names += " " + "\\|".join(str(c) for c in action.choices)
    elif action.nargs != 0:
        names += f" {action.metavar or action.dest.upper()}"
    return names


def render() -> str:
    parser = build_parser(every=True)
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help or "" for a in commands._choices_actions}
    lines = [HEADER]
    for name, sub in commands.choices.items():
        lines += [f"## `pure-hil {name}`", "", _cell(helps.get(name, "")), ""]
        lines += ["| option | what |", "|---|---|"]
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            default, text = action.default, action.help or ""
            # A help that says its default itself (as --help prints it) is not told it again.
            said = "(default" in text
            shown = "" if said or default in (None, False, [], argparse.SUPPRESS) else f" (default {default})"
            lines.append(f"| {_option(action)} | {_cell(text + shown)} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    if sys.argv[1:] == ["docs"]:
        PAGE.write_text(render())
    else:
        print(render())
