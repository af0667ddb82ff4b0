"""The run's tick loop: tick after tick under the scenario's clock, the plant's truth and the supervisor's
view recorded beside each other (hil/run/trace.py)."""

from __future__ import annotations

import math
import time

import numpy as np

from drivers.vocabulary import Event, State
from hil.outputs.bodies import PoseTaker
from hil.outputs.trace_log import TELEMETRY, TraceLog
from hil.run.build import Built, RunOptions, RunStatus
from hil.run.clock import Clock, LockstepClock, RealtimeClock
from hil.run.rig import Rig
from hil.run.trace import Failure, Trace, reason
from plant.ballbot import Truth

TELEMETRY_EVERY = 64
"""Ticks between takes of the controller's telemetry during a run."""


def tick_loop(built: Built, options: RunOptions) -> Trace:
    """Tick to the end of the scenario (or a fall, or the caller's stop) and return what happened. An
    exception in a tick ends the run there with a `Failure` naming the tick; the ticks before it are kept."""
    rig, plant = built.rig, built.plant
    ticks = round(built.duration / plant.dt)
    lockstep = built.clock == "lockstep"
    clock: Clock
    if lockstep:
        clock = LockstepClock(plant.dt, rig.command_guard)
    else:
        rt = built.realtime
        clock = RealtimeClock(plant.dt, rt.priority, rt.cpu, rt.lock_memory)
    log = TraceLog(ticks, built.trace_path)
    first_tick = plant.tick + 1

    def take_telemetry() -> None:
        for sample in rig.telemetry.drain():
            log.telemetry(sample.seq - first_tick, sample.command_speed, sample.tilt_command)

    supervisor = rig.supervisor  # its record outlives a kill
    logs = built.logs
    poses = _pose_taker(built)
    n = 0
    if poses is not None:
        poses.take(plant, n)
    began = time.monotonic()
    next_report = began + 0.5
    failure = None
    stopped = options.stop is not None and options.stop.is_set()  # already in the start-up: no tick
    clock.start()
    try:  # the clock's real-time settings (gc off) end with the loop, whatever ends it
        while n < ticks and not stopped:
            try:
                rig.tick(clock.command_deadline(), lockstep)
            except Exception as exc:  # a bug or a broken bus mid-run: keep what ran, say where it stopped
                failure = Failure(f"tick {plant.tick} (t = {plant.t:.4f} s)", reason(exc))
                break
            tr = plant.truth()
            row = _row(tr, rig)
            log.append(row)
            if logs is not None:
                logs.trace(row)
            n += 1
            if poses is not None and n % poses.every == 0:
                poses.take(plant, n)
            if n % TELEMETRY_EVERY == 0:  # long before the subscription's ring could overflow
                take_telemetry()
            if options.stop_on_fall and tr.fallen:
                break
            if options.on_tick is not None:
                options.on_tick(plant)
            if options.stop is not None and options.stop.is_set():
                stopped = True
                break
            if options.progress is not None and time.monotonic() > next_report:
                options.progress(_status(tr, rig, clock, built.duration, began))
                next_report = time.monotonic() + 0.5
            clock.wait_next()
    finally:
        clock.stop()
    rig.faults.finish(plant.tick, plant.t)
    if supervisor is None:
        rig.hear_operator()  # what was sent during the last tick
    # The operator's actions as the supervisor here took them in, or as the rig heard them sent elsewhere.
    operator = rig if supervisor is None else supervisor
    kept = None if poses is None else poses.close(plant, n)
    timing = clock.stats()
    for _ in range(50 if n else 0):  # the last telemetry samples may still be in flight
        take_telemetry()
        if log.last_told() or not rig.telemetry.wait(0.02):
            break
    rows = log.close()
    command, tilt_cmd = rows[:, TELEMETRY : TELEMETRY + 2], rows[:, TELEMETRY + 2 : TELEMETRY + 4]
    return Trace(
        t=rows[:, 0],
        velocity=rows[:, 1:3],
        tilt=rows[:, 3:5],
        lean=rows[:, 5:7],
        position=rows[:, 7:9],
        yaw_rate=rows[:, 9],
        ball_rate=rows[:, 10:12],
        command_speed=command,
        tilt_command=tilt_cmd,
        fallen=plant.fallen,
        stats=rig.stats,
        controller_telemetry_missing=int(np.isnan(command[:, 0]).sum()),
        timing=timing,
        bus=rig.can.stats.as_dict(),
        motor_torque=rows[:, 12:15],
        zenoh_inputs=rig.inputs.entries if rig.inputs.path is None else None,
        safety_state=rows[:, 15].astype(np.int8),
        safety_speed=rows[:, 16],
        powered=rows[:, 17].astype(bool),
        resting=rows[:, 18].astype(bool),
        safety_events=_announced_events(rig) if supervisor is None else list(supervisor.events),
        fence_misses=0 if supervisor is None else supervisor.fence_misses,
        identity_rejected={} if supervisor is None else dict(supervisor.monitors.rejected_identity),
        diagnostics={} if supervisor is None else supervisor.monitors.margins(),
        sc_arbitration={} if supervisor is None else supervisor.monitors.sc.summary(),
        faults=list(rig.faults.specs),
        fault_events=list(rig.faults.events),
        fault_windows=[rig.faults.window(n, plant.t) for n in range(len(rig.faults.specs))],
        operator_actions=list(operator.operator_actions),
        operator_actions_dropped=operator.operator_actions_dropped,
        failure=failure,
        stopped_early=stopped,
        poses=kept,
    )


def _pose_taker(built: Built) -> PoseTaker | None:
    """The bodies' poses for the outputs that draw them (the recording, run.mcap); None: neither does."""
    logs = built.logs
    send = logs.poses if logs is not None and logs.takes_poses else None
    if not built.keep_poses and send is None:
        return None
    folder = None if built.trace_path is None else built.trace_path.parent
    taker = PoseTaker(built.plant, built.keep_poses, folder, send)
    if logs is not None and send is not None:
        logs.bodies(taker.bodies)
    return taker


def _status(tr: Truth, rig: Rig, clock: Clock, duration: float, began: float) -> RunStatus:
    state = rig.safety_state
    return RunStatus(
        t=tr.t,
        duration=duration,
        speed_factor=tr.t / max(time.monotonic() - began, 1e-9),
        speed=math.hypot(*tr.velocity),
        tilt_deg=math.degrees(math.hypot(*tr.tilt)),
        supervisor=State(state).name if state >= 0 else "-",
        overruns=getattr(clock, "overruns", 0),
    )


def _row(tr: Truth, rig: Rig) -> tuple[float, ...]:
    """The rig's columns of a tick's row (hil/outputs/trace_log.py COLUMNS)."""
    return (
        tr.t,
        *tr.velocity,
        *tr.tilt,
        *tr.lean,
        *tr.position,
        tr.yaw_rate,
        *tr.ball_rate,
        *tr.motor_torque,
        rig.safety_state,
        _supervisor_speed(rig),
        tr.powered,
        tr.resting,
    )


def _announced_events(rig: Rig) -> list[Event]:
    """An external supervisor's transitions, from its pure/safety/state announcements."""
    events, previous = [], "NORMAL"
    for s in rig.safety_states.drain() if rig.safety_states is not None else ():
        if s.state != previous:
            events.append(Event(s.since, "transition", previous, s.state, s.reason.split(" ")[0]))
            previous = s.state
    return events


def _supervisor_speed(rig: Rig) -> float:
    observed = None if rig.supervisor is None else rig.supervisor.observation
    speed = None if observed is None else observed.speed
    return math.nan if speed is None else speed
