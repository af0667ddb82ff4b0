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
from tests.helpers import TWO_CASES
from tests.zenoh_helpers import private_bench

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs/campaigns/smoke.toml"


@pytest.fixture
def two_cases(tmp_path) -> Path:
    path = tmp_path / "two_cases.toml"
    path.write_text(TWO_CASES)
    return path


class Cluster:
    def __init__(self, tmp: Path, workers: int = 2, tls: list[str] = (), security=None):
        self.file = tmp / "scheduler.json"
        self.env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
        common = ["--no-dashboard", *tls]
        self.scheduler = self._start(
            ["scheduler", "--host", "127.0.0.1", "--port", "0", "--scheduler-file", str(self.file), *common]
        )
        deadline = time.monotonic() + 60
        while not self.file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        self.address = json.loads(self.file.read_text())["address"]
        worker = ["worker", self.address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny", *common]
        self.workers = [self._start(worker) for _ in range(workers)]
        from distributed import Client

        with Client(self.address, timeout="30s", security=security) as client:
            client.wait_for_workers(workers, timeout=60)

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


def test_a_campaign_on_two_workers_matches_the_local_run_and_carries_every_option(
    cluster, two_cases, tmp_path
):
    from hil.cli import main

    out = tmp_path / "remote"
    # --law is an option of the command: it must reach the workers (bench_smoke asks for hacs).
    argv = ["campaign", str(two_cases), "--scheduler", cluster.address, "--law", "ihacs", "--out", str(out)]
    assert main(argv) == 0
    cases = expand(load_campaign(two_cases))
    assert len(cases) == 2
    local = {r.case_id: r for r in run_campaign(cases, bench=private_bench(law="ihacs"))}
    for case in cases:  # each case's summary came back from its worker
        summary = json.loads((out / case.id / "summary.json").read_text())
        assert summary["as_run"]["law"] == "ihacs", case.id
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


def test_a_tls_cluster_runs_a_campaign_for_a_client_with_its_certificate_and_refuses_one_without(
    two_cases, tmp_path
):
    """docs/campaigns.md's securing recipe, end to end: scheduler and worker started with `--protocol tls`
    and certificates; the client configured through Dask's config (here its environment variables)."""
    from distributed.security import Security

    pem = Security.temporary()  # a throwaway CA-signed certificate, key and CA, as PEM text
    files = {"ca.pem": pem.tls_ca_file, "cert.pem": pem.tls_scheduler_cert, "key.pem": pem.tls_scheduler_key}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    ca, cert, key = (str(tmp_path / name) for name in files)
    tls = ["--protocol", "tls", "--tls-ca-file", ca, "--tls-cert", cert, "--tls-key", key]
    client = Security(tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key, require_encryption=True)
    cluster = Cluster(tmp_path, workers=1, tls=tls, security=client)
    try:
        assert cluster.address.startswith("tls://127.0.0.1:")
        configured = {
            **cluster.env,
            "DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION": "True",
            "DASK_DISTRIBUTED__COMM__TLS__CA_FILE": ca,
            "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT": cert,
            "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY": key,
        }

        def campaign(env: dict, out: Path) -> subprocess.CompletedProcess:
            argv = ["campaign", str(two_cases), "--scheduler", cluster.address, "--out", str(out)]
            return subprocess.run(
                [str(BIN / "pure-hil"), *argv], env=env, capture_output=True, text=True, timeout=180
            )

        secured = campaign(configured, tmp_path / "secured")
        assert secured.returncode == 0, secured.stderr
        assert 'tests="2"' in (tmp_path / "secured" / "junit.xml").read_text()
        # Positive control: the same command without the client's certificate is refused, in one line.
        refused = campaign(cluster.env, tmp_path / "refused")
        assert refused.returncode == 2, refused.stderr
        assert "Traceback" not in refused.stderr
        assert f"scheduler {cluster.address}" in refused.stderr
        assert not (tmp_path / "refused" / "junit.xml").exists()
    finally:
        cluster.close()
