"""The tick loop (docs/rig.md): the plant on one side, the controller under test on the wire on the other.

One tick k:
  1. the plant advances one tick under the torques the drives hold;
  2. sensors sample the truth;
  3. faults start or end, and alter the samples, frames and puts of the tick (hil/faults);
  4. the rig publishes the scenario's SC request and operator actions due (hil/run/agents.py) and the seat
     wrench (in lockstep then pure/rig/tick k with its put counts: the fence, drivers/zenoh_link.py
     `Fence`; in real time after SYNC), sends drive feedback and IMU frames, then SYNC(k);
  5. the drives' port (hil/run/drives_port.py) takes the three drive commands tagged k (a driven
     in-process controller answers them from the rig's thread first; lockstep waits for them) and hands
     them to the drives;
  6. the supervisor (in-process) updates from the same traffic; its SUPERVISOR_ESTOP frame, through the
     port, is the drives' permission to run, says who commands them (the takeover) and commands the main
     contactor;
  7. the recorder keeps the tick (the CAN log written from this thread; the trace row by the loop).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from mypy_extensions import mypyc_attr

from drivers.can_bus import BusRecorder
from drivers.can_codec import DRIVE_FEEDBACK, DRIVE_TORQUE, MessageName
from drivers.dut import DrivenDut, DutHandle
from drivers.plugs import Supervisor
from drivers.schemas import (
    TICK_MODULO,
    ControllerTelemetry,
    EstopCommand,
    Payload,
    SafetyState,
    TesWrench,
    encode,
)
from drivers.vocabulary import OPERATOR_ACTIONS_KEPT, Event, OperatorRecord, State
from drivers.zenoh_link import Subscription, ZenohLink
from hil.faults import FaultSet
from hil.outputs.inputs_log import InputsLog
from hil.run.agents import FREE_SCHEDULE, AgentLinks, OperatorStep, ScenarioAgents, ScStep
from hil.run.drives_port import STOP_POLL, DrivesPort
from plant.drives import DriveState
from plant.sensors import DriveFeedback, ImuSample, TesSample

TORQUE_EVERY = 4  # DRIVEn_TORQUE at 100 Hz on a 400 Hz tick (the DBC's GenMsgCycleTime)
TELEMETRY_CAPACITY = 1 << 12
"""Controller telemetry samples buffered between the loop's takes (hil/run/loop.py TELEMETRY_EVERY)."""


@dataclass(frozen=True, slots=True)
class RigParts:
    """What a rig is made of (hil/run/build.py `build` assembles it)."""

    port: DrivesPort
    """The drives' side of the wire: every frame the rig receives, what reaches the drives."""
    link: ZenohLink
    sc_schedule: Sequence[ScStep] = FREE_SCHEDULE
    supervisor: Supervisor | None = None
    """In-process supervisor, updated every tick; None: a supervisor elsewhere on the bus."""
    operator: Sequence[OperatorStep] = ()
    faults: FaultSet = field(default_factory=FaultSet)
    bitrate: int = 1_000_000
    agent_link: AgentLinks | None = None
    """Where the scenario's SC requests and operator actions go out (`sc_agent`, `operator` links under
    those roles' certificates on a secured bench); None: the rig's own link."""
    dut: DutHandle | None = None
    """The in-process controller's handle (process faults stop or pause it); None: external."""
    driven: bool = False
    """The rig drives the in-process controller from its tick (lockstep: its `poll()` right after SYNC)."""
    recorder: BusRecorder | None = None
    """The CAN log, written at the end of every tick (polled: no thread woken for every frame)."""
    inputs: InputsLog | None = None
    """Where the controller's zenoh inputs stream (None: kept in memory)."""


