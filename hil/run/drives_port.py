"""The drives' port (docs/rig.md "The drives' port"): the drives' side of the wire, one room.

Every frame the rig receives comes in here. The port hands the controller's commands for the expected tick to
the drives (in lockstep it waits for them), follows the supervisor's SUPERVISOR_ESTOP (the drives' permission
to run, the main contactor, the takeover) and, while the supervisor holds the drives, its recovery law's
torques instead of the controller's. `_drive` is the only code that writes a drive's command: the controller's
and the recovery law's torques take the same path. It keeps its own stop event and receive loop, so it needs
nothing of the rig that owns it.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from mypy_extensions import mypyc_attr

from drivers.can_bus import CanNode, Received
from drivers.can_codec import DRIVE_COMMAND, MessageName
from drivers.schemas import TICK_MODULO
from hil.run.lateness import Lateness
from plant.core import PlantCore

COMMANDS: dict[str, int] = {name: motor for motor, name in enumerate(DRIVE_COMMAND)}
"""Each drive's command frame (keyed by name as frames carry it: Received.name) -> its motor."""
RECOVERY_TORQUES = ("Torque1", "Torque2", "Torque3")
"""SUPERVISOR_RECOVERY's signals, drive by drive."""
STOP_POLL = 0.05
"""s: the longest a wait for a frame goes without looking whether the run was asked to stop."""


@dataclass(slots=True)
class TickStats:
    ticks: int = 0
    missing_commands: int = 0
    """Commands tagged with the current tick that did not arrive within the guard."""
    late_commands: int = 0
    """Commands tagged with an older tick (arrived after their tick was given up)."""
    guards_expired: int = 0
    """Lockstep ticks that waited out the whole wall-clock guard for the controller (a run under a fault
    must not wait tick after tick)."""
    controller_states: Counter[int] = field(default_factory=Counter)
    refused_commands: int = 0
    """Enabling commands the drives ignored because the supervisor had not given them permission."""
    permission_lost: int = 0
    """Times the drives lost their permission (e-stop asserted or the supervisor's frame went silent)."""
    permission_lost_at: list[float] = field(default_factory=list)
    """When, in simulated time."""
    supervisor_lost_at: list[float] = field(default_factory=list)
    """When the supervisor's frame went silent (the drives then follow the controller's own stop for
    `drive.supervisor_lost_grace`), in simulated time."""
    contactor_opened: int = 0
    """Times the main contactor opened (commanded open, or the supervisor's frame went silent)."""
    recovery_commands: int = 0
    """SUPERVISOR_RECOVERY frames the drives followed (the supervisor's takeover)."""
    overridden_commands: int = 0
    """The controller's commands the drives ignored because the recovery law held them."""


