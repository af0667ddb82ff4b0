"""Cost of one plant tick (both planes + yaw, drives, RK4), against a bare float RK4 measured in the same run.

    python benchmarks/plant_step.py [--ticks N]

Prints microseconds per tick (p50/p99 over batches) and the ratio to the baseline: one RK4 step of a
4-state cart-pole on Python floats, the cheapest integrator step this machine can do in CPython.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hil.run.truth_balancer import TruthBalancer
from plant.ballbot import Plant, RiderIntent
from plant.params import RiderParams, RobotParams, SimParams
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


def closed_loop_step_us(rider, substeps, intent, ticks) -> tuple[float, float]:
    """Plant.step() alone, timed per call, while the truth balancer keeps the robot up (not timed)."""
    plant = Plant(RobotParams(), rider, SimParams(substeps=substeps), intent)
    bal = TruthBalancer(plant)
    costs = []
    batch = []
    for _ in range(ticks):
        bal.drive()
        t0 = time.perf_counter_ns()
        plant.step()
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
    for label, r, substeps in (
        ("plant tick, robot alone", None, 1),
        ("plant tick, robot + rider", rider, 1),
        ("plant tick, robot + rider, 2 substeps", rider, 2),
    ):
        rows.append((label, *closed_loop_step_us(r, substeps, intent, args.ticks)))
    plant = Plant(RobotParams(), rider, SimParams(), intent)
    sensors = (
        ("sample: 3 drive feedbacks", plant.sample_drives),
        ("sample: IMU", plant.sample_imu),
        ("sample: TES (6 cells, calibration, COP)", plant.sample_tes),
    )
    for label, fn in sensors:
        rows.append((label, *per_call_us(fn, args.ticks)))

    print(f"plant step cost ({args.ticks} calls per row, batches of {BATCH}; p50 / p99 of batch means)")
    print(f"{'what':<42} {'p50 us':>8} {'p99 us':>8} {'x baseline':>11} {'x real time @400 Hz':>20}")
    for label, p50, p99 in rows:
        print(f"{label:<42} {p50:8.1f} {p99:8.1f} {p50 / base50:11.1f} {2500.0 / p50:20.1f}")


if __name__ == "__main__":
    main()
