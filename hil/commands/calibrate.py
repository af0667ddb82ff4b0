"""`pure-hil calibrate`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

from hil.commands.common import COUNT, add_bench_options, bench_from, out_folder


def add_arguments(parser: argparse.ArgumentParser) -> None:
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--fit",
        nargs="+",
        metavar="NAME[=LO:HI]",
        help="parameters to fit, e.g. rider.lean_rate_deg rider.lean_amplitude_deg=10:35 (docs/riders.md)",
    )
    what.add_argument(
        "--sensitivity", nargs="+", metavar="NAME", help="instead: each cell at each parameter moved ±--step"
    )
    parser.add_argument("--step", type=float, default=0.2, help="relative move for --sensitivity")
    parser.add_argument("--target", default="paper/ihacs_table2.toml", help="a table in the paper's format")
    parser.add_argument("--budget", type=COUNT, default=40, help="at most this many evaluations")
    parser.add_argument("--workers", type=COUNT, default=1, help="runs at a time, each in its own process")
    parser.add_argument(
        "--out", default=None, help="output folder (default: the bench's outputs.folder/NAME-TIMESTAMP)"
    )
    add_bench_options(parser, plant=True)


def handle(args: argparse.Namespace) -> int:
    from hil.suites.calibrate import Unknown, calibrate, sensitivity, write
    from hil.suites.paper import load_paper

    try:
        unknowns = [Unknown.parse(text) for text in args.fit or args.sensitivity]
    except ValueError as exc:
        print(f"pure-hil calibrate: {exc}", file=sys.stderr)
        return 2
    target = load_paper(args.target)
    bench = bench_from(args)
    if args.sensitivity:
        names = [u.name for u in unknowns]
        moved = f"{', '.join(names)} (±{args.step:.0%})"
        print(f"pure-hil calibrate: how each cell of {args.target} moves with {moved}")
        result = sensitivity(target, names, bench, args.step, args.workers)
        out = out_folder(args, bench, "sensitivity")
        metrics = [m.name for m in target.metric]
        result.write(out, metrics)
        print("\n\n".join(result.table(m) for m in metrics))
        print(f"outputs: {out}/sensitivity.md, sensitivity.json")
        return 0
    print(
        f"pure-hil calibrate: {', '.join(u.name for u in unknowns)} to {args.target} ({len(target.tasks)} "
        f"task(s) x {len(target.riders)} rider(s) x HACS/iHACS per evaluation, at most {args.budget})"
    )
    say = functools.partial(print, flush=True)
    calibration = calibrate(target, unknowns, bench, budget=args.budget, workers=args.workers, progress=say)
    out = out_folder(args, bench, "calibrate")
    fitted = write(calibration, out)
    print(calibration.table())
    print(f"outputs: {out}/calibrate.md, calibrate.json; fitted files: {Path(fitted.robot).parent}")
    return 0
