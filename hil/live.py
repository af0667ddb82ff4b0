"""The rig service's live stream (`PREFIX/rig/live`): what the console draws while a run goes.

About 20 samples a second of wall time (of wall time, not simulated time: a lockstep run at 5x real time
makes no more of them than a real-time run), taken in the run's own tick thread from the plant and the rig
it is attached to, so nothing is copied per tick and nothing is locked: the tick pays one clock read, and a
sample costs the plant's truth, a look at the rig's counters and one JSON put. The put is at low priority
with congestion control DROP: a slow or absent console loses samples, the run never waits for it.

A sample (JSON): scenario, run id, simulated time; speed (forward, signed), chassis tilt and torso lean
(pitch plane, signed) and the controller's command speed (forward), as plots.png draws them; the SC's
command cap (in limit mode) and the supervisor's state, cap, last cause and new events; the drives'
permission, power and the main contactor; the controller's heartbeats (rate in simulated time, state); the
run's overruns, missed commands and wall-clock speed; the faults in force; the robot's pose (`pose`, from
the same truth: chassis tilt and torso lean (pitch, roll) in trace.npy's signs, heading, the ball's place on
the floor).
"""

from __future__ import annotations

import json
import math
import time
from collections import Counter

import zenoh

from drivers.can_codec import MessageName
from drivers.keys import Keys
from drivers.schemas import ControllerTelemetry, PayloadError, SafetyState, ScCommand, decode
from drivers.vocabulary import State
from hil.faults import FaultSet
from hil.run.build import RunStatus

PERIOD = 0.05
"""s of wall time between samples (20 Hz; the console's charts want at least 10)."""


def _newest(subscriber: zenoh.Subscriber, kind: type):
    """The newest decodable payload waiting in a one-sample ring channel, or None."""
    newest = None
    while (sample := subscriber.try_recv()) is not None:
        newest = sample
    if newest is None:
        return None
    try:
        return decode(newest.payload.to_bytes(), kind)
    except PayloadError:
        return None


def pose(tr) -> dict:
    """The robot's pose in a truth, as the console draws it: chassis tilt and torso lean (relative to the
    chassis) as (pitch, roll) in degrees, signed as trace.npy (pitch + : the top forward, roll + : the top to
    the right); heading (yaw + : counter-clockwise seen from above) in degrees within [-180, 180); the ball's
    place on the floor (world x, y from the start) in metres."""
    heading = (math.degrees(tr.yaw) + 180.0) % 360.0 - 180.0
    return {
        "tilt_deg": [round(math.degrees(a), 3) for a in tr.tilt],
        "lean_deg": [round(math.degrees(a), 3) for a in tr.lean],
        "heading_deg": round(heading, 2),
        "position": [round(x, 4) for x in tr.position],
    }


