"""`pure-hil serve` for weeks: threads and memory over many short runs in a row, driven through the service's
zenoh API exactly as an operator's client drives it.

    python benchmarks/serve_soak.py [--runs 200] [--duration 0.5]

Prints threads and RSS after every 10th run, and the growth per run against the baseline measured after the
10th run in the same process (the first runs load numpy, scipy, rerun and zenoh and grow glibc's per-thread
malloc arenas; with MALLOC_ARENA_MAX=2 the plateau is lower and reached sooner).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
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


def soak(runs: int, duration: float, report=print) -> list[tuple[int, float]]:
    """(threads, RSS MB) after each run."""
    endpoint = free_loopback_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    client = open_session(role="member", hub_endpoint=endpoint)
    scenario = SCENARIO.format(duration=duration)
    samples: list[tuple[int, float]] = []
    with tempfile.TemporaryDirectory() as out:
        service = RigService(hub, load_bench().with_overrides(hub=endpoint), out_root=Path(out))
        try:
            for i in range(runs):
                reply = ask(client, "start", scenario)
                assert reply.get("ok"), reply
                while ask(client, "status")["state"] == "running":
                    time.sleep(0.02)
                service.wait_idle(30)
                last = ask(client, "status")["last"]
                assert last["passed"], last
                samples.append((os_threads(), rss_mb()))
                if report and (i == 0 or (i + 1) % 10 == 0):
                    report(f"  run {i + 1:4d}: {samples[-1][0]:3d} threads, {samples[-1][1]:7.1f} MB RSS")
        finally:
            service.close()
            client.close()
            hub.close()
    return samples


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--duration", type=float, default=0.5, help="simulated seconds per run")
    args = parser.parse_args()
    t0 = time.perf_counter()
    samples = soak(args.runs, args.duration)
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
