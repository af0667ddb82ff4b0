"""Build a run from a bench and a scenario: the plant, the bus, zenoh, the supervisor and the controller
where the bench puts them, every resource entered in one ExitStack (closed in reverse on any exit, a
failure included), then the start-up handshake before the first SYNC (docs/contract.md, Start-up)."""

from __future__ import annotations

import json
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
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import msgspec
import zenoh

from drivers.can_bus import BusConfig, BusRecorder, open_bus, private_channel
from drivers.can_codec import MessageName
from drivers.config import load_toml
from drivers.contract import CONTRACT_VERSION, mismatch
from drivers.devices import host_node
from drivers.dut import DutHandle, DutSpec, start_dut
from drivers.keys import Keys
from drivers.resources import find
from drivers.schemas import SafetyState
from drivers.zenoh_link import ZenohAccess, ZenohLink, lend
from hil.bench.bench import Bench, RealtimePart
from hil.bench.rigs import announce
from hil.devices import rig_node
from hil.faults import FaultError, FaultSet
from hil.outputs.inputs_log import InputsLog
from hil.outputs.mcap_log import McapLog
from hil.run.rig import AgentLinks, OperatorStep, Rig, ScStep
from hil.run.scenario import Scenario
from hil.run.trace import ControllerUnavailable
from plant.ballbot import Plant, RiderIntent
from plant.params import RiderParams, RobotParams, SimParams
from safety.config import RobotGeometry, SupervisorConfig
from safety.node import SupervisorNode


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
    on_tick: Callable[[Plant], None] | None = None
    """Called after every tick with the plant (the service applies live rider intent there)."""
    stop: threading.Event | None = None
    """Set it to end the run early (the service's stop)."""
    session: zenoh.Session | None = None
    """The rig's zenoh session, owned by the caller (the long-running service keeps one)."""
    fault_set: FaultSet | None = None
    """The run's faults, kept by a caller that injects more live (the service)."""
    stop_on_fall: bool = True


@dataclass(slots=True)
class Built:
    rig: Rig
    plant: Plant
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
    mcap: McapLog | None = None
    """run.mcap, which the loop hands every tick's row (None: not written)."""


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


def supervisor_config(bench: Bench, scenario: Scenario) -> SupervisorConfig:
    """The bench's supervisor rules with the scenario's `[safety]` overrides."""
    return scenario.supervisor_config(load_toml(find(bench.supervisor.config, "safety"), SupervisorConfig))


