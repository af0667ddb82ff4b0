"""What the supervisor knows of one drive: its feedback, its last command and its torque read-back, with
the checks each carries (safety/diagnostics.py), fed frame by frame by `safety.monitors.Monitors`. Pure: no
I/O, no clock."""

from __future__ import annotations

import math

from drivers.can_codec import ENCODERS
from drivers.robot import RobotModel
from drivers.vocabulary import Cause
from safety.config import SupervisorConfig
from safety.diagnostics import EncoderCheck, Stuck, TorqueCheck
from safety.observation import DriveReport, Finding

Signals = dict[str, float | int]
"""A trusted frame's decoded signals (Received.signals; a dict, not a Mapping: compiled, its look-ups are
then the dict's own)."""


class Drive:
    """What the supervisor knows of one drive."""

    def __init__(self, index: int, config: SupervisorConfig, robot: RobotModel, period: float):
        sensors, rules = config.sensors, config.drives
        self.index, self.period = index, period
        self.rad_per_count = 2.0 * math.pi / robot.encoder.counts_per_rev
        self.encoder = EncoderCheck(index, sensors, period, self.rad_per_count, 1 << robot.encoder.word_bits)
        self.torque = TorqueCheck(
            index,
            rules.torque_tolerance,
            rules.torque_relative,
            rules.torque_samples,
            robot.drive.torque_limit,
            robot.drive.stall_torque,
            robot.drive.no_load_speed,
        )
        self.stuck = Stuck(sensors.stuck_samples, 3 * self.rad_per_count)
        self.velocity = self.velocity_before = 0.0
        """rad/s: the motor's last two reported velocities."""
        self.counts: int | None = None
        self.seen = -math.inf
        self.enabled = self.watchdog = self.fault = False
        self.bus_powered = False
        self.command: tuple[float, bool] | None = None
        """(torque, enable) of the last command on the bus."""
        self.enable_since: float | None = None
        self.idle_since: float | None = None
        """Since when, under the recovery law, this drive has reported itself making no torque."""
        self.fault_since: float | None = None
        """Since when the drive has reported a fault without a break."""
        self.findings: dict[str, Finding | None] = {}

    def feedback(self, s: Signals, t: float, lost: int) -> None:
        counts = int(s["Position"])
        if t - self.seen > 8 * self.period + 1e-9:
            self.encoder.reset()  # a gap the window must not span
        moved = 0.0 if self.counts is None else abs(counts - self.counts) * self.rad_per_count
        self.velocity_before = self.velocity
        self.velocity, self.counts, self.seen = float(s["Velocity"]), counts, t
        self.enabled, self.watchdog = bool(s["Enabled"]), bool(s["WatchdogTripped"])
        self.fault, self.bus_powered = bool(s["Fault"]), bool(s["BusPowered"])
        if not self.fault:
            self.fault_since = None
        elif self.fault_since is None:
            self.fault_since = t
        self.findings["encoder"] = self.encoder.frame(counts, self.velocity, 1 + lost)
        frozen = self.stuck.sample(s["Velocity"], moved)
        self.findings["stuck"] = (
            Finding(
                Cause.SENSOR_STUCK,
                f"drive {self.index} velocity frozen at {self.velocity:.2f} rad/s while its position moved",
                (ENCODERS[self.index - 1],),
            )
            if frozen
            else None
        )

    def commanded(self, s: Signals, t: float) -> None:
        enable = bool(s["Enable"])
        self.command = (float(s["Torque"]), enable)
        if not enable:
            self.enable_since = None
        elif self.enable_since is None:
            self.enable_since = t

    def measured(self, torque: float) -> None:
        asked = self.command is not None and self.command[1]
        producing = self.enabled and self.bus_powered and asked
        commanded = None if self.command is None else self.command[0]
        self.findings["torque"] = self.torque.sample(
            torque, commanded, producing, self.velocity, self.velocity_before, asked
        )

    def faulted(self, t: float, confirm: float) -> bool:
        """The drive has reported a fault for `confirm`: one report is not enough to name it lost for good
        (a bit flipped where nothing protects the frame, as on CAN Simple, reads as one; a drive that has
        faulted reports it frame after frame). The state machine reacts to the first report all the same."""
        return self.fault_since is not None and t - self.fault_since >= confirm - 1e-9

    def dead_to_the_law(self, t: float, held: bool, confirm: float) -> bool:
        """Held by the recovery law (`held`), the drive has reported itself off, its watchdog tripped or
        faulted for `confirm`: the law's commands do not reach it or it cannot follow them. The drives come
        back within a few frames of a takeover (a dead controller's tripped watchdogs: 1-4 frames)."""
        if not held or (self.enabled and not self.watchdog and not self.fault):
            self.idle_since = None
            return False
        if self.idle_since is None:
            self.idle_since = t
        return t - self.idle_since >= confirm - 1e-9

    def report(self, t: float, timeout: float) -> DriveReport:
        fresh = t - self.seen <= timeout
        return DriveReport(
            enabled=self.enabled if fresh else None,
            watchdog=fresh and self.watchdog,
            fault=fresh and self.fault,
            bus_powered=self.bus_powered if fresh else None,
            commanded_for=0.0 if self.enable_since is None else t - self.enable_since,
        )
