"""Run a scenario and judge it: metrics, verdicts, and the run folder (docs/rig.md).

Run folder: summary.json (config echo, seed, versions, metrics, verdicts, bus and timing statistics),
can.log (candump -L format; python-can's LogReader and can-utils read it), zenoh_inputs.msgpack (what the
controller was told over zenoh, for `pure-hil replay`), recording.rrd (rerun), plots.png.
"""

from __future__ import annotations

import math
import platform
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import msgspec
import numpy as np

from drivers.can_bus import BusConfig
from drivers.config import load_toml
from drivers.resources import find
from hil.faults import FaultSet
from hil.faults.verdicts import fault_verdicts
from hil.metrics import NEEDS_TELEMETRY, plane_metrics
from hil.rig import OperatorStep, ScStep
from hil.scenario import UNITS, Criterion, Scenario, Verdict
from hil.session import RunSpec, Trace, run
from plant.ballbot import RiderIntent
from plant.params import RobotParams, SimParams

STOPPED = 0.1
"""m/s below which the robot counts as stopped (stop_time)."""


@dataclass(slots=True)
class RunResult:
    scenario: Scenario
    controller: str
    clock: str
    seed: int
    trace: Trace
    metrics: dict[str, float]
    verdicts: list[Verdict] = field(default_factory=list)
    ball_radius: float = math.nan
    """Of the plant's robot (metrics in rad/s need it)."""

    @property
    def passed(self) -> bool:
        return self.trace.failure is None and all(v.passed for v in self.verdicts)


def plane_speed(trace: Trace, plane: str) -> np.ndarray:
    """Ground speed along a plane's forward direction (the roll plane's forward is −y)."""
    return trace.velocity[:, 0] if plane == "pitch" else -trace.velocity[:, 1]


def measure(trace: Trace, c: Criterion, ball_radius: float) -> float:
    if c.metric == "fallen":
        return float(trace.fallen is not None)
    if c.metric == "missing_commands":
        return float(trace.stats.missing_commands)
    if c.metric == "distance":
        return float(np.hypot(*trace.position[-1]))
    if c.metric == "safety_state":
        return float(trace.safety_state[-1]) if len(trace.safety_state) else math.nan
    if c.metric == "resting":
        return float(bool(len(trace.resting)) and bool(trace.resting[-1]))
    if c.metric == "safety_reaction":
        times = [
            e.t
            for e in trace.safety_events
            if e.kind == "transition" and e.cause == c.cause and e.t >= c.after
        ]
        return times[0] - c.after if times else math.nan
    if c.metric == "drives_off_after":
        # From `after`, the first tick from which the drives stay off to the end of the run.
        on = np.nonzero((trace.t >= c.after) & trace.powered)[0]
        last_on = on[-1] if len(on) else np.searchsorted(trace.t, c.after) - 1
        if last_on + 1 >= len(trace.t):
            return math.nan
        return float(trace.t[last_on + 1] - c.after)
    window = trace.t >= c.after
    if not window.any():
        return math.nan  # the run ended (fell, controller lost) before the window: the criterion fails
    if c.metric == "max_yaw_rate":
        return float(np.abs(trace.yaw_rate[window]).max())
    planes = ("pitch", "roll") if c.plane == "both" else (c.plane,)
    values = []
    for plane in planes:
        k = 0 if plane == "pitch" else 1
        speed = plane_speed(trace, plane)
        if c.metric == "stop_time":
            moving = np.nonzero(window & (np.abs(speed) > STOPPED))[0]
            values.append(0.0 if len(moving) == 0 else float(trace.t[moving[-1]] - c.after))
            continue
        if c.metric == "final_speed":
            values.append(float(abs(speed[-1])))
            continue
        m = plane_metrics(
            trace.t[window],
            trace.lean[window, k],
            trace.tilt[window, k],
            speed[window],
            trace.command_speed[window, k],
            ball_radius,
        )
        values.append(getattr(m, c.metric))
    return max(values)


