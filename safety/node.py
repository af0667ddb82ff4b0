"""The supervisor on the wire: a thin adapter around the state machine.

In: every CAN frame (drive feedback, IMU, torque commands and measured torques, heartbeat, the wired
e-stop), and on zenoh the SC requests, operator e-stop/reset and the seat wrench. Out: SUPERVISOR_ESTOP
(the drives' permission to run, the takeover and the main contactor's command, every 10 ms and at once on a
transition), SUPERVISOR_DIAGNOSIS (the inputs found faulty and the rider alert, likewise), while the recovery
law holds the drives SUPERVISOR_RECOVERY every update, pure/sc/command (the only SC input the controller
reads), pure/safety/state, pure/safety/alert, and the event log.

In the rig it updates once per tick after the controller has answered (`update(t, fence=k)`: in lockstep it
first waits for the rig's fence of tick k, so every zenoh input of tick k has arrived, whatever a fault did
to them); standalone it runs on its own timer (`run`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import cast

import msgspec

from drivers.can_bus import CanNode, Received
from drivers.can_codec import PARTS, MessageName
from drivers.plugs import SupervisorReport
from drivers.robot import RobotModel
from drivers.schemas import (
    TICK_MODULO,
    EstopCommand,
    Payload,
    SafetyAlert,
    SafetyState,
    ScCommand,
    ScRequest,
    TesWrench,
    encode,
)
from drivers.vocabulary import (
    OPERATOR_ACTIONS_KEPT,
    Cause,
    Event,
    OperatorCommand,
    OperatorRecord,
    State,
    StateName,
)
from drivers.zenoh_link import Fence, ZenohLink
from safety.config import SupervisorConfig
from safety.machine import Decision, SafetyMachine
from safety.monitors import Monitors
from safety.observation import Observation
from safety.recovery import RecoveryLaw

log = logging.getLogger(__name__)

BUTTON = "button"
"""The source of a wired e-stop button's press (the OPERATOR_ESTOP frame carries no source)."""


