"""A dead drive on the 3-D plant, the supervisor's recovery law alone (docs/safety.md "A dead drive"): the
truth balancer holds the robot and its rider until the fault, then drive N makes no torque and the recovery
law, its estimator fed the sensors' samples (the values the wire carries), balances on the other two. No
rig, no controller, no diagnosis: the law's own physics, case by case, against the same law with its
coupled plane taken as a plane of its own (no product of inertia, no yaw in its feedback).

    python benchmarks/dead_drive.py            # 7 s on a quiet machine, 70 s on 2 loaded cores
    python benchmarks/dead_drive.py --sweep    # riders who heed the alert or not: the fastest kept upright

Not timings: the figures are the models', the same on every machine and build. The campaign's dead-drive
cases (configs/campaigns/diagnostics.toml) are the rig's figures: the diagnosis, the controller before it
and the wire between them.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import msgspec
import mujoco
import numpy as np

from drivers.bounds import G0
from drivers.config import load_toml
from drivers.robot import RobotModel
from hil.run.truth_balancer import TruthBalancer
from plant.ballbot3d import Plant3D
from plant.core import RiderIntent
from plant.params import RiderParams, RobotParams, SimParams
from plant.rider import Hold, Ramp
from safety.config import RecoveryRules, SupervisorConfig
from safety.estimator import IsolatedEstimator
from safety.recovery import RecoveryLaw

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Case:
    name: str
    rider: str
    lean: list  # the rider's pitch lean profile (deg), held after its last segment
    speed: float
    """m/s the truth balancer rolls at before the fault."""
    fault: float = 2.0
    duration: float = 8.0
    yaw_rate: float = 0.0
    """rad/s the truth balancer turns at before the fault (a turn)."""
    heeds: bool = False
    """The rider sits up and holds still `alert_reaction_time` after the fault (the alert)."""
    sway: list = field(default_factory=list)
    """The rider's roll lean profile (deg), as `lean`."""
    twist: list = field(default_factory=list)
    """The rider's twist torque profile (N m)."""
    detection: float = 0.0
    """s from the fault until the law takes over; until then the truth balancer goes on balancing on three
    drives, one dead, as the rig's controller does until the diagnosis names the drive."""


CASES = (
    Case("standing, the rider upright", "ref_60kg_180", [], 0.0),
    Case(
        "rolling at 0.25 m/s, the rider holding 8 deg", "s07_abi_73kg_176", [Ramp(to=8.0, duration=0.5)], 0.25
    ),
    Case(
        "rolling at 0.25 m/s, the rider leaning on to 20 deg",
        "s07_abi_73kg_176",
        [Ramp(to=8.0, duration=0.5), Hold(duration=1.5), Ramp(to=20.0, duration=4.0)],
        0.25,
    ),
    Case(
        "at 1.5 m/s, the rider holding 15 deg", "ref_60kg_180", [Ramp(to=15.0, duration=1.0)], 1.5, fault=3.0
    ),
)


def run(case: Case, dead: int, rules: RecoveryRules) -> dict[str, float | str | None]:
    robot = load_toml(ROOT / "configs/robot/pure.toml", RobotParams)
    rider = load_toml(ROOT / f"configs/riders/{case.rider}.toml", RiderParams)
    intent = RiderIntent(pitch=list(case.lean), roll=list(case.sway), twist=list(case.twist))
    plant = Plant3D(robot, rider, SimParams(), intent)
    plant.heeds_alert = case.heeds
    geometry = load_toml(ROOT / "configs/robot/pure.toml", RobotModel)
    estimate, law = IsolatedEstimator(geometry, rules, plant.sim.dt), RecoveryLaw(geometry, rules)
    law.design(rider.mass * G0)
    balancer = TruthBalancer(plant)
    ball, velocity = plant.model.body("ball").id, np.zeros(6)
    yaw = spin = tilt = 0.0
    command, engaged = (0.0, 0.0, 0.0), False
    while plant.t < case.duration and not plant.fallen:
        imu, drives = plant.sample_imu(), plant.sample_drives()
        estimate.update(
            plant.t, imu.attitude[:2], imu.rate, [d.velocity for d in drives], frozenset(), imu.accel
        )
        if plant.t >= case.fault:
            plant.drives.motors[dead].gain = 0.0
        if plant.t < case.fault + case.detection:
            ramp = min(plant.t / 1.5, 1.0)
            balancer.set_velocity(case.speed * ramp)
            balancer.yaw_rate_command = case.yaw_rate * ramp
            balancer.drive()
        else:
            if not engaged:
                engaged = True
                estimate.engage()
                plant.alert(2)
            plant.drives.set_commands(command, True, plant.t)
            command = law.torques(estimate, dead)  # applied the next tick, as on the wire
            truth = plant.truth()
            mujoco.mj_objectVelocity(plant.model, plant.data, mujoco.mjtObj.mjOBJ_BODY, ball, velocity, 0)
            yaw, spin = max(yaw, abs(truth.yaw_rate)), max(spin, abs(velocity[2]))
            tilt = max(tilt, *(abs(math.degrees(a)) for a in truth.tilt))
        plant.step()
    fell, speed = plant.fallen, math.hypot(*plant.velocity)
    return {
        "ended": ("at rest" if speed < AT_REST else f"upright, {speed:.2f} m/s")
        if fell is None
        else f"fell {plant.t - case.fault:.1f} s after",
        "cause": fell,
        "yaw": yaw,
        "spin": spin,
        "tilt": tilt,
    }


