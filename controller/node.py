"""The controller on the wire: CAN frames in, SYNC-triggered computation, torque commands and heartbeat out;
seat wrench, SC commands and operator commands from zenoh.

Lockstep: before computing tick k the node waits (bounded) for the rig's fence of tick k (pure/rig/tick k
and every payload it counts on the keys the node reads: drivers/zenoh_link.py `Fence`), which the rig puts
after every zenoh input of tick k and before SYNC(k). The seat sample and any SC command of that tick have
then arrived (or never will: a fault withheld them). That makes a lockstep run deterministic. In real time
it never waits.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any, Final

from controller.core import Controller, Fault, Output, Wrench
from drivers.can_bus import CanNode, Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, PARTS, MessageName
from drivers.contract import CONTRACT_VERSION
from drivers.keys import Keys
from drivers.schemas import TICK_MODULO, ControllerCommand, ControllerTelemetry, ScCommand, TesWrench
from drivers.vocabulary import ControllerState, State
from drivers.zenoh_link import Fence, Subscription, ZenohLink

log = logging.getLogger(__name__)

# Final: compiled (mypyc), a static rather than a look-up in the module's globals per frame.
FEEDBACK: Final[dict[str, int]] = {name: motor for motor, name in enumerate(DRIVE_FEEDBACK)}
SEAT_FLAGGED = frozenset({"WRENCH_IMPLAUSIBLE"})
"""SUPERVISOR_ESTOP.Reason values that say the seat's wrench is not a rider's: the controller stops using it
(as if the seat were silent) until the supervisor is back in NORMAL, instead of balancing on a phantom lean
through the controlled stop."""
LATE_RUN = 3
SHORT_WAIT = 0.005
"""s the lockstep controller waits for the rig's fence once it has been late LATE_RUN ticks in a row."""
BOOT_PERIOD = 0.1
"""s between boot-up heartbeats (State INIT) until the first SYNC: the rig's start-up handshake."""
RUN_OVER = 2.0
"""s without a SYNC after which the run is over: the node starts over in INIT for the next one and announces
its boot-up again (docs/contract.md "Between runs"); longer than any wait of a lockstep rig's tick (1 s)."""
REST_SPEED, REST_TILT, REST_TIME = 0.05, math.radians(3.0), 0.3
"""Without a supervisor this controller turns its drives off once it has stood still (m/s) and upright
(rad) this long (s): where the supervisor's own controlled stop would."""


