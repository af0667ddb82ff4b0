"""`pure-hil run`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import sys

from drivers.resources import find
from hil.commands.common import SEED, add_bench_options, bench_from, out_folder, stop_on_signals


def _progress(status) -> None:
    """The run's live status line (a terminal only)."""
    width = 20
    done = int(width * min(status.t / status.duration, 1.0))
    print(
        f"\r  [{'#' * done}{'.' * (width - done)}] {status.t:7.2f} / {status.duration:g} s "
        f"{status.speed_factor:5.1f}x  {status.speed:4.2f} m/s  tilt {status.tilt_deg:4.1f} deg  "
        f"{status.supervisor:<8} overruns {status.overruns}\x1b[K",
        end="",
        file=sys.stderr,
        flush=True,
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="a shipped scenario's name (balance, ...) or a scenario file")
    add_bench_options(parser, clock=True)
    parser.add_argument("--seed", type=SEED, default=None, help="the scenario's seed instead (>= 0)")
    parser.add_argument("--out", default=None, help="run folder (default: the bench's folder/NAME-TIMESTAMP)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def handle(args: argparse.Namespace) -> int:
    from hil.bench.parts import check
    from hil.pipeline import check_start, load_scenario, run
    from hil.report.folder import format_table
    from hil.run.build import RunOptions
    from hil.run.judge import EXIT_CODES

    scenario = load_scenario(args.scenario)
    bench = bench_from(args)
    check_start(scenario, bench, str(find(args.scenario, "scenarios")))
    check(bench)
    out = out_folder(args, bench, scenario.name)
    show_progress = sys.stderr.isatty() and not args.quiet
    print(f"pure-hil run: {scenario.name} on bench {bench.name} -> {out}")
    stop = stop_on_signals()  # Ctrl-C ends the run at the next tick; what ran is judged and written
    result = run(
        scenario,
        bench,
        out=out,
        seed=args.seed,
        options=RunOptions(progress=_progress if show_progress else None, stop=stop),
    )
    if show_progress:
        print(file=sys.stderr)
    failure = result.trace.failure
    if failure is not None and not len(result.trace.t):
        print(
            f"pure-hil run: {failure.error} ({failure.stage}; summary: {out}/summary.json)", file=sys.stderr
        )
        return 2 if failure.config else 1
    print(format_table(result))
    written = sorted(p.name for p in out.iterdir() if p.is_file() and p.name != "summary.json")
    print(f"outputs: {out}/summary.json, {', '.join(written)}")
    if result.trace.stopped_early:
        simulated = float(result.trace.t[-1]) if len(result.trace.t) else 0.0
        print(f"pure-hil run: stopped at t = {simulated:.2f} s of {scenario.duration:g} s", file=sys.stderr)
        return 130
    return EXIT_CODES[result.verdict]
