"""Lockstep speed of a scenario with everything on (plant, CAN frames through the DBC codec and E2E, zenoh,
the reference controller, the embedded supervisor, the CAN log recorder; can.log and run.mcap written in
their own process, whose CPU time a tick it prints too: their cost on the tick's thread is
benchmarks/mcap_cost.py), the per-stage cost of the rig's tick (from a second run of the same scenario with
its stages timed: the tick loop's own figure comes from a run with nothing timed), and, measured in the same
run:
- rig only: the same scenario with an instant responder in place of the controller (it answers every SYNC
  with disabled zero-torque commands and a heartbeat at once; the plant is clamped on its stand);
- the floor: bare python-can virtual send+recv of the tick's frames.

It runs on whichever build is installed (docs/performance.md, "Compiled build"): `build` in the output says
which, from where the compiled build's modules were imported.

    python benchmarks/lockstep.py [SCENARIO (default speed_limiting)] [--duration S] [--json]
                                  [--devices PROFILE ...]

--devices odrive: the same scenario on each device profile's shipped bench too (configs/benches/PROFILE.toml),
its tick loop and stages beside `pure`'s (the embedded bench), measured in the same run.

Every figure is on the bench's plant (the 3-D one by default); `planar` is the same scenario's tick loop and
stages on the planar plant (--plant planar), measured in the same run.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import can
import msgspec

import controller.embedded
import hil.run.build as build_module
import hil.run.rig as rig_module
from drivers.can_bus import BusRecorder, CanNode, open_bus, private_channel
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, MessageName
from drivers.contract import CONTRACT_VERSION
from drivers.dut import DutSpec
from drivers.e2e import COUNTER, CRC
from hil.bench.bench import load_bench
from hil.outputs import run_logs
from hil.pipeline import load_scenario, run
from hil.run.build import RunOptions
from plant.ballbot import Plant

FRAMES_PER_TICK = 12  # 3 feedback, 3 IMU, SYNC, 3 commands, heartbeat, + (DRIVEn_TORQUE, estop) / 4
STAGES = {
    "plant.step": "plant step (MuJoCo or RK4, rider)",
    "_sample": "sample the sensors (drives, IMU, seat)",
    "_send_sensors": "7 frames out (drives, IMU)",
    "_publish_tes": "seat wrench -> zenoh",
    "controller": "controller (driven: frames, step, out)",
    "port.collect": "collect the controller's answer",
    "_supervise": "supervisor (frames, decide, emit)",
}
RIG_STAGES = tuple(name for name in STAGES if name.startswith("_"))
"""The stages that are the rig's own methods: timed in a subclass (a compiled Rig cannot be patched)."""


def timed(totals: dict[str, float], name: str, fn):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            totals[name] = totals.get(name, 0.0) + time.perf_counter() - t0

    return wrapper


class InstantResponder:
    """In place of the controller: every SYNC answered at once from the rig's thread (DutSpec.driven)."""

    def __init__(self, spec: DutSpec):
        self.bus = open_bus(spec.can)
        self.node = CanNode(self.bus, name="responder")
        boot = {"State": 0, "Mode": 0, "FaultCode": 0, "Contract": CONTRACT_VERSION}
        self.node.send(MessageName.CONTROLLER_HEARTBEAT, boot)

    def poll(self) -> None:
        while (rx := self.node.recv(timeout=0.0)) is not None:
            if rx.name == MessageName.SYNC:
                for name in DRIVE_COMMAND:
                    self.node.send(name, {"Torque": 0.0, "Tick": rx.signals["Tick"], "Enable": 0})
                self.node.send(MessageName.CONTROLLER_HEARTBEAT, {"State": 1, "Mode": 0, "FaultCode": 0})

    def stop(self) -> None:
        self.bus.shutdown()


def timed_run(scenario, bench, out: Path, options: RunOptions | None = None):
    t0 = time.perf_counter()
    result = run(scenario, bench, out=out, options=options)
    return result, time.perf_counter() - t0


