"""A closed-loop run on the embedded default: python-can `virtual` bus, zenoh on loopback, the controller
under test started by name (entry point) in this process, the rig in lockstep.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zenoh

from drivers.can_bus import BusConfig, BusConfigError, BusRecorder, CanNode, open_bus, private_channel
from drivers.config import ConfigError, load_toml
from drivers.dut import DutNotFound, DutSpec, start_dut
from drivers.keys import Keys
from drivers.resources import SHIPPED
from drivers.schemas import SafetyState
from drivers.zenoh_link import LOOPBACK, ZenohConfigError, ZenohLink, open_hub
from hil.clock import LockstepClock, RealtimeClock, TimingStats
from hil.faults import FaultError, FaultEvent, FaultSet, FaultSpec
from hil.rig import OperatorStep, Rig, ScStep, TickStats
from plant.ballbot import Plant, RiderIntent
from plant.params import RiderParams, RobotParams, SimParams
from safety.config import RobotGeometry, SupervisorConfig
from safety.machine import Event
from safety.node import SupervisorNode


class ControllerUnavailable(RuntimeError):
    """The controller under test never showed up, or stopped answering (lockstep)."""


@dataclass(frozen=True, slots=True)
class Failure:
    """Why a run stopped before its end: where (`stage`: build, start-up, tick N, an output) and what."""

    stage: str
    error: str
    config: bool = False
    """A configuration error (a fault that cannot act on this rig, an unknown controller, a bad bus)."""


@dataclass(slots=True)
class RunSpec:
    rider: Path | str
    mode: str = "hacs"
    duration: float = 5.0
    robot: Path | str = SHIPPED / "robot/pure.toml"
    controller_robot: Path | str | None = None
    """The robot file the controller builds its model from (None: the plant's)."""
    controller_config: Path | str | None = None
    sim: SimParams = field(default_factory=SimParams)
    intent: RiderIntent = field(default_factory=RiderIntent)
    sc_schedule: tuple[ScStep, ...] = (ScStep(0.0, "free"),)
    operator: tuple[OperatorStep, ...] = ()
    supervisor: str = "embedded"
    """embedded: the supervisor runs in the rig's tick; external: one runs elsewhere on the bus."""
    safety: SupervisorConfig = field(default_factory=SupervisorConfig)
    initial_tilt_deg: tuple[float, float] = (0.0, 0.0)
    controller: str = "reference"
    zenoh_config: Path | str = LOOPBACK
    hub_endpoint: str | None = None
    can: BusConfig | None = None
    stop_on_fall: bool = True
    clock: str = "lockstep"
    """lockstep (simulated time, deterministic) or realtime (wall-clock pacing)."""
    can_log: Path | None = None
    """Tee the bus into this python-can log (.log candump format, .blf, .asc)."""
    progress: Callable[[float, float], None] | None = None
    """Called with (simulated time, duration) about every 0.5 s of wall time."""
    on_tick: Callable[[Plant], None] | None = None
    """Called after every tick with the plant (the service applies live rider intent there)."""
    stop: threading.Event | None = None
    """Set it to end the run early (the service's stop)."""
    boot_timeout: float | None = None
    """s to wait for the controller's boot-up before the first SYNC (None: 10 in-process, 120 external)."""
    session: zenoh.Session | None = None
    """An open hub session to use instead of opening one (the long-running service owns its session)."""
    faults: tuple[FaultSpec, ...] = ()
    """Scheduled faults (hil/faults; docs/faults.md)."""
    fault_set: FaultSet | None = None
    """The run's fault set, if the caller wants to inject live (the service); built from `faults` if None."""


@dataclass(slots=True)
class Trace:
    """Per-tick records of a run (SI units; planes ordered pitch, roll)."""

    t: np.ndarray
    velocity: np.ndarray
    """(n, 2) forward, left."""
    tilt: np.ndarray
    lean: np.ndarray
    position: np.ndarray
    yaw_rate: np.ndarray
    ball_rate: np.ndarray
    """(n, 2) φ̇ per plane, rad/s."""
    command_speed: np.ndarray
    """(n, 2) the controller's command speed (pitch fwd, roll fwd = −y), m/s; NaN if not received."""
    tilt_command: np.ndarray
    fallen: str | None
    stats: TickStats
    controller_telemetry_missing: int
    timing: TimingStats
    bus: dict
    """The rig node's CAN statistics (sent, received, E2E events, malformed frames)."""
    motor_torque: np.ndarray
    """(n, 3) motor torques the drives produced, Nm."""
    zenoh_inputs: list[tuple[int, str, bytes]]
    """What the controller was sent on zenoh: (tick, key, msgpack payload)."""
    safety_state: np.ndarray
    """(n,) the supervisor's state per tick as on the bus (SUPERVISOR_ESTOP.State; -1: no frame yet)."""
    safety_speed: np.ndarray
    """(n,) the embedded supervisor's own speed estimate, m/s (NaN: none)."""
    powered: np.ndarray
    """(n,) any drive's power stage on."""
    resting: np.ndarray
    """(n,) powered off at standstill, held by the rider's feet or the stand."""
    safety_events: list[Event]
    """The embedded supervisor's transitions and refused resets."""
    fence_misses: int = 0
    identity_rejected: dict[str, int] = field(default_factory=dict)
    """SC requests and resets the embedded supervisor ignored for want of an operator's identity."""
    diagnostics: dict[str, float] = field(default_factory=dict)
    """The embedded supervisor's checks: each one's largest |residual| / bound over the run."""
    sc_arbitration: dict = field(default_factory=dict)
    """The embedded supervisor's SC sources: accepted and refused requests per source, conflicts."""
    faults: list[FaultSpec] = field(default_factory=list)
    """Every fault of the run, scheduled and injected live, by number."""
    fault_events: list[FaultEvent] = field(default_factory=list)
    fault_windows: list[tuple[float, float] | None] = field(default_factory=list)
    """Per fault: (start, end) of the time it acted, None if it never started."""
    failure: Failure | None = None
    """Why the run stopped before its end (None: it ran to the end, or to a fall)."""

    @classmethod
    def empty(cls, failure: Failure) -> Trace:
        """A run that failed before its first tick."""
        none, pair = np.zeros(0), np.zeros((0, 2))
        return cls(
            t=none,
            velocity=pair,
            tilt=pair,
            lean=pair,
            position=pair,
            yaw_rate=none,
            ball_rate=pair,
            command_speed=pair,
            tilt_command=pair,
            fallen=None,
            stats=TickStats(),
            controller_telemetry_missing=0,
            timing=TimingStats(0, 0.0, 0.0),
            bus={},
            motor_torque=np.zeros((0, 3)),
            zenoh_inputs=[],
            safety_state=np.zeros(0, int),
            safety_speed=none,
            powered=np.zeros(0, bool),
            resting=np.zeros(0, bool),
            safety_events=[],
            failure=failure,
        )


CONFIG_ERRORS = (FaultError, DutNotFound, BusConfigError, ConfigError, ZenohConfigError)


def run(spec: RunSpec) -> Trace:
    """Build the run, hand-shake, tick to the end. Never raises for a run that failed: the trace says where
    (`failure`) and keeps the ticks done so far."""
    try:
        return _run(spec)
    except Exception as exc:  # before the first tick: nothing to keep but the reason
        stage = "start-up" if isinstance(exc, ControllerUnavailable) else "build"
        return Trace.empty(Failure(stage, _reason(exc), isinstance(exc, CONFIG_ERRORS)))


def _reason(exc: BaseException) -> str:
    return (
        f"{type(exc).__name__}: {exc}"
        if not isinstance(exc, (ControllerUnavailable, *CONFIG_ERRORS))
        else str(exc)
    )


def _run(spec: RunSpec) -> Trace:
    robot = load_toml(spec.robot, RobotParams)
    rider = load_toml(spec.rider, RiderParams)
    plant = Plant(robot, rider, spec.sim, spec.intent, tuple(math.radians(a) for a in spec.initial_tilt_deg))
    bus_config = spec.can or BusConfig(channel=private_channel())
    with ExitStack() as resources:  # every resource of the run, closed in reverse on any exit
        bus = open_bus(bus_config)
        resources.callback(bus.shutdown)
        # A run with every part in this process may move its hub when the default port is taken.
        self_contained = spec.controller != "external" and spec.supervisor == "embedded"
        if spec.session is not None:
            session, hub = spec.session, spec.hub_endpoint
        else:
            session, hub = open_hub(spec.zenoh_config, spec.hub_endpoint, fallback=self_contained)
            resources.callback(session.close)
        link = ZenohLink(session, Keys(), lossless=spec.clock == "lockstep")
        resources.callback(link.close)
        if spec.can_log is not None:
            resources.callback(BusRecorder(bus_config, spec.can_log).stop)
        supervisor = None
        if spec.supervisor == "embedded":
            supervisor_bus = open_bus(bus_config)
            resources.callback(supervisor_bus.shutdown)
            supervisor = SupervisorNode(
                CanNode(supervisor_bus, name="supervisor"),
                link,
                spec.safety,
                load_toml(spec.robot, RobotGeometry),
                tick_hz=spec.sim.tick_hz,
            )
        faults = spec.fault_set if spec.fault_set is not None else FaultSet(spec.faults, spec.sim.seed)
        rig = Rig(
            plant,
            CanNode(bus, name="rig"),
            link,
            spec.sc_schedule,
            supervisor=supervisor,
            operator=spec.operator,
            faults=faults,
            bitrate=bus_config.bitrate,
        )
        if supervisor is None:  # an external supervisor: its transitions as it announces them
            rig.safety_states = link.subscribe(link.keys.safety_state, SafetyState, capacity=1 << 14)
        dut = None
        if spec.controller != "external":
            dut = start_dut(
                spec.controller,
                DutSpec(
                    can=bus_config,
                    zenoh_config=str(spec.zenoh_config),
                    hub_endpoint=hub,
                    mode=spec.mode,  # type: ignore[arg-type]
                    robot=str(spec.controller_robot or spec.robot),
                    rider=str(spec.rider),
                    controller_config=None if spec.controller_config is None else str(spec.controller_config),
                    lockstep=spec.clock == "lockstep",
                    tick_hz=spec.sim.tick_hz,
                ),
            )
            resources.callback(dut.stop)
        rig.dut = dut
        faults.attach(rig)
        _start_up(rig, spec, bus_config, in_process=dut is not None)
        return _loop(rig, plant, spec, dut)


ZENOH_GRACE = 2.0
"""s the rig waits after the controller's boot-up for it to subscribe to the seat wrench; a controller on
CAN alone never does, and the run starts without it."""


def _start_up(rig: Rig, spec: RunSpec, bus: BusConfig, in_process: bool) -> None:
    """The start-up handshake before the first SYNC (docs/contract.md): the supervisor's first frame (the
    embedded one sends it now, at t = 0), the controller's boot-up heartbeat, then its zenoh subscriptions
    if it has any. Raises ControllerUnavailable saying what did not come."""
    if rig.supervisor is not None:
        rig.supervisor.update(0.0)
    timeout = spec.boot_timeout if spec.boot_timeout is not None else 10.0 if in_process else 120.0
    missing = rig.await_boot(timeout)
    if missing:
        where = f"{bus.interface}:{bus.channel}"
        raise ControllerUnavailable(
            f"waited {timeout:g} s on {where} for {missing}: start it on this bus "
            f"(docs/contract.md, start-up), e.g. python examples/balance_controller.py --can {where}"
        )
    rig.wait_for_subscriber(rig.keys.tes_wrench, ZENOH_GRACE)
    if rig.supervisor is None and not rig.wait_for_subscriber(rig.keys.sc_request, 10.0):
        raise ControllerUnavailable(
            f"the supervisor on {bus.interface}:{bus.channel} does not read pure/sc/request"
        )
    rig.apply_permission()


def _loop(rig: Rig, plant: Plant, spec: RunSpec, dut) -> Trace:
    ticks = round(spec.duration * spec.sim.tick_hz)
    lockstep = spec.clock == "lockstep"
    clock = LockstepClock(plant.dt, rig.command_guard) if lockstep else RealtimeClock(plant.dt)
    rows = np.full((ticks, 19), np.nan)
    supervisor = rig.supervisor  # its record outlives a kill
    n = 0
    next_report = time.monotonic() + 0.5
    failure = None
    clock.start()
    while n < ticks:
        try:
            rig.tick(clock.command_deadline(), lockstep)
        except Exception as exc:  # a bug or a broken bus mid-run: keep what ran, say where it stopped
            failure = Failure(f"tick {plant.tick} (t = {plant.t:.4f} s)", _reason(exc))
            break
        tr = plant.truth()
        rows[n] = (
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
        n += 1
        if spec.stop_on_fall and tr.fallen:
            break
        if spec.on_tick is not None:
            spec.on_tick(plant)
        if spec.stop is not None and spec.stop.is_set():
            break
        if spec.progress is not None and time.monotonic() > next_report:
            spec.progress(tr.t, spec.duration)
            next_report = time.monotonic() + 0.5
        clock.wait_next()
    clock.stop()
    rig.faults.finish(plant.t)
    timing = clock.stats()
    rows = rows[:n]
    command = np.full((n, 2), np.nan)
    tilt_cmd = np.full((n, 2), np.nan)
    first_tick = plant.tick - n + 1
    for _ in range(50 if n else 0):  # the last telemetry samples may still be in flight
        for sample in rig.telemetry.drain():
            i = sample.seq - first_tick
            if 0 <= i < n:
                command[i], tilt_cmd[i] = sample.command_speed, sample.tilt_command
        if not np.isnan(command[-1, 0]) or not rig.telemetry.wait(0.02):
            break
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
        zenoh_inputs=rig.zenoh_inputs,
        safety_state=rows[:, 15].astype(int),
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
        failure=failure,
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
