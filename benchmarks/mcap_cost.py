"""What run.mcap costs a lockstep tick: the same scenario on the embedded bench with `[outputs] mcap` off and
on, alternated in one process (the machine's drift hits both alike), each tick loop measured in wall time
and in its thread's CPU time (which other processes on a busy machine disturb less), then one more run
with the writer's own calls timed (its share of a tick, and the dearest single call: a chunk closing).
The recording and the plots are off in all runs: they are written after the loop and cost the same. The
logs are written on the tick's thread here (`RunOptions(logs_in_process=True)`): what they would cost the
tick there; a run writes them in a process of its own (hil/outputs/run_logs.py).

--replay N: instead, the writer alone: one run's calls to it (every frame with the simulated time it was
taken at, every zenoh input and row) kept, then fed N times to a fresh writer, its thread's CPU time per
tick (the whole file, closing included). Nothing else runs then: it tells a change to the writer apart on a
machine too busy for the tick loop's figures to.

    python benchmarks/mcap_cost.py [SCENARIO (default speed_limiting)] [--duration S] [--pairs N] [--json]
                                   [--replay N]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import msgspec

import hil.pipeline as pipeline
from drivers.keys import Keys
from hil.bench.bench import load_bench
from hil.outputs.mcap_log import McapLog
from hil.pipeline import load_scenario, run
from hil.run.build import RunOptions

TIMED = ("on_message_received", "zenoh", "trace")
IN_PROCESS = RunOptions(logs_in_process=True)


def bench_with(mcap: bool):
    bench = load_bench()
    outputs = msgspec.structs.replace(bench.outputs, mcap=mcap, recording=False, plots=False)
    return msgspec.structs.replace(bench, outputs=outputs)


def us_per_tick(scenario, mcap: bool, out: Path) -> tuple[float, float]:
    """(wall, CPU) µs per tick of the run's tick loop."""
    cpu = []
    loop = pipeline.tick_loop

    def timed_loop(*args):
        t0 = time.thread_time()
        try:
            return loop(*args)
        finally:
            cpu.append(time.thread_time() - t0)

    pipeline.tick_loop = timed_loop
    try:
        result = run(scenario, bench_with(mcap), out=out, options=IN_PROCESS)
    finally:
        pipeline.tick_loop = loop
    if result.trace.failure is not None:
        raise SystemExit(f"run failed: {result.trace.failure}")
    timing = result.trace.timing
    return timing.wall_time / timing.ticks * 1e6, cpu[0] / timing.ticks * 1e6


def writer_share(scenario, out: Path) -> tuple[float, float, int]:
    """(µs per tick inside McapLog's calls, the dearest single call in ms, ticks) of one run."""
    totals = {"sum": 0.0, "max": 0.0}
    originals = {name: getattr(McapLog, name) for name in TIMED}

    def timed(fn):
        def wrapper(*args):
            t0 = time.perf_counter()
            try:
                return fn(*args)
            finally:
                dt = time.perf_counter() - t0
                totals["sum"] += dt
                totals["max"] = max(totals["max"], dt)

        return wrapper

    for name, fn in originals.items():
        setattr(McapLog, name, timed(fn))
    try:
        result = run(scenario, bench_with(True), out=out, options=IN_PROCESS)
    finally:
        for name, fn in originals.items():
            setattr(McapLog, name, fn)
    ticks = result.trace.timing.ticks
    return totals["sum"] / ticks * 1e6, totals["max"] * 1e3, ticks


