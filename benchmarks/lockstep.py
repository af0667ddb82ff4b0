"""Lockstep speed of a scenario end to end (plant, CAN frames, zenoh, controller), with the per-stage cost
of the rig's tick and, measured in the same run, the floor: bare python-can virtual send+recv of the same
number of frames per tick.

    python benchmarks/lockstep.py [SCENARIO (default speed_limiting)] [--duration S]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import can
import msgspec

import hil.run.rig as rig_module
from drivers.can_bus import private_channel
from hil.run.pipeline import load_scenario, run
from plant.ballbot import Plant
from safety.node import SupervisorNode

FRAMES_PER_TICK = 12  # 3 feedback, 3 IMU, SYNC, 3 commands, heartbeat, + (DRIVEn_TORQUE, estop) / 4


def timed(totals: dict[str, float], name: str, fn):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            totals[name] = totals.get(name, 0.0) + time.perf_counter() - t0

    return wrapper


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


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("scenario", nargs="?", default="speed_limiting")
    parser.add_argument("--duration", type=float, default=None)
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    if args.duration:
        scenario = msgspec.structs.replace(scenario, duration=args.duration)
    totals: dict[str, float] = {}
    rig = rig_module.Rig
    for name in ("_send_sensors", "_publish_tes", "_publish_sc_request", "_collect_commands"):
        setattr(rig, name, timed(totals, name, getattr(rig, name)))
    Plant.step = timed(totals, "plant.step", Plant.step)
    SupervisorNode.update = timed(totals, "supervisor", SupervisorNode.update)
    t0 = time.perf_counter()
    result = run(scenario)
    wall = time.perf_counter() - t0
    ticks = result.trace.stats.ticks
    sim = result.trace.t[-1]
    floor = bare_floor(ticks)
    print(
        f"{scenario.name} ({result.law}, lockstep, {scenario.tick_hz:g} Hz): {sim:.2f} s simulated, "
        f"{ticks} ticks"
    )
    print(f"  end to end incl. start-up: {wall:.2f} s wall = {sim / wall:.2f}x real time")
    loop = result.trace.timing
    print(
        f"  tick loop only:            {loop.wall_time:.2f} s = {loop.speed:.2f}x real time, "
        f"{loop.wall_time / ticks * 1e3:.2f} ms/tick"
    )
    print("  per-stage cost of the rig's tick (wall, includes waiting on the other threads):")
    labels = {
        "plant.step": "plant step (RK4, rider)",
        "_send_sensors": "sample + 7 frames out",
        "_publish_tes": "seat wrench -> zenoh",
        "_publish_sc_request": "SC request -> zenoh",
        "_collect_commands": "wait for the controller's answer",
        "supervisor": "supervisor (frames, decide, emit)",
    }
    for name, label in labels.items():
        print(f"    {label:<34} {totals.get(name, 0.0) / ticks * 1e6:8.0f} us/tick")
    print(
        f"  floor, bare python-can virtual send+recv of {FRAMES_PER_TICK} frames/tick: "
        f"{floor / ticks * 1e6:.0f} us/tick = {sim / floor:.1f}x real time at most"
    )
    print(f"  ratio tick loop / floor: {result.trace.timing.wall_time / floor:.1f}")


if __name__ == "__main__":
    main()
