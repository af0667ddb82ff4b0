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
    print(
        "energy without friction or inputs, 10 s, off the floor and without gravity (drift of the kinetic):"
    )
    for steps in (2, 4):
        drifts = [free_energy_drift(seed, steps) for seed in range(STARTS)]
        print(
            f"  {steps} steps a tick, {STARTS} random starts: drift {min(drifts):+.2%} to "
            f"{max(drifts):+.2%}, median {float(np.median(drifts)):+.2%}"
        )
    lost, kinetic = floor_swing()
    print(
        f"  hanging from the ball through the floor, swinging: {lost:.2f} J lost of a {kinetic:.1f} J swing "
        "(the soft contact)"
    )
    print("the floor's contact:")
    print(f"  the ball sinks {sink() * 1e3:.3f} mm under the robot and the 75 kg rider at rest")
    print(f"  spin creep under 5 Nm of yaw torque on the ball, rider aboard: {spin_creep(5.0):.4f} rad/s")
    drift = checks.attitude_drift()
    print(
        "attitude against gyro, steady turn at 1.0 m/s and 1.5 rad/s, robot alone: mean gyro (as Euler "
        f"rates) minus the attitude's rates: roll {drift[0] * 1e3:+.3f}, pitch {drift[1] * 1e3:+.3f}, "
        f"yaw {drift[2] * 1e3:+.3f} mrad/s"
    )


STARTS = 8
"""Random starts for the energy figure."""


def sink() -> float:
    plant = checks.plant3d()
    for _ in range(400):
        plant.drives.set_permission(False)  # nothing drives: the ball settles under the weight
        plant.step()
    return plant.robot.ball.radius - float(plant.data.qpos[2])


def spin_creep(torque: float) -> float:
    """The ball's spin about the vertical under a constant yaw torque on it, with the 75 kg rider aboard and
    no drive friction (the chassis does not turn with it): the contact's creep below its spin friction."""
    plant = checks.plant3d(robot(friction=NO_FRICTION))
    d = plant.data
    ball = checks.mujoco.mj_name2id(plant.model, checks.mujoco.mjtObj.mjOBJ_BODY, "ball")
    balancer = checks.TruthBalancer(plant)
    rates = []
    for _ in range(800):
        d.xfrc_applied[ball, 5] = torque
        balancer.drive()
        plant.step()
        rates.append(float(d.qvel[5]))
    return float(np.mean(rates[400:]))


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


def free_energy_drift(seed: int, steps: int) -> float:
    """Largest |ΔE| / E0 over 10 s from a random start (tilts, limp torso, every joint's rate in ±1.5)."""
    rng = np.random.default_rng(seed)
    tilt = tuple(float(a) for a in rng.uniform(-deg(25.0), deg(25.0), 2))
    plant = checks.free_plant(
        tilt, lambda nv: rng.uniform(-1.5, 1.5, nv), mujoco=MujocoParams(steps_per_tick=steps)
    )
    e0, drift = plant.energy(), 0.0
    for _ in range(4000):
        plant.step()
        e = plant.energy() - e0
        drift = e if abs(e) > abs(drift) else drift
    return drift / e0


def floor_swing() -> tuple[float, float]:
    plant = checks.hanging_plant(NO_FRICTION)
    e0, kinetic = plant.energy(), 0.0
    for _ in range(4000):
        plant.step()
        plant.energy()  # MuJoCo's account, potential and kinetic, into data.energy
        kinetic = max(kinetic, float(plant.data.energy[1]))
    return e0 - plant.energy(), kinetic


if __name__ == "__main__":
    main()
