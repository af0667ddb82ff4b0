"""`pure-hil accounts`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil.console.roles import PERSON_ROLES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("add", "remove", "list"), help="add (or change), remove, list")
    parser.add_argument("file", help="the accounts file (JSON, kept mode 0600)")
    parser.add_argument("name", nargs="?", default=None, help="the account's name (add, remove)")
    parser.add_argument(
        "--role",
        default="monitor",
        choices=PERSON_ROLES,
        help="its bench role (add); the password is asked twice on a terminal, else read from stdin",
    )


def handle(args: argparse.Namespace) -> int:
    """Who may log in to a console: add (or change), remove, list the accounts of a file."""
    import getpass

    from hil.console import accounts

    path = Path(args.file)
    try:
        people = accounts.load(path) if path.exists() or args.action != "add" else {}
        if args.action == "list":
            for person in people.values():
                print(f"{person.name}\t{person.role}")
            return 0
        if args.name is None:
            raise accounts.AccountsError(
                f"pure-hil accounts {args.action} FILE NAME: give the account's NAME"
            )
        if args.action == "remove":
            if people.pop(args.name, None) is None:
                raise accounts.AccountsError(f"{path}: no account {args.name!r}")
            if not people:
                raise accounts.AccountsError(f"{path}: {args.name} is its last account (delete the file)")
        else:
            if sys.stdin.isatty():
                password = getpass.getpass(f"password for {args.name}: ")
                if getpass.getpass("again: ") != password:
                    raise accounts.AccountsError("the two passwords differ")
            else:  # a script: the first line of stdin
                password = sys.stdin.readline().rstrip("\n")
            accounts.check_new(args.name, args.role, password)
            people[args.name] = accounts.Account(args.name, args.role, accounts.hash_password(password))
        accounts.save(path, people)
    except accounts.AccountsError as exc:
        print(f"pure-hil accounts: {exc}", file=sys.stderr)
        return 2
    done = "removed" if args.action == "remove" else f"{args.role}, scrypt"
    print(f"pure-hil accounts: {args.name} {done} in {path} ({len(people)} accounts, mode 0600)")
    return 0
