"""The supervisor's cost per tick and its reaction latency on the bus.

1. Decision cost: the pure state machine (`Supervisor.update`), and the whole per-tick work without I/O
   (one tick of trusted frames into the monitors + observe + update), against the plant's own tick
   measured in the same run (the rig's budget is 2500 µs per tick at 400 Hz).
2. Reaction latency in real time: the standalone supervisor on its own 400 Hz timer (as `pure-hil
   supervisor` runs it) beside a stand-in robot sending healthy traffic at 400 Hz on a virtual bus; a
   CONTROLLER_HEARTBEAT reporting FAULT is sent at a random moment and the time until SUPERVISOR_ESTOP
   with Estop=1 is received is measured; then the heartbeat recovers, the operator resets, and again.
   Baseline in the same run: a bare frame round trip through a thread that echoes it.

    python benchmarks/supervisor.py [--ticks N] [--trips N]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import random
import statistics
import threading
import time

import can
import numpy as np

from drivers.can_bus import BusConfig, CanNode, open_bus, private_channel
from drivers.config import load_toml
from drivers.schemas import EstopCommand, TesWrench
from drivers.zenoh_link import ZenohLink, open_session
from hil.scenario import ROOT
from plant.ballbot import Plant
from plant.params import RiderParams, RobotParams, SimParams
from safety.config import RobotGeometry, SupervisorConfig
from safety.machine import BALANCING, FAULT, STREAMS, Observation, Request, Supervisor
from safety.monitors import Monitors

ROBOT = ROOT / "configs/robot/pure.toml"


def us_per_call(fn, n: int) -> float:
    best = []
    for _ in range(5):
        t0 = time.perf_counter_ns()
        for i in range(n):
            fn(i)
        best.append((time.perf_counter_ns() - t0) / n / 1e3)
    return min(best)


def decision_cost(ticks: int) -> None:
    robot = load_toml(ROBOT, RobotParams)
    plant = Plant(robot, load_toml(ROOT / "configs/riders/ref_60kg_180.toml", RiderParams), SimParams())
    machine = Supervisor(SupervisorConfig(), robot.drive.torque_limit)
    ages = dict.fromkeys(STREAMS, 0.0)
    request = Request("limit", 0.5, "agent")

    def update(i):
        machine.update(
            Observation(
                t=i / 400,
                speed=0.3,
                tilt=0.01,
                ages=ages,
                controller_state=BALANCING,
                torque_peak=0.5,
                seat_load=600.0,
                request=request,
            )
        )

    tx, rx = CanNode(None, name="tx"), CanNode(None, name="rx")  # encode/decode only, no bus
    frames = []
    for i in (1, 2, 3):
        frames.append(
            rx.decode(tx.message(f"DRIVE{i}_FEEDBACK", {"Position": 0, "Velocity": 1.0, "Enabled": 1}))
        )
    frames.append(rx.decode(tx.message("IMU_ATTITUDE", {"Roll": 0.0, "Pitch": 0.01, "Yaw": 0.0, "Valid": 1})))
    frames.append(rx.decode(tx.message("IMU_RATE", {"RateX": 0.0, "RateY": 0.01, "RateZ": 0.0, "Valid": 1})))
    for i in (1, 2, 3):
        frames.append(rx.decode(tx.message(f"DRIVE{i}_COMMAND", {"Torque": 0.5, "Tick": 1, "Enable": 1})))
    frames.append(rx.decode(tx.message("CONTROLLER_HEARTBEAT", {"State": BALANCING, "Mode": 0})))
    monitors = Monitors(SupervisorConfig(), load_toml(ROBOT, RobotGeometry))
    machine2 = Supervisor(SupervisorConfig(), robot.drive.torque_limit)

    def tick(i):
        t = i / 400
        for f in frames:
            monitors.frame(f, t)
        machine2.update(monitors.observe(t))

    plant_us = us_per_call(lambda i: plant.step(), ticks)
    update_us = us_per_call(update, ticks)
    tick_us = us_per_call(tick, ticks)
    print("decision cost per tick (best of 5 batches)")
    print(f"  state machine update         {update_us:8.1f} µs")
    print(f"  frames -> monitors -> update {tick_us:8.1f} µs  ({len(frames)} frames)")
    print(
        f"  plant step (baseline)        {plant_us:8.1f} µs  -> supervisor/plant = {tick_us / plant_us:.2f}"
    )
    print(f"  share of the 2500 µs tick    {100 * tick_us / 2500:8.1f} %")


def reaction_latency(trips: int) -> None:
    from safety.node import SupervisorNode, SupervisorThread

    config = BusConfig(channel=private_channel("bench"))
    endpoint = "tcp/127.0.0.1:7463"
    session = open_session(role="hub", hub_endpoint=endpoint)
    link = ZenohLink(session)
    sup_bus = open_bus(config)
    node = SupervisorNode(CanNode(sup_bus, name="supervisor"), link)
    thread = SupervisorThread(node).start()
    bus = open_bus(config)
    robot = CanNode(bus, name="robot")
    state = {"heartbeat": BALANCING, "tripped_at": None}
    latencies: list[float] = []
    done = threading.Event()
    lock = threading.Lock()

    def feeder():
        tick = 0
        while not done.is_set():
            tick += 1
            for i in (1, 2, 3):
                robot.send(f"DRIVE{i}_FEEDBACK", {"Position": 0, "Velocity": 0.0, "Enabled": 1})
            robot.send("IMU_ATTITUDE", {"Roll": 0.0, "Pitch": 0.0, "Yaw": 0.0, "Valid": 1})
            robot.send("IMU_RATE", {"RateX": 0.0, "RateY": 0.0, "RateZ": 0.0, "Valid": 1})
            with lock:
                hb = state["heartbeat"]
                if hb == FAULT and state["tripped_at"] is None:
                    state["tripped_at"] = time.perf_counter()
            robot.send("CONTROLLER_HEARTBEAT", {"State": hb, "Mode": 0})
            robot.send("SYNC", {"Tick": tick % 65536})
            link.put(
                link.keys.tes_wrench,
                TesWrench(
                    seq=tick,
                    stamp=tick / 400,
                    force=(0.0, 0.0, -600.0),
                    moment=(0.0, 0.0, 0.0),
                    cop=(0.0, 0.0),
                ),
            )
            deadline = time.perf_counter() + 0.0025
            while (remaining := deadline - time.perf_counter()) > 0:
                rx = robot.recv(timeout=remaining)
                if rx is not None and rx.name == "SUPERVISOR_ESTOP" and rx.signals["Estop"]:
                    with lock:
                        if state["tripped_at"] is not None and state["heartbeat"] == FAULT:
                            latencies.append(time.perf_counter() - state["tripped_at"])
                            state["heartbeat"] = BALANCING

    t = threading.Thread(target=feeder, daemon=True)
    t.start()
    time.sleep(1.0)  # past the start-up grace
    for n in range(trips):
        time.sleep(random.uniform(0.05, 0.15))
        with lock:
            state["heartbeat"], state["tripped_at"] = FAULT, None
        while True:
            with lock:
                if state["heartbeat"] == BALANCING:
                    break
            time.sleep(0.001)
        time.sleep(0.1)
        link.put(
            link.keys.safety_estop, EstopCommand(seq=n + 1, stamp=time.time(), action="reset", source="bench")
        )
        deadline = time.monotonic() + 2.0
        while node.machine.state.name != "NORMAL" and time.monotonic() < deadline:
            time.sleep(0.005)
    done.set()
    t.join(2)

    # Baseline: a frame's round trip through an echoing thread on the same kind of bus.
    a, b = open_bus(config), open_bus(config)
    echo_stop = threading.Event()

    def echo():
        while not echo_stop.is_set():
            m = b.recv(0.05)
            if m is not None and m.arbitration_id == 0x7FF:
                b.send(can.Message(arbitration_id=0x7FE, is_extended_id=False, data=m.data))

    et = threading.Thread(target=echo, daemon=True)
    et.start()
    rtt = []
    for _ in range(200):
        t0 = time.perf_counter()
        a.send(can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b"\x00"))
        while True:
            m = a.recv(1.0)
            if m is None or m.arbitration_id == 0x7FE:
                break
        rtt.append(time.perf_counter() - t0)
    echo_stop.set()
    et.join(1)
    thread.stop()
    for x in (a, b, bus, sup_bus):
        x.shutdown()
    link.close()
    session.close()

    ms = np.array(latencies) * 1e3
    base = np.array(rtt) * 1e3
    print(
        f"reaction latency, real time ({len(ms)} trips): "
        "FAULT heartbeat on the bus -> SUPERVISOR_ESTOP Estop=1"
    )
    print(
        f"  p50 {np.percentile(ms, 50):6.2f} ms   p99 {np.percentile(ms, 99):6.2f} ms   "
        f"max {ms.max():6.2f} ms"
    )
    print(f"  timer period {1e3 / node.config.output.rate_hz:.2f} ms (expected ≈ half of it plus the bus)")
    print(
        f"  baseline: bare echo round trip p50 {statistics.median(base):.3f} ms, "
        f"p99 {np.percentile(base, 99):.3f} ms"
        f" -> reaction/echo p50 = {np.percentile(ms, 50) / statistics.median(base):.1f}x"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--ticks", type=int, default=20000)
    parser.add_argument("--trips", type=int, default=50)
    args = parser.parse_args()
    decision_cost(args.ticks)
    reaction_latency(args.trips)


if __name__ == "__main__":
    main()
