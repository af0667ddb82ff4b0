"""A run's folder: summary.json (the scenario as loaded, what ran (`as_run`: law, clock, seed), the bench,
versions, measurements, verdicts, the supervisor's record, bus and timing statistics, the names and units of
trace.npy's columns), can.log (candump -L; written during the run by the bus recorder), zenoh_inputs.msgpack
(what the controller was told over zenoh, for `pure-hil replay`), trace.npy (streamed during the run,
hil/outputs/trace_log.py), run.mcap (written during the run, checked here), recording.rrd (rerun) and
plots.png; and the table `pure-hil run` prints."""

from __future__ import annotations

import functools
import math
import platform
import subprocess
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import msgspec
import numpy as np

from drivers.vocabulary import State
from hil.bench.bench import OutputsPart
from hil.outputs.mcap_log import FAULT_LOG, FAULT_WINDOWS, OPERATOR, RIG_LATE, SUPERVISOR
from hil.outputs.mcap_log import check as check_mcap
from hil.outputs.trace_log import describe
from hil.run.judge import RunResult, operator_actions
from hil.run.measurements import unavailable, with_unit
from hil.run.scenario import Scenario
from hil.run.trace import Trace


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
        "mcap",
    ):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = "?"
    return out


SOURCE = Path(__file__).resolve().parents[2]
"""Where pure-hil's packages are: a git checkout's root, or site-packages for an installed wheel."""


@functools.cache
def commit(root: Path = SOURCE) -> str | None:
    """The git commit pure-hil runs from (its source at `root`), `+dirty` when its tracked files differ
    from it; None when it does not run from a git checkout (an installed wheel, no git)."""
    try:
        # A wheel installed in a virtual environment inside someone's checkout is not that checkout.
        if Path(_git(root, "rev-parse", "--show-toplevel")).resolve() != root.resolve():
            return None
        dirty = _git(root, "status", "--porcelain", "--untracked-files=no")
        return _git(root, "rev-parse", "HEAD") + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def _git(root: Path, *args: str) -> str:
    done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10)
    if done.returncode:
        raise OSError(done.stderr.strip())
    return done.stdout.strip()


