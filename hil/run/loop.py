"""The run's tick loop: tick after tick under the scenario's clock, the plant's truth and the supervisor's
view recorded beside each other (hil/run/trace.py)."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from drivers.plugs import SupervisorReport
from drivers.vocabulary import Event, State
from hil.outputs.bodies import PoseTaker
from hil.outputs.trace_log import LAYOUT, Layout, Reorder, TraceLog
from hil.run.build import Built, RunOptions, RunStatus
from hil.run.clock import Clock, LockstepClock, RealtimeClock
from hil.run.rig import Rig
from hil.run.trace import Failure, Trace, reason
from plant.core import Truth

TELEMETRY_EVERY = 16
"""Ticks between takes of the controller's telemetry during a run: a take is one lump on its tick (64
ticks' took ~530 µs of it in real time, 2026-12-07); 16 ticks' ~130."""


def tick_loop(built: Built, options: RunOptions) -> Trace:
    """Tick to the end of the scenario (or a fall, or the caller's stop) and return what happened. An
    exception in a tick ends the run there with a `Failure` naming the tick; the ticks before it are kept."""
    rig, plant = built.rig, built.plant
    ticks = round(built.duration / plant.dt)
    lockstep = built.clock == "lockstep"
    clock: Clock
    if lockstep:
        clock = LockstepClock(plant.dt, rig.port.command_guard)
    else:
        rt = built.realtime
        clock = RealtimeClock(
            plant.dt, rt.priority, rt.cpu, rt.lock_memory, sync_allowance=rt.sync_allowance * plant.dt
        )
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
                rig.tick(clock.command_deadline(), lockstep, clock.sync_due())
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
    series = _series(log.close())
    report = SupervisorReport() if supervisor is None else supervisor.report()
    return Trace(
        **series,
        fallen=plant.fallen,
        stats=rig.port.stats,
        lateness=rig.port.lateness,
        controller_telemetry_missing=int(np.isnan(series["command_speed"][:, 0]).sum()),
        timing=timing,
        bus=rig.can.stats.as_dict(),
        zenoh_inputs=rig.inputs.entries if rig.inputs.path is None else None,
        safety_events=_announced_events(rig) if supervisor is None else list(supervisor.events),
        fence_misses=0 if supervisor is None else supervisor.fence_misses,
        identity_rejected=report.identity_rejected,
        diagnostics=report.diagnostics,
        sc_arbitration=report.sc_arbitration,
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
    state = rig.port.safety_state
    return RunStatus(
        t=tr.t,
        duration=duration,
        speed_factor=tr.t / max(time.monotonic() - began, 1e-9),
        speed=math.hypot(*tr.velocity),
        tilt_deg=math.degrees(math.hypot(*tr.tilt)),
        supervisor=State(state).name if state >= 0 else "-",
        overruns=getattr(clock, "overruns", 0),
    )


ROW_GROUPS = (
    "t",
    "velocity",
    "tilt",
    "lean",
    "position",
    "yaw_rate",
    "ball_rate",
    "motor_torque",
    "safety_state",
    "safety_speed",
    "powered",
    "resting",
)
"""The trace column groups `_row` writes, in its order (hil/outputs/trace_log.py COLUMNS)."""
ROW_ORDER = LAYOUT.order(ROW_GROUPS)
"""None: ROW_GROUPS are in the declared order (looked up once, here)."""


def _row(tr: Truth, rig: Rig, order: Reorder | None = ROW_ORDER) -> tuple[float, ...]:
    """The rig's columns of a tick's row in the declared order: ROW_GROUPS' order, so `order` is None and
    costs the tick nothing unless the declaration moved a column."""
    row = (
        tr.t,
        *tr.velocity,
        *tr.tilt,
        *tr.lean,
        *tr.position,
        tr.yaw_rate,
        *tr.ball_rate,
        *tr.motor_torque,
        rig.port.safety_state,
        _supervisor_speed(rig),
        tr.powered,
        tr.resting,
    )
    return row if order is None else order(row)


KINDS = {"safety_state": np.int8, "powered": bool, "resting": bool}
"""The columns a Trace holds as codes or flags (the rows hold every column as f8)."""


def _series(rows: np.ndarray, layout: Layout = LAYOUT) -> dict[str, Any]:
    """The rows' columns as the Trace's fields of the same names (a field per column group), by name."""
    series = {group: rows[:, span] for group, span in layout.spans.items()}
    for group, kind in KINDS.items():
        series[group] = series[group].astype(kind)
    return series


def _announced_events(rig: Rig) -> list[Event]:
    """An external supervisor's transitions, from its pure/safety/state announcements (the last ones too)."""
    rig.hear_announcements()
    return list(rig.announced)


def _supervisor_speed(rig: Rig) -> float:
    speed = None if rig.supervisor is None else rig.supervisor.observed_speed()
    return math.nan if speed is None else speed