class LiveStream:
    def __init__(self, session: zenoh.Session, keys: Keys):
        self._publisher = session.declare_publisher(
            keys.rig_live, congestion_control=zenoh.CongestionControl.DROP, priority=zenoh.Priority.DATA_LOW
        )
        # One-sample rings filled by zenoh's threads (no GIL, no Python callback per message): the newest
        # command speed and supervisor state are read only when a sample is due. The rig's own
        # subscriptions are left alone (its loop drains them).
        self._telemetry = session.declare_subscriber(keys.controller_telemetry, zenoh.handlers.RingChannel(1))
        self._safety = session.declare_subscriber(keys.safety_state, zenoh.handlers.RingChannel(1))
        self._sc = session.declare_subscriber(keys.sc_command, zenoh.handlers.RingChannel(1))
        self._next = 0.0
        self.begin("", None, 0)

    def begin(self, scenario: str, faults: FaultSet | None, run_id: int) -> None:
        """A new run: forget the last one's counters."""
        self._scenario, self._faults, self._run_id = scenario, faults, run_id
        self._beats: Counter[int] = Counter()
        self._beat_t = 0.0
        self._beat_rate = 0.0
        self._beat_state = "-"
        self._heartbeat_names: dict[int, str] | None = None
        self._events_seen = 0
        self._command = math.nan
        self._safety_state: SafetyState | None = None
        self._sc_command: ScCommand | None = None
        self.status: RunStatus | None = None
        """The run's latest RunStatus (the loop's progress report, every 0.5 s): overruns, speed factor."""

    def due(self) -> bool:
        """True once every PERIOD of wall time (the tick's only cost when no sample is due)."""
        now = time.monotonic()
        if now < self._next:
            return False
        self._next = now + PERIOD
        return True

    def put(self, plant) -> None:
        """Take a sample of the running plant and its rig (the tick thread, between ticks) and put it."""
        self._publisher.put(json.dumps(self.sample(plant)))

    def sample(self, plant) -> dict:
        tr = plant.truth()
        faults = self._faults
        rig = faults.rig if faults is not None else None
        telemetry = _newest(self._telemetry, ControllerTelemetry)
        if telemetry is not None:
            self._command = telemetry.command_speed[0]
        state = _newest(self._safety, SafetyState)
        if state is not None:
            self._safety_state = state
        sc = _newest(self._sc, ScCommand)
        if sc is not None:
            self._sc_command = sc
        sc = self._sc_command
        drives = plant.drives
        sample = {
            "run": self._run_id,
            "scenario": self._scenario,
            "t": round(tr.t, 4),
            "speed": round(tr.velocity[0], 4),
            "tilt_deg": round(math.degrees(tr.tilt[0]), 3),
            "lean_deg": round(math.degrees(tr.lean[0]), 3),
            "command_speed": None if math.isnan(self._command) else round(self._command, 4),
            "sc_mode": None if sc is None else sc.mode,
            "sc_cap": sc.speed_cap if sc is not None and sc.mode == "limit" else None,
            "powered": tr.powered,
            "resting": tr.resting,
            "fall_cause": tr.fallen,
            "permitted": all(m.permitted for m in drives.motors),
            "contactor": drives.contactor_closed,
            "supervisor": None,
            "cap": None,
            "cause": None,
            "estop_by": None,
            "events": None,  # the embedded supervisor's new events (elsewhere: its state stream says it)
            "pose": pose(tr),
        }
        safety = self._safety_state
        if safety is not None:
            sample.update(
                supervisor=safety.state, cap=safety.cap, cause=safety.reason, estop_by=safety.estop_by or None
            )
        if rig is not None:
            self._rig(rig, tr.t, sample)
        status = self.status
        sample["overruns"] = None if status is None else status.overruns
        sample["speed_factor"] = None if status is None else round(status.speed_factor, 3)
        sample["faults"] = (
            []
            if faults is None
            else [
                spec.describe()
                for spec, st in zip(list(faults.specs), list(faults.states), strict=False)
                if st.active
            ]
        )
        return sample

    def _rig(self, rig, t: float, sample: dict) -> None:
        """The rig's side: its view of the supervisor, the controller's heartbeats, missed commands."""
        if sample["supervisor"] is None and rig.port.safety_state >= 0:
            sample["supervisor"] = State(rig.port.safety_state).name
        if self._heartbeat_names is None:
            self._heartbeat_names = rig.can.catalog[MessageName.CONTROLLER_HEARTBEAT].values("State")
        beats = rig.port.stats.controller_states
        new = beats - self._beats  # the states heard since the last sample
        if t > self._beat_t:
            self._beat_rate = sum(new.values()) / (t - self._beat_t)
            self._beat_t = t
        if new:
            state = new.most_common(1)[0][0]
            self._beat_state = self._heartbeat_names.get(state, str(state))
        self._beats = Counter(beats)
        sample["heartbeat_hz"] = round(self._beat_rate, 1)
        sample["controller"] = self._beat_state if self._beat_rate > 0 else "SILENT"
        sample["missing_commands"] = rig.port.stats.missing_commands
        supervisor = rig.supervisor
        if supervisor is not None:
            events = supervisor.events
            sample["events"] = [
                {"t": round(e.t, 3), "kind": e.kind, "from": e.from_state, "to": e.to_state, "cause": e.cause}
                for e in events[self._events_seen :]
            ]
            self._events_seen = len(events)

    def close(self) -> None:
        for declared in (self._telemetry, self._safety, self._sc, self._publisher):
            declared.undeclare()
