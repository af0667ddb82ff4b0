"""What an open console costs a run: the same scenario on `pure-hil serve`, with no console and with a
console process and a page (an SSE client reading /api/events) open, interleaved in one invocation.

    python benchmarks/console.py [--reps 3] [--scenario speed_limiting] [--realtime balance]

Prints the speed (simulated / wall time, the run's own `timing.speed`) of each run, the median of each side
and their ratio, for lockstep and for the real-time clock (with its overruns and p99 period jitter); the
CPU time the service took per simulated second on each side (on a busy machine wall time swings by tens of
percent from run to run, CPU time much less) and the console's own; how many live samples the page received
per second. Everything on 127.0.0.1, the
service and the console as their own processes, a rig folder of their own (no other rig is found).
"""

from __future__ import annotations

import http.client
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from drivers.keys import Keys
from drivers.resources import find
from drivers.zenoh_link import free_loopback_endpoint, open_session

BIN = Path(sys.executable).parent


class Page:
    """A browser tab's share of the work: an SSE stream read as it comes, live samples counted."""

    def __init__(self, url: str):
        host, port = re.match(r"http://([\d.]+):(\d+)/", url).groups()
        self.connection = http.client.HTTPConnection(host, int(port), timeout=30)
        self.connection.request("GET", "/api/events")
        self.reply = self.connection.getresponse()
        self.live = 0
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        try:
            while chunk := self.reply.read1(65536):
                self.live += chunk.count(b"event: live\n")
        except (OSError, ValueError):
            pass  # closed by close()

    def close(self) -> None:
        self.reply.close()
        self.connection.close()


def _start(args: list[str], env: dict) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [str(BIN / "pure-hil"), *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    for line in proc.stdout:
        if line.startswith(("console: http", "pure-hil serve:")):
            threading.Thread(target=proc.stdout.read, daemon=True).start()  # keep its pipe drained
            return proc, line
    raise RuntimeError(f"{args[0]} ended before it started (exit {proc.wait()})")


def _stop(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def ask(client, name: str, payload: str = "") -> dict:
    for reply in client.get(Keys().rig(name), payload=payload, timeout=30.0):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_string())
    raise RuntimeError(f"the service did not answer pure/rig/{name}")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (/proc/PID/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def one_run(client, scenario: str, clock: str, service: int, console: int | None) -> dict:
    """Run a shipped scenario on the service under `clock` and wait for its end: its summary's timing, and
    the CPU time the service (and the console) took per simulated second while its tick loop ran (looked at
    in the status: from the first tick to the last one seen running; the outputs written after are not in
    it). CPU time is less at the mercy of other processes on the machine than wall time."""
    text = f'clock = "{clock}"\n' + find(scenario, "scenarios").read_text()
    started = ask(client, "start", text)
    if not started.get("ok"):
        raise RuntimeError(started)
    first = last = None
    while (status := ask(client, "status"))["state"] == "running":
        if status["sim_time"] > 0:
            seen = (status["sim_time"], cpu_seconds(service), cpu_seconds(console) if console else 0.0)
            first, last = first or seen, seen
        time.sleep(0.05)
    summary = json.loads((Path(started["out"]) / "summary.json").read_text())
    simulated = last[0] - first[0]
    return {
        **summary["timing"],
        "service_cpu": (last[1] - first[1]) / simulated,
        "console_cpu": (last[2] - first[2]) / simulated,
    }


def main() -> None:
    args = argparse_parser().parse_args()
    results: dict[tuple[str, bool], list[dict]] = {}
    rates: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "PURE_HIL_RIGS": f"{tmp}/rigs"}
        env.pop("PURE_HIL_HUB", None)
        hub = free_loopback_endpoint()
        service, _ = _start(["serve", "--hub", hub, "--out", f"{tmp}/runs"], env)
        client = open_session(role="member", hub_endpoint=hub)
        try:
            plan = [("lockstep", args.scenario)] + ([("realtime", args.realtime)] if args.realtime else [])
            for clock, scenario in plan:
                one_run(client, scenario, clock, service.pid, None)  # warm-up: imports, first allocations
                for rep in range(args.reps):
                    for with_page in (False, True) if rep % 2 == 0 else (True, False):  # ABBA: drift cancels
                        console = page = None
                        if with_page:
                            console, line = _start(["console", "--hub", hub, "--identity", "monitor"], env)
                            page = Page(line.split("console: ")[1].strip())
                        run = one_run(client, scenario, clock, service.pid, console.pid if console else None)
                        if page is not None:  # the run's samples over the run's own wall time
                            rates.append(page.live / run["wall_time"])
                            page.close()
                            _stop(console)
                        results.setdefault((clock, with_page), []).append(run)
                        side = "page open" if with_page else "no console"
                        print(
                            f"  {clock:8s} {scenario:15s} {side:10s} {run['speed']:5.2f}x real time, "
                            f"{run['overruns']:4d} overruns; CPU s per simulated s: service "
                            f"{run['service_cpu']:.3f}, console {run['console_cpu']:.3f}",
                            flush=True,
                        )
        finally:
            client.close()
            _stop(service)
    report(results, rates)


def report(results: dict[tuple[str, bool], list[dict]], rates: list[float]) -> None:
    def median(clock: str, page: bool, key: str) -> float:
        return statistics.median(r[key] for r in results[(clock, page)])

    for clock in ("lockstep", "realtime"):
        if (clock, False) not in results:
            continue
        without, with_page = median(clock, False, "speed"), median(clock, True, "speed")
        print(
            f"{clock}: median speed without a console {without:.3f}x, with a page open {with_page:.3f}x "
            f"(ratio {with_page / without:.3f})"
        )
        cpu0, cpu1 = median(clock, False, "service_cpu"), median(clock, True, "service_cpu")
        print(
            f"  the service's CPU s per simulated s: without {cpu0:.3f}, with a page open {cpu1:.3f} "
            f"(ratio {cpu1 / cpu0:.3f}); the console's own: {median(clock, True, 'console_cpu'):.3f}"
        )
        if clock == "realtime":
            for side in (False, True):
                runs = results[(clock, side)]
                p99 = [round(r["jitter_us"]["p99"]) for r in runs if r.get("jitter_us")]
                print(
                    f"  {'with a page open' if side else 'without a console'}: overruns "
                    f"{[r['overruns'] for r in runs]}, p99 period jitter {p99} us"
                )
    if rates:
        print(
            f"live samples the page received: {statistics.median(rates):.1f} a second of the run's wall time"
        )


def argparse_parser():
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=3, help="runs on each side per clock")
    parser.add_argument("--scenario", default="speed_limiting", help="the lockstep scenario")
    parser.add_argument("--realtime", default="balance", help="the real-time scenario ('' for none)")
    return parser


if __name__ == "__main__":
    main()