def replay(scenario, out: Path, times: int) -> tuple[list[float], int]:
    """(µs of thread CPU time per tick of each replay, ticks): the writer fed one run's calls again."""
    calls: list[tuple] = []
    originals = {name: getattr(McapLog, name) for name in TIMED}

    def on_message_received(self, msg):
        calls.append(("frame", self.clock(), msg))
        originals["on_message_received"](self, msg)

    def zenoh(self, tick, key, data):
        calls.append(("zenoh", tick, key, bytes(data)))
        originals["zenoh"](self, tick, key, data)

    def trace(self, row):
        calls.append(("trace", tuple(row)))
        originals["trace"](self, row)

    McapLog.on_message_received, McapLog.zenoh, McapLog.trace = on_message_received, zenoh, trace
    bench = bench_with(True)
    try:
        run(scenario, bench, out=out / "recorded", options=IN_PROCESS)
    finally:
        for name, fn in originals.items():
            setattr(McapLog, name, fn)
    ticks = sum(call[0] == "trace" for call in calls)
    figures, taken_at = [], [0.0]
    for i in range(times):
        log = McapLog(out / f"replay-{i}.mcap", scenario.tick_hz, Keys(bench.zenoh.prefix))
        log.clock = lambda: taken_at[0]  # simulated time when the recorder took the frame, as in the run
        frame, zenoh_input, row = log.on_message_received, log.zenoh, log.trace
        t0 = time.thread_time()
        for call in calls:
            if call[0] == "frame":
                taken_at[0] = call[1]
                frame(call[2])
            elif call[0] == "trace":
                row(call[1])
            else:
                zenoh_input(call[1], call[2], call[3])
        log.stop()
        figures.append((time.thread_time() - t0) / ticks * 1e6)
        if log.error is not None:
            raise SystemExit(f"the replay failed: {log.error}")
    return figures, ticks


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("scenario", nargs="?", default="speed_limiting")
    parser.add_argument("--duration", type=float, default=None)
    parser.add_argument("--pairs", type=int, default=3, help="off/on runs, alternated")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--replay", type=int, default=0, help="the writer alone, fed one run's calls N times")
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    if args.duration:
        scenario = msgspec.structs.replace(scenario, duration=args.duration)
    if args.replay:
        with tempfile.TemporaryDirectory(prefix="mcap-cost-") as tmp:
            figures, ticks = replay(scenario, Path(tmp), args.replay)
        median = statistics.median(figures)
        if args.json:
            print(json.dumps({"scenario": scenario.name, "ticks": ticks, "replay_cpu_us_per_tick": figures}))
        else:
            print(f"{scenario.name}: the writer alone, one run's calls ({ticks} ticks) replayed")
            print(f"  thread CPU: {' '.join(f'{x:.1f}' for x in figures)} us/tick, median {median:.1f}")
        return
    off, on = [], []
    with tempfile.TemporaryDirectory(prefix="mcap-cost-") as tmp:
        out = Path(tmp)
        us_per_tick(scenario, False, out / "warm-up")
        for i in range(args.pairs):
            off.append(us_per_tick(scenario, False, out / f"off-{i}"))
            on.append(us_per_tick(scenario, True, out / f"on-{i}"))
        share, dearest, ticks = writer_share(scenario, out / "timed")
        folder = out / "timed"
        simulated = ticks / scenario.tick_hz
        sizes = {name: (folder / name).stat().st_size / simulated / 1e3 for name in ("run.mcap", "can.log")}
    ratio = {
        kind: statistics.median(x[i] for x in on) / statistics.median(x[i] for x in off)
        for i, kind in enumerate(("wall", "cpu"))
    }
    figures = {
        "scenario": scenario.name,
        "ticks": ticks,
        "pairs": args.pairs,
        "off_us_per_tick": [x[0] for x in off],
        "on_us_per_tick": [x[0] for x in on],
        "off_cpu_us_per_tick": [x[1] for x in off],
        "on_cpu_us_per_tick": [x[1] for x in on],
        "ratio_wall": ratio["wall"],
        "ratio_cpu": ratio["cpu"],
        "writer_us_per_tick": share,
        "writer_share_of_cpu_tick": share / statistics.median(x[1] for x in off),
        "writer_dearest_call_ms": dearest,
        "kB_per_simulated_s": sizes,
    }
    if args.json:
        print(json.dumps(figures))
        return
    print(
        f"{scenario.name}: {ticks} ticks per run, {args.pairs} pairs (mcap off, on), lockstep, embedded bench"
    )
    for kind, i in (("wall", 0), ("CPU", 1)):
        print(f"  tick loop, {kind}, mcap off: {' '.join(f'{x[i]:.0f}' for x in off)} us/tick")
        print(f"  tick loop, {kind}, mcap on:  {' '.join(f'{x[i]:.0f}' for x in on)} us/tick")
    print(f"  ratio on/off (medians): wall {ratio['wall']:.3f}, CPU {ratio['cpu']:.3f}")
    off_cpu = statistics.median(x[1] for x in off)
    print(
        f"  inside the MCAP writer's calls: {share:.1f} us/tick ({share / off_cpu:.1%} of a tick's CPU "
        f"without it); dearest single call {dearest:.2f} ms"
    )
    print(f"  run.mcap {sizes['run.mcap']:.0f} kB, can.log {sizes['can.log']:.0f} kB per simulated second")


if __name__ == "__main__":
    main()