def build(
    bench: Bench, scenario: Scenario, seed: int, options: RunOptions, out: Path | None, stack: ExitStack
) -> Built:
    """out: the run folder, where the CAN log and the zenoh inputs stream during the run (None: none)."""
    mcap = None
    if out is not None and bench.outputs.mcap:  # first: a run that fails to build still leaves its file
        meta = {"scenario": scenario.name, "seed": str(seed), "bench": bench.name}
        mcap = stack.enter_context(
            McapLog(out / "run.mcap", scenario.tick_hz, Keys(bench.zenoh.prefix), meta)
        )
    robot_path, rider_path = find(scenario.robot, "robot"), find(scenario.rider, "riders")
    sim = msgspec.structs.replace(
        load_toml(find(bench.sim, "sim"), SimParams), tick_hz=scenario.tick_hz, seed=seed
    )
    intent = RiderIntent(list(scenario.intent.pitch), list(scenario.intent.roll), list(scenario.intent.twist))
    pitch_deg, roll_deg = scenario.initial_tilt_deg
    tilt = (math.radians(pitch_deg), math.radians(roll_deg))
    plant = Plant(load_toml(robot_path, RobotParams), load_toml(rider_path, RiderParams), sim, intent, tilt)
    plant.heeds_alert = scenario.intent.heeds_alert
    if mcap is not None:
        mcap.clock = lambda: plant.t
    law, clock = law_of(bench, scenario), clock_of(bench, scenario)
    lockstep = clock == "lockstep"
    safety = supervisor_config(bench, scenario)
    faults = options.fault_set if options.fault_set is not None else FaultSet(scenario.faults, seed)
    if faults and bench.rider_on_board:
        raise FaultError(f"bench {bench.name} says a person is on the robot (rider_on_board): no faults")

    bus_config = (
        bench.can if bench.can.channel else msgspec.structs.replace(bench.can, channel=private_channel())
    )
    bus = open_bus(bus_config)
    stack.callback(bus.shutdown)
    keys = Keys(bench.zenoh.prefix)
    if options.session is not None:
        session, zenoh_access = options.session, bench.zenoh
    else:
        session, zenoh_access = bench.zenoh.open_rig(fallback=bench.self_contained)
        stack.callback(session.close)
        if zenoh_access.mode == "loopback":  # operators' clients find it (hil/bench/rigs.py)
            where = zenoh_access.hub_endpoint()
            stack.enter_context(announce(session, keys.prefix, bench.name, where, f"run {scenario.name}"))
    if zenoh_access.mode == "loopback":
        stack.enter_context(lend(session, zenoh_access.endpoint))  # the embedded controller joins it
    puts: Counter[str] = Counter()  # every put of this process, whatever its session: the fence counts them
    link = ZenohLink(session, keys, lossless=lockstep, puts=puts)
    stack.callback(link.close)
    agent_link = _agent_link(zenoh_access, keys, lockstep, puts, stack)
    recorder = None
    if out is not None and (bench.outputs.can_log or mcap is not None):
        can_log = out / "can.log" if bench.outputs.can_log else None
        recorder = BusRecorder(bus_config, can_log, [mcap] if mcap is not None else [])
        stack.callback(recorder.stop)

    supervisor = None
    if bench.supervisor.where == "embedded":
        supervisor_bus = open_bus(bus_config)
        stack.callback(supervisor_bus.shutdown)
        supervisor_link = link
        if zenoh_access.mode == "router":  # its own certificate: the rig may not put the supervisor's keys
            supervisor_session = zenoh_access.open("supervisor")
            stack.callback(supervisor_session.close)
            supervisor_link = ZenohLink(supervisor_session, keys, lossless=lockstep, puts=puts)
            stack.callback(supervisor_link.close)
        geometry = load_toml(robot_path, RobotGeometry)
        supervisor = SupervisorNode(
            host_node(supervisor_bus, bench.devices, geometry.encoder.counts_per_rev, "supervisor"),
            supervisor_link,
            safety,
            geometry,
            tick_hz=sim.tick_hz,
        )
    rig = Rig(
        plant,
        rig_node(bus, bench.devices, plant.robot.encoder.counts_per_rev, sim.tick_hz),
        link,
        tuple(ScStep(scenario.tick_of(e.at), e.mode, e.cap) for e in scenario.sc),
        supervisor=supervisor,
        operator=tuple(OperatorStep(scenario.tick_of(e.at), e.action) for e in scenario.operator),
        faults=faults,
        bitrate=bus_config.bitrate,
        agent_link=agent_link,
        recovery_in_commands=not bench.devices.pure,
    )
    if supervisor is None:  # a supervisor in another process: its transitions as it announces them
        rig.safety_states = link.subscribe(keys.safety_state, SafetyState, capacity=1 << 14)

    work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="pure-hil-run-")))
    effective = msgspec.structs.replace(bench, can=bus_config, zenoh=zenoh_access)
    if bench.supervisor.where == "spawned":
        command = [*_pure_hil(), "supervisor", "--bench", str(write_bench(effective, work / "bench.json"))]
        command += ["--robot", str(robot_path), "--tick-hz", f"{sim.tick_hz:g}"]
        command += ["--clock", clock, "--safety", json.dumps(scenario.safety)]
        _spawn(command, "supervisor", stack)
    dut = None
    controller = bench.controller
    if controller.where == "embedded":
        dut = start_dut(
            controller.plugin,
            DutSpec(
                can=bus_config,
                zenoh=zenoh_access,
                mode=reference_law(bench, scenario),
                robot=str(find(controller.robot or robot_path, "robot")),
                rider=str(rider_path),
                devices=bench.devices,
                controller_config=str(find(controller.config, "controller")),
                lockstep=lockstep,
                tick_hz=sim.tick_hz,
                driven=lockstep,
            ),
        )
        stack.callback(dut.stop)
    elif controller.where == "spawned":
        command = list(controller.command) or [
            *_pure_hil(),
            "controller",
            "--bench",
            str(write_bench(effective, work / "bench.json")),
            "--rider",
            str(rider_path),
            "--robot",
            str(find(controller.robot or robot_path, "robot")),
            "--law",
            law,
            *(["--lockstep"] if lockstep else []),
        ]
        _spawn(command, "controller", stack)
    if out is not None:
        rig.inputs = InputsLog(out / "zenoh_inputs.msgpack", mcap.zenoh if mcap is not None else None)
        stack.callback(rig.inputs.close)
    rig.dut = dut
    rig.recorder = recorder
    rig.poll_dut = getattr(dut, "poll", None) if lockstep else None
    faults.attach(rig)
    trace = None if out is None else out / "trace.npy"
    return Built(rig, plant, bus_config, law, clock, scenario.duration, dut, trace, bench.realtime, mcap)


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


def write_bench(bench: Bench, path: Path) -> Path:
    """The bench as the rig runs it (its overrides applied), for the processes it spawns."""
    if not path.exists():
        path.write_bytes(msgspec.json.encode(bench))
    return path


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
        raise ControllerUnavailable(
            f"no supervisor on {built.bus.interface}:{built.bus.channel} reads pure/sc/request"
        )
    rig.apply_permission()
    if rig.recorder is not None:
        rig.recorder.poll()  # the start-up's frames, at t = 0
