"""What the supervisor observes, built from trusted CAN frames and zenoh payloads (no I/O: the adapter
passes them in with the time).

Speed is estimated independently of the controller: motor velocities -> ball-to-body rates through the
omniwheel map (this package's own, from the robot file), plus the chassis rate from the IMU, times the
ball radius. Untrusted frames (E2E) update nothing and count as integrity errors.
"""

from __future__ import annotations

import math
from collections import Counter, deque

import numpy as np

from drivers.can_bus import Received
from drivers.e2e import E2EStatus
from drivers.schemas import EstopCommand, ScRequest, TesWrench
from safety.config import RobotGeometry, SupervisorConfig
from safety.machine import STREAMS, Observation, Request

DRIVE_FEEDBACK = {"DRIVE1_FEEDBACK": 0, "DRIVE2_FEEDBACK": 1, "DRIVE3_FEEDBACK": 2}
DRIVE_COMMANDS = ("DRIVE1_COMMAND", "DRIVE2_COMMAND", "DRIVE3_COMMAND")


def motor_jacobian(robot: RobotGeometry) -> np.ndarray:
    """Motor-shaft rates = G @ [φ̇_x − θ̇_x, φ̇_y − θ̇_y, −ψ̇] (each wheel's contact direction on the ball)."""
    d = robot.drivetrain
    rho = robot.ball.radius / d.wheel_radius
    zenith = math.radians(d.zenith_deg)
    rows = []
    for i, sign in enumerate(d.motor_sign):
        azimuth = math.radians(d.azimuth0_deg) + 2.0 * math.pi * i / 3.0
        direction = (
            -math.cos(zenith) * math.cos(azimuth),
            -math.cos(zenith) * math.sin(azimuth),
            math.sin(zenith),
        )
        rows.append([sign * d.gear_ratio * rho * x for x in direction])
    return np.array(rows)


class Monitors:
    def __init__(self, config: SupervisorConfig, robot: RobotGeometry):
        self.config = config
        self.radius = robot.ball.radius
        self.to_relative = np.linalg.inv(motor_jacobian(robot))
        self.last: dict[str, float] = dict.fromkeys(STREAMS, -math.inf)
        self.drive_seen = [-math.inf] * 3
        self.motor_velocity = [0.0, 0.0, 0.0]
        self.attitude = (0.0, 0.0)
        self.rate = (0.0, 0.0)
        self.controller_state: int | None = None
        self.torque_peak = 0.0
        self.seat_load: float | None = None
        self.button = False
        self.request: Request | None = None
        self.operator: str | None = None
        self.operator_source = ""
        self._wrench_id: tuple[int, float] | None = None
        self.stale_wrench = 0
        """Seat samples that repeated the previous one unchanged (not counted as fresh)."""
        self._errors: deque[tuple[float, int]] = deque()
        self.operators = frozenset(config.identity.operators)
        self.rejected_identity: Counter[str] = Counter()
        """SC requests and resets ignored because their source is not a configured operator."""
        self._imu_parts = [-math.inf, -math.inf]

    # ------------------------------------------------------------------------------------------ inputs
    def frame(self, rx: Received, t: float) -> None:
        e2e = rx.e2e
        if e2e is not None and e2e.status is not E2EStatus.OK:
            self._errors.append((t, max(e2e.lost, 1)))
        if not rx.ok:
            return
        s, name = rx.signals, rx.name
        if name in DRIVE_FEEDBACK:
            i = DRIVE_FEEDBACK[name]
            self.motor_velocity[i] = float(s["Velocity"])
            self.drive_seen[i] = t
            self.last["drives"] = min(self.drive_seen)
        elif name in DRIVE_COMMANDS:
            self.torque_peak = max(self.torque_peak, abs(float(s["Torque"])))
        elif name == "IMU_ATTITUDE" and s["Valid"]:
            self.attitude = (float(s["Roll"]), float(s["Pitch"]))
            self._imu(0, t)
        elif name == "IMU_RATE" and s["Valid"]:
            self.rate = (float(s["RateX"]), float(s["RateY"]))
            self._imu(1, t)
        elif name == "CONTROLLER_HEARTBEAT":
            self.controller_state = int(s["State"])
            self.last["heartbeat"] = t
        elif name == "OPERATOR_ESTOP":
            self.button = bool(s["Request"])

    def _imu(self, part: int, t: float) -> None:
        self._imu_parts[part] = t
        self.last["imu"] = min(self._imu_parts)

    def wrench(self, w: TesWrench, t: float) -> None:
        self.seat_load = -w.force[2]
        # A sample repeated unchanged (same seq and stamp: a stale publisher) does not feed the watchdog.
        if (w.seq, w.stamp) != self._wrench_id:
            self._wrench_id = (w.seq, w.stamp)
            self.last["wrench"] = t
        else:
            self.stale_wrench += 1

    def _trusted(self, source: str, kind: str) -> bool:
        if not self.operators or source in self.operators:
            return True
        self.rejected_identity[kind] += 1
        return False

    def sc_request(self, r: ScRequest, t: float) -> None:
        if not self._trusted(r.source, "sc_request"):
            return
        self.request = Request(r.mode, r.speed_cap, r.source)
        self.last["sc"] = t

    def operator_command(self, cmd: EstopCommand) -> None:
        if cmd.action == "reset" and not self._trusted(cmd.source, "reset"):
            return  # an e-stop is accepted from anyone; a reset only from an operator
        # Within one update an e-stop outranks a reset, whatever the order they arrived in.
        if cmd.action == "estop" or self.operator != "estop":
            self.operator, self.operator_source = cmd.action, cmd.source

    # ----------------------------------------------------------------------------------------- observe
    def speed(self) -> float | None:
        if not (math.isfinite(self.last["drives"]) and math.isfinite(self.last["imu"])):
            return None
        rel = self.to_relative @ np.asarray(self.motor_velocity)
        pitch = float(rel[1]) + self.rate[1]
        roll = float(rel[0]) + self.rate[0]
        return self.radius * math.hypot(pitch, roll)

    def tilt(self) -> float | None:
        if not math.isfinite(self._imu_parts[0]):
            return None
        return max(abs(self.attitude[0]), abs(self.attitude[1]))

    def observe(self, t: float) -> Observation:
        """A snapshot at time t; the per-update parts (torque peak, operator command) start afresh."""
        window = t - self.config.integrity.e2e_window
        while self._errors and self._errors[0][0] < window:
            self._errors.popleft()
        obs = Observation(
            t=t,
            speed=self.speed(),
            tilt=self.tilt(),
            ages={k: t - v for k, v in self.last.items()},
            controller_state=self.controller_state,
            torque_peak=self.torque_peak,
            e2e_errors=sum(n for _, n in self._errors),
            seat_load=self.seat_load,
            button=self.button,
            request=self.request,
            operator=self.operator,
            operator_source=self.operator_source,
        )
        self.torque_peak = 0.0
        self.operator, self.operator_source = None, ""
        return obs
