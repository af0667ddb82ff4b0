"""Real-time pacing at the tick rate: period jitter and overruns of the rig's loop against the same clock
with no work at all, measured in the same run.

    python benchmarks/realtime.py [--seconds 60] [--hz 400] [--fifo] [--cpu N] [--json]
        the rig's own work only: plant step, sensor sampling, the tick's frames on an in-process bus
        drained by a second thread;
    python benchmarks/realtime.py --full [--seconds 60] [--scenario speed_limiting] [--fifo] [--lock-memory]
                                         [--cpu N] [--json]
        a whole run in real time on the embedded bench: the reference controller on its own thread, the
        supervisor in the tick, the recorder on; also missing and late commands, ticks without
        controller telemetry and the process's peak memory.
    python benchmarks/realtime.py --full --processes [...]
        the same on the `processes` bench: rig, controller and supervisor as three processes on python-can's
        udp_multicast bus, inside a network namespace whose only interface is lo that the benchmark creates
        and removes (needs the right to run `ip netns add`; the rig's memory only).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from drivers.bus_config import BusConfig, network_interfaces
from drivers.can_bus import CanNode, open_bus, private_channel
from hil.run.clock import RealtimeClock
from plant.ballbot import Plant
from plant.core import RiderIntent
from plant.params import RiderParams, RobotParams, SimParams
from plant.rider import Sine


def paced(seconds: float, hz: float, work, fifo: bool, cpu: int | None, late_wakes: list | None = None):
    """`work` every tick on the rig's clock; `late_wakes` gets each wake-up's lateness after its scheduled
    start, µs."""
    clock = RealtimeClock(1.0 / hz, priority=50 if fifo else 0, cpu=cpu)
    clock.start()
    for _ in range(int(seconds * hz)):
        work()
        clock.wait_next()
        if late_wakes is not None:
            late_wakes.append((time.perf_counter() - clock._next) * 1e6)
    return clock.stats()


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


class AnonymousMemory:
    """Anonymous memory (RssAnon) of this process and every process it started (the logs process, a
    spawned controller or supervisor), sampled every 0.1 s: what they hold themselves. RSS would also count
    file pages mapped (trace.npy is read back through a memory map), which the kernel may drop at any time.
    Keeps the peak and one sample a second, so a 10-minute run shows whether memory stays flat while it
    runs, apart from the outputs' stage at its end (plots of every tick)."""

    def __init__(self):
        self.peak = 0.0
        self.series: list[tuple[float, float]] = []
        """(seconds since the start, MB), one a second."""
        self._start = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, name="memory-sampler", daemon=True)
        self._thread.start()

    @staticmethod
    def _tree(pid: int) -> list[int]:
        pids, todo = [], [pid]
        while todo:
            p = todo.pop()
            pids.append(p)
            try:
                for task in os.listdir(f"/proc/{p}/task"):
                    with open(f"/proc/{p}/task/{task}/children") as children:
                        todo += [int(c) for c in children.read().split()]
            except OSError:
                continue  # gone meanwhile
        return pids

    @staticmethod
    def _anonymous_mb(pid: int) -> float:
        try:
            with open(f"/proc/{pid}/status") as status:
                for line in status:
                    if line.startswith("RssAnon:"):
                        return int(line.split()[1]) / 1024
        except OSError:
            pass
        return 0.0

    def _sample(self) -> None:
        while not self._stop.wait(0.1):
            mb = sum(self._anonymous_mb(p) for p in self._tree(os.getpid()))
            self.peak = max(self.peak, mb)
            t = time.monotonic() - self._start
            if not self.series or t - self.series[-1][0] >= 1.0:
                self.series.append((t, mb))

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        return self.peak

    def at(self, seconds: float) -> float:
        """MB at the first sample from `seconds` on (the last one if none)."""
        return next((mb for t, mb in self.series if t >= seconds), self.series[-1][1] if self.series else 0.0)