def rig_only(scenario, out: Path) -> float:
    """us per tick of the rig's loop with an instant responder in place of the controller."""
    sim = out / "clamped.toml"
    sim.write_text('fixture = "clamped"\n')
    bench = msgspec.structs.replace(load_bench(), sim=str(sim))
    original = build_module.start_dut
    build_module.start_dut = lambda name, spec: InstantResponder(spec)
    try:
        result, _ = timed_run(scenario, bench, out / "rig-only", RunOptions(stop_on_fall=False))
    finally:
        build_module.start_dut = original
    timing = result.trace.timing
    if result.trace.failure is not None:
        raise SystemExit(f"rig-only run failed: {result.trace.failure}")
    return timing.wall_time / timing.ticks * 1e6


def bare_floor(ticks: int) -> float:
    """Seconds of bare python-can virtual send+recv for FRAMES_PER_TICK frames per tick."""
    channel = private_channel("bench")
    a, b = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
    msg = can.Message(arbitration_id=0x181, is_extended_id=False, data=bytes(8))
    t0 = time.perf_counter()
    for _ in range(ticks * FRAMES_PER_TICK):
        a.send(msg)
        b.recv(0)
    elapsed = time.perf_counter() - t0
    a.shutdown()
    b.shutdown()
    return elapsed


SENT_BY_RIG = (*DRIVE_FEEDBACK, MessageName.IMU_ATTITUDE, MessageName.IMU_RATE, MessageName.IMU_ACCEL)
SENT_BY_CONTROLLER = (*DRIVE_COMMAND, MessageName.CONTROLLER_HEARTBEAT)


def frame_work(ticks: int, out: Path) -> float:
    """Seconds of the frame work the loop must keep, with nothing else: per tick the rig's 7 sensor frames
    and SYNC, the controller's 3 commands and heartbeat, the supervisor's SUPERVISOR_ESTOP every 4th tick,
    each encoded and sealed by its sender's CanNode, decoded and E2E-checked by every node that reads it
    (the controller reads the rig's and the supervisor's frames, the supervisor every frame, the rig the
    other two nodes'), and written by the CAN log recorder, on the in-process bus of the embedded bench."""
    config = load_bench().can
    config = msgspec.structs.replace(config, channel=private_channel("frames"))
    rig, controller, supervisor = (CanNode(open_bus(config), name=n) for n in ("rig", "ctl", "sup"))
    values = {
        name: {s: 1 for s in rig.catalog[name].signal_names if s not in (COUNTER, CRC)}
        for name in (*SENT_BY_RIG, *SENT_BY_CONTROLLER, MessageName.SUPERVISOR_ESTOP, MessageName.SYNC)
    }
    recorder = BusRecorder(config, out / "frames.log")
    t0 = time.perf_counter()
    for k in range(ticks):
        for name in SENT_BY_RIG:
            rig.send(name, values[name])
        rig.send(MessageName.SYNC, {"Tick": k % 65536})
        while controller.recv(0.0) is not None:
            pass
        for name in SENT_BY_CONTROLLER:
            controller.send(name, values[name])
        if k % 4 == 0:
            supervisor.send(MessageName.SUPERVISOR_ESTOP, values[MessageName.SUPERVISOR_ESTOP])
        while supervisor.recv(0.0) is not None:
            pass
        while rig.recv(0.0) is not None:
            pass
        recorder.poll()
    elapsed = time.perf_counter() - t0
    recorder.stop(settle=0.0)
    for node in (rig, controller, supervisor):
        node.bus.shutdown()
    return elapsed


def instrument(totals: dict[str, float]) -> None:
    """Time every stage of the runs from here on: the rig's own stages and the plant's step in subclasses
    the build makes instead of the Rig and the Plant (compiled, their methods cannot be replaced; a subclass
    may override them), the driven controller's poll (a Python class on both builds) in place."""
    rig = rig_module.Rig
    timed_rig = type(
        "TimedRig", (rig,), {name: timed(totals, name, getattr(rig, name)) for name in RIG_STAGES}
    )
    build_module.Rig = timed_rig
    port = build_module.DrivesPort
    collect = timed(totals, "port.collect", port.collect)
    build_module.DrivesPort = type("TimedPort", (port,), {"collect": collect})

    def timed_plant(robot, rider, sim, intent=None, initial_tilt=(0.0, 0.0)):
        if sim.plant == "3d":
            from plant.ballbot3d import Plant3D as cls
        else:
            cls = Plant
        timed_cls = type(f"Timed{cls.__name__}", (cls,), {"step": timed(totals, "plant.step", cls.step)})
        return timed_cls(robot, rider, sim, intent, initial_tilt)

    build_module.make_plant = timed_plant
    embedded = controller.embedded.EmbeddedController
    embedded.poll = timed(totals, "controller", embedded.poll)