@mypyc_attr(allow_interpreted_subclasses=True)  # tests and benchmarks/realtime.py's probe subclass it
class DrivesPort:
    def __init__(
        self,
        plant: PlantCore,
        can: CanNode,
        command_guard: float = 1.0,
        recovery_in_commands: bool = False,
        stop: threading.Event | None = None,
    ) -> None:
        """recovery_in_commands: the supervisor's takeover reaches the drives in their own command frames (a
        device profile: docs/devices.md) rather than in SUPERVISOR_RECOVERY. stop: set when the run is to
        end (Ctrl-C, SIGTERM, `rig stop`): no wait for a frame, in the start-up or a tick, lasts beyond
        STOP_POLL after it (a guard of 1 s, a boot timeout of minutes)."""
        self.plant, self.can = plant, can
        self.command_guard = command_guard
        self.recovery_in_commands = recovery_in_commands
        self.stop = stop
        self.stats = TickStats()
        self.lateness = Lateness()
        """Real time: the ticks whose SYNC the rig sent late, and what they cost the controller."""
        self._held: deque[tuple[int, int, float, bool]] = deque()
        """Commands a loop-delay fault holds back: (due tick, drive, torque, enable)."""
        self._expected = -1
        """The tick whose commands the controller's frames are taken for (-1: none: a command then is not
        counted, as one before the first tick)."""
        self._expected_delay = 0
        self._pending: set[str] = set()
        """The expected tick's commands not yet here."""
        self.silent = False
        """The controller let a whole guard pass without a word: it is not waited for until it speaks."""
        self._answered = False
        """The controller has answered a tick: only then does silence count (a fresh process may take
        several guards to warm up, especially on an emulated CPU)."""
        drive = plant.robot.drive
        self.permission_timeout, self.contactor_timeout = drive.permission_timeout, drive.contactor_timeout
        self.supervisor_lost_grace = drive.supervisor_lost_grace
        self._supervisor_lost = False
        self._permission_seen = -math.inf
        self._supervisor_silent = False
        """An external supervisor let a whole guard pass without a frame: not waited for until heard."""
        self._estop_asserted = False
        self._contactor_commanded = False
        self.takeover = False
        """The last trusted SUPERVISOR_ESTOP announces the takeover: the drives follow SUPERVISOR_RECOVERY
        and ignore the controller."""
        self._recovery_tick = -1
        """Tick tag of the last SUPERVISOR_RECOVERY the drives followed."""
        self.safety_state = -1
        """SUPERVISOR_ESTOP.State of the last trusted frame (-1: none yet)."""
        self._permitted = False
        plant.drives.set_permission(False)  # both paths open until the supervisor's first frame
        plant.drives.set_contactor(False)

    @property
    def stopping(self) -> bool:
        """The run was asked to end."""
        return self.stop is not None and self.stop.is_set()

    # ----------------------------------------------------------------------------------------- the wire
    def recv_until(self, deadline: float) -> Received | None:
        """The next frame, waiting until `deadline` (time.monotonic()) at most, and not past a stop."""
        return self.can.recv(timeout=min(max(deadline - time.monotonic(), 0.0), STOP_POLL))

    def drain(self) -> None:
        """Take in every frame already on the bus, without waiting."""
        while (rx := self.can.recv(timeout=0.0)) is not None:
            self.frame(rx)

    def frame(self, rx: Received) -> None:
        """One received frame, whatever it is (a command outside a lockstep wait: the answer to the last SYNC
        as the tick's drain takes it in)."""
        if rx.name == MessageName.CONTROLLER_HEARTBEAT:
            self.stats.controller_states[int(rx.signals["State"])] += 1
        elif rx.name == MessageName.SUPERVISOR_ESTOP and rx.ok:
            self._permission_seen = self.plant.t
            self._supervisor_silent = False
            self._estop_asserted = bool(rx.signals["Estop"])
            self._contactor_commanded = bool(rx.signals["Contactor"])
            self.takeover = bool(rx.signals["Takeover"])
            self.safety_state = int(rx.signals["State"])
        elif rx.name == MessageName.SUPERVISOR_RECOVERY and rx.ok and self.takeover:
            self._recover(rx.signals)
        elif rx.name in COMMANDS and self.recovery_in_commands and self.takeover:
            self._recover_drive(COMMANDS[rx.name], rx.signals)
        elif rx.name in COMMANDS:
            self._accept(rx)
        elif rx.name == MessageName.SUPERVISOR_DIAGNOSIS and rx.ok:
            # What a seat, a handle or an operator's screen tells the rider.
            self.plant.alert(int(rx.signals["Alert"]))

    def end_tick(self) -> None:
        """The tick's last word on the drives: every frame that came in, the supervisor's permission."""
        self.drain()
        self.apply_permission()
        self.stats.ticks += 1

    # ------------------------------------------------------------------------------------- the drives
    def _drive(self, index: int, torque: float, enable: bool, recovery: bool = False) -> None:
        """The only write of a drive's command: the controller's, or (`recovery`) the supervisor's recovery
        law's. One master at a time: while the recovery law holds the drives the controller's are ignored."""
        if self.takeover and not recovery:
            self.stats.overridden_commands += 1
            return
        drive = self.plant.drives.motors[index]
        if not drive.permitted and enable and not recovery:
            self.stats.refused_commands += 1
        drive.set_command(torque, enable, self.plant.t)

    def _recover(self, signals: Mapping[str, float | int]) -> None:
        """The recovery law's torques, applied like a command (fresh ones only: no older than the drives'
        own watchdog, in ticks)."""
        tag = int(signals["Tick"])
        age = (self.plant.tick - tag) % TICK_MODULO
        if age * self.plant.dt > self.plant.robot.drive.watchdog_timeout:
            self.stats.late_commands += 1
            return
        self._recovery_tick = tag
        self.stats.recovery_commands += 1
        for index, name in enumerate(RECOVERY_TORQUES):
            self._drive(index, signals[name], True, recovery=True)

    def _recover_drive(self, index: int, signals: Mapping[str, float | int]) -> None:
        """One drive's recovery command, as a device profile carries it (the controller is silent under
        the takeover: every command frame is the supervisor's)."""
        self._recovery_tick = int(signals["Tick"])
        self.stats.recovery_commands += index == 0
        self._drive(index, signals["Torque"], bool(signals["Enable"]), recovery=True)

    def apply_permission(self) -> None:
        """The drives run only while the last trusted SUPERVISOR_ESTOP does not assert e-stop, and turn off
        `supervisor_lost_grace` after it went silent (before, the controller brakes to rest and turns them
        off itself); the main contactor stays closed only on one that says so, until its own timeout after
        the grace. Called every tick, and once before the first so the drives take the first commands."""
        drives, age = self.plant.drives, self.plant.t - self._permission_seen
        lost = math.isfinite(age) and age > self.permission_timeout + 1e-9
        if lost and not self._supervisor_lost:
            self.stats.supervisor_lost_at.append(self.plant.t)
        self._supervisor_lost = lost
        # A lost supervisor is not an e-stop: the drives follow the controller's own stop for the grace.
        grace = self.permission_timeout + self.supervisor_lost_grace
        permitted = age <= grace + 1e-9 and not self._estop_asserted
        if permitted != self._permitted:
            if not permitted:
                self.stats.permission_lost += 1
                self.stats.permission_lost_at.append(self.plant.t)
            drives.set_permission(permitted)
            self._permitted = permitted
        closed = age <= grace + self.contactor_timeout + 1e-9 and self._contactor_commanded
        if closed != drives.contactor_closed:
            drives.set_contactor(closed)
            self.stats.contactor_opened += not drives.contactor_closed

    # ------------------------------------------------------------------------ the controller's commands
    def collect(self, k: int, deadline: float, delay: int = 0) -> None:
        """Lockstep: hand the controller's commands for tick k to the drives, waiting until `deadline` at
        most. The tick is over when the heartbeat follows a command of this tick (the contract: commands,
        then the heartbeat), so a command lost on the way is counted missing at once instead of waited for.
        A controller that has answered before and then let a whole guard pass without a word is dead or
        hung: it is not waited for again until it is heard from (a run under such a fault takes about the
        wall time of its fault-free twin)."""
        self.expect(k, delay)
        heard = spoke = False
        """heard: a command tagged k arrived (the next heartbeat closes the tick); spoke: any frame of the
        controller arrived."""
        waiting = not self.silent
        while True:
            rx = self.recv_until(deadline)
            if rx is None:
                if time.monotonic() >= deadline:
                    self.stats.guards_expired += waiting
                    break
                if self.stopping:
                    self._expected = -1  # the run's last tick: what did not come is not counted missing
                    self._deliver_held(k)
                    return
                continue
            if rx.name not in COMMANDS or (self.takeover and self.recovery_in_commands):
                self.frame(rx)  # under a takeover with device profiles: the supervisor's commands
                if rx.name == MessageName.CONTROLLER_HEARTBEAT:
                    spoke = True
                    if heard or self.takeover:  # under a takeover it commands nothing
                        break
                continue
            spoke = True
            heard = self._accept(rx) or heard
        self.close_tick(take_queued=False)
        self._answered = self._answered or heard
        if spoke:
            self.silent = False
        elif self._answered:
            self.silent = True

    def expect(self, k: int, delay: int) -> None:
        """From now on the controller's commands tagged k are this tick's (applied `delay` ticks late: a
        loop-delay fault)."""
        self._expected, self._expected_delay = k, delay
        self._pending = set(COMMANDS)

    def _accept(self, rx: Received) -> bool:
        """A command frame of the controller's: applied if it is for the expected tick (True), else counted
        late (its tick is over: never applied)."""
        k = self._expected
        if not rx.ok or k < 0:
            return False
        tick = int(rx.signals["Tick"])
        if tick != k % TICK_MODULO:
            self.stats.late_commands += 1
            self.lateness.late += self.lateness.owns_tag(k, tick)
            return False
        index, torque, enable = COMMANDS[rx.name], rx.signals["Torque"], bool(rx.signals["Enable"])
        if self._expected_delay or self._held:
            # A late loop: a command never overtakes an earlier one.
            due = max(k + self._expected_delay, self._held[-1][0] if self._held else k)
            self._held.append((due, index, torque, enable))
        else:
            self._drive(index, torque, enable)
        self._pending.discard(rx.name)
        return True

    def close_tick(self, take_queued: bool = True) -> None:
        """The expected tick is over: its commands that came are taken in (`take_queued`: all that are queued
        now; lockstep has taken them already), the rest counted missing (the rig's, in one of its late
        windows), the held ones due delivered."""
        k = self._expected
        if k < 0:
            return
        if take_queued:
            self.drain()
        pending = len(self._pending)
        self.stats.missing_commands += pending
        if pending and self.lateness.owns(k):
            self.lateness.missing += pending
        self._deliver_held(k)
        self._expected = -1

    def _deliver_held(self, k: int) -> None:
        while self._held and self._held[0][0] <= k:
            _, index, torque, enable = self._held.popleft()
            self._drive(index, torque, enable)

    # ---------------------------------------------------------------------- a supervisor elsewhere
    def await_supervisor(self, k: int, deadline: float) -> None:
        """Lockstep beside a supervisor elsewhere (another process or thread): its SUPERVISOR_ESTOP frames
        are an output the loop waits for like the controller's commands, once the last one is half the
        permission timeout old in simulated time (a supervisor merely slower than the loop must not look
        dead to the drives); while it holds the drives, so is its recovery command for tick k. One that
        stays silent for a whole guard is not waited for again until it is heard from."""
        if not (
            self._supervisor_silent or self.plant.t - self._permission_seen < self.permission_timeout / 2
        ):
            seen = self._permission_seen
            self._take_supervisor_frames(lambda: self._permission_seen != seen, deadline)
        if self.takeover:
            tag = k % TICK_MODULO
            self._take_supervisor_frames(lambda: not self.takeover or self._recovery_tick == tag, deadline)

    def _take_supervisor_frames(self, done: Callable[[], bool], deadline: float) -> None:
        """Take in frames until `done()`; a supervisor silent until `deadline` is not waited for again
        until it is heard from (a commands frame that turns up is late: its tick is over, never applied)."""
        while not done() and not self._supervisor_silent:
            rx = self.recv_until(deadline)
            if rx is None:
                if time.monotonic() >= deadline:
                    self._supervisor_silent = True
                elif self.stopping:
                    return  # the run's last tick: nothing is waited for
                continue
            if rx.name in COMMANDS:
                self.stats.late_commands += 1
            else:
                self.frame(rx)
