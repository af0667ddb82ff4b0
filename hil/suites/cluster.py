"""Campaign cases as tasks on a Dask distributed cluster: `pure-hil campaign FILE --scheduler tcp://HOST:PORT`
(docs/campaigns.md). Needs the `cluster` extra (`pip install '.[cluster]'`) here and on every worker.

A case travels whole: the Case and the Bench with every command option applied, so any worker runs it as
this machine would. Each case is a lockstep run on an in-process bus with its zenoh hub on a free loopback
port of the worker's machine: cases never meet, whatever runs beside them. What comes back is the case's
result and its summary.json and plots.png as bytes (~100 kB; no shared folder needed). A worker that
dies mid-case: the scheduler gives the case to another worker (Dask's
`distributed.scheduler.allowed-failures`); a case that raises or whose workers keep dying comes back as an
ERROR saying why, and the campaign goes on.
"""

from __future__ import annotations

import tempfile
import uuid
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Protocol, TypeVar

from hil.bench.bench import Bench


class Task(Protocol):
    @property
    def id(self) -> str:
        """Names the task on the cluster and its folder in `out` (read-only: a campaign's Case derives it)."""
        ...


T = TypeVar("T", bound=Task)
R = TypeVar("R")
Run = Callable[[T, Path | None, Bench], R]
"""How a worker runs one case (hil/suites/campaign_run.py's run_case): it travels by reference, so this module
needs nothing of the campaign's."""

CONNECT_TIMEOUT = "20s"


RETURNED = ("summary.json", "plots.png")
"""What of a case's run folder comes back from its worker (~100 kB); the CAN log, trace and recording stay
behind (rerun the case by its id and seed for them)."""


def run_remote(run: Run, case: T, bench: Bench, keep: bool) -> tuple[R, dict[str, bytes]]:
    """On a worker: the case, and the files of its folder in RETURNED when the campaign keeps folders."""
    if not keep:
        return run(case, None, bench), {}
    with tempfile.TemporaryDirectory(prefix="pure-hil-case-") as tmp:
        result = run(case, Path(tmp), bench)
        files = {name: (Path(tmp) / name).read_bytes() for name in RETURNED if (Path(tmp) / name).exists()}
        return result, files


def run_on_cluster(
    scheduler: str,
    phases: Iterable[list[T]],
    bench: Bench,
    out: Path | None,
    run: Run,
    errored: Callable[[T, str], R],
    done: Callable[[T, R], None],
) -> None:
    """Each phase's cases as tasks, each run by `run` on a worker (a phase completes before the next is
    submitted: coverage twins before their faulty cases); `done` sees every case's result as it comes
    back, `errored` makes the result of one that could not run."""
    from distributed import Client, as_completed

    check_tls(scheduler)
    run_id = uuid.uuid4().hex[:8]
    with Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False) as client:
        for phase in phases:
            keep = out is not None
            futures = {
                client.submit(run_remote, run, c, bench, keep, key=f"{c.id}-{run_id}", pure=False): c
                for c in phase
            }
            for future in as_completed(futures, loop=client.loop):  # (not the default client's)
                case = futures[future]
                try:
                    result, files = future.result()
                except Exception as exc:  # the worker died too often, or the task could not run there
                    result, files = errored(case, f"{type(exc).__name__}: {exc}"), {}
                if out is not None:  # (a worker returns files only then)
                    for name, data in files.items():
                        (out / case.id).mkdir(parents=True, exist_ok=True)
                        (out / case.id / name).write_bytes(data)
                done(case, result)


def check_tls(scheduler: str) -> None:
    """A tls:// scheduler needs this client's certificate in Dask's config. Without it distributed fails
    deep in its comm layer (a TypeError about ssl_context) and leaves a Client that hangs 40 s on close:
    say what is missing instead, before connecting."""
    if not scheduler.startswith("tls://"):
        return
    from distributed.security import Security

    if Security().get_connection_args("client").get("ssl_context") is None:
        raise ConnectionRefusedError(
            "a tls:// scheduler needs this client's certificate in the Dask config "
            "(distributed.comm.tls.ca-file, distributed.comm.tls.client.cert and .key; docs/campaigns.md)"
        )
