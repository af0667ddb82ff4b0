"""`pure-hil simulate`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse
import time

import msgspec

from drivers.config import load_toml
from drivers.resources import find
from hil.commands.common import DURATION, SEED


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", default="pure", help="robot file or shipped name")
    parser.add_argument("--rider", default="ref_60kg_180", help="rider file or shipped name")
    parser.add_argument("--no-rider", action="store_true", help="robot alone")
    parser.add_argument("--sim", default="default", help="simulation settings file or shipped name")
    parser.add_argument(
        "--duration", type=DURATION, default=10.0, help="simulated seconds (> 0, at most one day)"
    )
    parser.add_argument("--lean", type=float, default=15.0, help="forward torso lean the rider holds, deg")
    parser.add_argument("--tilt", type=float, default=3.0, help="initial chassis tilt, deg")
    parser.add_argument("--seed", type=SEED, default=None, help="the noise seed (>= 0)")


def handle(args: argparse.Namespace) -> int:
    from hil.run.plant_run import default_intent, format_summary, run_plant
    from hil.run.plants import load_sim
    from plant.params import RiderParams, RobotParams

    robot = load_toml(find(args.robot, "robot"), RobotParams)
    rider = None if args.no_rider else load_toml(find(args.rider, "riders"), RiderParams)
    sim = load_sim(find(args.sim, "sim"))
    if args.seed is not None:
        sim = msgspec.structs.replace(sim, seed=args.seed)
    started = time.perf_counter()
    summary = run_plant(robot, rider, sim, default_intent(args.lean, args.duration), args.duration, args.tilt)
    wall = time.perf_counter() - started
    print(
        f"pure-hil simulate: plant-only run of {robot.name} on the ideal truth balancer, "
        f"rider leaning {args.lean:g} deg"
    )
    print(format_summary(summary))
    print(f"  {'wall time':<24}  {wall:.2f} s ({summary.sim_time / wall:.1f}x real time)")
    return 1 if summary.fallen else 0
