"""The tick loop (docs/rig.md): the plant on one side, the controller under test on the wire on the other.

One tick k:
  1. the plant advances one tick under the torques the drives hold;
  2. sensors sample the truth;
  3. faults start or end, and alter the samples, frames and puts of the tick (hil/faults);
  4. the rig publishes the SC request of the schedule, any operator action due and the seat wrench (in
     lockstep then pure/rig/tick k with its put counts: the fence, drivers/zenoh_link.py `Fence`),
     sends drive feedback and IMU frames, then SYNC(k);
  5. it waits for the three drive commands tagged k (a driven in-process controller answers them from
     the rig's thread first) and hands them to the drives; in lockstep the tick
     is over when the controller's heartbeat follows its commands (a command lost on the way is counted
     missing, not waited for), and a controller that stayed silent for a whole wall-clock guard is not
     waited for again until it is heard from;
  6. the supervisor (in-process) updates from the same traffic; its SUPERVISOR_ESTOP frame is the drives'
     permission to run (they turn off when it asserts e-stop or goes silent), says who commands them
     (Takeover: its recovery law's SUPERVISOR_RECOVERY instead of the controller's DRIVEn_COMMAND, never
     both) and commands the main contactor in their power feed (it opens on Contactor = 0 or a longer
     silence);
  7. the recorder keeps the tick (the CAN log written from this thread; the trace row by the loop).
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import msgspec
from mypy_extensions import mypyc_attr

from drivers.can_bus import BusRecorder, CanNode, Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MessageName
from drivers.dut import DrivenDut, DutHandle
from drivers.plugs import Supervisor
from drivers.schemas import (
    TICK_MODULO,
    ControllerCommand,
    ControllerTelemetry,
    EstopCommand,
    Payload,
    SafetyState,
    ScRequest,
    TesWrench,
    encode,
)
from drivers.vocabulary import OPERATOR_ACTIONS_KEPT, Event, OperatorRecord, State
from drivers.zenoh_link import Subscription, ZenohLink
from hil.faults import FaultSet
from hil.outputs.inputs_log import InputsLog
from hil.run.lateness import Lateness
from plant.core import PlantCore
from plant.drives import DriveState, MotorDrive
from plant.sensors import DriveFeedback, ImuSample, TesSample

COMMANDS: dict[str, int] = {name: motor for motor, name in enumerate(DRIVE_COMMAND)}
"""Each drive's command frame (keyed by name as frames carry it: Received.name) -> its motor."""
TORQUE_EVERY = 4  # DRIVEn_TORQUE at 100 Hz on a 400 Hz tick (the DBC's GenMsgCycleTime)
TELEMETRY_CAPACITY = 1 << 12
"""Controller telemetry samples buffered between the loop's takes (hil/run/loop.py TELEMETRY_EVERY)."""
SC_REPEAT_EVERY = 40  # ticks between repeats of an unchanged SC request (keeps it fresh for the supervisor)
STOP_POLL = 0.05
"""s: the longest a wait for a frame goes without looking whether the run was asked to stop."""
SCENARIO_SOURCE = "scenario"
"""The source of the SC requests and operator actions the scenario schedules (a person's are theirs)."""


@dataclass(frozen=True, slots=True)
class ScStep:
    """From `tick` on, the shared controller asks for `request` (sent with its own seq and stamp)."""

    tick: int
    request: ScRequest


FREE_SCHEDULE = (ScStep(0, ScRequest(seq=0, stamp=0.0, mode="free", source=SCENARIO_SOURCE)),)
"""The schedule of a run that plans no SC request: the rider in charge throughout."""
OperatorAction = Literal["estop", "reset", "enable", "disable"]


@dataclass(frozen=True, slots=True)
class OperatorStep:
    """At `tick` the operator acts: estop or reset (pure/safety/estop), enable or disable the controller
    (pure/controller/command)."""

    tick: int
    action: OperatorAction


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


@dataclass(frozen=True, slots=True)
class AgentLinks:
    """The sessions the rig's scenario speaks through as the SC agent and the operator (secured bench)."""

    sc_agent: ZenohLink
    operator: ZenohLink


