"""Campaign cases as tasks on a Dask distributed cluster: `pure-hil campaign FILE --scheduler tcp://HOST:PORT`
(docs/campaigns.md). Needs the `cluster` extra (`pip install '.[cluster]'`) here and on every worker.

A case travels whole: the Case and the Bench with every command option applied, so any worker runs it as
this machine would. Each case is a lockstep run on an in-process bus with its zenoh hub on a free loopback
port of the worker's machine: cases never meet, whatever runs beside them. What comes back is the case's
result and its summary.json as bytes (a few kB; no shared folder needed). A worker that dies mid-case: the
scheduler gives the case to another worker (Dask's `distributed.scheduler.allowed-failures`); a case that
raises or whose workers keep dying comes back as an ERROR saying why, and the campaign goes on.
"""

from __future__ import annotations

import tempfile
import uuid
from collections.abc import Callable, Iterable
from pathlib import Path

from hil.bench.bench import Bench
from hil.suites.campaign import Case, CaseResult, run_case

CONNECT_TIMEOUT = "20s"


def run_remote(case: Case, bench: Bench, keep_summary: bool) -> tuple[CaseResult, bytes | None]:
    """On a worker: the case, and its summary.json when the campaign keeps folders."""
    if not keep_summary:
        return run_case(case, None, bench), None
    with tempfile.TemporaryDirectory(prefix="pure-hil-case-") as tmp:
        result = run_case(case, Path(tmp), bench)
        summary = Path(tmp) / "summary.json"
        return result, summary.read_bytes() if summary.exists() else None


def run_on_cluster(
    scheduler: str,
    phases: Iterable[list[Case]],
    bench: Bench,
    out: Path | None,
    done: Callable[[Case, CaseResult], None],
) -> None:
    """Each phase's cases as tasks (a phase completes before the next is submitted: coverage twins before
    their faulty cases); `done` sees every case's result as it comes back."""
    from distributed import Client, as_completed

    run_id = uuid.uuid4().hex[:8]
    with Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False) as client:
        for phase in phases:
            futures = {
                client.submit(run_remote, c, bench, out is not None, key=f"{c.id}-{run_id}", pure=False): c
                for c in phase
            }
            for future in as_completed(futures, loop=client.loop):  # (not the default client's)
                case = futures[future]
                try:
                    result, summary = future.result()
                except Exception as exc:  # the worker died too often, or the task could not run there
                    result, summary = _error(case, f"{type(exc).__name__}: {exc}"), None
                if summary is not None and out is not None:
                    (out / case.id).mkdir(parents=True, exist_ok=True)
                    (out / case.id / "summary.json").write_bytes(summary)
                done(case, result)


def _error(case: Case, why: str) -> CaseResult:
    return CaseResult(case.id, case.scenario, False, 0.0, error=why, role=case.role, twin=case.twin_id)
