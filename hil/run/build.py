"""Build a run from a bench and a scenario: the plant, the bus, zenoh, the supervisor and the controller
where the bench puts them, every resource entered in one ExitStack (closed in reverse on any exit, a
failure included), then the start-up handshake before the first SYNC (docs/contract.md, Start-up)."""

from __future__ import annotations

import math
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from collections import Counter
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import can
import msgspec
import zenoh

from drivers.bus_config import BusConfig
from drivers.can_bus import BusRecorder, open_bus, private_channel
from drivers.can_codec import MessageName
from drivers.config import ConfigError, load_toml
from drivers.contract import CONTRACT_VERSION, mismatch
from drivers.dut import DutHandle, DutSpec, start_dut
from drivers.keys import Keys
from drivers.plugs import Supervisor, SupervisorSpec, start_supervisor
from drivers.registry import SUPERVISOR_RULES, find_plug, installed
from drivers.resources import find
from drivers.rules import JudgedRules
from drivers.schemas import ScRequest
from drivers.zenoh_access import ZenohAccess
from drivers.zenoh_link import ZenohLink, lend
from hil.bench.bench import Bench, RealtimePart
from hil.bench.rigs import announce
from hil.devices import rig_node
from hil.faults import FaultError, FaultSet
from hil.outputs.inputs_log import InputsLog
from hil.outputs.run_logs import McapSpec, RunLogs, open_logs
from hil.run.agents import SCENARIO_SOURCE, AgentLinks, OperatorStep, ScStep
from hil.run.drives_port import DrivesPort
from hil.run.plants import load_sim, make_plant
from hil.run.rig import Rig, RigParts
from hil.run.scenario import Scenario
from hil.run.trace import ControllerUnavailable
from plant.core import PlantCore, RiderIntent
from plant.params import RiderParams, RobotParams, SimParams


@dataclass(frozen=True, slots=True)
class RunStatus:
    """A running run at a glance (a live status line)."""

    t: float
    duration: float
    speed_factor: float
    """Simulated seconds per wall second so far."""
    speed: float
    """Ground speed, m/s."""
    tilt_deg: float
    """Chassis tilt from upright, deg."""
    supervisor: str
    """The supervisor's state as on the bus ("-": no frame yet)."""
    overruns: int
    """Real time: ticks that started late."""


@dataclass(slots=True)
class RunOptions:
    """What a program adds to a bench and a scenario (nothing of it belongs in a file)."""

    progress: Callable[[RunStatus], None] | None = None
    """Called with the run's status about every 0.5 s of wall time."""
    on_tick: Callable[[PlantCore], None] | None = None
    """Called after every tick with the plant (the service applies live rider intent there)."""
    stop: threading.Event | None = None
    """Set it to end the run early (the service's stop)."""
    session: zenoh.Session | None = None
    """The rig's zenoh session, owned by the caller (the long-running service keeps one)."""
    fault_set: FaultSet | None = None
    """The run's faults, kept by a caller that injects more live (the service)."""
    stop_on_fall: bool = True
    logs_in_process: bool = False
    """Write can.log and run.mcap on the tick's thread, not in a process of their own
    (hil/outputs/run_logs.py): for a test that makes a writer fail and the benchmark that times them."""


@dataclass(slots=True)
class Built:
    rig: Rig
    plant: PlantCore
    bus: BusConfig
    law: str
    clock: str
    duration: float
    dut: DutHandle | None
    """The embedded controller's handle (process faults stop or pause it); None: in another process."""
    trace_path: Path | None = None
    """Where the run's rows stream (hil/outputs/trace_log.py); None: kept in memory."""
    realtime: RealtimePart = RealtimePart()  # noqa: RUF009 (frozen msgspec struct: one shared default is fine)
    """The loop's scheduling under the real-time clock."""
    logs: RunLogs | None = None
    """can.log and run.mcap, which the loop hands every tick's row (None: neither written)."""
    keep_poses: bool = False
    """The recording draws the bodies: the loop keeps their poses (hil/outputs/bodies.py)."""


BOOT_TIMEOUT = {"embedded": 10.0, "spawned": 30.0, "external": 120.0}
"""s the rig waits for the controller's boot-up by default (a spawned process imports numpy and scipy)."""
ZENOH_GRACE = 2.0
"""s the rig waits after the controller's boot-up for it to subscribe to the seat wrench; a controller on
CAN alone never does, and the run starts without it."""