class SupervisorNode:
    def __init__(
        self,
        can: CanNode,
        link: ZenohLink,
        config: SupervisorConfig | None = None,
        robot: RobotModel | None = None,
        tick_hz: float = 400.0,
        fence_wait: float = 0.5,
        on_put: Callable[[str, bytes], None] | None = None,
        stage_read_back: bool = True,
    ):
        self.config = config = config or SupervisorConfig()
        robot = robot or RobotModel()
        self.can, self.link, self.keys = can, link, link.keys
        self.machine = SafetyMachine(
            config, robot.drive.torque_limit, robot.drive.watchdog_timeout, stage_read_back=stage_read_back
        )
        self.monitors = Monitors(config, robot, tick_hz)
        self.recovery = RecoveryLaw(robot, config.recovery)
        self.recovery_torques: tuple[float, float, float] | None = None
        """What the recovery law commanded at the last update (None: it does not hold the drives)."""
        self.tick_hz, self.fence_wait, self.on_put = tick_hz, fence_wait, on_put
        keys = self.keys
        self.requests = link.subscribe(keys.sc_request, ScRequest, capacity=256)
        self.operator = link.subscribe(keys.safety_estop, EstopCommand, capacity=64)
        self.wrench = link.subscribe(keys.tes_wrench, TesWrench, capacity=64)
        self.fence = Fence(link, [self.requests, self.operator, self.wrench])
        link.declare_publishers([keys.sc_command, keys.safety_state, keys.safety_alert])
        self.decision: Decision | None = None
        self.observation: Observation | None = None
        """What the last update saw (the rig records its speed estimate next to the truth)."""
        self.tick: int | None = None
        self.fence_misses = 0
        """Lockstep updates that went ahead without every zenoh input of their tick (the guard ran out)."""
        self._events_seen = 0
        self._sc_seq = self._state_seq = self._alert_seq = 0
        self._diagnosis: dict[str, int] = {}
        """The diagnosis last sent."""
        self._diagnosis_now: dict[str, int] = {}
        self._diagnosis_shown: tuple[frozenset[str], int] | None = None
        """What `_diagnosis_now` shows: (the parts named, the alert)."""
        self._frame_sent = self._sc_sent = self._state_sent = -math.inf
        self._forwarded: ScCommand | None = None
        self._estop_by = ""
        self.operator_actions: list[OperatorRecord] = []
        """Every operator command taken in, whatever the state (the first OPERATOR_ACTIONS_KEPT of them)."""
        self.operator_actions_dropped = 0
        """Operator commands beyond OPERATOR_ACTIONS_KEPT: counted, not kept."""
        self._button = False

    @property
    def events(self) -> list[Event]:
        return self.machine.events

    # ---------------------------------------------------------------------------------------- inputs
    def frame(self, rx: Received, t: float) -> None:
        if rx.name == MessageName.SYNC:
            raw = int(rx.signals["Tick"])
            self.tick = raw if self.tick is None else self.tick + (raw - self.tick) % TICK_MODULO
            return
        self.monitors.frame(rx, t)

    def _drain_can(self, t: float) -> None:
        while (rx := self.can.recv(timeout=0.0)) is not None:
            self.frame(rx, t)

    def _drain_zenoh(self, t: float, fence: int | None) -> None:
        if fence is not None and not self.fence.wait(fence, self.fence_wait):
            self.fence_misses += 1
        for w in self.wrench.drain(fence):
            self.monitors.wrench(w, t)
        for r in self.requests.drain(fence):
            self.monitors.sc_request(r, t)
        for cmd in self.operator.drain(fence):
            log.warning("operator %s from %s", cmd.action, cmd.source)
            self._operator_action(t, cmd.action, cmd.source)
            self.monitors.operator_command(cmd)

    def _take_button(self, t: float) -> None:
        """A wired e-stop button's press is an operator action too (its release resets nothing)."""
        if self.monitors.button != self._button:
            self._button = self.monitors.button
            if self._button:
                self._operator_action(t, "estop", BUTTON)

    def _operator_action(self, t: float, action: OperatorCommand, source: str) -> None:
        if len(self.operator_actions) >= OPERATOR_ACTIONS_KEPT:
            self.operator_actions_dropped += 1
            return
        self.operator_actions.append(OperatorRecord(t, action, source, self.machine.state.name))

    # ------------------------------------------------------------------------------- as a plug reports
    def observed_speed(self) -> float | None:
        """The ground speed judged at the last update, m/s (drivers.plugs.Supervisor)."""
        return None if self.observation is None else self.observation.speed

    def report(self) -> SupervisorReport:
        return SupervisorReport(
            identity_rejected=dict(self.monitors.rejected_identity),
            diagnostics=self.monitors.margins(),
            sc_arbitration=self.monitors.sc.summary(),
        )

    # --------------------------------------------------------------------------------------- decide
    def update(self, t: float, fence: int | None = None, take_can: bool = True) -> Decision:
        """Take in everything that arrived, decide, and emit what is due at time t (`take_can` False: the
        caller has fed the CAN frames up to this tick's SYNC itself, and later ones wait for their update)."""
        if take_can:
            self._drain_can(t)
        self._drain_zenoh(t, fence)
        self._take_button(t)
        self.observation = self.monitors.observe(t)
        decision = self.machine.update(self.observation)
        changed, refused = False, ""
        if len(self.machine.events) > self._events_seen:  # most updates make no event
            changed, refused = self._take_events()
        self.decision = decision
        self._emit(t, decision, changed, refused)
        return decision

    def _take_events(self) -> tuple[bool, str]:
        """Act on the machine's new events and log them: whether the state or the contactor changed, and
        why the last reset was refused ('' none)."""
        new = self.machine.events[self._events_seen :]
        self._events_seen = len(self.machine.events)
        changed = any(e.kind in ("transition", "contactor_opened") for e in new)
        if any(e.kind == "transition" and e.to_state == State.RECOVERY.name for e in new):
            self.monitors.isolated.engage()
            self.recovery.design(self.monitors.seat_load)
        if any(e.kind == "transition" and e.cause == "RESET" for e in new):
            self.monitors.reset()
        refused = next((e.detail for e in reversed(new) if e.kind == "reset_refused"), "")
        for event in new:
            log.warning(
                "supervisor %s at t=%.3f: %s -> %s (%s) %s",
                event.kind,
                event.t,
                event.from_state,
                event.to_state,
                event.cause,
                event.detail,
            )
        return changed, refused

    def _emit(self, t: float, d: Decision, changed: bool, refused: str = "") -> None:
        out = self.config.output
        diagnosis = self._diagnosis_signals(d)
        if changed or diagnosis != self._diagnosis or t - self._frame_sent >= out.estop_frame_period - 1e-9:
            self._send_frame(d.state, d.cause, d.contactor_closed, d.takeover)
            self.can.send(MessageName.SUPERVISOR_DIAGNOSIS, diagnosis)
            self._diagnosis = diagnosis
            self._frame_sent = t
        self._recover(d)
        stamp = self._stamp(t)
        if d.command != self._forwarded or t - self._sc_sent >= out.sc_period - 1e-9:
            self._sc_seq += 1
            self._put(self.keys.sc_command, msgspec.structs.replace(d.command, seq=self._sc_seq, stamp=stamp))
            self._forwarded, self._sc_sent = d.command, t
        latched = d.estop_by != self._estop_by
        self._estop_by = d.estop_by
        if changed or refused or latched or t - self._state_sent >= out.state_period - 1e-9:
            self._state_seq += 1
            self._put(
                self.keys.safety_state,
                SafetyState(
                    seq=self._state_seq,
                    stamp=stamp,
                    state=cast(StateName, d.state.name),  # State's names are StateName
                    reason=d.cause.name + (f" (reset refused: {refused})" if refused else ""),
                    cap=d.cap,
                    since=max(d.since, 0.0),
                    estop_by=d.estop_by,
                    reset_refused=refused,
                ),
            )
            self._state_sent = t
            self._alert_seq += 1
            self._put(
                self.keys.safety_alert,
                SafetyAlert(seq=self._alert_seq, stamp=stamp, level=d.alert, reason=d.cause.name),
            )

    def _diagnosis_signals(self, d: Decision) -> dict[str, int]:
        """SUPERVISOR_DIAGNOSIS's signals, made again only when what they show changed."""
        shown = (self.monitors.named, d.alert)
        if shown != self._diagnosis_shown:
            named = self.monitors.named
            self._diagnosis_now = {**{name: int(name in named) for name in PARTS}, "Alert": d.alert}
            self._diagnosis_shown = shown
        return self._diagnosis_now

    def _recover(self, d: Decision) -> None:
        """While the recovery law holds the drives: its torques for this tick, every update."""
        if d.state is not State.RECOVERY:
            self.recovery_torques = None
            return
        torques = self.recovery.torques(self.monitors.isolated, self.monitors.dead_drive())
        self.recovery_torques = torques
        self.monitors.recovery_commanded(torques)
        self.can.send(
            MessageName.SUPERVISOR_RECOVERY,
            {
                "Torque1": torques[0],
                "Torque2": torques[1],
                "Torque3": torques[2],
                "Tick": (self.tick or 0) % TICK_MODULO,
            },
        )

    def _send_frame(self, state: State, cause: Cause, contactor_closed: bool, takeover: bool = False) -> None:
        self.can.send(
            MessageName.SUPERVISOR_ESTOP,
            {
                "Estop": int(state is State.ESTOP),
                "Contactor": int(contactor_closed),
                "Takeover": int(takeover),
                "State": int(state),
                "Reason": int(cause),
            },
        )

    def _stamp(self, t: float) -> float:
        """Stamps are in the controller's time base: the SYNC tick count over the tick rate."""
        return t if self.tick is None else self.tick / self.tick_hz

    def _put(self, key: str, payload: Payload) -> None:
        data = encode(payload)
        self.link.put(key, data)
        if self.on_put is not None:
            self.on_put(key, data)

    # ------------------------------------------------------------------------------------ standalone
    def run(self, stop: threading.Event, clock: Callable[[], float] = time.monotonic) -> None:
        """Standalone, wall-clock time: update on the configured timer, taking frames in as they arrive."""
        start = clock()
        period = 1.0 / self.config.output.rate_hz
        next_update = clock()
        while not stop.is_set():
            rx = self.can.recv(timeout=max(next_update - clock(), 0.0))
            now = clock()
            if rx is not None:
                self.frame(rx, now - start)
                if now < next_update:
                    continue
            self.update(now - start)
            next_update = max(next_update + period, clock())

    def run_on_sync(self, stop: threading.Event, poll: float = 0.1) -> None:
        """Standalone beside a lockstep rig: time is the SYNC tick (simulated time, whatever the wall clock
        does), and every SYNC triggers an update with the traffic of the tick before it. Until the first
        SYNC it announces itself every `poll` seconds (the rig's start-up handshake waits for its frame)."""
        period = self.config.output.estop_frame_period
        announce = 0.0
        while not stop.is_set():
            # Announced by the clock, not per frame received: a bus that echoes the supervisor's own frames
            # (udp_multicast) would otherwise make every announcement trigger the next.
            if self.tick is None and time.monotonic() >= announce:
                self._send_frame(self.machine.state, self.machine.cause, self.machine.contactor_closed)
                announce = time.monotonic() + period
            rx = self.can.recv(timeout=poll if self.tick is not None else period)
            if rx is None:
                continue
            self.frame(rx, self._stamp(0.0))
            if rx.name != MessageName.SYNC:
                continue
            if self.fence.heard():
                # A rig that sends fences tags its zenoh puts with their tick: however far behind (a busy
                # machine), each SYNC is its own update, with the frames before it and the zenoh inputs of
                # its tick and earlier, the same in every run.
                self.update(self._stamp(0.0), fence=self.tick, take_can=False)
                continue
            # Otherwise, behind the rig: take in what is already queued first, each frame at the tick it came
            # in, so an untagged zenoh input is judged at the newest tick, not an old one it overtook.
            while (queued := self.can.recv(timeout=0.0)) is not None:
                self.frame(queued, self._stamp(0.0))
            self.update(self._stamp(0.0))
