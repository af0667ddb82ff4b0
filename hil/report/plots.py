"""plots.png: what a person looks at first after a run (speed, tilt, torso lean, motor torques), titled with
its verdict and faults, with what the supervisor did, when each fault acted, the SC's command cap and the
criteria's bounds."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import warnings

import matplotlib.pyplot as plt
import msgspec
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from drivers.vocabulary import State
from hil.run.judge import RunResult

STRETCHES = 2000
"""A longer run is drawn as the min and max of this many stretches of ticks (the 900-pixel-wide figure
shows no more): the plot's time and memory stay flat in the run's length, and every peak stays visible."""


def _stretched(t, values, reduce):
    """(start time, `reduce`d value) per stretch of ticks; the run itself when it is short enough."""
    values = np.asarray(values, float)
    if len(t) <= 2 * STRETCHES:
        return np.asarray(t, float), values
    k = -(-len(t) // STRETCHES)
    padded = np.full(-(-len(t) // k) * k, np.nan)
    padded[: len(values)] = values
    with warnings.catch_warnings():  # a stretch without telemetry is all NaN: drawn as a gap
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.asarray(t[::k], float), reduce(padded.reshape(-1, k), axis=1)


def _line(ax, t, values, *args, **kwargs) -> None:
    times, low = _stretched(t, values, np.nanmin)
    _, high = _stretched(t, values, np.nanmax)
    if len(times) == len(t):
        ax.plot(times, low, *args, **kwargs)
    else:
        ax.plot(np.repeat(times, 2), np.column_stack([low, high]).ravel(), *args, **kwargs)


SHADES = {State.LIMITING: "gold", State.STOPPING: "orange", State.RECOVERY: "deepskyblue", State.ESTOP: "red"}
"""The supervisor's states other than NORMAL, shaded where it was in them."""
FAULT_COLOR = "purple"
TITLE_WIDTH = 150
"""Characters per line of the title's list of faults (the figure's width at its font size)."""
CRITERIA_AXES = {"max_speed": 0, "max_tilt_deg": 1, "max_lean_deg": 2}
"""Criteria whose bounds are drawn: metric -> the plot of that quantity, in the metric's unit."""


def write_plots(path: Path, result: RunResult) -> None:
    fig = figure(result)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def figure(result: RunResult) -> Figure:
    """The run's plots, titled with its verdict and faults; what the supervisor did shaded, each fault's
    window marked, the SC's command cap and the bounds of the criteria on speed, tilt and lean drawn."""
    trace = result.trace
    t = trace.t
    fig, axes = plt.subplots(4, 1, figsize=(13, 10.5), sharex=True)
    ax = axes[0]
    _line(ax, t, trace.velocity[:, 0], label="speed (forward)")
    _line(ax, t, trace.command_speed[:, 0], "--", label="command speed")
    _sc_cap(ax, result)
    ax.set_ylabel("m/s")
    ax = axes[1]
    _line(ax, t, np.degrees(trace.tilt[:, 0]), label="chassis tilt (pitch)")
    _line(ax, t, np.degrees(trace.tilt_command[:, 0]), "--", label="θ_EQ command")
    _line(ax, t, np.degrees(trace.tilt[:, 1]), lw=0.8, label="chassis tilt (roll)")
    ax.set_ylabel("deg")
    ax = axes[2]
    _line(ax, t, np.degrees(trace.lean[:, 0]), label="torso lean (pitch)")
    _line(ax, t, np.degrees(trace.lean[:, 1]), lw=0.8, label="torso lean (roll)")
    ax.set_ylabel("deg")
    ax = axes[3]
    for i in range(3):
        _line(ax, t, trace.motor_torque[:, i], lw=0.8, label=f"motor {i + 1}")
    ax.set_ylabel("Nm")
    ax.set_xlabel("simulated time (s)")
    _criteria(axes, result)
    _faults(axes, trace)
    shaded = _supervisor(axes, trace) + _rig_late(axes, trace)
    for ax in axes:
        ax.grid(alpha=0.3)
        # Beside the plot, never over its lines.
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.legend(handles=shaded, loc="lower center", ncol=len(shaded), fontsize=9, frameon=False)
    fig.suptitle(title(result), fontsize=11)
    fig.tight_layout(rect=(0, 0.025, 1, 1))
    return fig


def title(result: RunResult) -> str:
    """The run, its verdict (with the failed criteria) and its faults, each with the window it acted in."""
    tr = result.trace
    head = f"{result.scenario.name} ({result.law}, {result.clock}, seed {result.seed}): {result.verdict}"
    failed = [v.criterion for v in result.verdicts if not v.passed]
    if failed:
        head += " — failed: " + ", ".join(failed)
    if tr.failure is not None:
        head += f" — the run failed at {tr.failure.stage}"
    if tr.fallen:
        head += f" — FELL: {tr.fallen}"
    faults = [f"F{n} {_fault_name(spec)} {_window(tr, w)}" for n, (spec, w) in enumerate(_faults_of(tr))]
    lines = ["faults: " + (faults[0] if faults else "none")]
    for fault in faults[1:]:  # a line breaks between faults, never inside one
        if len(lines[-1]) + len(fault) + 2 > TITLE_WIDTH:
            lines[-1] += ";"
            lines.append(fault)
        else:
            lines[-1] += "; " + fault
    return "\n".join([head, *lines])