@mypyc_attr(allow_interpreted_subclasses=True)  # benchmarks/lockstep.py times its stages in a subclass
class Rig:
    def __init__(
        self,
        plant: PlantCore,
        can: CanNode,
        link: ZenohLink,
        sc_schedule: list[ScStep] | tuple[ScStep, ...] = FREE_SCHEDULE,
        command_guard: float = 1.0,
        supervisor: Supervisor | None = None,
        operator: list[OperatorStep] | tuple[OperatorStep, ...] = (),
        faults: FaultSet | None = None,
        bitrate: int = 1_000_000,
        agent_link: AgentLinks | None = None,
        recovery_in_commands: bool = False,
        dut: DutHandle | None = None,
        driven: bool = False,
        recorder: BusRecorder | None = None,
        inputs: InputsLog | None = None,
    ) -> None:
        """agent_link: where the scenario's SC requests and operator actions go out (`sc_agent`, `operator`
        links under those roles' certificates on a secured bench); None: the rig's own link.
        recovery_in_commands: the supervisor's takeover reaches the drives in their own command frames (a
        device profile: docs/devices.md) rather than in SUPERVISOR_RECOVERY.
        dut, driven: the in-process controller's handle, and whether the rig drives it from its tick
        (lockstep: its `poll()` right after SYNC). recorder: the CAN log. inputs: where the controller's
        zenoh inputs stream (None: kept in memory)."""
        self.plant, self.can, self.link = plant, can, link
        self.sc_link = link if agent_link is None else agent_link.sc_agent
        self.operator_link = link if agent_link is None else agent_link.operator
        self.keys = keys = link.keys
        self._logged_keys = frozenset((keys.tes_wrench, keys.sc_command, keys.controller_command))
        """The keys whose puts the inputs log keeps."""
        self.sc_schedule = sorted(sc_schedule, key=lambda s: s.tick)
        self.operator = sorted(operator, key=lambda s: s.tick)
        self.command_guard = command_guard
        self.supervisor = supervisor
        """In-process supervisor, updated every tick; None: a supervisor elsewhere on the bus."""
        self.dut = dut
        """The in-process controller's handle (process faults stop or pause it); None: external."""
        self.controller_contract: int | None = None
        """CONTROLLER_HEARTBEAT.Contract of the controller's boot-up (docs/contract.md, Versions)."""
        self.recorder = recorder
        """The CAN log, written at the end of every tick (polled: no thread woken for every frame)."""
        self.poll_dut: Callable[[], None] | None = dut.poll if driven and isinstance(dut, DrivenDut) else None
        """A driven in-process controller (drivers/dut.py, DutSpec.driven): called right after SYNC, it
        answers from this thread."""
        self.faults = faults if faults is not None else FaultSet()
        self.bitrate = bitrate
        self.stop: threading.Event | None = None
        """Set when the run is to end (Ctrl-C, SIGTERM, `rig stop`): no wait for a frame, in the start-up or
        a tick, lasts beyond STOP_POLL after it (a guard of 1 s, a boot timeout of minutes)."""
        self.recovery_in_commands = recovery_in_commands
        self._held: deque[tuple[int, int, float, bool]] = deque()
        """Commands a loop-delay fault holds back: (due tick, drive, torque, enable)."""
        self._expected = -1
        """The tick whose commands the controller's frames are taken for (-1: none: a command then is not
        counted, as one before the first tick)."""
        self._expected_delay = 0
        self._pending: set[str] = set()
        """The expected tick's commands not yet here."""
        self.stats = TickStats()
        self.lateness = Lateness()
        """Real time: the ticks whose SYNC the rig sent late, and what they cost the controller."""
        self.telemetry = link.subscribe(
            keys.controller_telemetry, ControllerTelemetry, capacity=TELEMETRY_CAPACITY
        )
        link.declare_publishers([keys.tes_wrench, keys.rig_tick])
        self.sc_link.declare_publishers([keys.sc_request])
        self.operator_link.declare_publishers([keys.safety_estop, keys.controller_command])
        self._seq: Counter[str] = Counter()
        self._sc_last: ScStep | None = None
        self._sc_sent_tick = -SC_REPEAT_EVERY
        self._operator_next = 0
        self._silent = False
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
        self.safety_states: Subscription[SafetyState] | None = (
            None if supervisor is not None else link.subscribe(keys.safety_state, SafetyState, capacity=256)
        )
        """With a supervisor in another process: its state as it announces it (every 0.1 s and at once on a
        transition), taken in every tick: a sample zenoh holds pins its network buffer, and a ring of
        thousands left to the run's end grew the rig's process by 0.45 MB/s and lost the oldest."""
        self.announced: list[Event] = []
        """The transitions `safety_states` announced so far."""
        self._announced_state = "NORMAL"
        self.operator_heard: Subscription[EstopCommand] | None = (
            None if supervisor is not None else link.subscribe(keys.safety_estop, EstopCommand, capacity=256)
        )
        """With a supervisor in another process: the operator commands the rig hears it sent (the embedded
        supervisor records those it takes in itself, `Supervisor.operator_actions`, drivers/plugs.py)."""
        self.operator_actions: list[OperatorRecord] = []
        """What `operator_heard` brought, with the supervisor's state as its last frame said."""
        self.operator_actions_dropped = 0
        self._permitted = False
        plant.drives.set_permission(False)  # both paths open until the supervisor's first frame
        plant.drives.set_contactor(False)
        self.inputs = inputs if inputs is not None else InputsLog()
        """Every (tick, key, payload) the controller was sent on zenoh, in the order it could see them
        (what `pure-hil replay` replays)."""
        if supervisor is not None:
            # What it puts at the end of tick k reaches the controller for tick k + 1.
            supervisor.on_put = lambda key, data: self._record(self.plant.tick + 1, key, data)

    def wait_for_subscriber(self, key: str, timeout: float = 10.0) -> bool:
        """Someone subscribes to `key` (the controller: the seat wrench; the supervisor: SC requests).
        Reads the bus while it waits: the supervisor announces itself at its frame rate until the first
        SYNC, and a socket left unread for seconds overflows, which its E2E counter then reports as lost
        or repeated frames (they alias beyond 8)."""
        link = self.sc_link if key == self.keys.sc_request else self.link
        deadline = time.monotonic() + timeout
        while not link.wait_for_subscriber(key, min(STOP_POLL, max(deadline - time.monotonic(), 0.0))):
            self.drain_bus()
            if time.monotonic() >= deadline or self.stopping:
                return False
        return True

    def drain_bus(self) -> None:
        """Take in every frame already on the bus, without waiting."""
        while (rx := self.can.recv(timeout=0.0)) is not None:
            self._other_frame(rx)

    def await_boot(self, timeout: float) -> str:
        """The start-up handshake, before the first SYNC: wait until the controller's boot-up heartbeat
        (CONTROLLER_HEARTBEAT, any state) and the supervisor's first SUPERVISOR_ESTOP have arrived.
        Returns '' or what is still missing after `timeout` seconds. The heartbeat's Contract goes to
        `controller_contract`."""
        deadline = time.monotonic() + timeout
        controller = supervisor = False
        while True:
            missing = [
                what
                for what, seen in (
                    ("the controller's boot-up (CONTROLLER_HEARTBEAT)", controller),
                    ("the supervisor's first SUPERVISOR_ESTOP", supervisor),
                )
                if not seen
            ]
            remaining = deadline - time.monotonic()
            if not missing or remaining <= 0 or self.stopping:
                return " and ".join(missing)
            rx = self.can.recv(timeout=min(remaining, STOP_POLL))
            if rx is None:
                continue
            self._other_frame(rx)
            if rx.name == MessageName.CONTROLLER_HEARTBEAT and not controller:
                controller, self.controller_contract = True, int(rx.signals["Contract"])
            supervisor = supervisor or (rx.name == MessageName.SUPERVISOR_ESTOP and rx.ok)

    @property
    def stopping(self) -> bool:
        """The run was asked to end."""
        return self.stop is not None and self.stop.is_set()

    def _recv_until(self, deadline: float) -> Received | None:
        """The next frame, waiting until `deadline` at most, and not past a stop request."""
        return self.can.recv(timeout=min(max(deadline - time.monotonic(), 0.0), STOP_POLL))

    def tick(self, deadline: float | None = None, lockstep: bool = True, sync_due: float = math.inf) -> None:
        """One tick. Lockstep: wait for the controller's answer until `deadline` (time.monotonic()), and for
        the heartbeat that follows the commands, so every frame of tick k is on the bus before tick k + 1
        starts (a deterministic CAN log).

        Real time: nothing is waited for. The controller has until the next tick starts (docs/contract.md):
        that tick takes first what it answered, then steps the plant under it (the drives hold a command
        for the tick after its own either way). A SYNC sent after `sync_due` (time.monotonic()) makes the
        tick one of the rig's late ones (hil/run/lateness.py).
        """
        plant, faults = self.plant, self.faults
        if not lockstep:
            self._close_tick()
        plant.step()
        k = plant.tick
        faults.update(k, plant.t)
        feedback, imu, tes, silent = self._sample()
        if lockstep:  # the fence counts the tick's puts: they go before it, and it before SYNC
            self._publish_zenoh(k, tes)
            self.link.put_fence(k, plant.t)
        self._send_sensors(k, feedback, imu, silent)
        faults.flush(plant.t)
        self._send_sync(k, sync_due)
        if not lockstep:
            # After SYNC: a put wakes zenoh's sending thread, which takes the rig's core from it at once
            # (perf sched, docs/performance.md "Real time"); the controller reads the newest seat sample.
            self._publish_zenoh(k, tes)
        guard = time.monotonic() + self.command_guard if deadline is None else deadline
        if self.poll_dut is not None:
            self.poll_dut()  # driven: what it answers is queued when poll() returns, or it is not coming
        if lockstep:
            # Neither a driven controller nor a silent one is waited for: take what is queued.
            waiting = self.poll_dut is None and not self._silent
            self._collect_commands(k, guard if waiting else time.monotonic(), faults.command_delay())
            self._deliver_held(k)
        else:
            self._expect(k, faults.command_delay())
        self._supervise(k, guard, lockstep)
        self.drain_bus()
        self.apply_permission()
        if self.recorder is not None:
            self.recorder.poll()
        self.stats.ticks += 1

    def _supervise(self, k: int, guard: float, lockstep: bool) -> None:
        """The supervisor's part of tick k: the in-process one updates from the tick's traffic; in lockstep
        one elsewhere is waited for (its permission, and its recovery commands while it holds the drives)."""
        if self.supervisor is not None:
            self.supervisor.update(self.plant.t, fence=k if lockstep else None)
            return
        self.hear_operator()
        self.hear_announcements()
        if lockstep:
            self._await_supervisor(guard)
            if self.takeover:
                self._await_recovery(k, guard)

    def hear_operator(self) -> None:
        """The operator commands sent to a supervisor elsewhere, each with the state it was last heard in."""
        heard = self.operator_heard
        for cmd in heard.drain() if heard is not None else ():
            if len(self.operator_actions) >= OPERATOR_ACTIONS_KEPT:
                self.operator_actions_dropped += 1
                continue
            state = State(self.safety_state).name if self.safety_state >= 0 else "none"
            self.operator_actions.append(OperatorRecord(self.plant.t, cmd.action, cmd.source, state))

    def hear_announcements(self) -> None:
        """A supervisor elsewhere's transitions, from its pure/safety/state announcements."""
        for s in self.safety_states.drain() if self.safety_states is not None else ():
            if s.state != self._announced_state:
                reason = s.reason.split(" ")[0]
                self.announced.append(Event(s.since, "transition", self._announced_state, s.state, reason))
                self._announced_state = s.state

    # ------------------------------------------------------------------------------------------ outputs
    def _sample(self) -> tuple[Sequence[DriveFeedback], ImuSample, TesSample, set[str]]:
        """The sensors' outputs of this tick as the (maybe faulty) sensors report them, and the frames
        that stay silent."""
        plant = self.plant
        feedback, imu, tes = plant.sample_drives(), plant.sample_imu(), plant.sample_tes()
        if self.faults.sensing:
            return self.faults.sensors(plant, feedback, imu, tes)
        return feedback, imu, tes, set()

    def _send_sensors(
        self, k: int, feedback: Sequence[DriveFeedback], imu: ImuSample, silent: set[str]
    ) -> None:
        plant, send = self.plant, self.can.send
        for name, fb, motor in zip(DRIVE_FEEDBACK, feedback, plant.drives.motors, strict=True):
            if silent and name in silent:
                continue
            send(
                name,
                {
                    "Position": fb.counts,
                    "Velocity": fb.velocity,
                    "Enabled": int(motor.state is DriveState.ENABLED),
                    "WatchdogTripped": int(motor.state is DriveState.WATCHDOG),
                    "BusPowered": int(motor.bus_powered),
                },
            )
        if k % TORQUE_EVERY == 0:
            for name, fb in zip(DRIVE_TORQUE, feedback, strict=True):
                if not (silent and name in silent):
                    send(name, {"Torque": fb.torque})
        (roll, pitch, yaw), (rx, ry, rz), (ax, ay, az) = imu.attitude, imu.rate, imu.accel
        frames = (
            (MessageName.IMU_ATTITUDE, {"Roll": roll, "Pitch": pitch, "Yaw": yaw, "Valid": 1}),
            (MessageName.IMU_RATE, {"RateX": rx, "RateY": ry, "RateZ": rz, "Valid": 1}),
            (MessageName.IMU_ACCEL, {"AccX": ax, "AccY": ay, "AccZ": az, "Valid": 1}),
        )
        for name, signals in frames:
            if not (silent and name in silent):
                send(name, signals)

    def _record(self, k: int, key: str, data: bytes) -> None:
        if key in self._logged_keys:
            self.inputs.append(k, key, data)

    def _put(self, k: int, key: str, payload: Payload, link: ZenohLink | None = None) -> None:
        self._put_bytes(k, key, encode(payload), link)

    def _put_bytes(self, k: int, key: str, data: bytes, link: ZenohLink | None = None) -> None:
        (link or self.link).put_bytes(key, data, tick=k)
        self._record(k, key, data)

    def _next_seq(self, key: str) -> int:
        self._seq[key] += 1
        return self._seq[key]

    def _send_sync(self, k: int, due: float) -> None:
        """SYNC(k), and whether it went out after `due` (time.monotonic(); inf in lockstep)."""
        self.can.send(MessageName.SYNC, {"Tick": k % TICK_MODULO})
        if due != math.inf:
            plant = self.plant
            self.lateness.sync(k, plant.t, plant.dt, time.monotonic() - due)

    def _publish_zenoh(self, k: int, tes: TesSample) -> None:
        """The tick's zenoh puts: the SC request, operator actions, the seat's wrench, fault traffic."""
        self._publish_sc_request(k)
        self._publish_operator()
        self._publish_tes(k, tes)
        if self.faults:
            self._publish_fault_traffic(k)

    def _publish_tes(self, k: int, s: TesSample) -> None:
        """Publish the seat sample of tick k (as seat faults alter it)."""
        key = self.keys.tes_wrench
        payload = TesWrench(
            seq=k, stamp=self.plant.t, force=s.force, moment=s.moment, cop=s.cop, cells=s.cells
        )
        data = encode(payload)
        for d in self.faults.wrench(payload, data) if self.faults.topical else [data]:
            self._put_bytes(k, key, d)

    def _publish_fault_traffic(self, k: int) -> None:
        for key, data in self.faults.extra_puts():
            self._put_bytes(k, key, data)

    def _publish_sc_request(self, k: int) -> None:
        current = None
        for step in self.sc_schedule:
            if step.tick <= k:
                current = step
        if current is None:
            return
        if current is self._sc_last and k - self._sc_sent_tick < SC_REPEAT_EVERY:
            return
        key = self.keys.sc_request
        request = msgspec.structs.replace(current.request, seq=self._next_seq(key), stamp=self.plant.t)
        self._put(k, key, request, self.sc_link)
        self._sc_last, self._sc_sent_tick = current, k

    def _publish_operator(self) -> None:
        k, t = self.plant.tick, self.plant.t
        while self._operator_next < len(self.operator) and self.operator[self._operator_next].tick <= k:
            action = self.operator[self._operator_next].action
            self._operator_next += 1
            command: EstopCommand | ControllerCommand
            if action == "estop" or action == "reset":
                key = self.keys.safety_estop
                command = EstopCommand(
                    seq=self._next_seq(key), stamp=t, action=action, source=SCENARIO_SOURCE
                )
            else:
                key = self.keys.controller_command
                command = ControllerCommand(
                    seq=self._next_seq(key), stamp=t, action=action, source=SCENARIO_SOURCE
                )
            self._put(k, key, command, self.operator_link)

    # ------------------------------------------------------------------------------------- permission
    def _await_supervisor(self, deadline: float) -> None:
        """Lockstep beside a supervisor elsewhere (another process or thread): its SUPERVISOR_ESTOP frames
        are an output the loop waits for like the controller's commands, once the last one is half the
        permission timeout old in simulated time; a supervisor merely slower than the loop must not look
        dead to the drives. One that stays silent for a whole guard is not waited for again until heard."""
        if self._supervisor_silent or self.plant.t - self._permission_seen < self.permission_timeout / 2:
            return
        seen = self._permission_seen
        self._take_supervisor_frames(lambda: self._permission_seen != seen, deadline)

    def _await_recovery(self, k: int, deadline: float) -> None:
        """Lockstep beside a supervisor elsewhere that holds the drives: its recovery command for tick k is
        an output the loop waits for, like the controller's."""
        tag = k % TICK_MODULO
        self._take_supervisor_frames(lambda: not self.takeover or self._recovery_tick == tag, deadline)

    def _take_supervisor_frames(self, done: Callable[[], bool], deadline: float) -> None:
        """Take in frames until `done()`; a supervisor silent until `deadline` is not waited for again
        until it is heard from (a commands frame that turns up is late: its tick is over, never applied)."""
        while not done() and not self._supervisor_silent:
            rx = self._recv_until(deadline)
            if rx is None:
                if time.monotonic() >= deadline:
                    self._supervisor_silent = True
                elif self.stopping:
                    return  # the run's last tick: nothing is waited for
                continue
            if rx.name in COMMANDS:
                self.stats.late_commands += 1
            else:
                self._other_frame(rx)

    def _other_frame(self, rx: Received) -> None:
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
            self._accept(rx)  # real time: the answer to the last SYNC as the tick's drain takes it in
        elif rx.name == MessageName.SUPERVISOR_DIAGNOSIS and rx.ok:
            # What a seat, a handle or an operator's screen tells the rider.
            self.plant.alert(int(rx.signals["Alert"]))

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
        now = self.plant.t
        for drive, name in zip(self.plant.drives.motors, ("Torque1", "Torque2", "Torque3"), strict=True):
            drive.set_command(signals[name], True, now)

    def _recover_drive(self, index: int, signals: Mapping[str, float | int]) -> None:
        """One drive's recovery command, as a device profile carries it (the controller is silent under
        the takeover: every command frame is the supervisor's)."""
        self._recovery_tick = int(signals["Tick"])
        self.stats.recovery_commands += index == 0
        self.plant.drives.motors[index].set_command(signals["Torque"], bool(signals["Enable"]), self.plant.t)

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

    # ------------------------------------------------------------------------------------------- inputs
    def _collect_commands(self, k: int, deadline: float, delay: int = 0) -> None:
        """Lockstep: hand the controller's commands for tick k to the drives, waiting until `deadline` at
        most. The tick is over when the heartbeat follows a command of this tick (the contract: commands,
        then the heartbeat), so a command lost on the way is counted missing at once instead of waited for.
        A controller that has answered before and then let a whole guard pass without a word is dead or
        hung: it is not waited for again until it is heard from (a run under such a fault takes about the
        wall time of its fault-free twin)."""
        self._expect(k, delay)
        heard = spoke = False
        """heard: a command tagged k arrived (the next heartbeat closes the tick); spoke: any frame of the
        controller arrived."""
        waiting = not self._silent
        while True:
            rx = self._recv_until(deadline)
            if rx is None:
                if time.monotonic() >= deadline:
                    self.stats.guards_expired += waiting
                    break
                if self.stopping:
                    self._expected = -1
                    return  # the run's last tick: what did not come is not counted missing
                continue
            if rx.name not in COMMANDS or (self.takeover and self.recovery_in_commands):
                self._other_frame(rx)  # under a takeover with device profiles: the supervisor's commands
                if rx.name == MessageName.CONTROLLER_HEARTBEAT:
                    spoke = True
                    if heard or self.takeover:  # under a takeover it commands nothing
                        break
                continue
            spoke = True
            heard = self._accept(rx) or heard
        self._close_tick(take_queued=False)
        self._answered = self._answered or heard
        if spoke:
            self._silent = False
        elif self._answered:
            self._silent = True

    def _expect(self, k: int, delay: int) -> None:
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
            self._command(self.plant.drives.motors[index], torque, enable)
        self._pending.discard(rx.name)
        return True

    def _close_tick(self, take_queued: bool = True) -> None:
        """The expected tick is over: its commands that came are taken in (`take_queued`: all that are queued
        now; lockstep has taken them already), the rest counted missing (the rig's, in one of its late
        windows), the held ones due delivered."""
        k = self._expected
        if k < 0:
            return
        if take_queued:
            self.drain_bus()
        pending = len(self._pending)
        self.stats.missing_commands += pending
        if pending and self.lateness.owns(k):
            self.lateness.missing += pending
        self._deliver_held(k)
        self._expected = -1

    def _command(self, drive: MotorDrive, torque: float, enable: bool) -> None:
        if self.takeover:
            self.stats.overridden_commands += 1  # one master at a time: the recovery law holds the drives
            return
        if not drive.permitted and enable:
            self.stats.refused_commands += 1
        drive.set_command(torque, enable, self.plant.t)

    def _deliver_held(self, k: int) -> None:
        drives = self.plant.drives.motors
        while self._held and self._held[0][0] <= k:
            _, index, torque, enable = self._held.popleft()
            self._command(drives[index], torque, enable)