def law_of(bench: Bench, scenario: Scenario) -> str:
    if bench.controller.where == "external":
        return "external"
    return reference_law(bench, scenario)


def reference_law(bench: Bench, scenario: Scenario) -> Literal["hacs", "ihacs"]:
    """The law the reference controller runs: the bench's, or the scenario's."""
    return scenario.law if bench.controller.law == "scenario" else bench.controller.law


def clock_of(bench: Bench, scenario: Scenario) -> str:
    return scenario.clock if bench.clock == "scenario" else bench.clock


def supervisor_rules(bench: Bench, scenario: Scenario, overrides: str = "") -> dict[str, Any]:
    """The bench's supervisor rules file with the scenario's `[safety]` overrides, as its plug is handed
    them, checked against the type the plug registers (drivers/rules.py) and against the limits the rig
    judges by: ConfigError names the file, or the overrides (`overrides`: where they came from; default the
    scenario's [safety]) when the file alone is fine."""
    path = find(bench.supervisor.config, "safety")
    schemas: list[Any] = [JudgedRules]
    if bench.supervisor.plugin in installed(SUPERVISOR_RULES):
        schemas.append(find_plug(SUPERVISOR_RULES, bench.supervisor.plugin, "supervisor rules"))
    base = _checked(load_toml(path, dict[str, Any]), schemas, str(path))
    origin = overrides or f"scenario {scenario.name} [safety]"
    try:
        rules = scenario.rules_over(base)
    except ValueError as exc:
        raise ConfigError(origin, str(exc)) from None
    return _checked(rules, schemas, origin)


def _checked(rules: dict[str, Any], schemas: list[Any], origin: str) -> dict[str, Any]:
    for schema in schemas:
        try:
            msgspec.convert(rules, schema)
        except msgspec.ValidationError as exc:
            raise ConfigError(origin, str(exc)) from None
    return rules


def judged_rules(bench: Bench, scenario: Scenario) -> JudgedRules:
    """The limits the run is judged by (drivers/rules.py), from the supervisor's rules."""
    return msgspec.convert(supervisor_rules(bench, scenario), JudgedRules)


@dataclass(frozen=True, slots=True)
class Placement:
    """Where a part runs: its bus and zenoh, the rig's tick rate, and how it keeps time."""

    can: BusConfig
    zenoh: ZenohAccess
    tick_hz: float
    lockstep: bool
    """It decides once per SYNC (lockstep) or on its own timer (real time)."""
    driven: bool = False
    """The rig updates it from its own tick (drivers/plugs.py, drivers/dut.py)."""


def supervisor_spec(bench: Bench, scenario: Scenario, at: Placement, overrides: str = "") -> SupervisorSpec:
    """The bench's supervisor for this scenario on this bus and zenoh: what a run and `pure-hil supervisor`
    start the plug from."""
    return SupervisorSpec(
        can=at.can,
        zenoh=at.zenoh,
        devices=bench.devices,
        robot=str(find(scenario.robot, "robot")),
        rules=supervisor_rules(bench, scenario, overrides),
        tick_hz=at.tick_hz,
        lockstep=at.lockstep,
        driven=at.driven,
    )


def build(
    bench: Bench,
    scenario: Scenario,
    seed: int,
    options: RunOptions,
    out: Path | None,
    logs: RunLogs | None,
    stack: ExitStack,
) -> Built:
    """The run's parts in order: the bus and zenoh, the plant, the parts where the bench puts them, then
    the rig once. out: the run folder, where the zenoh inputs stream (None: none); logs: `run_logs`'s, which
    the caller opened first (a run that fails to build still leaves complete files) and stops last."""
    clock = clock_of(bench, scenario)
    lockstep = clock == "lockstep"
    faults = options.fault_set if options.fault_set is not None else FaultSet(scenario.faults, seed)
    if faults and bench.rider_on_board:
        raise FaultError(f"bench {bench.name} says a person is on the robot (rider_on_board): no faults")
    wire = _connect(bench, scenario, options, lockstep, stack)
    plant = _plant(bench, scenario, seed)
    if logs is not None:
        logs.clock = lambda: plant.t
    recorder = _recorder(wire.bus_config, logs, stack)  # before the parts: their boot-up too
    parts = _start_parts(bench, scenario, plant, wire, lockstep, stack)
    port = DrivesPort(
        plant,
        rig_node(wire.bus, bench.devices, plant.robot.encoder.counts_per_rev, plant.sim.tick_hz),
        recovery_in_commands=not bench.devices.pure,
        stop=options.stop,
    )
    sc = tuple(
        ScStep(
            scenario.tick_of(e.at),
            ScRequest(seq=0, stamp=0.0, mode=e.mode, speed_cap=e.cap, source=SCENARIO_SOURCE),
        )
        for e in scenario.sc
    )
    rig = Rig(
        RigParts(
            port,
            wire.link,
            sc,
            supervisor=parts.supervisor,
            operator=tuple(OperatorStep(scenario.tick_of(e.at), e.action) for e in scenario.operator),
            faults=faults,
            bitrate=wire.bus_config.bitrate,
            agent_link=wire.agent_link,
            dut=parts.dut,
            driven=bench.controller.where == "embedded",
            recorder=recorder,
            inputs=_inputs(out, logs, stack),
        )
    )
    faults.attach(rig)
    trace = None if out is None else out / "trace.npy"
    law = law_of(bench, scenario)
    built = Built(
        rig, plant, wire.bus_config, law, clock, scenario.duration, parts.dut, trace, bench.realtime, logs
    )
    built.keep_poses = out is not None and bench.outputs.recording
    return built