def _faults_of(trace):
    return zip(trace.faults, trace.fault_windows, strict=True)


def _fault_name(spec) -> str:
    """A fault's kind and the parameters it sets (beside when it acts and what it expects)."""
    fields = msgspec.structs.fields(spec)
    params = [
        f"{f.name}={getattr(spec, f.name)}"
        for f in fields
        if f.name not in ("at", "duration", "expect") and getattr(spec, f.name) != f.default
    ]
    return " ".join([spec.kind, *params])


def _window(trace, window) -> str:
    if window is None:
        return "(never started)"
    start, end = window
    return f"{start:.2f}–{end:.2f} s" if _ended(trace, end) else f"from {start:.2f} s to the end"


def _ended(trace, end: float) -> bool:
    """The fault ended before the run did (a window that reaches the last tick is one still acting)."""
    return len(trace.t) > 1 and end < trace.t[-1] - 0.5 * (trace.t[1] - trace.t[0])


def _faults(axes, trace) -> None:
    """Each fault's start (solid) and end (dashed) on every plot, numbered as in the title."""
    labels = {"start": "fault start", "end": "fault end"}  # once each, in the top plot's legend
    for n, (_, window) in enumerate(_faults_of(trace)):
        if window is None:
            continue
        start, end = window
        for ax in axes:
            ax.axvline(
                start, color=FAULT_COLOR, lw=1.2, label=labels.pop("start", None) if ax is axes[0] else None
            )
            if _ended(trace, end):
                label = labels.pop("end", None) if ax is axes[0] else None
                ax.axvline(end, color=FAULT_COLOR, lw=1.2, ls="--", label=label)
        axes[0].annotate(
            f"F{n}",
            (start, 1.0),
            xycoords=axes[0].get_xaxis_transform(),
            xytext=(2, -2),
            textcoords="offset points",
            va="top",
            color=FAULT_COLOR,
            fontsize=9,
        )


def _sc_cap(ax, result: RunResult) -> None:
    """The cap the shared controller asks of the controller, where it is in limit mode: a command, not a
    criterion (the scenario's criteria are drawn as their own lines)."""
    sc, end = result.scenario.sc, float(result.trace.t[-1])
    enforced = result.safety.speed.enforce_requested_cap
    why = "enforced by the supervisor" if enforced else "to the controller;\nnot enforced by the supervisor"
    for i, entry in enumerate(sc):
        until = sc[i + 1].at if i + 1 < len(sc) else end
        if entry.mode == "limit" and entry.at < end:
            first = all(e.mode != "limit" for e in sc[:i])
            label = f"SC command cap {entry.cap:g} m/s\n({why})" if first else None
            ax.hlines(entry.cap, entry.at, min(until, end), color="red", lw=0.9, ls=":", label=label)


def _criteria(axes, result: RunResult) -> None:
    """The bounds of the scenario's criteria on what is plotted (max_speed, max_tilt_deg, max_lean_deg),
    from their `after` on: the limits a verdict is judged by (a measurement of |value|: drawn at ±bound)."""
    end = float(result.trace.t[-1])
    for c in result.scenario.criteria:
        if c.metric not in CRITERIA_AXES:
            continue
        label: str | None = f"criterion {c.label}\n{c.describe()}" + (
            f" from {c.after:g} s" if c.after else ""
        )
        for bound, style in ((c.max, "-."), (c.min, (0, (1, 3)))):
            if bound is None:
                continue
            for sign in (1, -1):
                axes[CRITERIA_AXES[c.metric]].hlines(
                    sign * bound, c.after, end, color="darkred", lw=1.0, ls=style, label=label
                )
                label = None


RIG_LATE = "#6a1b9a"
"""The rig's own late windows in real time (the console's INCONCLUSIVE colour)."""


def _rig_late(axes, trace) -> list[Patch]:
    """Hatch the windows in which the rig itself sent SYNC late (hil/run/lateness.py); the legend's handle
    when there were any."""
    windows = trace.lateness.windows
    if not windows:
        return []
    for ax in axes:
        for start, end in windows:
            ax.axvspan(start, end, facecolor="none", edgecolor=RIG_LATE, hatch="//", lw=0, alpha=0.5)
    label = f"the rig late ({trace.lateness.ticks} SYNCs, {trace.lateness.cost} commands lost to it)"
    return [Patch(facecolor="none", edgecolor=RIG_LATE, hatch="//", label=label)]


def _supervisor(axes, trace) -> list[Patch]:
    """Shade where the supervisor was in each state but NORMAL (a stretch of ticks shows its highest state
    code); the legend's handles for the states the run had."""
    times, state = _stretched(trace.t, trace.safety_state, np.nanmax)
    handles = []
    for value, color in SHADES.items():
        mask = state == value
        if not mask.any():
            continue
        handles.append(Patch(color=color, alpha=0.3, label=f"supervisor {value.name}"))
        for ax in axes:
            ax.fill_between(
                times, 0, 1, where=mask, transform=ax.get_xaxis_transform(), color=color, alpha=0.12, lw=0
            )
    if not handles:
        handles.append(Patch(color="none", label="supervisor: NORMAL throughout (nothing shaded)"))
    return handles
