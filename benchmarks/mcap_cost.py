"""What run.mcap costs a lockstep tick: the same scenario on the embedded bench with `[outputs] mcap` off and
on, alternated in one process (the machine's drift hits both alike), each tick loop measured in wall time
and in its thread's CPU time (which other processes on a busy machine disturb less), then one more run
with the writer's own calls timed (its share of a tick, and the dearest single call: a chunk closing).
The recording and the plots are off in all runs: they are written after the loop and cost the same. The
logs are written on the tick's thread here (`RunOptions(logs_in_process=True)`): what they would cost the
tick there; a run writes them in a process of its own (hil/outputs/run_logs.py).

--poses: instead, what the bodies' poses cost (hil/outputs/bodies.py: taken every 4th tick, FrameTransforms in
run.mcap): tick loops without and with them alternated in one process (run.mcap written in its own process,
as a run writes it), the loop's pose calls in its thread's CPU time, and the writer alone fed one run's calls
without and with the poses', alternated.

--replay N: instead, the writer alone: one run's calls to it (every frame with the simulated time it was
taken at, every zenoh input and row) kept, then fed N times to a fresh writer, its thread's CPU time per
tick (the whole file, closing included). Nothing else runs then: it tells a change to the writer apart on a
machine too busy for the tick loop's figures to.

    python benchmarks/mcap_cost.py [SCENARIO (default speed_limiting)] [--duration S] [--pairs N] [--json]
                                   [--replay N] [--poses]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import msgspec

import hil.pipeline as pipeline
import hil.run.loop as loop_module
from drivers.keys import Keys
from hil.bench.bench import load_bench
from hil.outputs.bodies import PoseTaker
from hil.outputs.mcap_log import McapLog
from hil.pipeline import load_scenario, run
from hil.run.build import RunOptions

TIMED = ("on_message_received", "zenoh", "trace", "bodies", "poses")
IN_PROCESS = RunOptions(logs_in_process=True)


def bench_with(mcap: bool):
    bench = load_bench()
    outputs = msgspec.structs.replace(bench.outputs, mcap=mcap, recording=False, plots=False)
    return msgspec.structs.replace(bench, outputs=outputs)


@contextlib.contextmanager
def without_poses():
    """Runs that take no poses (as a run with neither run.mcap nor a recording)."""
    taker = loop_module._pose_taker
    loop_module._pose_taker = lambda built: None
    try:
        yield
    finally:
        loop_module._pose_taker = taker


def us_per_tick(scenario, mcap: bool, out: Path, options: RunOptions = IN_PROCESS) -> tuple[float, float]:
    """(wall, CPU) µs per tick of the run's tick loop (CPU: its thread's)."""
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
        result = run(scenario, bench_with(mcap), out=out, options=options)
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


def record_calls(scenario, out: Path) -> tuple[list[tuple], object]:
    """Every call one run makes to run.mcap's writer, with the simulated time each frame was taken at."""
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

    def bodies(self, bodies):
        calls.append(("bodies", bodies))
        originals["bodies"](self, bodies)

    def poses(self, t, row):
        calls.append(("poses", t, list(row)))
        originals["poses"](self, t, row)

    McapLog.on_message_received, McapLog.zenoh, McapLog.trace = on_message_received, zenoh, trace
    McapLog.bodies, McapLog.poses = bodies, poses
    bench = bench_with(True)
    try:
        run(scenario, bench, out=out / "recorded", options=IN_PROCESS)
    finally:
        for name, fn in originals.items():
            setattr(McapLog, name, fn)
    return calls, bench


def replay_once(calls: list[tuple], scenario, bench, path: Path, poses: bool = True) -> float:
    """µs of thread CPU time per tick: a fresh writer fed `calls` (without the poses' unless `poses`)."""
    ticks = sum(call[0] == "trace" for call in calls)
    taken_at = [0.0]
    log = McapLog(path, scenario.tick_hz, Keys(bench.zenoh.prefix))
    log.clock = lambda: taken_at[0]  # simulated time when the recorder took the frame, as in the run
    frame, zenoh_input, row = log.on_message_received, log.zenoh, log.trace
    t0 = time.thread_time()
    for call in calls:
        kind = call[0]
        if kind == "frame":
            taken_at[0] = call[1]
            frame(call[2])
        elif kind == "trace":
            row(call[1])
        elif kind == "zenoh":
            zenoh_input(call[1], call[2], call[3])
        elif not poses:
            continue
        elif kind == "poses":
            log.poses(call[1], call[2])
        else:
            log.bodies(call[1])
    log.stop()
    if log.error is not None:
        raise SystemExit(f"the replay failed: {log.error}")
    return (time.thread_time() - t0) / ticks * 1e6


def replay(scenario, out: Path, times: int) -> tuple[list[float], int]:
    """(µs of thread CPU time per tick of each replay, ticks): the writer fed one run's calls again."""
    calls, bench = record_calls(scenario, out)
    figures = [replay_once(calls, scenario, bench, out / f"replay-{i}.mcap") for i in range(times)]
    return figures, sum(call[0] == "trace" for call in calls)


