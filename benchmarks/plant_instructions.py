"""Instructions a plant tick costs, counted by valgrind's callgrind: the 3-D plant beside the planar one.

    python benchmarks/plant_instructions.py [--ticks N]

Wall-clock figures on a shared machine move by tens of percent from one run to the next; an instruction
count does not (the same build, inputs and interpreter give the same count whatever else runs). Each plant
runs twice under callgrind, for 50 ticks and for 50 + N, and the difference over N is its cost a tick: step,
truth and the three samples, as the rig asks of it, with the truth balancer driving (its cost counted in
both runs alike, so it cancels). Needs valgrind (Debian's package).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile

WARMUP = 50
KINDS = ("planar", "3d-1", "3d-2", "3d-4")
"""The planar plant, and the 3-D plant at 1, 2 (the default) and 4 MuJoCo steps a tick."""


def child(kind: str, ticks: int) -> None:
    from hil.run.truth_balancer import TruthBalancer
    from plant.ballbot import RiderIntent
    from plant.models import make_plant
    from plant.params import MujocoParams, RiderParams, RobotParams, SimParams
    from plant.rider import Hold, Ramp

    rider = RiderParams(name="ref", mass=60.0, height=1.80)
    intent = RiderIntent(pitch=[Hold(duration=0.5), Ramp(to=10.0, duration=1.0)])
    if kind == "planar":
        sim = SimParams(plant="planar")
    else:
        sim = SimParams(plant="3d", mujoco=MujocoParams(steps_per_tick=int(kind.split("-")[1])))
    plant = make_plant(RobotParams(), rider, sim, intent)
    balancer = TruthBalancer(plant)
    for _ in range(WARMUP + ticks):
        balancer.drive()
        plant.step()
        plant.truth()
        plant.sample_drives()
        plant.sample_imu()
        plant.sample_tes()


def count(kind: str, ticks: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run(
            [
                "valgrind",
                "--tool=callgrind",
                f"--callgrind-out-file={tmp}/cg.out",
                sys.executable,
                __file__,
                "--child",
                kind,
                str(ticks),
            ],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
        )
    found = re.search(r"Collected : (\d+)", out.stderr)
    if found is None:
        raise SystemExit(f"callgrind printed no count:\n{out.stderr[-2000:]}")
    return int(found.group(1))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--ticks", type=int, default=400)
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], int(args.child[1]))
        return
    per_tick = {kind: (count(kind, args.ticks) - count(kind, 0)) / args.ticks for kind in KINDS}
    print(f"instructions a plant tick (step, truth, samples; callgrind, {args.ticks} ticks, robot + rider)")
    for kind, n in per_tick.items():
        print(f"  {kind:<8} {n / 1e3:8.0f} k   x planar {n / per_tick['planar']:.2f}")


if __name__ == "__main__":
    main()