def summary(result: RunResult) -> dict:
    tr = result.trace
    t = tr.timing
    return {
        "scenario": msgspec.to_builtins(result.scenario),
        # The scenario's own law, clock and seed are its wishes; the bench and the command line may
        # override them: these ran.
        "as_run": {"law": result.law, "clock": result.clock, "seed": result.seed},
        "bench": result.bench,
        "versions": versions(),
        "commit": commit(),
        "passed": result.passed,
        "verdict": result.verdict,
        "inconclusive": result.rig_was_late(),
        "failure": None if tr.failure is None else {"stage": tr.failure.stage, "error": tr.failure.error},
        # The same meaning as the `fallen` measurement (a criterion's value 1 or 0); how and when beside it.
        "fallen": tr.fallen is not None,
        "fall_cause": tr.fallen,
        "simulated": round(float(tr.t[-1]), 6) if len(tr.t) else 0.0,
        "stopped_early": tr.stopped_early,
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
            # Real time: the ticks whose SYNC the rig sent late and what that cost; the rest of the missing
            # and late commands above are the controller's own.
            "late": tr.lateness.as_dict(),
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
        "operator_actions": result.operator_actions(),
        "operator_actions_dropped": tr.operator_actions_dropped,
        "bus": tr.bus,
        "timing": {
            "wall_time": round(t.wall_time, 3),
            "speed": round(t.speed, 2),
            "overruns": t.overruns,
            "jitter_us": t.jitter_us,
            "policy": t.realtime_policy,
            "first_tick_at": t.started,
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
    final = int(tr.safety_state[-1]) if len(tr.safety_state) else -1
    return {
        "final_state": State(final).name if final in State._value2member_map_ else "none",
        "events": events,
        "speed_estimate_error_max": None if np.isnan(error).all() else round(float(np.nanmax(error)), 6),
        "drives_refused_commands": tr.stats.refused_commands,
        "drives_permission_lost": tr.stats.permission_lost,
        "contactor_opened": tr.stats.contactor_opened,
        "recovery_commands": tr.stats.recovery_commands,
        "overridden_commands": tr.stats.overridden_commands,
        "fence_misses": tr.fence_misses,
        "identity_rejected": tr.identity_rejected,
        "sc_arbitration": tr.sc_arbitration,
        "diagnostics": tr.diagnostics,
        "ended_resting": bool(len(tr.resting) and tr.resting[-1]),
        "drives_off_at": _drives_off_at(tr),
    }


def events(tr: Trace, scenario: Scenario) -> list[tuple[str, float, dict]]:
    """The run's events as run.mcap carries them, (topic, t, message): each fault's window, the fault log,
    the supervisor's events, the operator's actions, the rig's late windows; the same records as the
    summary's."""
    out: list[tuple[str, float, dict]] = []
    for n, (spec, window) in enumerate(zip(tr.faults, tr.fault_windows, strict=True)):
        if window is not None:
            window_message = {
                "fault": n,
                "kind": spec.kind,
                "description": spec.describe(),
                "start": round(window[0], 6),
                "end": round(window[1], 6),
                "live": n >= len(scenario.faults),
                "expect": msgspec.to_builtins(spec.expect),
            }
            out.append((FAULT_WINDOWS, window[0], window_message))
    out += [
        (FAULT_LOG, e.t, {k: v for k, v in msgspec.to_builtins(e).items() if k != "t"})
        for e in tr.fault_events
    ]
    out += [
        (
            SUPERVISOR,
            e.t,
            {
                "kind": e.kind,
                "from_state": e.from_state,
                "to_state": e.to_state,
                "cause": e.cause,
                "detail": e.detail,
            },
        )
        for e in tr.safety_events
    ]
    out += [
        (OPERATOR, a["t"], {k: v for k, v in a.items() if k != "t"}) for a in operator_actions(tr, scenario)
    ]
    out += [(RIG_LATE, a, {"start": round(a, 6), "end": round(b, 6)}) for a, b in tr.lateness.windows]
    return sorted(out, key=lambda event: event[1])


def _drives_off_at(tr: Trace) -> float | None:
    """The time from which every drive stayed off to the end of the run (None: on at the end)."""
    if not len(tr.powered) or tr.powered[-1]:
        return None
    on = np.nonzero(tr.powered)[0]
    return round(float(tr.t[on[-1] + 1 if len(on) else 0]), 6)


def write_outputs(result: RunResult, out: Path, outputs: OutputsPart) -> dict[str, str]:
    """The run folder: summary.json first and always, then each other output the bench's `[outputs]` asks
    for on its own (one that fails is named in the summary, and the rest are still written). Returns the
    failed outputs and why."""
    summary_file = out / "summary.json"

    trace = describe(len(result.trace.t)) if (out / "trace.npy").exists() else None

    def write_summary(failed: dict[str, str]) -> None:
        data = {**summary(result), "trace": trace, "outputs_failed": failed}
        summary_file.write_bytes(msgspec.json.format(msgspec.json.encode(data), indent=2))

    write_summary({})
    failed: dict[str, str] = {}
    for name, write in _outputs(result, out, outputs):
        try:
            write()
        except Exception as exc:  # one output failing must not lose the others or the summary
            failed[name] = f"{type(exc).__name__}: {exc}"
    failed.update(result.trace.outputs_failed)  # the writer's own word on why, over what the file shows
    if failed:
        write_summary(failed)
    return failed


def _outputs(result: RunResult, out: Path, outputs: OutputsPart):
    """(file, writer) of the run folder besides summary.json and can.log (the recorder writes that one);
    run.mcap was written during the run: its writer here checks that it is complete."""
    tr = result.trace
    if outputs.mcap:
        yield "run.mcap", lambda: check_mcap(out / "run.mcap")
    if tr.zenoh_inputs is not None:  # None: the run streamed it there already
        yield (
            "zenoh_inputs.msgpack",
            lambda: (out / "zenoh_inputs.msgpack").write_bytes(msgspec.msgpack.encode(tr.zenoh_inputs)),
        )
    if not len(tr.t):
        return  # nothing ran: no recording, no plots
    # Imported here: matplotlib and rerun cost seconds of start-up (a minute on an emulated CPU), and a
    # run without a folder never needs them.
    from hil.outputs.recording import write_rrd
    from hil.report.plots import write_plots

    if outputs.recording:
        yield "recording.rrd", lambda: write_rrd(out / "recording.rrd", tr, result.scenario.name)
    if outputs.plots:
        yield "plots.png", lambda: write_plots(out / "plots.png", result)


def format_table(result: RunResult) -> str:
    rows = [
        (
            v.criterion,
            "unavailable" if v.note.startswith("unavailable") else with_unit(f"{v.value:.3f}", v.units),
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
    lines += [f"INCONCLUSIVE: {why}" for why in result.rig_was_late()]
    # Under the real-time clock: the rig's own lateness beside the controller's.
    late = ""
    if result.clock == "realtime":
        s, rig = tr.stats, tr.lateness
        late = (
            f", {tr.timing.overruns} overruns of {tr.timing.ticks} ticks, {rig.ticks} SYNCs late; commands "
            f"missing {s.missing_commands - rig.missing} and late {s.late_commands - rig.late} (the "
            f"controller's), {rig.missing} and {rig.late} (the rig's)"
        )
    lines.append(
        f"{result.scenario.name}: {tr.t[-1] if len(tr.t) else 0:.2f} s simulated "
        f"({result.law}, {result.clock}) in {tr.timing.wall_time:.1f} s wall "
        f"({tr.timing.speed:.1f}x real time){late}; {result.verdict}"
    )
    if math.isfinite(tr.timing.speed) and tr.fallen:
        lines.append(f"the robot fell: {tr.fallen}")
    return "\n".join(lines)