def watch_log_writers(cpu: list[float]) -> None:
    """Keep each run's log writer process's CPU time (can.log and run.mcap, off the tick's thread)."""
    stop = run_logs.LogProcess.stop

    def watched(self: run_logs.LogProcess) -> None:
        stop(self)
        cpu.append(self.cpu_s)

    run_logs.LogProcess.stop = watched  # type: ignore[method-assign]


COMPILED_PROBES = ("drivers.can_codec", "drivers.can_bus", "hil.run.rig")


def build() -> str:
    """'compiled' when the compiled build's modules are C extensions here (setup.py), else 'pure'."""
    files = [importlib.import_module(name).__file__ or "" for name in COMPILED_PROBES]
    if all(f.endswith(".so") for f in files):
        return "compiled"
    return "pure" if not any(f.endswith(".so") for f in files) else "mixed"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("scenario", nargs="?", default="speed_limiting")
    parser.add_argument("--duration", type=float, default=None)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    parser.add_argument("--devices", nargs="*", default=[], help="device profiles to measure beside pure")
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    if args.duration:
        scenario = msgspec.structs.replace(scenario, duration=args.duration)
    with tempfile.TemporaryDirectory(prefix="lockstep-bench-") as tmp:
        out = Path(tmp)
        only_us = rig_only(scenario, out)
        writers: list[float] = []
        watch_log_writers(writers)
        result, wall = timed_run(scenario, load_bench(), out / "full")
        logs_cpu = writers[-1] if writers else float("nan")
        totals: dict[str, float] = {}
        instrument(totals)
        staged, _ = timed_run(scenario, load_bench(), out / "staged")
        if staged.trace.failure is not None:
            raise SystemExit(f"staged run failed: {staged.trace.failure}")
        profiles = {}
        pure_stages = dict(totals)
        for profile in args.devices:
            totals.clear()
            other, _ = timed_run(scenario, load_bench(profile), out / profile)
            if other.trace.failure is not None:
                raise SystemExit(f"run on {profile} failed: {other.trace.failure}")
            n = other.trace.stats.ticks
            profiles[profile] = {
                "us_per_tick": other.trace.timing.wall_time / n * 1e6,
                "speed_tick_loop": other.trace.timing.speed,
                "passed": other.passed,
                "stages_us_per_tick": {name: totals.get(name, 0.0) / n * 1e6 for name in STAGES},
            }
        totals.clear()
        planar, _ = timed_run(scenario, load_bench().with_overrides(plant="planar"), out / "planar")
        if planar.trace.failure is not None:
            raise SystemExit(f"run on the planar plant failed: {planar.trace.failure}")
        n = planar.trace.stats.ticks
        on_planar = {
            "us_per_tick": planar.trace.timing.wall_time / n * 1e6,
            "speed_tick_loop": planar.trace.timing.speed,
            "passed": planar.passed,
            "stages_us_per_tick": {name: totals.get(name, 0.0) / n * 1e6 for name in STAGES},
        }
        totals.clear()
        totals.update(pure_stages)
    trace = result.trace
    if trace.failure is not None:
        raise SystemExit(f"run failed: {trace.failure}")
    ticks, sim, loop = trace.stats.ticks, float(trace.t[-1]), trace.timing
    floor = bare_floor(ticks)
    with tempfile.TemporaryDirectory(prefix="lockstep-frames-") as tmp:
        frames = frame_work(ticks, Path(tmp))
    figures = {
        "build": build(),
        "scenario": scenario.name,
        "law": result.law,
        "tick_hz": scenario.tick_hz,
        "ticks": ticks,
        "simulated_s": sim,
        "speed_tick_loop": loop.speed,
        "speed_end_to_end": sim / wall,
        "us_per_tick": loop.wall_time / ticks * 1e6,
        "staged_us_per_tick": staged.trace.timing.wall_time / staged.trace.stats.ticks * 1e6,
        "rig_only_us_per_tick": only_us,
        "floor_us_per_tick": floor / ticks * 1e6,
        "frame_work_us_per_tick": frames / ticks * 1e6,
        "logs_process_cpu_us_per_tick": logs_cpu / ticks * 1e6,
        "stages_us_per_tick": {
            name: totals.get(name, 0.0) / staged.trace.stats.ticks * 1e6 for name in STAGES
        },
        "missing_commands": trace.stats.missing_commands,
        "passed": result.passed,
        "devices": profiles,
        "plant": staged.bench["plant"],
        "planar": on_planar,
    }
    if args.json:
        print(json.dumps(figures))
        return
    print(
        f"{scenario.name} ({result.law}, lockstep, {scenario.tick_hz:g} Hz, recorder and run.mcap on, "
        f"{figures['build']} build): {sim:.2f} s simulated, {ticks} ticks, passed: {result.passed}"
    )
    print(
        f"  end to end (start-up, run, outputs): {wall:.2f} s wall = "
        f"{figures['speed_end_to_end']:.2f}x real time"
    )
    print(
        f"  tick loop only:                      {loop.wall_time:.2f} s = {loop.speed:.2f}x real time, "
        f"{figures['us_per_tick']:.0f} us/tick"
    )
    print(
        "  per-stage cost of the rig's tick (a second run, stages timed: "
        f"{figures['staged_us_per_tick']:.0f} us/tick):"
    )
    for name, label in STAGES.items():
        print(f"    {label:<40} {figures['stages_us_per_tick'][name]:8.0f} us/tick")
    print(
        f"  can.log and run.mcap in their own process: {figures['logs_process_cpu_us_per_tick']:.0f} us "
        "CPU a tick there, off the tick's thread (its start-up's imports included)"
    )
    print(
        f"  rig only (instant responder, clamped): {only_us:.0f} us/tick = "
        f"{1e6 / scenario.tick_hz / only_us:.1f}x real time"
    )
    print(
        f"  floor, bare python-can virtual send+recv of {FRAMES_PER_TICK} frames/tick: "
        f"{figures['floor_us_per_tick']:.0f} us/tick = {sim / floor:.1f}x real time at most"
    )
    print(
        f"  the frames' kept work alone (codec, E2E, every reader, recorder): "
        f"{figures['frame_work_us_per_tick']:.0f} us/tick = "
        f"{figures['frame_work_us_per_tick'] / figures['us_per_tick']:.0%} of the tick loop"
    )
    if profiles:
        print("  per device profile (same scenario, that profile's shipped bench), us/tick:")
        print(f"    {'stage':<40} {'pure':>8} " + " ".join(f"{p:>8}" for p in profiles))
        for name, label in STAGES.items():
            row = " ".join(f"{v['stages_us_per_tick'][name]:8.0f}" for v in profiles.values())
            print(f"    {label:<40} {figures['stages_us_per_tick'][name]:8.0f} {row}")
        row = " ".join(f"{v['us_per_tick']:8.0f}" for v in profiles.values())
        print(f"    {'tick loop':<40} {figures['us_per_tick']:8.0f} {row}")
        for p, v in profiles.items():
            print(f"    {p}: {v['speed_tick_loop']:.2f}x real time, passed: {v['passed']}")
    print(f"  the same scenario on the planar plant (staged, us/tick): {'3-D':>8} {'planar':>8}")
    for name in ("plant.step", "_sample"):
        print(
            f"    {STAGES[name]:<40} {figures['stages_us_per_tick'][name]:8.0f} "
            f"{on_planar['stages_us_per_tick'][name]:8.0f}"
        )
    print(
        f"    tick loop {figures['us_per_tick']:.0f} us on {figures['plant']}, "
        f"{on_planar['us_per_tick']:.0f} us on planar (planar passed: {on_planar['passed']}): 3-D / planar "
        f"{figures['us_per_tick'] / on_planar['us_per_tick']:.2f}"
    )
    print(
        f"  ratios: tick loop / rig only {figures['us_per_tick'] / only_us:.2f}, "
        f"tick loop / floor {figures['us_per_tick'] / figures['floor_us_per_tick']:.1f}, "
        f"rig only / floor {only_us / figures['floor_us_per_tick']:.1f}"
    )


if __name__ == "__main__":
    main()