class Probe:
    """Where a real-time tick's time goes, tick by tick (--probe): each stage's end after the tick's
    scheduled start. wake: the clock's wake-up; taken: the last tick's commands taken in
    (hil/run/drives_port.py `close_tick`); sampled: the plant stepped and its sensors sampled; frames: the
    sensors' CAN frames sent; sync: SYNC sent; published: the tick's zenoh puts (after SYNC in real time);
    answered: a driven controller has answered (the rig expects the next commands); supervised: the
    supervisor's part done;
    done: the loop's own work done, before it sleeps. Beside them, how often the scheduler took the core
    from the rig's thread between its wake-up and SYNC (involuntary switches, getrusage). From a Rig and a
    clock subclassed by the build (a compiled Rig cannot be patched)."""

    STAGES = ("wake", "taken", "sampled", "frames", "sync", "published", "answered", "supervised", "done")
    PREEMPTED = len(STAGES)
    """Rows' column: involuntary switches of the rig's thread from its wake-up to SYNC."""

    def __init__(self):
        self.rows: list[list[float]] = []
        self.scheduled = 0.0
        self._switches = 0

    def install(self) -> None:
        import hil.run.build as build_module
        import hil.run.loop as loop_module

        probe = self
        clock = loop_module.RealtimeClock
        rig, port = build_module.Rig, build_module.DrivesPort

        class ProbedClock(clock):
            def start(self):
                super().start()
                probe.scheduled = self._next
                probe.row("wake")

            def wait_next(self):
                probe.row("done")
                super().wait_next()
                probe.scheduled = self._next
                probe.row("wake")

        def after(stage: str, method):
            def wrapper(self, *a, **kw):
                try:
                    return method(self, *a, **kw)
                finally:
                    probe.row(stage)

            return wrapper

        def expect(self, *a, **kw):
            probe.row("answered")
            return port.expect(self, *a, **kw)

        class ProbedRig(rig):
            pass

        class ProbedPort(port):
            pass

        ProbedPort.close_tick = after("taken", port.close_tick)
        ProbedPort.expect = expect
        ProbedRig._sample = after("sampled", rig._sample)
        ProbedRig._send_sensors = after("frames", rig._send_sensors)
        ProbedRig._send_sync = after("sync", rig._send_sync)
        ProbedRig._publish_tes = after("published", rig._publish_tes)
        ProbedRig._supervise = after("supervised", rig._supervise)
        loop_module.RealtimeClock = ProbedClock
        build_module.Rig = ProbedRig
        build_module.DrivesPort = ProbedPort

    def row(self, stage: str) -> None:
        now = (time.perf_counter() - self.scheduled) * 1e6
        if stage == "wake":
            self.rows.append([math.nan] * (len(self.STAGES) + 1))
        if not self.rows:
            return
        self.rows[-1][self.STAGES.index(stage)] = now
        if stage in ("wake", "sync"):
            switches = resource.getrusage(resource.RUSAGE_THREAD).ru_nivcsw
            if stage == "sync":
                self.rows[-1][self.PREEMPTED] = switches - self._switches
            self._switches = switches

    def report(self, late_us: float) -> dict[str, dict[str, float]]:
        """Each stage's percentiles; the preemptions before SYNC a tick, and a tick whose SYNC was later
        than `late_us` after its scheduled start."""
        import numpy as np

        a = np.array(self.rows[:-1])
        out = {}
        for i, name in enumerate(self.STAGES):
            col = a[:, i][np.isfinite(a[:, i])]
            if len(col):
                q = {
                    name: float(np.percentile(col, p))
                    for name, p in (("p50", 50), ("p99", 99), ("p99.9", 99.9))
                }
                out[name] = {**q, "max": float(col.max())}
        switches = a[:, self.PREEMPTED]
        late = a[:, self.STAGES.index("sync")] > late_us
        out["preempted_before_sync"] = {
            "per_tick": float(np.nanmean(switches)),
            "per_late_sync": float(np.nanmean(switches[late])) if late.any() else 0.0,
        }
        return out


def bare_floor_us(ticks: int = 4000) -> float:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from lockstep import bare_floor

    return bare_floor(ticks) / ticks * 1e6