def run_scenario(
    scenario: Scenario,
    *,
    controller: str | None = None,
    can: BusConfig | None = None,
    clock: str | None = None,
    seed: int | None = None,
    out: Path | None = None,
    progress=None,
    hub_endpoint: str | None = None,
    on_tick=None,
    stop=None,
    session=None,
    supervisor: str = "embedded",
    fault_set: FaultSet | None = None,
    boot_timeout: float | None = None,
) -> RunResult:
    """Run and judge a scenario. `fault_set`: a FaultSet built from the scenario's faults that the caller
    keeps to inject more live (the service)."""
    controller = controller or scenario.controller
    clock = clock or scenario.clock
    seed = scenario.seed if seed is None else seed
    robot_path = find(scenario.robot, "robot")
    robot = load_toml(robot_path, RobotParams)
    sim = SimParams(tick_hz=scenario.tick_hz, seed=seed)
    intent = RiderIntent(list(scenario.intent.pitch), list(scenario.intent.roll), list(scenario.intent.twist))
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    spec = RunSpec(
        rider=find(scenario.rider, "riders"),
        mode="hacs" if controller == "external" else controller,
        controller="external" if controller == "external" else "reference",
        duration=scenario.duration,
        robot=robot_path,
        sim=sim,
        intent=intent,
        sc_schedule=tuple(ScStep(e.at, e.mode, e.cap) for e in scenario.sc),
        operator=tuple(OperatorStep(e.at, e.action) for e in scenario.operator),
        safety=scenario.safety,
        supervisor=supervisor,
        faults=tuple(scenario.faults),
        fault_set=fault_set,
        initial_tilt_deg=scenario.initial_tilt_deg,
        can=can,
        clock=clock,
        can_log=None if out is None else out / "can.log",
        progress=progress,
        hub_endpoint=hub_endpoint,
        on_tick=on_tick,
        stop=stop,
        session=session,
        controller_config=find("controller/default.toml"),
        boot_timeout=boot_timeout,
    )
    trace = run(spec)
    result = RunResult(
        scenario,
        controller,
        clock,
        seed,
        trace,
        summary_metrics(trace, robot.ball.radius),
        [],
        robot.ball.radius,
    )
    for c in scenario.criteria:
        value = measure(trace, c, robot.ball.radius)
        note = unavailable(trace, c.metric) if math.isnan(value) else ""
        result.verdicts.append(
            Verdict(c.label, value, c.describe(), UNITS[c.metric], c.check(value), note or c.note)
        )
    result.verdicts += fault_verdicts(trace)
    if out is not None:
        write_outputs(result, out)
    return result


def summary_metrics(trace: Trace, ball_radius: float) -> dict[str, float]:
    """The run's metrics; NaN for those with nothing to measure (unavailable(): why)."""
    out: dict[str, float] = {}
    for k, plane in enumerate(("pitch", "roll")):
        speed = plane_speed(trace, plane)
        m = plane_metrics(
            trace.t, trace.lean[:, k], trace.tilt[:, k], speed, trace.command_speed[:, k], ball_radius
        )
        for name in ("max_speed", "max_tilt_deg", "max_lean_deg", "rmse", "rmse_paper"):
            out[f"{plane}.{name}"] = round(float(getattr(m, name)), 9)
    ran = bool(len(trace.t))
    out["distance"] = round(float(np.hypot(*trace.position[-1])), 9) if ran else math.nan
    out["max_yaw_rate"] = round(float(np.abs(trace.yaw_rate).max()), 9) if ran else math.nan
    return out


def unavailable(trace: Trace, metric: str) -> str:
    """Why a metric could not be measured in this run ('' if it could)."""
    if not len(trace.t):
        return "unavailable (the run never ticked)"
    if metric.split(".")[-1] in NEEDS_TELEMETRY and trace.controller_telemetry_missing == len(trace.t):
        return "unavailable (no controller telemetry)"
    return ""


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in (
        "pure-hil",
        "numpy",
        "scipy",
        "control",
        "python-can",
        "cantools",
        "eclipse-zenoh",
        "rerun-sdk",
        "msgspec",
    ):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = "?"
    return out


def summary(result: RunResult) -> dict:
    tr = result.trace
    t = tr.timing
    return {
        "scenario": msgspec.to_builtins(result.scenario),
        "controller": result.controller,
        "clock": result.clock,
        "seed": result.seed,
        "versions": versions(),
        "passed": result.passed,
        "failure": None if tr.failure is None else {"stage": tr.failure.stage, "error": tr.failure.error},
        "fallen": tr.fallen,
        "simulated": round(float(tr.t[-1]), 6) if len(tr.t) else 0.0,
        "metrics": {k: None if math.isnan(v) else v for k, v in result.metrics.items()},
        "metrics_unavailable": {k: why for k in result.metrics if (why := unavailable(tr, k))},
        "verdicts": [msgspec.to_builtins(v) for v in result.verdicts],
        "rig": {
            "ticks": tr.stats.ticks,
            "missing_commands": tr.stats.missing_commands,
            "late_commands": tr.stats.late_commands,
            "guards_expired": tr.stats.guards_expired,
            "controller_states": {str(k): v for k, v in sorted(tr.stats.controller_states.items())},
            "controller_telemetry_missing": tr.controller_telemetry_missing,
        },
        "safety": safety_summary(tr),
        "faults": [
            {
                "number": n,
                "fault": msgspec.to_builtins(spec),
                "acted": None if window is None else [round(window[0], 6), round(window[1], 6)],
            }
            for n, (spec, window) in enumerate(zip(tr.faults, tr.fault_windows, strict=True))
        ],
        "fault_events": [msgspec.to_builtins(e) for e in tr.fault_events],
        "bus": tr.bus,
        "timing": {
            "wall_time": round(t.wall_time, 3),
            "speed": round(t.speed, 2),
            "overruns": t.overruns,
            "jitter_us": t.jitter_us,
            "policy": t.realtime_policy,
        },
    }


