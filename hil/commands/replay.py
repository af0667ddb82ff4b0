"""`pure-hil replay`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from hil.commands.common import COUNT, add_bench_options, bench_from


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", help="a lockstep run's folder (can.log, zenoh_inputs.msgpack)")
    parser.add_argument("--limit", type=COUNT, default=None, help="replay only the first N ticks")
    add_bench_options(parser)


def handle(args: argparse.Namespace) -> int:
    from hil.suites.replay import replay

    run_dir = Path(args.run_dir)
    if not (run_dir / "can.log").exists() or not (run_dir / "zenoh_inputs.msgpack").exists():
        print(
            f"pure-hil replay: {run_dir} is not a run folder (needs can.log and zenoh_inputs.msgpack)",
            file=sys.stderr,
        )
        return 2
    try:
        clock = json.loads((run_dir / "summary.json").read_text())["as_run"]["clock"]
    except (OSError, ValueError, KeyError, TypeError):
        clock = "lockstep"  # replay() says what is wrong with the folder
    if clock != "lockstep":
        print(
            f"pure-hil replay: {run_dir} ran on the {clock} clock: only a lockstep run can be "
            "compared tick for tick (a real-time run's frames met its controller at times no replay repeats)",
            file=sys.stderr,
        )
        return 2
    result = replay(run_dir, bench_from(args), limit=args.limit)
    print(
        f"pure-hil replay {run_dir}: {result.ticks} ticks, {result.frames_compared} controller frames "
        f"compared, {len(result.mismatches)} tick(s) differ"
    )
    for line in result.mismatches[:10]:
        print("  " + line)
    return 0 if result.identical else 1