AT_REST = 0.05
"""m/s: below this at the end, the robot has come to rest."""
LEAN_PER_SPEED = 8.0
"""deg of forward lean per m/s the sweep's rider rides at (HACS: the rider leans to ride)."""
TURN_PER_SPEED = 0.8
"""rad/s of turn per m/s in the sweep's turns (a 1.25 m radius)."""
SWEEP_STEP = 0.2
SWEEP_SPEEDS = tuple(round(SWEEP_STEP * i, 6) for i in range(1, 6))
"""m/s before the fault."""


def riding(rider: str, speed: float, turn: float, heeds: bool) -> Case:
    """The sweep's ride: `rider` leaning LEAN_PER_SPEED deg per m/s at `speed`, turning at `turn` rad/s per
    m/s, a drive lost at 3 s."""
    lean = [Ramp(to=LEAN_PER_SPEED * speed, duration=0.5)]
    return Case("sweep", rider, lean, speed, fault=3.0, duration=10.0, yaw_rate=turn * speed, heeds=heeds)


def sweep() -> None:
    """Each dead drive in straight riding and in a turn, with a rider who heeds the alert (issue 47's case)
    and one who does not (the campaign's scripted riders): how each run ends, and the largest speed up to
    which every run stayed upright."""
    rules = SupervisorConfig().recovery
    for heeds in (True, False):
        rider = "heeding the alert (1 s)" if heeds else "not heeding the alert (leaning on)"
        print(f"s07 (73 kg) leaning {LEAN_PER_SPEED:.0f} deg per m/s, {rider}; fault at 3 s")
        for turn in (0.0, TURN_PER_SPEED):
            for dead in (0, 1, 2):
                kept, ends = 0.0, []
                for speed in SWEEP_SPEEDS:
                    r = run(riding("s07_abi_73kg_176", speed, turn, heeds), dead, rules)
                    ends.append(f"{speed:.1f}: {r['ended']}")
                    if r["cause"] is None and kept == round(speed - SWEEP_STEP, 6):
                        kept = speed  # every slower run ended upright too
                label = "in a turn" if turn else "straight"
                print(f"  drive {dead + 1} dead, {label:<9} kept up to {kept:.1f} m/s; " + "; ".join(ends))


def main() -> None:
    if "--sweep" in sys.argv[1:]:
        sweep()
        return
    law = SupervisorConfig().recovery
    own = msgspec.structs.replace(law.two_wheels, coupled_velocity_share=1.0)
    alone = msgspec.structs.replace(law, two_wheels=own, rider_roll_yaw_product=0.0)
    print("peak yaw rate (rad/s), peak ball spin on the floor (rad/s), peak tilt (deg), how it ended")
    for case in CASES:
        print(f"{case.name}:")
        for dead in (0, 1):
            for label, rules in (("the law", law), ("coupled plane alone", alone)):
                r = run(case, dead, rules)
                print(
                    f"  drive {dead + 1} dead, {label:<20} yaw {r['yaw']:5.1f}  spin {r['spin']:5.1f}  "
                    f"tilt {r['tilt']:5.1f}  {r['ended']}" + (f" ({r['cause']})" if r["cause"] else "")
                )


if __name__ == "__main__":
    main()