@dataclass(frozen=True, slots=True)
class Wiring:
    """How the run's parts meet: the bus and zenoh, as the rig opened them."""

    bus_config: BusConfig
    """The bench's bus, with the run's private channel on an in-process one."""
    bus: can.BusABC
    access: ZenohAccess
    """The bench's zenoh with the hub's endpoint as opened."""
    link: ZenohLink
    agent_link: AgentLinks | None
    puts: Counter[str]
    """Every put of this process, whatever its session: the lockstep fence counts them."""


@dataclass(frozen=True, slots=True)
class Parts:
    supervisor: Supervisor | None
    """The supervisor the rig updates in its tick (None: in another process)."""
    dut: DutHandle | None
    """The embedded controller's handle (process faults stop or pause it); None: in another process."""


def run_logs(
    bench: Bench, scenario: Scenario, seed: int, options: RunOptions, out: Path | None
) -> RunLogs | None:
    """can.log and run.mcap as the bench asks for them, into `out` (None: no folder, no logs)."""
    if out is None:
        return None
    mcap = None
    if bench.outputs.mcap:
        meta = {"scenario": scenario.name, "seed": str(seed), "bench": bench.name}
        mcap = McapSpec(out / "run.mcap", scenario.tick_hz, bench.zenoh.prefix, meta)
    can_log = out / "can.log" if bench.outputs.can_log else None
    # In lockstep a writer process pays only beside a rig alone in its process: where the controller or the
    # supervisor runs in a process of its own, the tick waits on them, and a writer would compete for their
    # CPU. In real time the writer runs in the background (SCHED_IDLE, run_logs._background): it takes
    # only what CPU the others leave, and its work is off the rig's tick whatever the bench.
    lockstep = clock_of(bench, scenario) == "lockstep"
    in_process = options.logs_in_process or (lockstep and not bench.self_contained)
    return open_logs(can_log, mcap, in_process, realtime=not lockstep)


def _connect(
    bench: Bench, scenario: Scenario, options: RunOptions, lockstep: bool, stack: ExitStack
) -> Wiring:
    """The bus (a private channel on an in-process one) and the rig's zenoh: the caller's session or the
    bench's, announced to the machine's clients and lent to the parts of this process on loopback."""
    bus_config = (
        bench.can if bench.can.channel else msgspec.structs.replace(bench.can, channel=private_channel())
    )
    bus = open_bus(bus_config)
    stack.callback(bus.shutdown)
    keys = Keys(bench.zenoh.prefix)
    if options.session is not None:
        session, access = options.session, bench.zenoh
    else:
        session, access = bench.zenoh.open_rig(fallback=bench.self_contained)
        stack.callback(session.close)
        if access.mode == "loopback":  # operators' clients find it (hil/bench/rigs.py)
            where = access.hub_endpoint()
            stack.enter_context(announce(session, keys.prefix, bench.name, where, f"run {scenario.name}"))
    if access.mode == "loopback":
        stack.enter_context(lend(session, access.endpoint))  # the embedded controller joins it
    puts: Counter[str] = Counter()
    link = ZenohLink(session, keys, lossless=lockstep, puts=puts)
    stack.callback(link.close)
    agent_link = _agent_link(access, keys, lockstep, puts, stack)
    return Wiring(bus_config, bus, access, link, agent_link, puts)