class ControllerNode:
    def __init__(
        self,
        controller: Controller,
        can: CanNode,
        link: ZenohLink,
        keys: Keys | None = None,
        lockstep: bool = False,
        tes_wait: float = 0.5,
    ):
        self.controller, self.can, self.link = controller, can, link
        self.keys = keys = keys or link.keys
        self.lockstep, self.tes_wait = lockstep, tes_wait
        # The seat's subscription last: the rig starts once it sees it, and a fence needs the others in place.
        self.sc = link.subscribe(keys.sc_command, ScCommand, capacity=16)
        self.operator = link.subscribe(keys.controller_command, ControllerCommand, capacity=16)
        fence_reads: list[Subscription[Any]] = [self.sc, self.operator]
        self.fence = Fence(link, fence_reads) if lockstep else None
        self.tes = link.subscribe(keys.tes_wrench, TesWrench, capacity=64)
        fence_reads.append(self.tes)
        self.estop = False
        self.seat_flagged = False
        self.supervisor_seen: float | None = None
        """When the last SUPERVISOR_ESTOP arrived (controller time; None: never)."""
        self._still_since: float | None = None
        self.stopped_alone = False
        """The supervisor was lost and this controller stopped the robot itself: disabled until an enable."""
        reasons = can.catalog[MessageName.SUPERVISOR_ESTOP].values("Reason")
        self._seat_flags = frozenset(code for code, name in reasons.items() if name in SEAT_FLAGGED)
        self.tick: int | None = None
        self.synced_at = 0.0
        """time.monotonic() of the last SYNC handled."""
        self.late = 0
        """Lockstep ticks computed before the rig's fence of that tick arrived (the wait timed out)."""
        self._late_run = 0
        self.last_output: Output | None = None
        self._wrench: TesWrench | None = None
        self._sc: ScCommand | None = None
        """The newest SC command as the controller takes it (made again only when a new one arrives)."""
        # What every tick reads, read once.
        self._mode = controller.config.mode
        self._permission_timeout = controller.robot.drive.permission_timeout

    # ------------------------------------------------------------------------------------------ frames
    def handle(self, rx: Received) -> None:
        name, s = rx.name, rx.signals
        if name == MessageName.SYNC:
            self.on_sync(int(s["Tick"]))
            return
        if not rx.ok:
            return  # untrusted (CRC, repeat, out of order): the estimator holds the last good value
        t = self._time()
        est = self.controller.estimator
        motor = FEEDBACK.get(name)
        if motor is not None:
            est.drive(motor, int(s["Position"]), s["Velocity"], t)
        elif name == MessageName.IMU_ATTITUDE and s["Valid"]:
            est.imu_attitude(s["Roll"], s["Pitch"], s["Yaw"], t)
        elif name == MessageName.IMU_RATE and s["Valid"]:
            est.imu_rate(s["RateX"], s["RateY"], s["RateZ"], t)
        elif name == MessageName.SUPERVISOR_DIAGNOSIS:
            est.drop(frozenset(part for part in PARTS if s[part]))
        elif name == MessageName.SUPERVISOR_ESTOP:
            # The supervisor's recovery law holding the drives is an e-stop for this controller: its commands
            # are ignored, and it waits for an operator's enable after the reset (docs/contract.md).
            self.estop = bool(s["Estop"]) or bool(s["Takeover"])
            self.supervisor_seen = t
            if int(s["Reason"]) in self._seat_flags:
                self.seat_flagged = True
            elif int(s["State"]) == State.NORMAL:  # a reset
                self.seat_flagged = False

    def _time(self) -> float:
        return 0.0 if self.tick is None else self.tick * self.controller.dt

    def on_sync(self, raw_tick: int) -> Output:
        self.synced_at = time.monotonic()
        if self.tick is None:
            self.tick = raw_tick
        else:
            self.tick += (raw_tick - self.tick) % TICK_MODULO
        t = self._time()
        self._update_zenoh(self.tick)
        wrench, age = None, math.inf
        if self._wrench is not None and not self.seat_flagged:
            wrench = Wrench(self._wrench.force, self._wrench.moment)
            age = max(t - self._wrench.stamp, 0.0)
        sc = self._sc
        if self._supervisor_lost(t):
            # No supervisor: brake to rest, then off (docs/contract.md).
            sc = ScCommand(seq=0, stamp=t, mode="idle", source="controller", reason="no supervisor")
        try:
            out = self.controller.step(t, wrench, age, sc, self.estop or self.stopped_alone)
        except Exception:  # a bug in the controller must fail safe (drives off), not kill the node
            log.exception("controller step failed at tick %d: drives disabled", self.tick)
            self.controller.state, self.controller.fault = ControllerState.FAULT, Fault.INTERNAL
            out = Output((0.0, 0.0, 0.0), False, ControllerState.FAULT, Fault.INTERNAL)
        enable = int(out.enable)
        for motor, name in enumerate(DRIVE_COMMAND):
            self.can.send(name, {"Torque": out.motor_torque[motor], "Tick": raw_tick, "Enable": enable})
        mode = self._mode
        self.can.send(
            MessageName.CONTROLLER_HEARTBEAT,
            {
                "State": int(out.state),
                "Mode": int(mode == "ihacs"),
                "FaultCode": int(out.fault),
                "Contract": CONTRACT_VERSION,
            },
        )
        self.link.put(
            self.keys.controller_telemetry,
            ControllerTelemetry(
                seq=self.tick,
                stamp=t,
                state=int(out.state),
                mode=mode,
                command_speed=out.command_speed,
                tilt_command=out.tilt_command,
                yaw_rate_command=out.yaw_rate_command,
                ball_torque=out.ball_torque,
            ),
        )
        self.last_output = out
        return out

    def _supervisor_lost(self, t: float) -> bool:
        """The supervisor's frame has gone silent: stop on our own, and once still and upright for
        REST_TIME turn the drives off (latched until an operator's enable)."""
        if self.supervisor_seen is None or t - self.supervisor_seen <= self._permission_timeout:
            self._still_since = None
            return False
        if not self.stopped_alone and self.controller.state is ControllerState.BALANCING:
            estimate = self.controller.estimator.estimate(t)
            pitch, roll = estimate.planes
            speed = self.controller.robot.ball.radius * math.hypot(pitch.ball_rate, roll.ball_rate)
            if speed <= REST_SPEED and max(abs(pitch.tilt), abs(roll.tilt)) <= REST_TILT:
                self._still_since = t if self._still_since is None else self._still_since
                if t - self._still_since >= REST_TIME:
                    log.warning("supervisor lost: stopped and at rest at t=%.3f, drives off", t)
                    self.stopped_alone = True
            else:
                self._still_since = None
        return True

    def _update_zenoh(self, tick: int) -> None:
        for cmd in self.operator.drain():
            if cmd.action == "enable":
                self.controller.request_enable()
                self.stopped_alone = False
        if self.fence is not None:
            # A rig that stopped putting its fence (none on this bus) must not stall every tick.
            wait = self.tes_wait if self._late_run < LATE_RUN else SHORT_WAIT
            late = not self.fence.wait(tick, wait)
            self.late += late
            self._late_run = self._late_run + 1 if late else 0
        self._take_wrench()
        latest_sc = self.sc.latest()
        if latest_sc is not None and latest_sc is not self._sc:
            self._sc = latest_sc

    def _take_wrench(self) -> None:
        samples = self.tes.drain()
        if samples:
            self._wrench = samples[-1]

    # -------------------------------------------------------------------------------------------- loop
    def boot(self) -> None:
        """The boot-up heartbeat: State INIT, sent until the first SYNC (after the zenoh subscriptions are
        declared, so a rig that starts on it finds them)."""
        mode = self.controller.config.mode
        boot = {
            "State": int(ControllerState.INIT),
            "Mode": int(mode == "ihacs"),
            "FaultCode": 0,
            "Contract": CONTRACT_VERSION,
        }
        self.can.send(MessageName.CONTROLLER_HEARTBEAT, boot)

    def poll(self) -> None:
        """Handle every frame already queued, without waiting (a lockstep rig that drives the node from its
        own thread calls this right after each SYNC: no thread hand-off per tick)."""
        while (rx := self.can.recv(timeout=0.0)) is not None:
            self.handle(rx)

    def reset(self) -> None:
        """The run is over: back to INIT as at power-on (a fresh law, no tick, nothing heard), so the node
        serves the next run without a restart."""
        c = self.controller
        self.controller = Controller(c.config, c.robot, c.rider)
        self.tick, self.last_output = None, None
        self.estop = self.seat_flagged = self.stopped_alone = False
        self.supervisor_seen = self._still_since = None
        self._wrench, self._sc = None, None
        self.late = self._late_run = 0

    def run(self, stop: threading.Event, poll: float = 0.1, paused: threading.Event | None = None) -> None:
        """Receive until `stop` is set (recv blocks at most `poll` seconds, so stopping is prompt); while
        `paused` is set, take nothing in (a hung controller, for fault injection). A SYNC silent for RUN_OVER
        ends the run: the node starts over for the next (`reset`)."""
        next_boot = time.monotonic()
        while not stop.is_set():
            if paused is not None and paused.is_set():
                stop.wait(0.001)
                continue
            if self.tick is not None and time.monotonic() - self.synced_at > RUN_OVER:
                self.reset()
                next_boot = time.monotonic()
            if self.tick is None and time.monotonic() >= next_boot:
                self.boot()
                next_boot = time.monotonic() + BOOT_PERIOD
            rx = self.can.recv(timeout=min(poll, BOOT_PERIOD) if self.tick is None else poll)
            if rx is not None:
                self.handle(rx)
