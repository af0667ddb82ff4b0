"""Campaigns on a Dask cluster: a scheduler and two workers on 127.0.0.1 as separate processes, as a lab
runs them on its machines (docs/campaigns.md)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from hil.suites.campaign import expand, load_campaign, run_campaign
from tests.zenoh_helpers import private_bench

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs/campaigns/smoke.toml"


class Cluster:
    def __init__(self, tmp: Path):
        self.file = tmp / "scheduler.json"
        self.env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
        common = ["--no-dashboard"]
        self.scheduler = self._start(
            ["scheduler", "--host", "127.0.0.1", "--port", "0", "--scheduler-file", str(self.file), *common]
        )
        deadline = time.monotonic() + 60
        while not self.file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        self.address = json.loads(self.file.read_text())["address"]
        worker = ["worker", self.address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny", *common]
        self.workers = [self._start(worker) for _ in range(2)]
        from distributed import Client

        with Client(self.address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)

    def _start(self, args: list[str]) -> subprocess.Popen:
        # A session of its own: killing a worker kills nothing else.
        return subprocess.Popen(
            [str(BIN / "dask"), *args],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=self.env,
            start_new_session=True,
        )

    def close(self) -> None:
        for proc in [*self.workers, self.scheduler]:
            if proc.poll() is None:
                proc.terminate()
        for proc in [*self.workers, self.scheduler]:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()


@pytest.fixture
def cluster(tmp_path):
    c = Cluster(tmp_path)
    try:
        yield c
    finally:
        c.close()


def _verdicts(results) -> dict[str, tuple[bool, list[str]]]:
    return {
        r.case_id: (r.passed, sorted(v["criterion"] for v in r.verdicts if not v["passed"])) for r in results
    }


def test_the_smoke_campaign_on_two_workers_matches_the_local_run_and_carries_every_option(cluster, tmp_path):
    from hil.cli import main

    out = tmp_path / "remote"
    # --law is an option of the command: it must reach the workers.
    argv = ["campaign", str(SMOKE), "--scheduler", cluster.address, "--law", "hacs", "--out", str(out)]
    assert main(argv) == 0
    cases = expand(load_campaign(SMOKE))
    local = {r.case_id: r for r in run_campaign(cases, bench=private_bench(law="hacs"))}
    for case in cases:  # each case's summary came back from its worker
        summary = json.loads((out / case.id / "summary.json").read_text())
        assert summary["law"] == "hacs", case.id
        failed = sorted(v["criterion"] for v in summary["verdicts"] if not v["passed"])
        assert (summary["passed"], failed) == _verdicts([local[case.id]])[case.id]
    assert f'tests="{len(cases)}"' in (out / "junit.xml").read_text()


def test_a_worker_killed_mid_campaign_loses_no_case(cluster):
    cases = expand(load_campaign(SMOKE))
    killed: list[int] = []

    def progress(done: int, total: int, result) -> None:
        if not killed:  # the first case is back: the other worker is busy with the next ones
            victim = cluster.workers[0]
            os.killpg(victim.pid, signal.SIGKILL)
            killed.append(victim.pid)

    results = run_campaign(cases, bench=private_bench(), scheduler=cluster.address, progress=progress)
    assert killed and cluster.workers[0].wait(10) is not None
    assert sorted(r.case_id for r in results) == sorted(c.id for c in cases)
    # Each case ran to its verdict on the surviving worker (Dask moved the killed worker's task) or, if
    # its workers kept dying, came back as an ERROR naming why; the campaign went on either way.
    for r in results:
        assert r.verdicts or r.error, r
    assert sum(1 for r in results if not r.error) >= len(cases) - 1