def sim_params(bench: Bench, scenario: Scenario | None = None, seed: int | None = None) -> SimParams:
    """The bench's simulation settings with its plant override, the scenario's tick rate and the seed."""
    sim = load_sim(find(bench.sim, "sim"))
    changes: dict[str, object] = {} if bench.plant == "sim" else {"plant": bench.plant}
    if scenario is not None:
        changes["tick_hz"] = scenario.tick_hz
    if seed is not None:
        changes["seed"] = seed
    return msgspec.structs.replace(sim, **changes)


def _plant(bench: Bench, scenario: Scenario, seed: int) -> PlantCore:
    sim = sim_params(bench, scenario, seed)
    intent = RiderIntent(list(scenario.intent.pitch), list(scenario.intent.roll), list(scenario.intent.twist))
    pitch_deg, roll_deg = scenario.initial_tilt_deg
    tilt = (math.radians(pitch_deg), math.radians(roll_deg))
    robot = load_toml(find(scenario.robot, "robot"), RobotParams)
    plant = make_plant(robot, load_toml(find(scenario.rider, "riders"), RiderParams), sim, intent, tilt)
    plant.heeds_alert = scenario.intent.heeds_alert
    return plant


def controller_spec(bench: Bench, scenario: Scenario, at: Placement) -> DutSpec:
    """The bench's controller for this scenario on this bus and zenoh: what a run and `pure-hil controller`
    start the plug from (its model is the bench's robot if it names one: a model mismatch on purpose)."""
    return DutSpec(
        can=at.can,
        zenoh=at.zenoh,
        mode=reference_law(bench, scenario),
        robot=str(find(bench.controller.robot or scenario.robot, "robot")),
        rider=str(find(scenario.rider, "riders")),
        devices=bench.devices,
        controller_config=str(find(bench.controller.config, "controller")),
        lockstep=at.lockstep,
        tick_hz=at.tick_hz,
        driven=at.driven,
    )


def _start_parts(
    bench: Bench, scenario: Scenario, plant: PlantCore, wire: Wiring, lockstep: bool, stack: ExitStack
) -> Parts:
    """The supervisor and the controller as the bench places them (drivers/plugs.py): a plug in this
    process (embedded), the same plug in a child process from its spec (spawned), or nobody (external)."""
    work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="pure-hil-run-")))
    at = Placement(wire.bus_config, wire.access, plant.sim.tick_hz, lockstep)
    supervisor = None
    part = bench.supervisor
    if part.where != "external":
        spec = supervisor_spec(bench, scenario, replace(at, driven=part.where == "embedded"))
        if part.where == "embedded":
            handle = start_supervisor(part.plugin, spec, link=_supervisor_link(wire, lockstep, stack))
            stack.callback(handle.stop)
            supervisor = handle.node
        else:
            _spawn_part("supervisor", part.plugin, msgspec.json.encode(spec), work, stack)
    else:  # its rules are its starter's to hand it, but the run is judged by them: a bad one fails it here
        supervisor_rules(bench, scenario)
    dut = None
    controller = bench.controller
    if controller.where != "external":
        # An embedded controller is driven from the rig's tick under both clocks: in one process the GIL
        # runs one thread at a time, so a thread of its own only adds a hand-off per frame (in real time
        # it cost 58 % overruns and 11850 of 36000 commands where driven had 9 % and none; docs/rig.md).
        dut_spec = controller_spec(bench, scenario, replace(at, driven=controller.where == "embedded"))
        if controller.where == "embedded":
            dut = start_dut(controller.plugin, dut_spec)
            stack.callback(dut.stop)
        elif controller.command:  # a program of the lab's own, started as the bench file says
            _spawn(list(controller.command), "controller", stack)
        else:
            _spawn_part("controller", controller.plugin, msgspec.json.encode(dut_spec), work, stack)
    return Parts(supervisor, dut)


def _supervisor_link(wire: Wiring, lockstep: bool, stack: ExitStack) -> ZenohLink:
    """The embedded supervisor's zenoh: the rig's link on loopback; on the secured bench a session under
    its own certificate (the rig may not put the supervisor's keys), its puts counted with the rig's."""
    if wire.access.mode != "router":
        return wire.link
    session = wire.access.open("supervisor")
    stack.callback(session.close)
    link = ZenohLink(session, wire.link.keys, lossless=lockstep, puts=wire.puts)
    stack.callback(link.close)
    return link