def safety_summary(tr: Trace) -> dict:
    """The supervisor's record, each event with the plant's truth at that moment (the referee's view)."""
    truth_speed = np.hypot(tr.velocity[:, 0], tr.velocity[:, 1])
    events = []
    for e in tr.safety_events:
        i = min(int(np.searchsorted(tr.t, e.t - 1e-9)), len(tr.t) - 1)
        events.append(
            {
                **msgspec.to_builtins(e),
                "truth": {
                    "speed": round(float(truth_speed[i]), 6),
                    "tilt_deg": round(float(np.degrees(np.abs(tr.tilt[i]).max())), 6),
                },
            }
        )
    error = np.abs(tr.safety_speed - truth_speed)
    names = ("NORMAL", "LIMITING", "STOPPING", "ESTOP")
    final = int(tr.safety_state[-1]) if len(tr.safety_state) else -1
    return {
        "final_state": names[final] if 0 <= final < len(names) else "none",
        "events": events,
        "speed_estimate_error_max": None if np.isnan(error).all() else round(float(np.nanmax(error)), 6),
        "drives_refused_commands": tr.stats.refused_commands,
        "drives_permission_lost": tr.stats.permission_lost,
        "contactor_opened": tr.stats.contactor_opened,
        "fence_misses": tr.fence_misses,
        "identity_rejected": tr.identity_rejected,
        "sc_arbitration": tr.sc_arbitration,
        "diagnostics": tr.diagnostics,
        "ended_resting": bool(len(tr.resting) and tr.resting[-1]),
        "drives_off_at": _drives_off_at(tr),
    }


def _drives_off_at(tr: Trace) -> float | None:
    """The time from which every drive stayed off to the end of the run (None: on at the end)."""
    if not len(tr.powered) or tr.powered[-1]:
        return None
    on = np.nonzero(tr.powered)[0]
    return round(float(tr.t[on[-1] + 1 if len(on) else 0]), 6)


def write_outputs(result: RunResult, out: Path) -> dict[str, str]:
    """The run folder: summary.json first and always, then each other output on its own (one that fails
    is named in the summary, and the rest are still written). Returns the failed outputs and why."""
    summary_file = out / "summary.json"

    def write_summary(failed: dict[str, str]) -> None:
        data = {**summary(result), "outputs_failed": failed}
        summary_file.write_bytes(msgspec.json.format(msgspec.json.encode(data), indent=2))

    write_summary({})
    failed: dict[str, str] = {}
    for name, write in _outputs(result, out):
        try:
            write()
        except Exception as exc:  # one output failing must not lose the others or the summary
            failed[name] = f"{type(exc).__name__}: {exc}"
    if failed:
        write_summary(failed)
    return failed


def _outputs(result: RunResult, out: Path):
    """(file, writer) of the run folder besides summary.json and can.log (the recorder writes that one)."""
    tr = result.trace
    yield (
        "zenoh_inputs.msgpack",
        lambda: (out / "zenoh_inputs.msgpack").write_bytes(msgspec.msgpack.encode(tr.zenoh_inputs)),
    )
    if not len(tr.t):
        return  # nothing ran: no recording, no plots
    # Imported here: matplotlib and rerun cost seconds of start-up (a minute on an emulated CPU), and a
    # run without a folder never needs them.
    from hil.plots import write_plots
    from hil.recording import write_rrd

    caps = [e.cap for e in result.scenario.sc if e.mode == "limit"]
    title = f"{result.scenario.name} ({result.controller}, {result.clock})"
    yield "recording.rrd", lambda: write_rrd(out / "recording.rrd", tr, result.scenario.name)
    yield "plots.png", lambda: write_plots(out / "plots.png", tr, title, caps[0] if caps else None)


def format_table(result: RunResult) -> str:
    rows = [
        (
            v.criterion,
            "unavailable" if v.note.startswith("unavailable") else f"{v.value:.3f} {v.units}".strip(),
            v.limit,
            "PASS" if v.passed else "FAIL",
        )
        for v in result.verdicts
    ]
    head = ("criterion", "measured", "limit", "verdict")
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(4)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    lines += [f"  {v.criterion}: {v.note}" for v in result.verdicts if not v.passed and v.note]
    tr = result.trace
    if tr.failure is not None:
        lines.append(f"the run failed at {tr.failure.stage}: {tr.failure.error}")
    lines.append(
        f"{result.scenario.name}: {tr.t[-1] if len(tr.t) else 0:.2f} s simulated "
        f"({result.controller}, {result.clock}) in {tr.timing.wall_time:.1f} s wall "
        f"({tr.timing.speed:.1f}x real time); " + ("PASSED" if result.passed else "FAILED")
    )
    if math.isfinite(tr.timing.speed) and tr.fallen:
        lines.append(f"the robot fell: {tr.fallen}")
    return "\n".join(lines)


def load_scenario(path: Path) -> Scenario:
    return load_toml(path, Scenario)
