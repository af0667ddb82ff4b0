"""The lab controllers of the VM suite (tests/socketcan/test_vcan.py, LAB_CLIENTS) run as its
run_bench runs them, outside the VM: the client, the supervisor (`--clock lockstep`) and the rig
(`--controller external --supervisor external --clock lockstep`) as three processes, on the shipped
bench's `[devices]`, `bench_smoke` cut to 1 s, no plots, recording or MCAP. The bus is python-can's
udp_multicast inside a network namespace whose only interface is lo, which this benchmark creates and
removes (needs the right to run `ip netns add`): not vcan0, so it measures the processes' own cost, not the
kernel's CAN.

    python benchmarks/lab_clients.py [--repeat 2] [--seconds 1.0] [--quota 0.11] [--json]

Prints, per run (the clients interleaved, so a machine's changing load falls on all of them), the rig's
loop wall time per simulated second, the rig's end from the start of the three processes, how long the
client takes from a SYNC to the heartbeat that closes its answer (from can.log), each process's CPU
seconds, and what the rig counted (missing commands, expired guards). `--quota F`: the three processes
held together to F of one CPU (a cgroup v1 `cpu` quota, root only): 0.11 is about the VM's share of this
2-core host (18x slower per core), to see whether a client's cost grows out of proportion on a slow CPU.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import can

from hil.bench.netns import NamespaceRefused, loopback_namespace

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
CLIENTS = ("odrive", "cia402", "xsens")
CHANNEL = "239.74.163.9"
CGROUP_V1 = Path("/sys/fs/cgroup/cpu")
SYNC_ID, HEARTBEAT_ID = 0x080, 0x720
NO_EXTRA_OUTPUTS = "\n[outputs]\nplots = false\nrecording = false\nmcap = false\n"


def bench_file(profile: str, folder: Path) -> tuple[Path, dict]:
    """The vcan bench's shape (everything external) on udp_multicast, with the shipped bench's [devices]."""
    text = (ROOT / f"configs/benches/{profile}.toml").read_text()
    table = text[text.index("[devices]") :]
    path = folder / "bench.toml"
    path.write_text(
        f'name = "lab_clients"\n[can]\ninterface = "udp_multicast"\nchannel = "{CHANNEL}"\n'
        '[controller]\nwhere = "external"\nboot_timeout = 120\n[supervisor]\nwhere = "external"\n'
        f'[zenoh]\nmode = "loopback"\n\n{table}{NO_EXTRA_OUTPUTS}'
    )
    return path, tomllib.loads(table)["devices"]


def scenario_file(seconds: float, folder: Path) -> Path:
    """bench_smoke cut to `seconds`, judged on not falling only (test_vcan.py's `_scenario`)."""
    text = (
        (ROOT / "configs/scenarios/bench_smoke.toml")
        .read_text()
        .replace("duration = 2.0", f"duration = {seconds}")
    )
    text = text[: text.index("[[criteria]]")] + '[[criteria]]\nmetric = "fallen"\nequals = false\n'
    path = folder / "scenario.toml"
    path.write_text(text)
    return path


def client_command(profile: str, devices: dict) -> list[str]:
    command = [
        sys.executable,
        str(ROOT / f"examples/{profile}_controller.py"),
        "--can",
        f"udp_multicast:{CHANNEL}",
    ]
    if profile == "xsens":
        return [*command, "--xsens-base", hex(devices["xsens"]["base_id"])]
    return [*command, "--nodes", *map(str, devices[profile]["node_ids"])]


def cpu_seconds(pid: int, timeout: float) -> float | None:
    """Reap `pid` within `timeout` s: its user + system CPU seconds (None: it had to be killed)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        done, _, usage = os.wait4(pid, os.WNOHANG)
        if done:
            return round(usage.ru_utime + usage.ru_stime, 2)
        time.sleep(0.05)
    os.kill(pid, signal.SIGKILL)
    os.wait4(pid, 0)
    return None


def run_once(profile: str, seconds: float, netns: str, folder: Path) -> dict:
    bench, devices = bench_file(profile, folder)
    scenario = scenario_file(seconds, folder)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    inside = ["ip", "netns", "exec", netns]
    rig = [str(BIN / "pure-hil"), "run", str(scenario), "--bench", str(bench), "--out", str(folder / "run")]
    commands = {
        "supervisor": [str(BIN / "pure-hil"), "supervisor", "--bench", str(bench), "--clock", "lockstep"],
        "client": client_command(profile, devices),
        "rig": [
            *rig,
            "--supervisor",
            "external",
            "--controller",
            "external",
            "--clock",
            "lockstep",
            "--quiet",
        ],
    }
    start = time.monotonic()
    procs = {
        name: subprocess.Popen(
            [*inside, *argv],
            stdout=(folder / f"{name}.log").open("w"),
            stderr=subprocess.STDOUT,
            env=env,
            cwd=ROOT,
        )
        for name, argv in commands.items()
    }
    cpu = {"rig": cpu_seconds(procs["rig"].pid, 900.0)}
    rig_done = time.monotonic() - start
    for name in ("supervisor", "client"):
        procs[name].send_signal(signal.SIGTERM)  # `ip netns exec` execs the command: the signal reaches it
    cpu |= {name: cpu_seconds(procs[name].pid, 30.0) for name in ("supervisor", "client")}
    for proc in procs.values():
        proc.returncode = 0  # reaped above
    summary = json.loads((folder / "run" / "summary.json").read_text())
    rig = summary["rig"]
    median, p90 = answer_ms(folder / "run" / "can.log")
    return {
        "client": profile,
        "wall_per_sim_s": round(summary["timing"]["wall_time"] / summary["simulated"], 2),
        "rig_done_s": round(rig_done, 1),
        "answer_ms": {"median": median, "p90": p90},
        "cpu_s": cpu,
        "verdict": summary["verdict"],
        "missing_commands": rig["missing_commands"],
        "guards_expired": rig["guards_expired"],
    }


def answer_ms(can_log: Path) -> tuple[float, float]:
    """Median and 90th percentile of the time from each SYNC to the client's CONTROLLER_HEARTBEAT that
    closes its answer, in the rig's own receive timestamps (can.log): the client's share of a tick."""
    answers, sync = [], None
    for msg in can.LogReader(str(can_log)):
        if msg.arbitration_id == SYNC_ID:
            sync = msg.timestamp
        elif msg.arbitration_id == HEARTBEAT_ID and sync is not None:
            answers.append(1000.0 * (msg.timestamp - sync))
            sync = None
    if len(answers) < 2:
        return math.nan, math.nan
    return round(statistics.median(answers), 2), round(statistics.quantiles(answers, n=10)[-1], 2)


def describe(row: dict) -> str:
    return (
        f"{row['client']:7} {row['wall_per_sim_s']:6.2f} wall s per simulated s, rig done at "
        f"{row['rig_done_s']:6.1f} s, SYNC to heartbeat {row['answer_ms']} ms, CPU s {row['cpu_s']}, "
        f"{row['verdict']}, "
        f"missing {row['missing_commands']}, guards expired {row['guards_expired']}"
    )


def quota_group(fraction: float) -> Path:
    """A cgroup v1 `cpu` group that holds its processes to `fraction` of one CPU (1 ms periods)."""
    if not (CGROUP_V1 / "cgroup.procs").is_file():
        raise SystemExit(f"--quota: needs the cgroup v1 cpu controller at {CGROUP_V1} (not found)")
    group = CGROUP_V1 / f"lab_clients_{os.getpid()}"
    group.mkdir()
    (group / "cpu.cfs_period_us").write_text("10000")
    (group / "cpu.cfs_quota_us").write_text(str(max(1000, round(10000 * fraction))))
    (group / "cgroup.procs").write_text(str(os.getpid()))  # the processes started from now on inherit it
    return group


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=2, help="runs of each client")
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per run")
    parser.add_argument("--quota", type=float, default=None, help="CPU share per process (0 < F <= 1)")
    parser.add_argument("--clients", nargs="+", choices=CLIENTS, default=list(CLIENTS))
    parser.add_argument("--json", action="store_true", help="one JSON object per run")
    args = parser.parse_args()
    if args.repeat < 1 or not args.seconds > 0.0:
        parser.error(f"--repeat {args.repeat}, --seconds {args.seconds}: at least one run of more than 0 s")
    if args.quota is not None and not 0.0 < args.quota <= 1.0:
        parser.error(f"--quota {args.quota}: a share of one CPU, 0 < F <= 1")
    group = quota_group(args.quota) if args.quota is not None else None
    try:
        with loopback_namespace("lab-clients") as netns, tempfile.TemporaryDirectory() as tmp:
            for rep in range(args.repeat):
                for profile in args.clients:
                    folder = Path(tmp) / f"{profile}_{rep}"
                    folder.mkdir()
                    row = run_once(profile, args.seconds, netns, folder)
                    if args.json:
                        print(json.dumps(row), flush=True)
                    else:
                        print(describe(row), flush=True)
    except NamespaceRefused as exc:
        raise SystemExit(
            f"lab_clients: {exc} (udp_multicast runs only in a namespace whose only interface is lo)"
        ) from None
    finally:
        if group is not None:
            (CGROUP_V1 / "cgroup.procs").write_text(str(os.getpid()))
            try:
                group.rmdir()
            except OSError as exc:  # a process of a failed run still in it: say so, keep the run's own error
                print(f"lab_clients: {group} not removed: {exc}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
