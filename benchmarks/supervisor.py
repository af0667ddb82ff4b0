"""The supervisor's cost per tick and its reaction latency on the bus.

1. Decision cost: the whole per-tick work without I/O, by stage (a moving robot's frames into the
   monitors with their per-frame checks; observe with the cross-checks and the isolated estimate the
   recovery law would balance on; the state machine; the recovery law's torques as during a takeover),
   against the plant's own tick measured in the same run (the rig's budget is 2500 µs per tick at 400 Hz).
2. Reaction latency in real time: the standalone supervisor on its own 400 Hz timer (as `pure-hil
   supervisor` runs it) beside a stand-in robot sending healthy traffic at 400 Hz on a virtual bus; a
   CONTROLLER_HEARTBEAT reporting FAULT is sent at a random moment and the time until SUPERVISOR_ESTOP
   with Takeover=1 (the recovery law holds the drives) or Estop=1 is received is measured; then the
   heartbeat recovers, the operator resets, and again.
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

from drivers.bus_config import BusConfig
from drivers.can_bus import CanNode, open_bus, private_channel
from drivers.config import load_toml
from drivers.resources import find
from drivers.robot import RobotModel
from drivers.schemas import EstopCommand, TesWrench
from drivers.vocabulary import ControllerState
from drivers.zenoh_link import ZenohLink, free_loopback_endpoint, open_session
from hil.run.truth_balancer import TruthBalancer
from plant.ballbot import Plant
from plant.core import RiderIntent
from plant.params import RiderParams, RobotParams, SimParams
from plant.rider import Ramp
from safety.config import SupervisorConfig
from safety.machine import SafetyMachine
from safety.monitors import Monitors
from safety.recovery import RecoveryLaw

ROBOT = find("pure", "robot")


def us_per_call(fn, n: int) -> float:
    best = []
    for _ in range(5):
        t0 = time.perf_counter_ns()
        for i in range(n):
            fn(i)
        best.append((time.perf_counter_ns() - t0) / n / 1e3)
    return min(best)


def recorded_ticks(n: int) -> list[tuple[list, TesWrench]]:
    """n ticks of the frames and seat sample a moving robot sends (the plant driven by the truth balancer
    through a lean and a turn), decoded as the supervisor receives them: the checks do their real work."""
    robot = load_toml(ROBOT, RobotParams)
    rider = load_toml(find("ref_60kg_180", "riders"), RiderParams)
    intent = RiderIntent(pitch=[Ramp(to=8.0, duration=1.0)])
    plant = Plant(robot, rider, SimParams(), intent)
    balancer = TruthBalancer(plant)
    tx, rx = CanNode(None, name="tx"), CanNode(None, name="rx")  # encode/decode only, no bus
    out = []
    for k in range(1, n + 1):
        balancer.set_velocity(0.6 * min(k / 400, 1.0))
        balancer.yaw_rate_command = 0.3
        torques = balancer.command()
        plant.drives.set_commands(torques, True, plant.t)
        plant.step()
        fb, imu, tes = plant.sample_drives(), plant.sample_imu(), plant.sample_tes()
        msgs = [
            (
                f"DRIVE{i}_FEEDBACK",
                {"Position": f.counts, "Velocity": f.velocity, "Enabled": 1, "BusPowered": 1},
            )
            for i, f in enumerate(fb, 1)
        ]
        if k % 4 == 0:
            msgs += [(f"DRIVE{i}_TORQUE", {"Torque": f.torque}) for i, f in enumerate(fb, 1)]
        att, rate, acc = imu.attitude, imu.rate, imu.accel
        msgs += [
            ("IMU_ATTITUDE", {"Roll": att[0], "Pitch": att[1], "Yaw": att[2], "Valid": 1}),
            ("IMU_RATE", {"RateX": rate[0], "RateY": rate[1], "RateZ": rate[2], "Valid": 1}),
            ("IMU_ACCEL", {"AccX": acc[0], "AccY": acc[1], "AccZ": acc[2], "Valid": 1}),
        ]
        msgs += [
            (f"DRIVE{i}_COMMAND", {"Torque": q, "Tick": k, "Enable": 1}) for i, q in enumerate(torques, 1)
        ]
        msgs.append(("CONTROLLER_HEARTBEAT", {"State": ControllerState.BALANCING, "Mode": 0}))
        frames = [rx.decode(tx.message(name, values)) for name, values in msgs]
        seat = TesWrench(seq=k, stamp=plant.t, force=tes.force, moment=tes.moment, cop=tes.cop)
        out.append((frames, seat))
    return out


def decision_cost(ticks: int) -> None:
    robot = load_toml(ROBOT, RobotParams)
    plant = Plant(robot, load_toml(find("ref_60kg_180", "riders"), RiderParams), SimParams())
    recorded = recorded_ticks(ticks)
    config, geometry = SupervisorConfig(), load_toml(ROBOT, RobotModel)
    stages = {"frames": 0.0, "observe": 0.0, "update": 0.0, "recovery": 0.0}
    law = RecoveryLaw(geometry, config.recovery)
    best = dict.fromkeys(stages, float("inf"))
    for _ in range(5):
        monitors, machine = Monitors(config, geometry), SafetyMachine(config, robot.drive.torque_limit)
        for stage in stages:
            stages[stage] = 0.0
        for k, (frames, seat) in enumerate(recorded, 1):
            t = k / 400
            t0 = time.perf_counter_ns()
            for f in frames:
                monitors.frame(f, t)
            monitors.wrench(seat, t)
            t1 = time.perf_counter_ns()
            obs = monitors.observe(t)
            t2 = time.perf_counter_ns()
            machine.update(obs)
            t3 = time.perf_counter_ns()
            law.torques(monitors.isolated)
            t4 = time.perf_counter_ns()
            stages["frames"] += t1 - t0
            stages["observe"] += t2 - t1
            stages["update"] += t3 - t2
            stages["recovery"] += t4 - t3
        for stage, ns in stages.items():
            best[stage] = min(best[stage], ns / len(recorded) / 1e3)
        assert machine.state.name == "NORMAL", f"the healthy recording tripped it: {machine.events[-1]}"
    plant_us = us_per_call(lambda i: plant.step(), ticks)
    total = sum(best.values())
    frames = sum(len(f) for f, _ in recorded) / len(recorded)
    print(f"decision cost per tick, a moving robot's {frames:.0f} frames + seat sample (best of 5 runs)")
    print(f"  frames -> monitors (per-frame checks)  {best['frames']:7.1f} µs")
    print(f"  observe (cross-checks, isolation, ...) {best['observe']:7.1f} µs")
    print(f"  state machine update                   {best['update']:7.1f} µs")
    print(f"  recovery law (only during a takeover)  {best['recovery']:7.1f} µs")
    print(f"  supervisor total                       {total:7.1f} µs")
    print(
        f"  plant step (baseline, same run)        {plant_us:7.1f} µs"
        f"  -> supervisor/plant = {total / plant_us:.2f}"
    )
    print(f"  share of the 2500 µs tick              {100 * total / 2500:7.1f} %")


def reaction_latency(trips: int) -> None:
    from drivers.plugs import NodeThread
    from safety.node import SupervisorNode

    config = BusConfig(channel=private_channel("bench"))
    endpoint = free_loopback_endpoint()
    session = open_session(role="hub", hub_endpoint=endpoint)
    link = ZenohLink(session)
    sup_bus = open_bus(config)
    node = SupervisorNode(CanNode(sup_bus, name="supervisor"), link)
    thread = NodeThread(node.run, "supervisor").start()
    bus = open_bus(config)
    robot = CanNode(bus, name="robot")
    state = {"heartbeat": ControllerState.BALANCING, "tripped_at": None, "permitted": True, "bus": True}
    latencies: list[float] = []
    done = threading.Event()
    lock = threading.Lock()

    def feeder():
        tick = 0
        while not done.is_set():
            tick += 1
            # The drives obey the supervisor's frame: off under e-stop, their bus live while the contactor is.
            feedback = {
                "Position": 0,
                "Velocity": 0.0,
                "Enabled": int(state["permitted"]),
                "BusPowered": int(state["bus"]),
            }
            for i in (1, 2, 3):
                robot.send(f"DRIVE{i}_FEEDBACK", feedback)
            robot.send("IMU_ATTITUDE", {"Roll": 0.0, "Pitch": 0.0, "Yaw": 0.0, "Valid": 1})
            robot.send("IMU_RATE", {"RateX": 0.0, "RateY": 0.0, "RateZ": 0.0, "Valid": 1})
            with lock:
                hb = state["heartbeat"]
                if hb == ControllerState.FAULT and state["tripped_at"] is None:
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
                if rx is not None and rx.name == "SUPERVISOR_ESTOP":
                    state["permitted"], state["bus"] = not rx.signals["Estop"], bool(rx.signals["Contactor"])
                # The reaction: the recovery law takes the drives (Takeover) or they lose their permission.
                reacted = rx is not None and rx.name == "SUPERVISOR_ESTOP"
                if reacted and (rx.signals["Estop"] or rx.signals["Takeover"]):
                    with lock:
                        if state["tripped_at"] is not None and state["heartbeat"] == ControllerState.FAULT:
                            latencies.append(time.perf_counter() - state["tripped_at"])
                            state["heartbeat"] = ControllerState.BALANCING

    t = threading.Thread(target=feeder, daemon=True)
    t.start()
    time.sleep(1.0)  # past the start-up grace
    for n in range(trips):
        time.sleep(random.uniform(0.05, 0.15))
        with lock:
            state["heartbeat"], state["tripped_at"] = ControllerState.FAULT, None
        while True:
            with lock:
                if state["heartbeat"] == ControllerState.BALANCING:
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
        "FAULT heartbeat on the bus -> SUPERVISOR_ESTOP Takeover=1 or Estop=1"
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
