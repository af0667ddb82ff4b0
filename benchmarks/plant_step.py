"""Cost of one plant tick, the 3-D plant (MuJoCo) and the planar one (two planes + yaw, RK4) side by side,
against a bare float RK4 measured in the same run.

    python benchmarks/plant_step.py [--ticks N] [--cpu]

Prints microseconds per tick (p50/p99 over batches) and the ratio to the baseline: one RK4 step of a
4-state cart-pole on Python floats, the cheapest integrator step this machine can do in CPython. A plant
tick here is what the rig asks of it every tick: step, the truth, and the drives', IMU's and seat's samples.
The rows take turns, a batch each, so a change in the machine's load falls on all of them alike and the
ratios within a run hold on a busy machine. --cpu times with the thread's CPU clock instead of the wall
clock: what a tick costs without the time other processes hold the core, for a machine too loaded for
wall time to say anything.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import msgspec

from hil.run.plants import make_plant
from hil.run.truth_balancer import TruthBalancer
from plant.core import RiderIntent
from plant.params import MujocoParams, RiderParams, RobotParams, SimParams
from plant.rider import Ramp, Sine

BATCH = 200
clock = time.perf_counter_ns


def batch_us(fn) -> float:
    """Mean cost of one call over a batch, microseconds."""
    t0 = clock()
    for _ in range(BATCH):
        fn()
    return (clock() - t0) / BATCH / 1e3


def cartpole_rk4_step():
    """Baseline: a 4-state nonlinear cart-pole, one RK4 step of 2.5 ms on floats."""
    state = [0.0, 0.1, 0.0, 0.0]

    def f(s):
        _, th, dx, dth = s
        st, ct = math.sin(th), math.cos(th)
        den = 1.0 + 0.1 * st * st
        ddx = (0.1 * st * (0.5 * dth * dth - 9.81 * ct)) / den
        ddth = (9.81 * st - ct * ddx) / 0.5
        return [dx, dth, ddx, ddth]

    def step():
        h = 0.0025
        s = state
        k1 = f(s)
        k2 = f([a + 0.5 * h * b for a, b in zip(s, k1, strict=True)])
        k3 = f([a + 0.5 * h * b for a, b in zip(s, k2, strict=True)])
        k4 = f([a + h * b for a, b in zip(s, k3, strict=True)])
        state[:] = [
            a + h / 6 * (p + 2 * (q + r) + w) for a, p, q, r, w in zip(s, k1, k2, k3, k4, strict=True)
        ]

    return step


class ClosedLoop:
    """A plant's tick (step, truth, samples), timed per call, while the truth balancer keeps the robot up
    (not timed)."""

    def __init__(self, rider, sim: SimParams, intent):
        self.plant = make_plant(RobotParams(), rider, sim, intent)
        self.balancer = TruthBalancer(self.plant)

    def batch_us(self) -> float:
        plant, total = self.plant, 0
        for _ in range(BATCH):
            self.balancer.drive()
            t0 = clock()
            plant.step()
            plant.truth()
            plant.sample_drives()
            plant.sample_imu()
            plant.sample_tes()
            total += clock() - t0
        assert plant.fallen is None, plant.fallen
        return total / BATCH / 1e3


def p50_p99(means: list[float]) -> tuple[float, float]:
    means = sorted(means)
    return statistics.median(means), means[min(len(means) - 1, int(0.99 * len(means)))]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--ticks", type=int, default=20000)
    parser.add_argument("--cpu", action="store_true", help="time with the thread's CPU clock")
    args = parser.parse_args()
    if args.cpu:
        global clock
        clock = time.thread_time_ns
    rider = RiderParams(name="ref", mass=60.0, height=1.80)
    intent = RiderIntent(
        pitch=[Ramp(to=15.0, duration=1.0), Sine(amplitude=5.0, frequency_hz=0.5, duration=1e6)]
    )

    planar, spatial = SimParams(plant="planar"), SimParams(plant="3d")
    cases = (
        ("planar tick, robot alone", None, planar),
        ("planar tick, robot + rider", rider, planar),
        ("planar tick, robot + rider, 2 RK4 steps", rider, msgspec.structs.replace(planar, substeps=2)),
        ("3-D tick, robot alone", None, spatial),
        ("3-D tick, robot + rider (default: 2 steps)", rider, spatial),
        ("3-D tick, robot + rider, 1 step", rider, _steps(spatial, 1)),
        ("3-D tick, robot + rider, 4 steps", rider, _steps(spatial, 4)),
    )
    baseline = cartpole_rk4_step()
    loops = [ClosedLoop(r, sim, intent) for _, r, sim in cases]
    means: list[list[float]] = [[] for _ in range(len(loops) + 1)]
    for _ in range(max(args.ticks // BATCH, 1)):
        means[0].append(batch_us(baseline))
        for i, loop in enumerate(loops):
            means[i + 1].append(loop.batch_us())
    labels = ["baseline: cart-pole RK4 step on floats", *(label for label, _, _ in cases)]
    rows = [(label, *p50_p99(m)) for label, m in zip(labels, means, strict=True)]
    base50 = rows[0][1]

    print(
        f"plant tick cost ({args.ticks} calls per row, batches of {BATCH}; p50 / p99 of batch means; "
        f"{'thread CPU time' if args.cpu else 'wall time'})"
    )
    print(f"{'what':<44} {'p50 us':>8} {'p99 us':>8} {'x baseline':>11} {'x planar':>9}")
    planar50 = rows[2][1]
    for label, p50, p99 in rows:
        print(f"{label:<44} {p50:8.1f} {p99:8.1f} {p50 / base50:11.1f} {p50 / planar50:9.2f}")


def _steps(sim: SimParams, n: int) -> SimParams:
    return msgspec.structs.replace(sim, mujoco=MujocoParams(steps_per_tick=n))


if __name__ == "__main__":
    main()
