"""Campaign throughput: cases per minute on 1 and 2 workers, in the local process pool and through a Dask
cluster on 127.0.0.1 (a scheduler and N single-thread worker processes started here), with the speed-up
of 2 workers over 1 measured in the same run.

    python benchmarks/campaign.py [FILE] [--repeat K]
        FILE: a campaign (default configs/campaigns/smoke.toml); --repeat: its cases K times (more cases,
        steadier figures).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hil.suites.campaign import expand, load_campaign, run_campaign

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[1]


def local(cases, workers: int) -> float:
    t0 = time.perf_counter()
    results = run_campaign(cases, workers)
    assert all(not r.error for r in results), [r.error for r in results if r.error]
    return time.perf_counter() - t0


def cluster(cases, workers: int) -> float:
    """The same cases through a scheduler and `workers` worker processes on 127.0.0.1."""
    from distributed import Client

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryDirectory() as tmp:
        file = Path(tmp) / "scheduler.json"
        scheduler = ["scheduler", "--host", "127.0.0.1", "--port", "0", "--scheduler-file", str(file)]
        procs = [
            subprocess.Popen(
                [str(BIN / "dask"), *scheduler, "--no-dashboard"], env=env, stderr=subprocess.DEVNULL
            )
        ]
        try:
            while not file.exists():
                time.sleep(0.1)
            address = json.loads(file.read_text())["address"]
            worker = ["worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-dashboard"]
            procs += [
                subprocess.Popen([str(BIN / "dask"), *worker], env=env, stderr=subprocess.DEVNULL)
                for _ in range(workers)
            ]
            with Client(address, timeout="30s") as client:
                client.wait_for_workers(workers, timeout=60)
                client.run(lambda: __import__("hil.pipeline"))  # imports once, before the clock starts
            t0 = time.perf_counter()
            results = run_campaign(cases, scheduler=address)
            wall = time.perf_counter() - t0
            assert all(not r.error for r in results), [r.error for r in results if r.error]
            return wall
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                p.wait(10)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("file", nargs="?", default=str(ROOT / "configs/campaigns/smoke.toml"))
    p.add_argument("--repeat", type=int, default=6)
    args = p.parse_args()
    logging.basicConfig(level=logging.ERROR)  # 1 worker runs in this process: no fault/supervisor lines
    base = expand(load_campaign(args.file))
    cases = [replace(c, seed=c.seed + 1000 * k) for k in range(args.repeat) for c in base]  # distinct ids
    print(f"{len(cases)} cases ({Path(args.file).name} x {args.repeat}), {os.cpu_count()} CPUs")
    rows = {}
    for label, how in (("local process pool", local), ("Dask on 127.0.0.1", cluster)):
        for workers in (1, 2):
            wall = how(cases, workers)
            rows[(label, workers)] = wall
            print(
                f"  {label:<20} {workers} worker(s): {wall:6.1f} s = {60 * len(cases) / wall:6.1f} cases/min"
            )
    for label in ("local process pool", "Dask on 127.0.0.1"):
        print(f"  {label}: 2 workers / 1 worker speed-up {rows[(label, 1)] / rows[(label, 2)]:.2f}")
    print(
        "  Dask / local at 2 workers: "
        f"{rows[('local process pool', 2)] / rows[('Dask on 127.0.0.1', 2)]:.2f} (> 1: Dask faster)"
    )


if __name__ == "__main__":
    main()
