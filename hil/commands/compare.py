"""`pure-hil compare`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import json
import sys

from drivers.config import load_toml
from drivers.resources import find
from hil.commands.common import COUNT, add_bench_options, bench_from, out_folder, progress_bar


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenarios", nargs="+", help="shipped scenario names or files")
    parser.add_argument("--riders", nargs="*", default=None, help="riders (default: the paper's four)")
    parser.add_argument("--trials", type=COUNT, default=1, help="seeds per rider")
    parser.add_argument(
        "--out", default=None, help="output folder (default: the bench's outputs.folder/NAME-TIMESTAMP)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object (cells, orderings, runs)")
    parser.add_argument("--workers", type=COUNT, default=1, help="runs at a time, each in its own process")
    add_bench_options(parser, plant=True)


def handle(args: argparse.Namespace) -> int:
    from hil.bench.parts import check
    from hil.pipeline import load_scenario
    from hil.suites.compare import compare, write
    from hil.suites.paper import load_paper
    from plant.params import RiderParams

    scenarios = [load_scenario(s) for s in args.scenarios]
    riders = tuple(args.riders) if args.riders else tuple(load_paper().riders)
    for rider in riders:
        load_toml(find(rider, "riders"), RiderParams)  # a bad rider file fails now, not after an hour of runs
    bench = bench_from(args)
    check(bench)
    log = sys.stderr if args.json else sys.stdout  # --json: stdout holds the object alone
    print(
        f"pure-hil compare: {len(scenarios)} scenario(s) x {len(riders)} rider(s) x {args.trials} trial(s) "
        f"x HACS/iHACS, lockstep, bench {bench.name}",
        file=log,
    )
    bar = progress_bar(len(scenarios) * len(riders) * args.trials * 2, "run")

    def progress(line: str) -> None:
        if bar is None:
            print(line, file=log, flush=True)
        else:
            bar.write(line)
            bar.update()

    try:
        paths = tuple(str(find(r, "riders")) for r in riders)
        result = compare(scenarios, paths, args.trials, progress=progress, bench=bench, workers=args.workers)
    finally:
        if bar is not None:
            bar.close()
    out = out_folder(args, bench, "compare")
    write(result, out)
    if args.json:
        print(json.dumps(result.to_json()))
        return 0
    print(result.table())
    print(
        f"outputs: {out}/compare.md, compare.json"
        + (", compare.png" if (out / "compare.png").exists() else "")
    )
    return 0
