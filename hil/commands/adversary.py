"""`pure-hil adversary`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import functools
import sys

import msgspec

from hil.commands.common import COUNT, SEED, add_bench_options, bench_from, out_folder


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="shipped scenario name or file")
    parser.add_argument(
        "--objective",
        choices=("overspeed", "tilt", "rmse"),
        default="overspeed",
        help="what the worst rider maximises (docs/riders.md)",
    )
    parser.add_argument("--budget", type=COUNT, default=50, help="lockstep runs")
    parser.add_argument("--workers", type=COUNT, default=1, help="runs at a time, each in its own process")
    parser.add_argument(
        "--seed", type=SEED, default=0, help="the search's seed: the same seed, the same search"
    )
    parser.add_argument(
        "--sampler",
        choices=("random", "qmc", "cmaes"),
        default="random",
        help="optuna's uniform random, Sobol or CMA-ES sampling (docs/riders.md: which finds it sooner)",
    )
    parser.add_argument(
        "--out", default=None, help="output folder (default: the bench's outputs.folder/NAME-TIMESTAMP)"
    )
    add_bench_options(parser, plant=True)


def handle(args: argparse.Namespace) -> int:
    from hil.pipeline import load_scenario
    from hil.suites.adversary import requirement, search, summary, write_worst

    scenario = load_scenario(args.scenario)
    if args.law:
        scenario = msgspec.structs.replace(scenario, law=args.law)
    bench = bench_from(args)
    try:
        requirement(args.objective, scenario, bench)
    except ValueError as exc:
        print(f"pure-hil adversary: {exc}", file=sys.stderr)
        return 2
    print(
        f"pure-hil adversary: {scenario.name} ({scenario.law}), objective {args.objective}, sampler "
        f"{args.sampler} seed {args.seed}, {args.budget} lockstep runs, {args.workers} at a time"
    )
    found = search(
        scenario,
        args.objective,
        args.budget,
        args.workers,
        args.seed,
        bench,
        functools.partial(print, flush=True),
        args.sampler,
    )
    out = out_folder(args, bench, "adversary")
    path = write_worst(found, out, bench)
    print(summary(found))
    print(f"worst profile: {path} (pure-hil run {path}); its run folder: {out / 'run'}")
    return 0
