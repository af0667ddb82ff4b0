"""`pure-hil serve` for weeks: threads and memory over many short runs in a row, driven through the service's
zenoh API exactly as an operator's client drives it.

    python benchmarks/serve_soak.py [--runs 200] [--duration 0.5] [--console]

Prints threads and RSS after every 10th run, and the growth per run against the baseline measured after the
10th run in the same process (the first runs load numpy, scipy, rerun and zenoh and grow glibc's per-thread
malloc arenas; with MALLOC_ARENA_MAX=2 the plateau is lower and reached sooner).

--console: a console (hil/console) runs in the same process, on its own zenoh session, for the whole soak,
with a page (an SSE client) open on it throughout and a second page opened and closed during every run: the
threads and RSS printed are then the service's and the console's together.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from drivers.keys import Keys
from drivers.zenoh_link import free_loopback_endpoint, open_session
from hil.bench.bench import load_bench
from hil.service import RigService

WARM_UP = 10
"""Runs before the baseline: the first runs load modules and grow malloc's per-thread arenas to their size."""

SCENARIO = """
name = "soak"
rider = "ref_60kg_180"
duration = {duration}
[[criteria]]
metric = "fallen"
equals = false
"""


def os_threads() -> int:
    """Every thread of the process, native ones (zenoh's, rerun's) included."""
    return len(os.listdir("/proc/self/task"))


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def ask(client, action: str, payload: str = "") -> dict:
    replies = [r.ok for r in client.get(Keys().rig(action), payload=payload, timeout=30.0) if r.ok]
    if not replies:
        raise RuntimeError(f"the service did not answer pure/rig/{action} within 30 s")
    return json.loads(replies[0].payload.to_string())


class Page:
    """An SSE client on the console's /api/events, counting the live samples it reads."""

    def __init__(self, port: int):
        self.connection = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        self.connection.request("GET", "/api/events")
        self.reply = self.connection.getresponse()
        assert self.reply.status == 200, self.reply.status
        self.live = 0
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        try:
            while chunk := self.reply.read1(65536):
                self.live += chunk.count(b"event: live\n")
        except (OSError, ValueError):
            pass  # closed

    def close(self) -> None:
        self.reply.close()
        self.connection.close()


def soak(runs: int, duration: float, report=print, console: bool = False) -> list[tuple[int, float]]:
    """(threads, RSS MB) after each run."""
    endpoint = free_loopback_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    client = open_session(role="member", hub_endpoint=endpoint)
    scenario = SCENARIO.format(duration=duration)
    samples: list[tuple[int, float]] = []
    screen = None
    with tempfile.TemporaryDirectory() as out:
        service = RigService(hub, load_bench().with_overrides(hub=endpoint), out_root=Path(out))
        if console:
            screen = Screen(endpoint)
        try:
            for i in range(runs):
                reply = ask(client, "start", scenario)
                assert reply.get("ok"), reply
                churn = Page(screen.port) if screen else None  # a page that comes and goes every run
                while ask(client, "status")["state"] == "running":
                    time.sleep(0.02)
                service.wait_idle(30)
                if churn is not None:
                    churn.close()
                last = ask(client, "status")["last"]
                assert last["passed"], last
                samples.append((os_threads(), rss_mb()))
                if report and (i == 0 or (i + 1) % 10 == 0):
                    report(f"  run {i + 1:4d}: {samples[-1][0]:3d} threads, {samples[-1][1]:7.1f} MB RSS")
        finally:
            if screen is not None:
                report(f"  the open page read {screen.page.live} live samples over {runs} runs")
                screen.close()
            service.close()
            client.close()
            hub.close()
    return samples


class Screen:
    """A console in this process, on its own session, with one page open for the whole soak."""

    def __init__(self, endpoint: str):
        from hil.console.events import Broadcast
        from hil.console.rig_link import RigLink
        from hil.console.server import Console

        self.session = open_session(role="member", hub_endpoint=endpoint)
        self.link = RigLink(self.session, Keys(), "monitor", "soak", Broadcast())
        self.server = Console(self.link, {"card": None, "bench": "embedded", "faults": []}).start()
        self.port = self.server.server_address[1]
        self.page = Page(self.port)

    def close(self) -> None:
        self.page.close()
        self.server.close()
        self.link.close()
        self.session.close()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--duration", type=float, default=0.5, help="simulated seconds per run")
    parser.add_argument(
        "--console", action="store_true", help="a console with a page open (and one per run) throughout"
    )
    args = parser.parse_args()
    t0 = time.perf_counter()
    samples = soak(args.runs, args.duration, console=args.console)
    wall = time.perf_counter() - t0
    warm = min(WARM_UP, len(samples)) - 1
    (threads0, rss0), (threads1, rss1) = samples[warm], samples[-1]
    n, last = len(samples) - 1 - warm, len(samples)
    print(
        f"{last} runs of {args.duration:g} s in {wall:.0f} s wall; baseline: after run {warm + 1} (warmed up)"
    )
    print(
        f"  threads after run {warm + 1}: {threads0}, after run {last}: {threads1} ({threads1 - threads0:+d})"
    )
    peak = max(r for _, r in samples)
    print(
        f"  RSS after run 1: {samples[0][1]:.1f} MB, after run {warm + 1}: {rss0:.1f} MB, after run {last}: "
        f"{rss1:.1f} MB ({(rss1 - rss0) / max(n, 1) * 1024:+.0f} kB per run since), peak {peak:.1f} MB"
    )


if __name__ == "__main__":
    main()