def _spawn_part(kind: str, plugin: str, spec: bytes, work: Path, stack: ExitStack) -> None:
    """`pure-hil part KIND PLUGIN SPEC.json`: the plug in a child process, stopped with the run."""
    path = work / f"{kind}.json"
    path.write_bytes(spec)
    _spawn([*_pure_hil(), "part", kind, plugin, str(path)], kind, stack)


def _recorder(bus_config: BusConfig, logs: RunLogs | None, stack: ExitStack) -> BusRecorder | None:
    """The bus's frames into the run's logs (their writers own the files: the recorder writes none)."""
    if logs is None:
        return None
    recorder = BusRecorder(bus_config, None, [logs])
    stack.callback(recorder.stop)  # before the logs stop: it hands them the last frames
    return recorder


def _inputs(out: Path | None, logs: RunLogs | None, stack: ExitStack) -> InputsLog:
    if out is None:
        return InputsLog()
    inputs = InputsLog(out / "zenoh_inputs.msgpack", logs.zenoh if logs is not None else None)
    stack.callback(inputs.close)
    return inputs


def _agent_link(
    access: ZenohAccess, keys: Keys, lockstep: bool, puts: Counter[str], stack: ExitStack
) -> AgentLinks | None:
    """On the secured bench the scenario's SC requests and operator actions go out under the certificates
    of those roles (the rig's own may not put them); on loopback through the rig's session (None)."""
    if access.mode != "router":
        return None
    links = {}
    for role in ("sc-agent", "operator"):
        session = access.open(role)
        stack.callback(session.close)
        links[role] = ZenohLink(session, keys, lossless=lockstep, puts=puts)
        stack.callback(links[role].close)
    return AgentLinks(links["sc-agent"], links["operator"])


def _pure_hil() -> list[str]:
    script = Path(sys.executable).with_name("pure-hil")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hil.cli"]


def _spawn(command: list[str], name: str, stack: ExitStack) -> None:
    if shutil.which(command[0]) is None and not Path(command[0]).exists():
        raise FileNotFoundError(f"{name} command not found: {command[0]}")
    proc = subprocess.Popen(command)
    stack.callback(_stop, proc)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)  # it closes its bus and zenoh session
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def start_up(built: Built, bench: Bench) -> None:
    """The start-up handshake before the first SYNC (docs/contract.md): the supervisor's first frame (the
    embedded one sends it now, at t = 0), the controller's boot-up heartbeat, then its zenoh subscriptions
    if it has any. Raises ControllerUnavailable saying what did not come and what to check."""
    rig = built.rig
    if rig.supervisor is not None:
        rig.supervisor.update(0.0)
    where = bench.controller.where
    timeout = bench.controller.boot_timeout or BOOT_TIMEOUT[where]
    missing = rig.await_boot(timeout)
    if rig.port.stopping:
        return  # asked to end before the first tick: the tick loop runs none
    if missing:
        bus = f"{built.bus.interface}:{built.bus.channel}"
        hint = {
            "external": "start it on this bus (docs/contract.md, Start-up), e.g. "
            f"python examples/balance_controller.py --can {bus}",
            "spawned": "the spawned process did not come up: its output above says why",
            "embedded": "the embedded controller did not start",
        }[where]
        if MessageName.CONTROLLER_HEARTBEAT in missing:
            hint += (
                f"; since contract 2 a controller announces itself before the first SYNC: "
                f"CONTROLLER_HEARTBEAT State INIT, Contract {CONTRACT_VERSION}, every 100 ms"
            )
        raise ControllerUnavailable(f"waited {timeout:g} s on {bus} for {missing}: {hint}")
    wrong = mismatch(rig.controller_contract or 0)
    if wrong:
        raise ControllerUnavailable(wrong)
    rig.wait_for_subscriber(rig.keys.tes_wrench, ZENOH_GRACE)
    if rig.supervisor is None and not rig.wait_for_subscriber(rig.keys.sc_request, 10.0):
        if rig.port.stopping:
            return  # asked to end while waiting: a stop, not a missing supervisor
        raise ControllerUnavailable(
            f"no supervisor on {built.bus.interface}:{built.bus.channel} reads pure/sc/request"
        )
    rig.port.drain()
    rig.port.apply_permission()
    if rig.recorder is not None:
        rig.recorder.poll()  # the start-up's frames, at t = 0
