"""What faults cost, and what parallel workers buy a campaign.

1. Tick cost (best of three interleaved rounds): the rig's tick with no controller (sensors sampled,
   frames sent, seat published, no wait) with no faults, then with one active fault of each family that
   touches every tick (a sensor, a CAN frame, a zenoh topic fault) and with all three; µs per tick and
   the ratio to the fault-free tick measured in the same run.
2. Campaign: `configs/campaigns/smoke.toml` (or --campaign FILE) run on 1 and on N worker processes; wall
   time per case and the speed-up (cases are independent lockstep runs; workers are spawned processes).

    python benchmarks/faults.py [--ticks N] [--workers N] [--no-campaign]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import logging
import time

from drivers.bus_config import BusConfig
from drivers.can_bus import CanNode, open_bus, private_channel
from drivers.config import load_toml
from drivers.keys import Keys
from drivers.resources import find
from drivers.zenoh_link import LOOPBACK, ZenohLink, free_loopback_endpoint, open_session
from hil.faults import FaultSet, parse_fault
from hil.run.drives_port import DrivesPort
from hil.run.rig import Rig, RigParts
from hil.suites.campaign import expand, load_campaign, run_campaign
from plant.ballbot import Plant
from plant.params import RiderParams, RobotParams, SimParams

FAULTS = {
    "none": [],
    "sensor": [{"kind": "sensor.noise", "channel": "imu.pitch", "sigma": 0.01}],
    "frame": [{"kind": "can.corrupt", "message": "IMU_RATE"}],
    "topic": [{"kind": "zenoh.wrench_frozen"}],
}
FAULTS["all three"] = FAULTS["sensor"] + FAULTS["frame"] + FAULTS["topic"]


def tick_cost(session, faults, ticks: int) -> float:
    robot = load_toml(find("pure", "robot"), RobotParams)
    rider = load_toml(find("ref_60kg_180", "riders"), RiderParams)
    plant = Plant(robot, rider, SimParams(seed=0))
    bus = open_bus(BusConfig(channel=private_channel()))
    link = ZenohLink(session, Keys(private_channel("bench").replace("-", "")))
    port = DrivesPort(plant, CanNode(bus, name="rig"))
    rig = Rig(RigParts(port, link, faults=FaultSet([parse_fault(f) for f in faults])))
    rig.faults.attach(rig)
    try:
        for _ in range(50):
            rig.tick(deadline=0.0, lockstep=False)
        start = time.perf_counter()
        for _ in range(ticks):
            rig.tick(deadline=0.0, lockstep=False)
        return (time.perf_counter() - start) / ticks * 1e6
    finally:
        link.close()
        bus.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--ticks", type=int, default=2000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--campaign", default="smoke")
    parser.add_argument("--no-campaign", action="store_true")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)

    session = open_session(LOOPBACK, "hub", free_loopback_endpoint())
    costs = dict.fromkeys(FAULTS, float("inf"))
    try:
        for _ in range(3):  # interleaved rounds, best of three: this machine is shared and noisy
            for name, faults in FAULTS.items():
                costs[name] = min(costs[name], tick_cost(session, faults, args.ticks))
    finally:
        session.close()
    print(f"rig tick without a controller ({args.ticks} ticks, best of 3 rounds), µs per tick:")
    for name, us in costs.items():
        print(f"  {name:10s} {us:8.1f} µs   x{us / costs['none']:.2f} of the fault-free tick")

    if args.no_campaign:
        return
    cases = expand(load_campaign(args.campaign))
    walls = {}
    for workers in (1, args.workers):
        start = time.monotonic()
        results = run_campaign(cases, workers)
        walls[workers] = time.monotonic() - start
        passed = sum(r.passed for r in results)
        print(
            f"campaign {len(cases)} cases on {workers} worker(s): {walls[workers]:.1f} s wall, "
            f"{walls[workers] / len(cases):.1f} s per case, {passed}/{len(cases)} passed"
        )
    print(
        f"speed-up with {args.workers} workers: x{walls[1] / walls[args.workers]:.2f} "
        f"(cpus: {os.cpu_count()})"
    )


if __name__ == "__main__":
    main()
