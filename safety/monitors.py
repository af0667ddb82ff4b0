"""What the supervisor observes, built from trusted CAN frames and zenoh payloads (no I/O: the adapter
passes them in with the time).

Speed is estimated independently of the controller: motor velocities -> ball-to-body rates through the
omniwheel map (this package's own, from the robot file), plus the chassis rate from the IMU, times the
ball radius. Once a sensor check has failed the estimate turns conservative: the largest of the estimate
from all three drives and the three that each leave one drive out (its place taken by the gyro's yaw
rate), so a single wrong encoder cannot hide a runaway from the stop's own checks.

Untrusted frames (E2E) update nothing. Each protected stream's E2E checks are judged over a window
(safety/e2e_window.py): a burst is ridden through, a stream whose errors persist is named (its parts, as
CHANNEL_INPUT lists them) until a whole window of its frames is clean again. The diagnostics
(safety/diagnostics.py) are fed frame by frame where one frame carries both sides of a check (a drive's
position and velocity, a torque sample after its command) and at each observation where the sides come in
different frames.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable

import numpy as np

from drivers.bounds import G0
from drivers.can_bus import Received
from drivers.can_codec import (
    DRIVE_COMMAND,
    DRIVE_FEEDBACK,
    DRIVE_TORQUE,
    ENCODERS,
    MOTOR_OF,
    TILT_INPUTS,
    MessageName,
)
from drivers.e2e import COUNTER, COUNTER_MODULO, CRC
from drivers.robot import RobotModel
from drivers.rotations import heading_frame
from drivers.schemas import EstopCommand, ScRequest, TesWrench
from drivers.vocabulary import Cause
from safety.arbiter import ScArbiter
from safety.config import SupervisorConfig
from safety.diagnostics import (
    AttitudeCheck,
    Replay,
    Resolution,
    SeatCheck,
    Stuck,
    TrendCheck,
    YawCheck,
    motor_jacobian,
    trend_inputs,
)
from safety.drive_monitor import Drive, Signals
from safety.e2e_window import E2EWindow, WindowState
from safety.estimator import IsolatedEstimator, leave_one_out
from safety.observation import STREAMS, Finding, Observation

IMU_CHANNELS: dict[str, tuple[str, str, str]] = {
    MessageName.IMU_ATTITUDE: ("Roll", "Pitch", "Yaw"),
    MessageName.IMU_RATE: ("RateX", "RateY", "RateZ"),
    MessageName.IMU_ACCEL: ("AccX", "AccY", "AccZ"),
}
REPLAY_CHECKED = (*DRIVE_FEEDBACK, *DRIVE_TORQUE, *IMU_CHANNELS)
"""Sensor streams checked for a replay from one counter period back."""
CHANNEL_INPUT: dict[str, tuple[str, ...]] = {
    **{name: (encoder,) for name, encoder in zip(DRIVE_FEEDBACK, ENCODERS, strict=True)},
    **{name: () for name in DRIVE_TORQUE},  # an actuator's read-back, not an input of balance
    MessageName.IMU_ATTITUDE: ("Roll", "Pitch", ""),
    MessageName.IMU_RATE: ("RateX", "RateY", "RateZ"),
    MessageName.IMU_ACCEL: ("Accel", "Accel", "Accel"),
}
"""The parts (drivers.can_codec.PARTS) each stream carries, per channel for the IMU ('': none: the yaw angle
is used by no one)."""
CROSS_CHECKS = ("yaw", "roll", "pitch", "pitch trend", "roll trend")
"""The checks `_cross_checks` runs, in its order (the forward speed trend is the pitch plane's)."""
PLANES = tuple(
    (plane, attitude, rate) for plane, (attitude, rate) in zip(("roll", "pitch"), TILT_INPUTS, strict=True)
)
"""Per plane: its checks' name, its attitude input, its rate input."""
ATTITUDES = frozenset(attitude for _, attitude, _ in PLANES)
"""The IMU's attitude inputs (Roll, Pitch)."""
DRIVES = frozenset(f"Drive{i}" for i in (1, 2, 3))
"""The drives' parts (drivers.can_codec.PARTS)."""
ATTITUDE_LSB = 1e-4
"""rad: IMU_ATTITUDE's resolution (the DBC); "it moved" means several of these."""
CONTRACT_STEP: dict[str, float] = {
    MessageName.IMU_ATTITUDE: ATTITUDE_LSB,
    MessageName.IMU_RATE: 1e-3,
    MessageName.IMU_ACCEL: 1e-3,
}
"""Each IMU message's resolution in the contract (the DBC): rad, rad/s, m/s². A device profile may step
coarser (xsens: 2^-7 deg, 2^-9 rad/s, 2^-8 m/s²); the stuck check takes each stream's step from its values."""
MOVED = 3 * ATTITUDE_LSB


class Monitors:
    def __init__(self, config: SupervisorConfig, robot: RobotModel, tick_hz: float = 400.0):
        self.config = config
        self.period = period = 1.0 / tick_hz
        self.radius = robot.ball.radius
        self.imu_height = robot.body.imu_height
        jacobian = motor_jacobian(robot)
        to_relative = np.linalg.inv(jacobian)
        self._to_relative_rows = tuple(tuple(float(x) for x in row) for row in to_relative)
        self._leave_one_out = leave_one_out(jacobian)
        self.isolated = IsolatedEstimator(robot, config.recovery, period)
        """The recovery law's state estimate, without the inputs the diagnosis names."""
        self.last: dict[str, float] = dict.fromkeys(STREAMS, -math.inf)
        self.drives = [Drive(i, config, robot, period) for i in (1, 2, 3)]
        sensors = config.sensors
        self.yaw = YawCheck(sensors, period)
        self.attitude_checks = (AttitudeCheck("roll", sensors), AttitudeCheck("pitch", sensors))
        self.trend = (TrendCheck("forward", sensors, period), TrendCheck("left", sensors, period))
        self.seat = SeatCheck(
            config.seat, config.motion.rider_min_load, robot.body.seat_height, period, MOVED
        )
        self.imu: dict[str, list[float]] = {name: [0.0, 0.0, 0.0] for name in IMU_CHANNELS}
        self._imu_seen: dict[str, float] = dict.fromkeys(IMU_CHANNELS, -math.inf)
        noise: dict[str, float] = {
            MessageName.IMU_ATTITUDE: sensors.attitude_noise,
            MessageName.IMU_RATE: sensors.rate_noise,
            MessageName.IMU_ACCEL: sensors.accel_noise,
        }
        self.imu_resolution = {
            name: Resolution(CONTRACT_STEP[name], noise[name], sensors.stuck_samples) for name in IMU_CHANNELS
        }
        """Each IMU stream's step as its values show it, and the run that shows one of its channels frozen:
        a live channel whose step is coarse against its noise repeats its value at rest (xsens' gyro)."""
        self._imu_stuck: dict[str, list[Stuck]] = {
            name: [Stuck(sensors.stuck_samples, MOVED, self.imu_resolution[name]) for _ in names]
            for name, names in IMU_CHANNELS.items()
        }
        self._attitude_at_rate = (0.0, 0.0)
        self._imu_motion = 0.0
        """rad the chassis turned (|rates| × dt) since the last seat sample: evidence for the seat's."""
        self._replay: dict[str, Replay] = {name: Replay(COUNTER_MODULO) for name in REPLAY_CHECKED}
        self._found: dict[tuple[str, str], Finding | None] = {}
        """What the frame-driven checks found at their last frame, by (message, check) (None: nothing)."""
        self._checks_at: float | None = None
        self.degraded = False
        """A sensor check failed: the speed estimate is the conservative one until a reset."""
        self.recovering = False
        """The drives follow the recovery law (its commands, not the controller's, are checked)."""
        self._law_commanded = False
        """The recovery law commanded the drives since the last observation."""
        self.named: frozenset[str] = frozenset()
        """What the diagnosis named at the last observation (`suspects`)."""
        self._named: set[str] = set()
        """Parts a check has isolated by itself (latched until a reset)."""
        self._failed: set[str] = set()
        """Cross-checks that need other evidence to isolate their input and have failed ('yaw', 'roll',
        'pitch', 'roll trend', 'pitch trend'; latched until a reset)."""
        self.controller_state: int | None = None
        self.torque_peak = 0.0
        self.seat_load: float | None = None
        self.button = False
        self.operator: str | None = None
        self.operator_source = ""
        self._wrench_id: tuple[int, float] | None = None
        self.stale_wrench = 0
        """Seat samples that repeated the previous one unchanged (not counted as fresh)."""
        self._windows: dict[str, E2EWindow] = {}
        """Each protected stream's E2E window, by message (made at its first frame)."""
        self.operators = frozenset(config.identity.operators)
        self.rejected_identity: Counter[str] = Counter()
        """SC requests and resets ignored because their source is not a configured operator."""
        self.sc = ScArbiter(config.sc)
        self._readers: dict[str, Callable[[str, Signals, float, int], None]] = {
            **dict.fromkeys(DRIVE_FEEDBACK, self._feedback),
            **dict.fromkeys(DRIVE_COMMAND, self._commanded),
            **dict.fromkeys(DRIVE_TORQUE, self._measured),
            **dict.fromkeys(IMU_CHANNELS, self._imu_frame),
            MessageName.CONTROLLER_HEARTBEAT: self._heartbeat,
            MessageName.OPERATOR_ESTOP: self._button,
        }
        """What a trusted frame updates, by message: (name, signals, t, frames lost before it) -> None."""

    # ------------------------------------------------------------------------------------------ inputs
    def frame(self, rx: Received, t: float) -> None:
        e2e = rx.e2e
        if e2e is not None:
            window = self._windows.get(rx.name)
            if window is None:
                rules = self.config.integrity.rules(rx.name)
                window = self._windows[rx.name] = E2EWindow(rules.window, rules.max_errors)
            window.frame(e2e.status, e2e.lost)
        if not rx.ok:
            return
        s, name = rx.signals, rx.name
        replay = self._replay.get(name)
        if replay is not None:
            replayed = replay.frame(tuple(v for k, v in s.items() if k not in (COUNTER, CRC)))
            self._found[name, "replay"] = (
                Finding(
                    Cause.SENSOR_STUCK,
                    f"{name} repeats its frames of {COUNTER_MODULO} frames ago: "
                    "replayed (E2E's counter aliases)",
                    tuple(i for i in dict.fromkeys(CHANNEL_INPUT[name]) if i),
                )
                if replayed
                else None
            )
        read = self._readers.get(name)
        if read is not None:
            read(name, s, t, 0 if e2e is None else e2e.lost)

    def _feedback(self, name: str, s: Signals, t: float, lost: int) -> None:
        self.drives[MOTOR_OF[name]].feedback(s, t, lost)
        self.last["drives"] = min(d.seen for d in self.drives)

    def _commanded(self, name: str, s: Signals, t: float, lost: int) -> None:
        self.torque_peak = max(self.torque_peak, abs(float(s["Torque"])))
        if not self.recovering:
            self.drives[MOTOR_OF[name]].commanded(s, t)

    def recovery_commanded(self, torques: tuple[float, float, float]) -> None:
        """The recovery law holds the drives: its commands are the ones they follow (for the torque check),
        not the controller's, until a reset."""
        self.recovering = self._law_commanded = True
        for drive, torque in zip(self.drives, torques, strict=True):
            drive.command = (torque, True)

    def _measured(self, name: str, s: Signals, t: float, lost: int) -> None:
        self.drives[MOTOR_OF[name]].measured(float(s["Torque"]))

    def _heartbeat(self, name: str, s: Signals, t: float, lost: int) -> None:
        self.controller_state = int(s["State"])
        self.last["heartbeat"] = t

    def _button(self, name: str, s: Signals, t: float, lost: int) -> None:
        self.button = bool(s["Request"])

    def _imu_frame(self, name: str, s: Signals, t: float, lost: int) -> None:
        if not s["Valid"]:
            return
        values, signals = self.imu[name], IMU_CHANNELS[name]
        for i, signal in enumerate(signals):
            values[i] = float(s[signal])
        self._imu_seen[name] = t
        self.last["imu"] = min(self._imu_seen[MessageName.IMU_ATTITUDE], self._imu_seen[MessageName.IMU_RATE])
        rates, attitude = self.imu[MessageName.IMU_RATE], self.imu[MessageName.IMU_ATTITUDE]
        # What says each channel must have moved since its previous frame (evidence for the stuck check).
        if name == MessageName.IMU_ATTITUDE:  # the body rates
            evidence = [abs(r) * self.period for r in rates]
        elif name == MessageName.IMU_RATE:  # the attitude they drive; the yaw rate the encoders determine
            encoder_yaw = self.yaw.encoders(self._relative(), rates, attitude[0], attitude[1])
            evidence = [
                abs(attitude[0] - self._attitude_at_rate[0]),
                abs(attitude[1] - self._attitude_at_rate[1]),
                abs(encoder_yaw) * self.period,
            ]
            self._attitude_at_rate = (attitude[0], attitude[1])
        else:  # the specific force turns with the chassis
            turned = (abs(rates[0]) + abs(rates[1]) + abs(rates[2])) * self.period
            evidence = [turned] * 3
            self._imu_motion += turned
        checkers = self._imu_stuck[name]
        stuck = [i for i in range(3) if checkers[i].sample(s[signals[i]], evidence[i])]
        self._found[name, "stuck"] = (
            Finding(
                Cause.SENSOR_STUCK,
                f"{name}.{signals[stuck[0]]} frozen at {values[stuck[0]]:.4f} for "
                f"{self._imu_stuck[name][stuck[0]].run} frames while other evidence moved",
                tuple(i for i in dict.fromkeys(CHANNEL_INPUT[name][c] for c in stuck) if i),
            )
            if stuck
            else None
        )

    def wrench(self, w: TesWrench, t: float) -> None:
        self.seat_load = -w.force[2]
        # A sample repeated unchanged (same seq and stamp: a stale publisher) does not feed the watchdog.
        if (w.seq, w.stamp) != self._wrench_id:
            self._wrench_id = (w.seq, w.stamp)
            self.last["wrench"] = t
            attitude = self.imu[MessageName.IMU_ATTITUDE]
            vertical = heading_frame(self.imu[MessageName.IMU_ACCEL], attitude[0], attitude[1])[2]
            found = self.seat.sample(
                w.force,
                w.moment,
                w.cop,
                vertical if self._imu_seen[MessageName.IMU_ACCEL] > -math.inf else G0,
                self._imu_motion,
                w.cells,
            )
            self._found["seat", "wrench"] = found and dataclasses.replace(found, parts=("Seat",))
            self._imu_motion = 0.0
        else:
            self.stale_wrench += 1

    def _trusted(self, source: str, kind: str) -> bool:
        if not self.operators or source in self.operators:
            return True
        self.rejected_identity[kind] += 1
        return False

    def sc_request(self, r: ScRequest, t: float) -> None:
        if self._trusted(r.source, "sc_request"):
            self.sc.offer(r, t)

    def operator_command(self, cmd: EstopCommand) -> None:
        if cmd.action == "reset" and not self._trusted(cmd.source, "reset"):
            return  # an e-stop is accepted from anyone; a reset only from an operator
        # Within one update an e-stop outranks a reset, whatever the order they arrived in.
        if cmd.action == "estop" or self.operator != "estop":
            self.operator, self.operator_source = cmd.action, cmd.source

    def reset(self) -> None:
        """A reset was accepted: the sensors were found healthy again."""
        self.degraded = self.recovering = False
        self.isolated.clear()
        self.named = frozenset()
        self._named.clear()
        self._failed.clear()

    def e2e_invalid(self) -> tuple[str, ...]:
        """The protected streams whose E2E errors persist (their window INVALID), in the order first heard."""
        return tuple(name for name, w in self._windows.items() if w.state is WindowState.INVALID)

    def _e2e_named(self) -> set[str]:
        """The parts of the streams E2E cannot trust now: named while their window is INVALID, trusted again
        once a whole window of their frames is clean (not latched, unlike the checks' findings)."""
        return {part for name in self.e2e_invalid() for part in CHANNEL_INPUT.get(name, ()) if part}

    def suspects(self) -> frozenset[str]:
        """The parts the diagnosis names faulty (drivers.can_codec.PARTS): latched until a reset, but for a
        stream's parts E2E names, which it names only while that stream's errors persist.

        What a check isolates by itself (an encoder's position against its velocity, a frozen or replayed
        channel) is named directly. A cross-check that fails names its likeliest input unless a direct
        finding already explains it: the yaw check the one of the gyro and the three encoders whose
        exclusion leaves the smoothest ball rates (safety/estimator.py `odd_one_out`), unless a drive is
        named (a dead drive's partners' yaw torque spins the ball on the floor: the encoders then disagree
        with the gyro although none lies; on the 3-D plant within 22 ms, before the torque check); an
        attitude or speed-trend check the plane's attitude, rate or accelerometer by the accelerometer's own
        tilt (safety/estimator.py `blame`)."""
        named = self._named | self._e2e_named()
        failed = self._failed
        if not failed:
            return frozenset(named)
        out = set(named)
        if "yaw" in failed and not named & {*ENCODERS, "RateZ", *DRIVES}:
            out.add(self.isolated.odd_one_out())
        # The speed trend rests on the encoders too: a named encoder explains it (in motion a corrupted
        # velocity fails the trend a frame or two before the encoder's own window names it).
        encoder_named = not named.isdisjoint(ENCODERS)
        for i, (plane, attitude, rate) in enumerate(PLANES):
            trend = f"{plane} trend" in failed and not encoder_named
            if (plane in failed or trend) and not named & {attitude, rate, "Accel"}:
                blamed = self.isolated.blame(i, accel_suspect=plane not in failed)
                out.add({"attitude": attitude, "rate": rate, "accel": "Accel"}[blamed])
        return frozenset(out)

    # ----------------------------------------------------------------------------------------- observe
    def _fresh(self, t: float) -> bool:
        w = self.config.watchdogs
        return t - self.last["drives"] <= w.drives and all(
            t - seen <= w.imu for seen in self._imu_seen.values()
        )

    def _relative(self) -> tuple[float, float, float]:
        """Ball-to-body rates from the three encoders (G⁻¹ m), as floats: numpy's per-call overhead
        dominates a 3 x 3 product at 400 Hz."""
        m1, m2, m3 = (d.velocity for d in self.drives)
        r = self._to_relative_rows
        return (
            r[0][0] * m1 + r[0][1] * m2 + r[0][2] * m3,
            r[1][0] * m1 + r[1][1] * m2 + r[1][2] * m3,
            r[2][0] * m1 + r[2][1] * m2 + r[2][2] * m3,
        )

    def speed(self) -> float | None:
        if not (math.isfinite(self.last["drives"]) and math.isfinite(self.last["imu"])):
            return None
        rate = self.imu[MessageName.IMU_RATE]
        roll, pitch, _ = self.imu[MessageName.IMU_ATTITUDE]
        nominal = self._ground_speed(self._relative(), rate, roll, pitch)
        if not self.degraded:
            return nominal
        if self.named & set(ENCODERS) and self.isolated.ready:
            return self.isolated.speed  # the encoder that lies is known (its own position check): drop it
        velocities = [d.velocity for d in self.drives]
        estimates = [nominal]
        for solve, others in self._leave_one_out:
            known = [velocities[j] for j in others]
            estimates.append(self._ground_speed(solve(known, rate, roll, pitch), rate, roll, pitch))
        return max(estimates)

    def _ground_speed(
        self, relative: tuple[float, float, float], rate: list[float], roll: float, pitch: float
    ) -> float:
        """The ball's speed over the floor: its rotation (relative + the chassis') turned into the heading
        frame, the horizontal part (a ball spinning on the floor spins about the vertical: no speed)."""
        x, y, _ = heading_frame(
            (relative[0] + rate[0], relative[1] + rate[1], relative[2] + rate[2]), roll, pitch
        )
        return self.radius * math.hypot(x, y)

    def tilt(self) -> float | None:
        if not math.isfinite(self._imu_seen[MessageName.IMU_ATTITUDE]):
            return None
        if self.named & ATTITUDES and self.isolated.ready:
            return self.isolated.tilt  # the attitude lies: the rates integrated from where it was good
        attitude = self.imu[MessageName.IMU_ATTITUDE]
        return max(abs(attitude[0]), abs(attitude[1]))

    def _cross_checks(self, t: float) -> list[Finding]:
        """The checks whose two sides come in different frames, once per observation."""
        dt = None if self._checks_at is None else t - self._checks_at
        self._checks_at = t
        if not self._fresh(t):
            for check in (*self.attitude_checks, *self.trend):
                check.reset()
            return []
        if not dt:
            return []
        roll, pitch, _ = self.imu[MessageName.IMU_ATTITUDE]
        rate = self.imu[MessageName.IMU_RATE]
        rel = self._relative()
        coupling = (abs(rate[0]) + abs(rate[1]) + abs(rate[2])) * math.tan(max(abs(roll), abs(pitch)))
        if self._drive_named():
            # Two wheels' torque carries a yaw torque past what the floor holds: the ball spins on it, and
            # the yaw check's premise fails (docs/safety.md "A dead drive").
            self.yaw.reset()
            yaw = None
        else:
            yaw = self.yaw.update(rel, rate, roll, pitch, dt)
        found = [
            yaw,
            self.attitude_checks[0].update(roll, rate[0], coupling, dt),
            self.attitude_checks[1].update(pitch, rate[1], coupling, dt),
        ]
        (forward, a_forward), (left, a_left) = trend_inputs(
            rel, rate, self.imu[MessageName.IMU_ACCEL], roll, pitch, self.radius, self.imu_height
        )
        found.append(self.trend[0].update(forward, a_forward, dt))
        found.append(self.trend[1].update(left, a_left, dt))
        for i, finding in enumerate(found):
            if finding is not None:
                self._failed.add(CROSS_CHECKS[i])
        return [f for f in found if f is not None]

    def findings(self, t: float) -> tuple[Finding, ...]:
        found = self._cross_checks(t)
        for drive in self.drives:
            found += [f for f in drive.findings.values() if f is not None]
        found += [f for f in self._found.values() if f is not None]
        if any(f.cause in (Cause.SENSOR_STUCK, Cause.SENSOR_DISAGREE) for f in found):
            self.degraded = True
        for f in found:
            self._named.update(f.parts)
        held, self._law_commanded = self._law_commanded, False
        confirm = self.config.drives.confirm
        for drive in self.drives:
            # A drive's own fault names it once it persists; one that stays off under the recovery law names
            # itself too (its commands are lost, as on cia402 where the law's torques ride in its RPDO1).
            if drive.faulted(t, confirm) or drive.dead_to_the_law(t, held, confirm):
                self._named.add(f"Drive{drive.index}")
        return tuple(found)

    def _drive_named(self) -> bool:
        return not self.named.isdisjoint(DRIVES)

    def dead_drive(self) -> int | None:
        """The drive (0-2) the diagnosis names, if one: the recovery law balances on the other two."""
        named = [i for i, d in enumerate(self.drives) if f"Drive{d.index}" in self.named]
        return named[0] if len(named) == 1 else None

    def _drives_left(self) -> bool:
        """At least two drives not named faulty: two omniwheels can still balance the ball."""
        return sum(f"Drive{d.index}" in self.named for d in self.drives) <= 1

    def _isolate(self, t: float) -> None:
        """Feed the recovery law's estimator with the fresh trusted streams and what the diagnosis names."""
        drives = self.config.watchdogs.drives
        self.named = self.suspects()
        failed = self._failed
        self.isolated.update(
            t,
            self._fresh_imu(MessageName.IMU_ATTITUDE, t),
            self._fresh_imu(MessageName.IMU_RATE, t),
            [d.velocity if t - d.seen <= drives else None for d in self.drives],
            self.named,
            self._fresh_imu(MessageName.IMU_ACCEL, t),
            frozenset(a for p, a, _ in PLANES if p in failed or f"{p} trend" in failed),
        )

    def _fresh_imu(self, name: str, t: float) -> list[float] | None:
        """An IMU stream's last values if fresh (None: silent)."""
        return self.imu[name] if t - self._imu_seen[name] <= self.config.watchdogs.imu else None

    def margins(self) -> dict[str, float]:
        """Each check's largest |residual| / bound so far (1: where it would fire)."""
        checks = [self.yaw, *self.attitude_checks, *self.trend, self.seat]
        for d in self.drives:
            checks += [d.encoder, d.torque]
        out = {c.name: round(c.peak, 4) for c in checks}
        out.update({f"seat {part}": round(v, 4) for part, v in self.seat.peaks.items()})
        return out

    def observe(self, t: float) -> Observation:
        """A snapshot at time t; the per-update parts (torque peak, operator command) start afresh."""
        ages = {k: t - v for k, v in self.last.items()}
        ages["sc"] = self.sc.age(t)
        findings = self.findings(t)
        self._isolate(t)
        timeout = self.config.watchdogs.drives
        obs = Observation(
            t=t,
            speed=self.speed(),
            tilt=self.tilt(),
            ages=ages,
            controller_state=self.controller_state,
            torque_peak=self.torque_peak,
            e2e_errors=sum(w.errors for w in self._windows.values()),
            e2e_invalid=self.e2e_invalid(),
            seat_load=self.seat_load,
            button=self.button,
            request=self.sc.request,
            operator=self.operator,
            operator_source=self.operator_source,
            findings=findings,
            drives=tuple(d.report(t, timeout) for d in self.drives),
            recoverable=self.config.recovery.enabled and self.isolated.ready and self._drives_left(),
        )
        self.torque_peak = 0.0
        self.operator, self.operator_source = None, ""
        return obs