@mypyc_attr(allow_interpreted_subclasses=True)  # benchmarks/lockstep.py times its stages in a subclass
class Rig:
    def __init__(self, parts: RigParts) -> None:
        port, link, supervisor = parts.port, parts.link, parts.supervisor
        self.port = port
        self.plant, self.can, self.link = port.plant, port.can, link
        self.keys = keys = link.keys
        self._logged_keys = frozenset((keys.tes_wrench, keys.sc_command, keys.controller_command))
        """The keys whose puts the inputs log keeps."""
        self.supervisor = supervisor
        self.dut = dut = parts.dut
        self.controller_contract: int | None = None
        """CONTROLLER_HEARTBEAT.Contract of the controller's boot-up (docs/contract.md, Versions)."""
        self.recorder = parts.recorder
        self.poll_dut: Callable[[], None] | None = (
            dut.poll if parts.driven and isinstance(dut, DrivenDut) else None
        )
        """A driven in-process controller (drivers/dut.py, DutSpec.driven): called right after SYNC, it
        answers from this thread."""
        self.faults = parts.faults
        self.bitrate = parts.bitrate
        self.telemetry = link.subscribe(
            keys.controller_telemetry, ControllerTelemetry, capacity=TELEMETRY_CAPACITY
        )
        link.declare_publishers([keys.tes_wrench, keys.rig_tick])
        self.agents = ScenarioAgents(link, parts.sc_schedule, parts.operator, parts.agent_link, self._put)
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
        self.inputs = parts.inputs if parts.inputs is not None else InputsLog()
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
        link = self.agents.sc_link if key == self.keys.sc_request else self.link
        deadline = time.monotonic() + timeout
        while not link.wait_for_subscriber(key, min(STOP_POLL, max(deadline - time.monotonic(), 0.0))):
            self.port.drain()
            if time.monotonic() >= deadline or self.port.stopping:
                return False
        return True

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
            if not missing or time.monotonic() >= deadline or self.port.stopping:
                return " and ".join(missing)
            rx = self.port.recv_until(deadline)
            if rx is None:
                continue
            self.port.frame(rx)
            if rx.name == MessageName.CONTROLLER_HEARTBEAT and not controller:
                controller, self.controller_contract = True, int(rx.signals["Contract"])
            supervisor = supervisor or (rx.name == MessageName.SUPERVISOR_ESTOP and rx.ok)

    def tick(self, deadline: float | None = None, lockstep: bool = True, sync_due: float = math.inf) -> None:
        """One tick. Lockstep: wait for the controller's answer until `deadline` (time.monotonic()), and for
        the heartbeat that follows the commands, so every frame of tick k is on the bus before tick k + 1
        starts (a deterministic CAN log).

        Real time: nothing is waited for. The controller has until the next tick starts (docs/contract.md):
        that tick takes first what it answered, then steps the plant under it (the drives hold a command
        for the tick after its own either way). A SYNC sent after `sync_due` (time.monotonic()) makes the
        tick one of the rig's late ones (hil/run/lateness.py).
        """
        plant, faults, port = self.plant, self.faults, self.port
        if not lockstep:
            port.close_tick()  # what the controller answered to the last SYNC
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
        guard = time.monotonic() + port.command_guard if deadline is None else deadline
        if self.poll_dut is not None:
            self.poll_dut()  # driven: what it answers is queued when poll() returns, or it is not coming
        if lockstep:
            # Neither a driven controller nor a silent one is waited for: take what is queued.
            waiting = self.poll_dut is None and not port.silent
            port.collect(k, guard if waiting else time.monotonic(), faults.command_delay())
        else:
            port.expect(k, faults.command_delay())
        self._supervise(k, guard, lockstep)
        port.end_tick()
        if self.recorder is not None:
            self.recorder.poll()

    def _supervise(self, k: int, guard: float, lockstep: bool) -> None:
        """The supervisor's part of tick k: the in-process one updates from the tick's traffic; in lockstep
        one elsewhere is waited for (its permission, and its recovery commands while it holds the drives)."""
        if self.supervisor is not None:
            self.supervisor.update(self.plant.t, fence=k if lockstep else None)
            return
        self.hear_operator()
        self.hear_announcements()
        if lockstep:
            self.port.await_supervisor(k, guard)

    def hear_operator(self) -> None:
        """The operator commands sent to a supervisor elsewhere, each with the state it was last heard in."""
        heard = self.operator_heard
        for cmd in heard.drain() if heard is not None else ():
            if len(self.operator_actions) >= OPERATOR_ACTIONS_KEPT:
                self.operator_actions_dropped += 1
                continue
            safety = self.port.safety_state
            state = State(safety).name if safety >= 0 else "none"
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

    def _put(self, k: int, key: str, payload: Payload, link: ZenohLink) -> None:
        self._put_bytes(k, key, encode(payload), link)

    def _put_bytes(self, k: int, key: str, data: bytes, link: ZenohLink | None = None) -> None:
        (link or self.link).put(key, data, tick=k)
        self._record(k, key, data)

    def _send_sync(self, k: int, due: float) -> None:
        """SYNC(k), and whether it went out after `due` (time.monotonic(); inf in lockstep)."""
        self.can.send(MessageName.SYNC, {"Tick": k % TICK_MODULO})
        if due != math.inf:
            plant = self.plant
            self.port.lateness.sync(k, plant.t, plant.dt, time.monotonic() - due)

    def _publish_zenoh(self, k: int, tes: TesSample) -> None:
        """The tick's zenoh puts: the SC request, operator actions, the seat's wrench, fault traffic."""
        self.agents.publish(k, self.plant.t)
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