def full(args) -> None:
    import msgspec

    from hil.bench.bench import load_bench
    from hil.pipeline import load_scenario, run

    probe = Probe() if args.probe else None
    # The machine's speed in the same run: python-can's bare send+recv of a tick's frames (lockstep.py's
    # floor), so a tick's work reads in floors as well as in microseconds.
    floor_us = bare_floor_us()
    if probe is not None:
        probe.install()

    # The machine's own stalls: the same clock with no work. On a shared VM a few wake-ups a minute come
    # late by a whole period or more, which no work in the loop can avoid.
    idle_wakes: list[float] = []
    idle = paced(min(args.seconds, 30.0), 400.0, lambda: None, False, None, idle_wakes)
    scenario = msgspec.structs.replace(load_scenario(args.scenario), duration=args.seconds)
    bench = load_bench("processes" if args.processes or args.external else "embedded")
    controller = None
    if args.external:
        # A lab's controller in a process of its own at host speed, on the bench's bus: examples/ written
        # from docs/contract.md, which reads nothing from zenoh (so `balance`, not a riding scenario).
        bench = bench.with_overrides(controller="external", supervisor="embedded")
        example = Path(__file__).resolve().parents[1] / "examples" / "balance_controller.py"
        where = f"{bench.can.interface}:{bench.can.channel}"
        controller = subprocess.Popen([sys.executable, str(example), "--can", where])
    realtime = msgspec.structs.replace(
        bench.realtime, priority=50 if args.fifo else 0, lock_memory=args.lock_memory, cpu=args.cpu
    )
    bench = msgspec.structs.replace(bench, clock="realtime", realtime=realtime)
    with tempfile.TemporaryDirectory(prefix="realtime-bench-") as tmp:
        anonymous = AnonymousMemory()
        t0 = time.perf_counter()
        try:
            result = run(scenario, bench, out=Path(tmp))
        finally:
            if controller is not None:
                controller.terminate()
                controller.wait(10)
        wall = time.perf_counter() - t0
        peak_anonymous = anonymous.stop()
    tr = result.trace
    timing, stats = tr.timing, tr.stats
    figures = {
        "scenario": scenario.name,
        "seconds": args.seconds,
        "ticks": stats.ticks,
        "overruns": timing.overruns,
        "jitter_us": timing.jitter_us,
        "idle_jitter_us": idle.jitter_us,
        "idle_overruns": idle.overruns,
        "idle_ticks": idle.ticks,
        "missing_commands": stats.missing_commands,
        "late_commands": stats.late_commands,
        "telemetry_missing": tr.controller_telemetry_missing,
        "passed": result.passed,
        "verdict": result.verdict,
        "rig_late": tr.lateness.as_dict(),
        "floor_us": floor_us,
        "failure": None if tr.failure is None else str(tr.failure),
        "peak_rss_mb": peak_rss_mb(),
        "peak_anonymous_mb": peak_anonymous,
        # In the run, by its scenario's clock (a few seconds of start-up before it): flat memory reads alike.
        "anonymous_mb_at": {f"{share:.0%}": anonymous.at(share * args.seconds) for share in (0.1, 0.5, 0.9)},
        "wall_s": wall,
        "policy": timing.realtime_policy,
        "bench": bench.name,
        "probe_us": probe.report(1e6 * realtime.sync_allowance / args.hz) if probe is not None else None,
    }
    if probe is not None:
        # The machine's own share of late SYNCs: idle wake-ups later than the slack the rig's work leaves
        # before SYNC is due (the allowance less the median wake-up to SYNC).
        q = figures["probe_us"]
        slack = 1e6 * realtime.sync_allowance / args.hz - (q["sync"]["p50"] - q["wake"]["p50"])
        figures["idle_wakes_past_slack"] = {
            "slack_us": slack,
            "per_10k": 1e4 * sum(w > slack for w in idle_wakes) / max(len(idle_wakes), 1),
        }
    if probe is not None and args.probe_rows is not None:
        import numpy as np

        np.save(args.probe_rows, np.array(probe.rows[:-1]))
    if args.json:
        print(json.dumps(figures))
        return
    j, i = timing.jitter_us or {}, idle.jitter_us or {}
    print(
        f"{scenario.name}, {args.seconds:g} s in real time on the {bench.name} bench "
        f"({timing.realtime_policy}): passed: {result.passed}"
    )
    print(
        f"  ticks {stats.ticks}, overruns {timing.overruns} = {1e4 * timing.overruns / stats.ticks:.1f} per "
        f"10k ticks (no work: {idle.overruns} in {idle.ticks} = {1e4 * idle.overruns / idle.ticks:.1f})"
    )
    print("  jitter = |period - nominal|, us      p50     p99   p99.9     max")
    for label, q in (("the run", j), ("no work (baseline)", i)):
        print(f"    {label:<32}" + "".join(f"{q.get(p, 0):8.0f}" for p in ("p50", "p99", "p99.9", "max")))
    late = tr.lateness
    print(
        f"  commands missing {stats.missing_commands}, late {stats.late_commands} (of them the rig's: "
        f"{late.missing}, {late.late}, in {late.ticks} late SYNCs); ticks without controller telemetry "
        f"{tr.controller_telemetry_missing}; verdict {result.verdict}"
    )
    period_floors = 1e6 / args.hz / floor_us
    print(f"  floor (bare python-can, 12 frames) {floor_us:.0f} us: the period is {period_floors:.1f} floors")
    print(
        f"  peak memory {figures['peak_rss_mb']:.0f} MB (anonymous {peak_anonymous:.0f} MB, this process and "
        f"those it started); whole command {wall:.1f} s (outputs included)"
    )
    print(
        "  anonymous memory at "
        + ", ".join(f"{share} of the run {mb:.0f} MB" for share, mb in figures["anonymous_mb_at"].items())
    )
    if probe is not None:
        work = figures["probe_us"]["done"]["p50"] - figures["probe_us"]["wake"]["p50"]
        print(f"  the tick's work (wake to done, medians) {work:.0f} us = {work / floor_us:.1f} floors")
        print("  each stage's end after the tick's scheduled start, us   p50     p99   p99.9     max")
        for name, q in figures["probe_us"].items():
            if name in Probe.STAGES:
                print(f"    {name:<50}" + "".join(f"{q[p]:8.0f}" for p in ("p50", "p99", "p99.9", "max")))
        past = figures["idle_wakes_past_slack"]
        late_syncs = tr.lateness.ticks
        print(
            f"  late SYNCs {1e4 * late_syncs / max(stats.ticks, 1):.1f} per 10k ticks; the idle loop's "
            f"wake-ups later than the slack the rig's work leaves before SYNC is due "
            f"({past['slack_us']:.0f} us): {past['per_10k']:.1f} per 10k ticks"
        )
        pre = figures["probe_us"]["preempted_before_sync"]
        print(
            f"  the rig's thread preempted between its wake-up and SYNC: {pre['per_tick']:.2f} times a tick, "
            f"{pre['per_late_sync']:.2f} on a tick whose SYNC was late"
        )


