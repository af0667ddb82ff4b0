"""How soon `rig stop` and SIGTERM end a run of `pure-hil serve`, flooded at the catalog's bounds, and what
the service's memory does meanwhile.

    python benchmarks/stop.py [--repeats 5] [--flood 2.0]

For each case (no fault; can.babble filling the bus; zenoh.sc_flood at its bound; both) and each way of
stopping (pure/rig/stop to a service in this process; SIGTERM to `pure-hil serve` in a process of its own):
a long run starts, goes 1 s of simulated time, gets its faults, floods for --flood s of wall time, then is
stopped. Timed from the request (time.time()): the run's last tick (its summary.json: the first tick's time
plus the loop's wall time) and its folder written (the service idle; the process gone). RSS: the serving
process's as the faults start and just before the stop (a flood that grew memory would show here); the
simulated seconds the flood lasted.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from drivers.keys import Keys
from drivers.zenoh_link import free_loopback_endpoint, open_session
from hil.bench.bench import load_bench
from hil.commands.serve import STOPPED
from hil.faults.base import bounds_of
from hil.faults.bounds import reference_rig
from hil.faults.topics import ScFlood
from hil.service import RigService

SCENARIO = """
name = "flooded"
rider = "ref_60kg_180"
duration = 3600.0
[[criteria]]
metric = "fallen"
equals = false
"""
_SC_BOUND = bounds_of(ScFlood)["per_tick"].limit
assert _SC_BOUND is not None
SC_PER_TICK = int(_SC_BOUND(ScFlood(), reference_rig())[0])  # type: ignore[index]
CASES = {
    "no fault": [],
    "can.babble (the bus full)": [{"kind": "can.babble"}],
    f"zenoh.sc_flood per_tick={SC_PER_TICK}": [{"kind": "zenoh.sc_flood", "per_tick": SC_PER_TICK}],
    "both": [{"kind": "can.babble"}, {"kind": "zenoh.sc_flood", "per_tick": SC_PER_TICK}],
}


def ask(client, action: str, payload: str = "") -> dict:
    replies = [r.ok for r in client.get(Keys().rig(action), payload=payload, timeout=30.0) if r.ok]
    if not replies:
        raise RuntimeError(f"the service did not answer pure/rig/{action} within 30 s")
    return json.loads(replies[0].payload.to_string())


def rss_mb(pid: int | str = "self") -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Flood(NamedTuple):
    folder: str
    rss: tuple[float, float]
    """MB as the faults start, and before the stop."""
    simulated: float
    """s of simulated time the faults acted."""


def flood(client, faults: list[dict], seconds: float, pid: int | str = "self") -> Flood:
    """Start a run, let it reach 1 s, inject `faults`, let them act `seconds` of wall time."""
    started = ask(client, "start", SCENARIO)
    assert started["ok"], started
    while ask(client, "status")["sim_time"] < 1.0:
        time.sleep(0.02)
    for fault in faults:
        reply = ask(client, "fault/inject", json.dumps(fault))
        assert reply["ok"], reply
    first, begun = rss_mb(pid), ask(client, "status")["sim_time"]
    time.sleep(seconds)
    simulated = ask(client, "status")["sim_time"] - begun
    return Flood(str(started["out"]), (first, rss_mb(pid)), simulated)


def ended(folder: str, asked: float) -> float:
    """s from `asked` (time.time()) to the run's last tick, from its summary."""
    timing = json.loads((Path(folder) / "summary.json").read_text())["timing"]
    return timing["first_tick_at"] + timing["wall_time"] - asked


def in_process(faults: list[dict], seconds: float, root: Path) -> tuple[float, float, Flood]:
    """pure/rig/stop to a service in this process: (s to the last tick, s to its folder written, flood)."""
    endpoint = free_loopback_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    client = open_session(role="member", hub_endpoint=endpoint)
    service = RigService(hub, load_bench().with_overrides(hub=endpoint), out_root=root)
    try:
        flooded = flood(client, faults, seconds)
        asked = time.time()
        assert ask(client, "stop")["stopping"]
        service.wait_idle()
        written = time.time() - asked
        assert service.last is not None and service.last["verdict"] == "STOPPED", service.last
    finally:
        service.close()
        client.close()
        hub.close()
    return ended(flooded.folder, asked), written, flooded


def by_signal(faults: list[dict], seconds: float, root: Path) -> tuple[float, float, Flood]:
    """SIGTERM to `pure-hil serve`: (s to the last tick, s to the process's exit, the flood)."""
    endpoint = free_loopback_endpoint()
    pure_hil = str(Path(sys.executable).with_name("pure-hil"))
    env = {**os.environ, "PURE_HIL_RIGS": str(root / "rigs")}
    serve = subprocess.Popen(
        [pure_hil, "serve", "--hub", endpoint, "--out", str(root)], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert serve.stdout is not None and endpoint in serve.stdout.readline()
        client = open_session(role="member", hub_endpoint=endpoint)
        try:
            flooded = flood(client, faults, seconds, serve.pid)
        finally:
            client.close()
        asked = time.time()
        serve.send_signal(signal.SIGTERM)
        serve.communicate(timeout=120)
        gone = time.time() - asked
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.communicate()
    assert serve.returncode == STOPPED, serve.returncode
    return ended(flooded.folder, asked), gone, flooded


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--flood", type=float, default=2.0, help="wall s each flood acts before the stop")
    args = parser.parse_args()
    print(f"{args.repeats} stops per case and way, each after {args.flood:g} s of wall time under the faults")
    print(
        f"{'case':28s} {'stopped':9s} {'to the last tick ms':>20s} {'to the folder s':>23s} "
        f"{'RSS MB':>8s} {'flood +MB':>9s} {'flood sim s':>11s}"
    )
    with tempfile.TemporaryDirectory() as out:
        for name, faults in CASES.items():
            for way, stop in (("rig stop", in_process), ("SIGTERM", by_signal)):
                runs = [stop(faults, args.flood, Path(out) / f"{way}-{i}") for i in range(args.repeats)]
                last = [1e3 * r[0] for r in runs]
                written = [r[1] for r in runs]
                growth = [r[2].rss[1] - r[2].rss[0] for r in runs]
                print(
                    f"{name:28s} {way:9s} {statistics.median(last):7.1f} (max {max(last):6.1f}) "
                    f"{statistics.median(written):11.2f} (max {max(written):5.2f}) "
                    f"{max(r[2].rss[1] for r in runs):8.0f} {max(growth):+9.1f} "
                    f"{min(r[2].simulated for r in runs):9.2f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