def pose_cost(scenario, out: Path, pairs: int) -> dict:
    """What the poses cost a run (run.mcap in its own process, as a run writes it): tick loops without and
    with them alternated; in one more run the loop's pose calls (taking them, handing them over) in its
    thread's CPU time against the whole loop's; the writer alone fed one run's calls without and with the
    poses', alternated; run.mcap's size."""
    own_process = RunOptions()
    off, on = [], []
    for i in range(pairs):
        with without_poses():
            off.append(us_per_tick(scenario, True, out / f"off-{i}", own_process))
        on.append(us_per_tick(scenario, True, out / f"on-{i}", own_process))
    took = {"cpu": 0.0, "calls": 0}
    take, loop = PoseTaker.take, pipeline.tick_loop
    loop_cpu = []

    def timed_take(self, plant, ticks):
        t0 = time.thread_time()
        try:
            return take(self, plant, ticks)
        finally:
            took["cpu"] += time.thread_time() - t0
            took["calls"] += 1

    def timed_loop(*args):
        t0 = time.thread_time()
        try:
            return loop(*args)
        finally:
            loop_cpu.append(time.thread_time() - t0)

    PoseTaker.take, pipeline.tick_loop = timed_take, timed_loop
    try:
        result = run(scenario, bench_with(True), out=out / "timed", options=own_process)
    finally:
        PoseTaker.take, pipeline.tick_loop = take, loop
    ticks = result.trace.timing.ticks
    calls, bench = record_calls(scenario, out)
    writer: dict[str, list[float]] = {"without": [], "with": []}
    for i in range(pairs):
        writer["without"].append(replay_once(calls, scenario, bench, out / f"w-off-{i}.mcap", poses=False))
        writer["with"].append(replay_once(calls, scenario, bench, out / f"w-on-{i}.mcap"))
    simulated = ticks / scenario.tick_hz
    return {
        "pairs": pairs,
        "off": off,
        "on": on,
        "take_cpu_us_per_tick": took["cpu"] / ticks * 1e6,
        "take_cpu_us_per_call": took["cpu"] / took["calls"] * 1e6,
        "take_share_of_loop_cpu": took["cpu"] / loop_cpu[0],
        "writer_cpu_us_per_tick": writer,
        "kB_per_simulated_s": {
            "without": (out / "w-off-0.mcap").stat().st_size / simulated / 1e3,
            "with": (out / "w-on-0.mcap").stat().st_size / simulated / 1e3,
        },
    }


def print_pose_cost(scenario, ticks: int, figures: dict) -> None:
    print(f"{scenario.name}: {ticks} ticks per run, {figures['pairs']} pairs (poses off, on), lockstep")
    off, on = figures["off"], figures["on"]
    for kind, i in (("wall", 0), ("CPU", 1)):
        print(f"  tick loop, {kind}, poses off: {' '.join(f'{x[i]:.0f}' for x in off)} us/tick")
        print(f"  tick loop, {kind}, poses on:  {' '.join(f'{x[i]:.0f}' for x in on)} us/tick")
    ratio = [statistics.median(x[i] for x in on) / statistics.median(x[i] for x in off) for i in (0, 1)]
    print(f"  ratio on/off (medians): wall {ratio[0]:.3f}, CPU {ratio[1]:.3f}")
    print(
        f"  the loop's pose calls: {figures['take_cpu_us_per_tick']:.1f} us/tick of thread CPU "
        f"({figures['take_share_of_loop_cpu']:.1%} of the loop's; {figures['take_cpu_us_per_call']:.1f} us "
        "per pose taken)"
    )
    writer = figures["writer_cpu_us_per_tick"]
    for name in ("without", "with"):
        print(f"  the writer alone, {name} the poses: {' '.join(f'{x:.1f}' for x in writer[name])} us/tick")
    size = figures["kB_per_simulated_s"]
    print(
        f"  run.mcap per simulated second: {size['without']:.0f} kB without poses, {size['with']:.0f} kB with"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("scenario", nargs="?", default="speed_limiting")
    parser.add_argument("--duration", type=float, default=None)
    parser.add_argument("--pairs", type=int, default=3, help="off/on runs, alternated")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--replay", type=int, default=0, help="the writer alone, fed one run's calls N times")
    parser.add_argument("--poses", action="store_true", help="what the bodies' poses cost")
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    if args.duration:
        scenario = msgspec.structs.replace(scenario, duration=args.duration)
    if args.poses:
        with tempfile.TemporaryDirectory(prefix="mcap-cost-") as tmp:
            us_per_tick(scenario, True, Path(tmp) / "warm-up")
            figures = pose_cost(scenario, Path(tmp), args.pairs)
        ticks = round(scenario.duration * scenario.tick_hz)
        if args.json:
            print(json.dumps({"scenario": scenario.name, "ticks": ticks, **figures}))
        else:
            print_pose_cost(scenario, ticks, figures)
        return
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
