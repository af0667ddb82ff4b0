"""Plant-only run: PURE + rider held by the ideal (truth) balancer, the rider following a lean profile.

The rig's main job until the tick loop over CAN and zenoh exists: it exercises the physics, the drives,
the sensors and the rider end to end and reports what happened.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hil.run.plants import make_plant
from hil.run.truth_balancer import TruthBalancer
from plant.core import RiderIntent
from plant.params import RiderParams, RobotParams, SimParams
from plant.rider import Hold, Ramp


def default_intent(lean_deg: float, duration: float) -> RiderIntent:
    """Lean forward to `lean_deg` over 1 s, hold, return upright over 1 s in the last quarter."""
    hold = max(duration - 3.0, 0.5) * 0.75
    return RiderIntent(
        pitch=[
            Hold(duration=1.0),
            Ramp(to=lean_deg, duration=1.0),
            Hold(duration=hold),
            Ramp(to=0.0, duration=1.0),
        ]
    )


@dataclass(frozen=True, slots=True)
class PlantRunSummary:
    rider: str
    ticks: int
    sim_time: float
    max_speed: float
    max_tilt_deg: float
    max_lean_deg: float
    max_seat_moment: float
    distance: float
    final_speed: float
    fallen: str | None
    tes_samples: int
    imu_samples: int
    encoder_samples: int


def run_plant(
    robot: RobotParams,
    rider: RiderParams | None,
    sim: SimParams,
    intent: RiderIntent,
    duration: float,
    initial_tilt_deg: float = 0.0,
) -> PlantRunSummary:
    plant = make_plant(robot, rider, sim, intent, initial_tilt=(math.radians(initial_tilt_deg), 0.0))
    balancer = TruthBalancer(plant)
    max_speed = max_tilt = max_lean = max_moment = 0.0
    n_tes = n_imu = n_enc = 0
    ticks = round(duration * sim.tick_hz)
    truth = plant.truth()
    tare = plant.sample_tes().moment[1]  # upright rider at rest: what a seat tare removes
    for _ in range(ticks):
        balancer.drive()
        plant.step()
        truth = plant.truth()
        plant.sample_drives()
        plant.sample_imu()
        tes = plant.sample_tes()
        n_enc, n_imu, n_tes = n_enc + 3, n_imu + 1, n_tes + 1
        max_speed = max(max_speed, math.hypot(*truth.velocity))
        max_tilt = max(max_tilt, abs(truth.tilt[0]), abs(truth.tilt[1]))
        max_lean = max(max_lean, abs(truth.lean[0]), abs(truth.lean[1]))
        max_moment = max(max_moment, abs(tes.moment[1] - tare))
        if truth.fallen:
            break
    return PlantRunSummary(
        rider=rider.name if rider else "(none)",
        ticks=plant.tick,
        sim_time=plant.t,
        max_speed=max_speed,
        max_tilt_deg=math.degrees(max_tilt),
        max_lean_deg=math.degrees(max_lean),
        max_seat_moment=max_moment,
        distance=math.hypot(*truth.position),
        final_speed=math.hypot(*truth.velocity),
        fallen=truth.fallen,
        tes_samples=n_tes,
        imu_samples=n_imu,
        encoder_samples=n_enc,
    )


def format_summary(s: PlantRunSummary) -> str:
    rows = [
        ("rider", s.rider),
        ("simulated", f"{s.sim_time:.2f} s in {s.ticks} ticks"),
        ("max |speed|", f"{s.max_speed:.3f} m/s"),
        ("max |chassis tilt|", f"{s.max_tilt_deg:.2f} deg"),
        ("max |torso lean|", f"{s.max_lean_deg:.2f} deg"),
        ("max |tared seat moment My|", f"{s.max_seat_moment:.1f} Nm"),
        ("distance travelled", f"{s.distance:.2f} m"),
        ("final speed", f"{s.final_speed:.3f} m/s"),
        ("sensor samples", f"{s.encoder_samples} encoder, {s.imu_samples} IMU, {s.tes_samples} TES"),
        ("outcome", f"FELL: {s.fallen}" if s.fallen else "balanced to the end"),
    ]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)
