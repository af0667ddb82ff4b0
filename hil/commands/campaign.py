"""`pure-hil campaign`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import sys
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path

from hil.commands.common import COUNT, add_bench_options, bench_from, out_folder, progress_bar


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="a shipped campaign's name or a campaign file")
    parser.add_argument("--workers", type=COUNT, default=1, help="parallel processes (lockstep runs)")
    parser.add_argument(
        "--scheduler",
        default=None,
        help="run the cases on a Dask cluster, e.g. tcp://127.0.0.1:8786 (needs pip install '.[cluster]')",
    )
    parser.add_argument("--out", default=None, help="report folder (default runs/campaign-NAME-TIMESTAMP)")
    parser.add_argument(
        "--select",
        action="append",
        metavar="TEXT",
        help="only the cases whose id contains TEXT (and their twins); repeat for more",
    )
    add_bench_options(parser, plant=True)


def handle(args: argparse.Namespace) -> int:
    """A campaign's cases in parallel processes: progress, a report (worst first; Markdown, JSON, HTML) and
    JUnit XML."""
    from hil.bench.parts import check
    from hil.history import History, NoHistory
    from hil.suites.campaign import (
        distributable,
        expand,
        junit_xml,
        load_campaign,
        report,
        report_json,
        run_campaign,
    )
    from hil.suites.html_report import html_report

    try:
        campaign = load_campaign(args.file)
        cases = expand(campaign, args.select)
    except ValueError as exc:
        print(f"pure-hil campaign: {exc}", file=sys.stderr)
        return 2
    if args.bench is None:
        args.bench = campaign.bench  # the bench its cases need, unless the command names another
    bench = bench_from(args)
    check(bench)
    out = out_folder(args, bench, f"campaign-{campaign.name}")
    out.mkdir(parents=True, exist_ok=True)
    where = f"the cluster at {args.scheduler}" if args.scheduler else f"{args.workers} worker(s)"
    print(f"campaign {campaign.name}: {len(cases)} cases on {where}, bench {bench.name} -> {out}")
    if args.scheduler and not distributable(bench):
        print(
            f"pure-hil campaign: bench {bench.name} cannot run on a cluster: every part must be in the rig's "
            "process on an in-process bus (e.g. the embedded bench)",
            file=sys.stderr,
        )
        return 2

    bar = progress_bar(len(cases), "case")
    counts = {"PASS": 0, "FAIL": 0, "ERROR": 0}

    def progress(done: int, total: int, r) -> None:
        verdict = "ERROR" if r.error else "PASS" if r.passed else "FAIL"
        counts[verdict] += 1
        lines = [f"[{done}/{total}] {verdict:5s} {r.case_id} ({r.wall:.1f} s)"]
        lines += [f"        {line}" for line in (r.message().splitlines() if not r.passed else ())]
        if bar is None:
            print("\n".join(lines), flush=True)
            return
        for line in lines if not r.passed else ():  # above the bar: what failed and why
            bar.write(line)
        bar.set_postfix(passed=counts["PASS"], failed=counts["FAIL"], errors=counts["ERROR"])
        bar.update()

    if args.workers > 1 and not (bench.self_contained and bench.can.in_process):
        print(
            f"pure-hil campaign: on bench {bench.name} cases run one at a time (a shared bus)",
            file=sys.stderr,
        )
    # The bench's history (the console lists it) holds a campaign in the bench's folder beside the
    # service's runs; one put elsewhere with --out was meant to stay apart.
    outputs = Path(bench.outputs.folder).resolve()
    history = History(outputs) if out.resolve().is_relative_to(outputs) else NoHistory()
    controller = f"{bench.controller.where} {bench.controller.plugin}"
    entry = history.begin(out, f"campaign {campaign.name}", bench.name, controller, "lockstep")
    # Under a bar, what does get logged (errors) is written above it, as a failed case's lines are.
    above_bar: AbstractContextManager[None] = nullcontext()
    if bar is not None:
        from tqdm.contrib.logging import logging_redirect_tqdm

        above_bar = logging_redirect_tqdm()
    try:
        try:
            with above_bar:
                results = run_campaign(cases, args.workers, out, progress, bench, args.scheduler)
        except OSError as exc:  # the scheduler cannot be reached (distributed: OSError after its timeout)
            print(f"pure-hil campaign: scheduler {args.scheduler}: {exc}", file=sys.stderr)
            history.end(entry, "ERROR", error=f"scheduler {args.scheduler}: {exc}")
            return 2
        finally:
            if bar is not None:
                bar.close()
        text = report(campaign.name, results)
        (out / "report.md").write_text(text)
        (out / "report.json").write_bytes(report_json(campaign.name, results))
        (out / "junit.xml").write_bytes(junit_xml(campaign.name, results))
        (out / "report.html").write_text(html_report(campaign.name, results, out))
        print(text)
        reports = "  ".join(str(out / name) for name in ("report.md", "report.json", "report.html"))
        print(f"report: {reports}  junit: {out / 'junit.xml'}")
        passed = all(r.passed for r in results)
        history.end(entry, "PASSED" if passed else "FAILED")
        return 0 if passed else 1
    except BaseException as exc:  # Ctrl-C or a crash: the history says how it ended, then it goes on up
        history.end(entry, "STOPPED" if isinstance(exc, KeyboardInterrupt) else "ERROR", error=str(exc))
        raise
    finally:
        history.close()
