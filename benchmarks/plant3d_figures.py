"""The 3-D plant's validation figures, side by side with the planar plant and with the analytic results
(docs/physics.md §11.5 shows them; tests/test_plant3d.py holds the plant to them).

    python benchmarks/plant3d_figures.py

Not timings: every figure is a property of the models, the same on every machine and build.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checks are tests/test_plant3d.py's

import numpy as np
from scipy.optimize import brentq

from plant.ballbot import Plant
from plant.params import MujocoParams
from tests import test_plant3d as checks
from tests.helpers import NO_FRICTION, RIDER_75, deg, robot, sim


def main() -> None:
    print("linearised poles at upright, yaw held (1/s): planar | 3-D | difference")
    for label, rider in (("robot alone", None), ("robot + 75 kg rider", RIDER_75)):
        planar, spatial = checks.planar_poles(rider), checks.poles_3d(rider)
        for a, b in zip(planar, spatial, strict=True):
            print(
                f"  {label:<22} {a.real:8.3f}{a.imag:+7.3f}j | {b.real:8.3f}{b.imag:+7.3f}j | "
                f"{abs(b - a) / abs(a):6.2%}"
            )
    planar, spatial = checks.planar_poles(RIDER_75), checks.poles_3d(RIDER_75, hold=False)
    print(
        "yaw left free (no drivetrain friction, no hold), with the rider: the 3-D tilt poles "
        + ", ".join(f"{z.real:.3f}{z.imag:+.3f}j" for z in spatial if z.real > 0)
        + " (the rider's legs ahead of the ball couple roll and yaw; the planar split has "
        + ", ".join(f"{z.real:.3f}" for z in planar if z.real > 0)
        + ")"
    )
    print("tilt step of 2 deg under the truth balancer, 2 s: largest difference planar - 3-D")
    for plane in ("pitch", "roll"):
        planar = checks.balanced_step(lambda t: Plant(robot(), RIDER_75, sim(), initial_tilt=t), plane)
        spatial = checks.balanced_step(lambda t: checks.plant3d(tilt=t), plane)
        worst = np.abs(spatial - planar).max()
        print(f"  {plane:<6} {math.degrees(worst):.4f} deg = {worst / deg(2.0):.2%} of the step")

    print(
        "steady turn at 1.0 m/s and 0.8 rad/s (lean into the turn, deg): 3-D | Newton-Euler | atan(v psi'/g)"
    )
    for label, rider in (("robot alone", None), ("robot + rider", RIDER_75)):
        plant, (roll, pitch, v, r), _ = checks.steady_turn(rider, 1.0, 0.8)
        predicted = brentq(
            lambda phi, p=plant, th=pitch, sp=v, w=r: checks.roll_moment(p, phi, th, sp, w), -0.5, 0.5
        )
        naive = math.atan(v * r / checks.G0)
        print(
            f"  {label:<14} {-math.degrees(roll):6.3f} | {-math.degrees(predicted):6.3f} | "
            f"{math.degrees(naive):6.3f}"
            f"   (3-D / naive {-roll / naive:.2f})"
        )
        _, gyro, _ = plant.imu_truth()
        print(
            f"    gyro y {gyro[1]:+.4f} rad/s against psi' sin(roll) cos(pitch) "
            f"{r * math.sin(roll) * math.cos(pitch):+.4f} (a planar plant's gyro y reads its pitch rate, 0)"
        )

    plant = checks.ride(checks.plant3d(intent=checks.MANOEUVRE))
    print(f"rolling, 1.2 m/s, 0.8 rad/s, leaning: largest contact slip {plant.max_slip * 1e3:.3f} mm/s")
    plant = checks.ride(
        checks.plant3d(
            robot(ball=checks.msgspec.structs.replace(checks.RobotParams().ball, floor_friction=0.03)),
            intent=checks.MANOEUVRE,
        ),
        seconds=2.0,
    )
    print(f"  on a floor with mu = 0.03: {plant.slip_ticks} ticks slipping, up to {plant.max_slip:.2f} m/s")
    print(
        "steps a tick, on the rolling manoeuvre above: largest error against 20 steps, relative to the range"
    )
    reference = manoeuvre(20)
    for steps in (1, 2, 4):
        err = np.abs(manoeuvre(steps) - reference).max(axis=0) / np.abs(reference).max(axis=0)
        print(f"  {steps} step(s): tilt {err[0]:.2%} {err[1]:.2%}, speed {err[2]:.2%}, yaw rate {err[3]:.2%}")
    print("energy without friction or inputs, 10 s:")
    print(f"  off the floor, no gravity: drift {free_energy_drift():.3%} of the kinetic energy")
    lost, kinetic = floor_swing()
    print(
        f"  hanging from the ball through the floor, swinging: {lost:.2f} J lost of a {kinetic:.1f} J swing "
        "(the soft contact)"
    )


def manoeuvre(steps: int) -> np.ndarray:
    plant = checks.plant3d(intent=checks.MANOEUVRE, mujoco=MujocoParams(steps_per_tick=steps))
    balancer = checks.TruthBalancer(plant)
    balancer.yaw_rate_command = 0.8
    rows = []
    for i in range(1600):
        balancer.set_velocity(1.2 * min(1.0, i / 400))
        balancer.drive()
        plant.step()
        truth = plant.truth()
        rows.append((*truth.tilt, math.hypot(*truth.velocity), truth.yaw_rate))
    return np.array(rows)


def free_energy_drift() -> float:
    plant = checks.plant3d(robot(friction=NO_FRICTION), tilt=(deg(20.0), deg(-20.0)))
    plant.torso = None
    m, d = plant.model, plant.data
    m.opt.gravity[:] = 0.0
    m.geom_conaffinity[:] = 0
    d.qvel[:] = np.linspace(-1.5, 1.5, m.nv)
    checks.mujoco.mj_forward(m, d)
    e0, drift = plant.energy(), 0.0
    for _ in range(4000):
        plant.step()
        drift = max(drift, abs(plant.energy() - e0))
    return drift / e0


def floor_swing() -> tuple[float, float]:
    plant = checks.plant3d(robot(friction=NO_FRICTION), rider=None, tilt=(deg(150.0), deg(-20.0)))
    m = plant.model
    m.geom_contype[checks.mujoco.mj_name2id(m, checks.mujoco.mjtObj.mjOBJ_GEOM, "chassis_rim")] = 0
    for _ in range(10):
        plant.step()
    e0, kinetic = plant.energy(), 0.0
    for _ in range(4000):
        plant.step()
        plant.energy()  # MuJoCo's account, potential and kinetic, into data.energy
        kinetic = max(kinetic, float(plant.data.energy[1]))
    return e0 - plant.energy(), kinetic


if __name__ == "__main__":
    main()
