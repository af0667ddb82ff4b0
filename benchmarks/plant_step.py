"""Cost of one plant tick, the 3-D plant (MuJoCo) and the planar one (two planes + yaw, RK4) side by side,
against a bare float RK4 measured in the same run.

    python benchmarks/plant_step.py [--ticks N]

Prints microseconds per tick (p50/p99 over batches) and the ratio to the baseline: one RK4 step of a
4-state cart-pole on Python floats, the cheapest integrator step this machine can do in CPython. A plant
tick here is what the rig asks of it every tick: step, the truth, and the drives', IMU's and seat's samples.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import msgspec

from hil.run.truth_balancer import TruthBalancer
from plant.ballbot import RiderIntent
from plant.models import make_plant
from plant.params import MujocoParams, RiderParams, RobotParams, SimParams
from plant.rider import Ramp, Sine

BATCH = 200


def per_call_us(fn, calls: int) -> tuple[float, float]:
    """p50 and p99 of batch-mean cost in microseconds."""
    means = []
    for _ in range(max(calls // BATCH, 1)):
        t0 = time.perf_counter_ns()
        for _ in range(BATCH):
            fn()
        means.append((time.perf_counter_ns() - t0) / BATCH / 1e3)
    means.sort()
    return statistics.median(means), means[min(len(means) - 1, int(0.99 * len(means)))]


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


def closed_loop_tick_us(rider, sim: SimParams, intent, ticks) -> tuple[float, float]:
    """A plant's tick (step, truth, samples), timed per call, while the truth balancer keeps the robot up
    (not timed)."""
    plant = make_plant(RobotParams(), rider, sim, intent)
    bal = TruthBalancer(plant)
    costs = []
    batch = []
    for _ in range(ticks):
        bal.drive()
        t0 = time.perf_counter_ns()
        plant.step()
        plant.truth()
        plant.sample_drives()
        plant.sample_imu()
        plant.sample_tes()
        batch.append(time.perf_counter_ns() - t0)
        if len(batch) == BATCH:
            costs.append(sum(batch) / BATCH / 1e3)
            batch = []
    assert plant.fallen is None, plant.fallen
    costs.sort()
    return statistics.median(costs), costs[min(len(costs) - 1, int(0.99 * len(costs)))]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--ticks", type=int, default=20000)
    args = parser.parse_args()
    rider = RiderParams(name="ref", mass=60.0, height=1.80)
    intent = RiderIntent(
        pitch=[Ramp(to=15.0, duration=1.0), Sine(amplitude=5.0, frequency_hz=0.5, duration=1e6)]
    )

    base50, base99 = per_call_us(cartpole_rk4_step(), args.ticks)
    rows = [("baseline: cart-pole RK4 step on floats", base50, base99)]
    planar, spatial = SimParams(plant="planar"), SimParams(plant="3d")
    for label, r, sim in (
        ("planar tick, robot alone", None, planar),
        ("planar tick, robot + rider", rider, planar),
        ("planar tick, robot + rider, 2 RK4 steps", rider, msgspec.structs.replace(planar, substeps=2)),
        ("3-D tick, robot alone", None, spatial),
        ("3-D tick, robot + rider (default: 2 steps)", rider, spatial),
        ("3-D tick, robot + rider, 1 step", rider, _steps(spatial, 1)),
        ("3-D tick, robot + rider, 4 steps", rider, _steps(spatial, 4)),
    ):
        rows.append((label, *closed_loop_tick_us(r, sim, intent, args.ticks)))

    print(f"plant tick cost ({args.ticks} calls per row, batches of {BATCH}; p50 / p99 of batch means)")
    print(f"{'what':<44} {'p50 us':>8} {'p99 us':>8} {'x baseline':>11} {'x planar':>9}")
    planar50 = rows[2][1]
    for label, p50, p99 in rows:
        print(f"{label:<44} {p50:8.1f} {p99:8.1f} {p50 / base50:11.1f} {p50 / planar50:9.2f}")


def _steps(sim: SimParams, n: int) -> SimParams:
    return msgspec.structs.replace(sim, mujoco=MujocoParams(steps_per_tick=n))


if __name__ == "__main__":
    main()
