"""One run, one pipeline: build (every resource in one ExitStack) -> tick loop -> judge -> write.

    result = run(load_scenario("balance"), load_bench("embedded"), out=Path("runs/balance"))

Every command that runs a scenario (run, compare, campaign, serve, the pytest plugin) comes through here.
It never raises for a run that failed: the result's trace says where (`failure`) and keeps the ticks done so
far, and the run folder is written all the same.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path
from typing import TypeVar

import msgspec

from drivers.config import ConfigError, load_toml
from drivers.resources import find
from drivers.rules import JudgedRules
from hil.bench.bench import Bench, load_bench
from hil.faults import load_with_faults
from hil.outputs.run_logs import RunLogs
from hil.report.folder import events, write_outputs
from hil.run.build import (
    RunOptions,
    build,
    clock_of,
    judged_rules,
    law_of,
    run_logs,
    sim_params,
    start_up,
    supervisor_rules,
)
from hil.run.judge import RunResult, judge
from hil.run.loop import tick_loop
from hil.run.plants import load_sim
from hil.run.scenario import Scenario
from hil.run.trace import CONFIG_ERRORS, ControllerUnavailable, Failure, Trace, reason
from plant.params import RiderParams, RobotParams

T = TypeVar("T")


def run(
    scenario: Scenario,
    bench: Bench | None = None,
    *,
    out: Path | None = None,
    seed: int | None = None,
    options: RunOptions | None = None,
) -> RunResult:
    """Run `scenario` on `bench` (default: the embedded bench), judge it and, with `out`, write its folder."""
    bench = bench or load_bench()
    options = options or RunOptions()
    seed = scenario.seed if seed is None else seed
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    trace = execute(bench, scenario, seed, options, out)
    result = RunResult(
        scenario,
        law_of(bench, scenario),
        clock_of(bench, scenario),
        seed,
        trace,
        {},
        ball_radius=_ball_radius(scenario),
        safety=_safety(bench, scenario),
        bench=describe(bench),
    )
    judge(result)
    if out is not None:
        write_outputs(result, out, bench.outputs)
    return result


def execute(bench: Bench, scenario: Scenario, seed: int, options: RunOptions, out: Path | None) -> Trace:
    """Build, hand-shake and tick; a failure before the first tick is an empty trace saying why."""
    stage = "build"
    logs = None
    try:
        with ExitStack() as stack:  # every resource of the run, closed in reverse on any exit
            logs = run_logs(bench, scenario, seed, options, out)
            if logs is not None:
                stack.callback(logs.stop)  # last: the recorder hands it the bus's last frames first
            check_start(scenario, bench, f"scenario {scenario.name}")
            built = build(bench, scenario, seed, options, out, logs, stack)
            stage = "start-up"
            start_up(built, bench)
            trace = tick_loop(built, options)
            if logs is not None:
                _hand_events(logs, trace, scenario)
    except Exception as exc:  # nothing ran: keep the reason
        stage = "start-up" if isinstance(exc, ControllerUnavailable) else stage
        trace = Trace.empty(Failure(stage, reason(exc), isinstance(exc, CONFIG_ERRORS)))
    if logs is not None:
        trace.outputs_failed.update(logs.failed)
    return trace


def _hand_events(logs: RunLogs, trace: Trace, scenario: Scenario) -> None:
    """The run's events into run.mcap, before its logs stop; a failure loses them, never the run."""
    try:
        for topic, t, message in events(trace, scenario):
            logs.event(topic, t, message)
    except Exception as exc:
        trace.outputs_failed.setdefault("run.mcap", f"its events: {type(exc).__name__}: {exc}")


def _named_file(origin: str, field: str, name: str, kind: str, schema: type[T]) -> T:
    """The file a scenario's `field` names, decoded; its error under that field and `origin`."""
    try:
        return load_toml(find(name, kind), schema)
    except ConfigError as exc:
        said = exc.detail if exc.path == Path(name) else str(exc)  # its path once
        raise ConfigError(origin, f'{field} = "{name}": {said}') from None


def check_start(scenario: Scenario, bench: Bench, origin: str) -> RiderParams:
    """The scenario's rider, once the run can start; else ConfigError naming `origin` (the scenario's file,
    or where its text came from), the file, the field and the bound, before anything runs: a robot or rider
    file that cannot be read or is not one, a number of either beyond its physical bound (drivers/bounds.py),
    `[safety]` overrides the bench's supervisor does not take, a rider's intent past that rider's reach, or
    a start the robot cannot be released in on this bench (beyond its sim file's fall bound, or a foot or
    the rim on the floor)."""
    robot = _named_file(origin, "robot", scenario.robot, "robot", RobotParams)
    rider = _named_file(origin, "rider", scenario.rider, "riders", RiderParams)
    robot_file, rider_file = find(scenario.robot, "robot"), find(scenario.rider, "riders")
    supervisor_rules(bench, scenario, f"{origin} [safety]")
    sim_file = find(bench.sim, "sim")
    try:
        scenario.intent.check_reach(rider, str(rider_file))
        scenario.check_start(
            load_sim(sim_file).fall_tilt_deg,
            str(sim_file),
            robot,
            rider,
            f"robot {robot_file} with rider {rider_file}",
        )
    except ValueError as exc:
        raise ConfigError(origin, str(exc)) from None
    return rider


def describe(bench: Bench) -> dict:
    """The bench as a run's summary reports it: where each part ran and how they met."""
    return {
        "name": bench.name,
        "can": f"{bench.can.interface}:{bench.can.channel or '(private)'}",
        "controller": bench.controller.where,
        "supervisor": bench.supervisor.where,
        "supervisor_plug": bench.supervisor.plug,
        "zenoh": bench.zenoh.mode,
        "devices": msgspec.to_builtins(bench.devices),
        "rider_on_board": bench.rider_on_board,
        "plant": _plant_kind(bench),
    }


def _plant_kind(bench: Bench) -> str:
    try:
        return sim_params(bench).plant
    except CONFIG_ERRORS:
        return "unknown"  # the trace already says why the run failed


def load_scenario(name: str | Path) -> Scenario:
    """A scenario by path or shipped short name."""
    return load_with_faults(find(name, "scenarios"), Scenario)


def _ball_radius(scenario: Scenario) -> float:
    try:
        return load_toml(find(scenario.robot, "robot"), RobotParams).ball.radius
    except CONFIG_ERRORS:
        return float("nan")  # the trace already says why the run failed


def _safety(bench: Bench, scenario: Scenario) -> JudgedRules:
    try:
        return judged_rules(bench, scenario)
    except CONFIG_ERRORS:
        return JudgedRules()  # the trace already says why the run failed