def in_a_loopback_namespace(argv: list[str]) -> int:
    """Run this benchmark again inside a network namespace of its own whose only interface is lo."""
    from hil.bench.netns import NamespaceRefused, loopback_namespace

    try:
        with loopback_namespace("pure-rt") as name:
            return subprocess.run(["ip", "netns", "exec", name, sys.executable, __file__, *argv]).returncode
    except NamespaceRefused as exc:
        print(f"--processes: {exc}", file=sys.stderr)
        return 2


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--hz", type=float, default=400.0)
    p.add_argument("--fifo", action="store_true", help="SCHED_FIFO 50 (needs privileges)")
    p.add_argument("--lock-memory", action="store_true", help="--full: mlockall for the run's loop")
    p.add_argument("--cpu", type=int, default=None, help="pin to this CPU")
    p.add_argument("--full", action="store_true", help="a whole run (controller, supervisor, recorder)")
    p.add_argument(
        "--scenario", default="speed_limiting", help="--full: the scenario (its duration: --seconds)"
    )
    p.add_argument(
        "--processes", action="store_true", help="--full: controller and supervisor in their own processes"
    )
    p.add_argument(
        "--external",
        action="store_true",
        help="--full: examples/balance_controller.py in its own process, the supervisor in the rig's tick "
        "(use --scenario balance: the example reads nothing from zenoh)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--probe", action="store_true", help="--full: where each tick's time goes (Probe)")
    p.add_argument(
        "--probe-rows",
        type=Path,
        default=None,
        help="--probe: also save every tick's stage ends (µs after its scheduled start) to this .npy file, "
        "one row a tick, columns as Probe.STAGES, then the preemptions before SYNC",
    )
    args = p.parse_args()
    if args.external:
        args.full = True
    if (args.processes or args.external) and network_interfaces() != ["lo"]:
        sys.exit(in_a_loopback_namespace(sys.argv[1:]))
    if args.full:
        full(args)
        return

    plant = Plant(
        RobotParams(),
        RiderParams(name="ref", mass=60.0, height=1.80),
        SimParams(tick_hz=args.hz, fixture="clamped"),
        RiderIntent(pitch=[Sine(amplitude=5.0, frequency_hz=0.5, duration=1e9)]),
    )
    config = BusConfig(channel=private_channel("rt"))
    tx_bus, rx_bus = open_bus(config), open_bus(config)
    node = CanNode(tx_bus, name="rig")
    stop = threading.Event()

    def drain():
        while not stop.is_set():
            rx_bus.recv(0.1)

    drainer = threading.Thread(target=drain, daemon=True)
    drainer.start()

    def rig_work():
        plant.step()
        for i, fb in enumerate(plant.sample_drives()):
            node.send(
                f"DRIVE{i + 1}_FEEDBACK", {"Position": fb.counts, "Velocity": fb.velocity, "Enabled": 1}
            )
        imu = plant.sample_imu()
        node.send("IMU_ATTITUDE", {"Roll": imu.attitude[0], "Pitch": imu.attitude[1], "Yaw": imu.attitude[2]})
        node.send("IMU_RATE", {"RateX": imu.rate[0], "RateY": imu.rate[1], "RateZ": imu.rate[2]})
        node.send("IMU_ACCEL", {"AccX": imu.accel[0], "AccY": imu.accel[1], "AccZ": imu.accel[2]})
        plant.sample_tes()
        node.send("SYNC", {"Tick": plant.tick % 65536})

    idle = paced(min(args.seconds, 10.0), args.hz, lambda: None, args.fifo, args.cpu)
    loaded = paced(args.seconds, args.hz, rig_work, args.fifo, args.cpu)
    stop.set()
    drainer.join()
    tx_bus.shutdown()
    rx_bus.shutdown()
    if args.json:
        print(
            json.dumps(
                {
                    "ticks": loaded.ticks,
                    "overruns": loaded.overruns,
                    "jitter_us": loaded.jitter_us,
                    "idle_jitter_us": idle.jitter_us,
                    "idle_overruns": idle.overruns,
                    "idle_ticks": idle.ticks,
                    "policy": loaded.realtime_policy,
                }
            )
        )
        return
    print(f"real-time pacing at {args.hz:g} Hz ({loaded.realtime_policy}); jitter = |period - nominal|, us")
    print(f"{'loop':<34}{'ticks':>7}{'overruns':>9}{'p50':>8}{'p99':>8}{'p99.9':>8}{'max':>8}")
    for label, s in (("no work (baseline)", idle), ("plant + sensors + 8 frames", loaded)):
        j = s.jitter_us or {}
        print(
            f"{label:<34}{s.ticks:>7}{s.overruns:>9}{j.get('p50', 0):8.0f}{j.get('p99', 0):8.0f}"
            f"{j.get('p99.9', 0):8.0f}{j.get('max', 0):8.0f}"
        )
    base, work = (idle.jitter_us or {}).get("p99", 0.0), (loaded.jitter_us or {}).get("p99", 0.0)
    if base:
        print(f"p99 jitter with the rig's work / without: {work / base:.1f}")


if __name__ == "__main__":
    main()
