"""`pure-hil serve`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path
from types import FrameType

from hil.commands.common import add_bench_options, bench_from, until_interrupted


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bench_options(parser, clock=True)
    parser.add_argument("--out", default=None, help="where run folders go (default: the bench's folder)")
    parser.add_argument(
        "--view",
        default=None,
        metavar="URL",
        help="stream every run live to a rerun viewer you run, e.g. rerun+http://127.0.0.1:9876/proxy",
    )


def handle(args: argparse.Namespace) -> int:
    from hil.bench.parts import check
    from hil.service import RigService

    bench = bench_from(args)
    check(bench)
    view = None
    if args.view:
        import rerun as rr

        # The operator's own viewer (`rerun` on their machine); the rig connects out to it and never serves.
        view = rr.GrpcSink(args.view)
    session, _ = bench.zenoh.open_rig(
        fallback=False
    )  # operators find it where the bench says: it never moves
    service = RigService(session, bench, out_root=Path(args.out or bench.outputs.folder), view=view)

    def at_once(signum: int, _frame: FrameType | None) -> None:
        # The run's folder is left as far as it got, but its history row is completed before leaving: a
        # row left RUNNING would say so until the service's next start.
        try:
            service.interrupt(f"serve ended at once by a second {signal.Signals(signum).name}")
            os.write(sys.stdout.fileno(), b"pure-hil serve: stopped at once\n")  # print may be mid-write
        finally:
            os._exit(STOPPED)

    until_interrupted(
        f"pure-hil serve: bench {bench.name}, hub {service.endpoint}, queryables {service.keys.rig('*')}; "
        "Ctrl-C to stop",
        then=at_once,
    )
    if service.state == "running":
        print(
            "pure-hil serve: stopping the run and writing its folder (a second Ctrl-C: at once)", flush=True
        )
    service.close()
    session.close()
    print("pure-hil serve: stopped")
    return STOPPED


STOPPED = 130
"""serve ends only on SIGINT or SIGTERM: exit 130, as `pure-hil run` stopped by either (README)."""
