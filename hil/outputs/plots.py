"""plots.png: what a person looks at first after a run (speed, tilt, torso lean, motor torques)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import warnings

import matplotlib.pyplot as plt
import numpy as np

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


def write_plots(path: Path, trace, title: str, sc_cap: float | None = None) -> None:
    t = trace.t
    fig, axes = plt.subplots(4, 1, figsize=(10, 10), sharex=True)
    ax = axes[0]
    _line(ax, t, trace.velocity[:, 0], label="speed (forward)")
    _line(ax, t, trace.command_speed[:, 0], "--", label="command speed")
    if sc_cap is not None:
        ax.axhline(sc_cap, color="red", lw=0.8, ls=":", label=f"SC cap {sc_cap:g} m/s")
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
    # Shade the supervisor's interventions: limiting (yellow), stopping (orange), e-stop (red).
    # (A stretch of ticks shows its most severe state.)
    times, state = _stretched(t, trace.safety_state, np.nanmax)
    for value, color in ((1, "gold"), (2, "orange"), (3, "red")):
        mask = state == value
        if mask.any():
            for ax in axes:
                ax.fill_between(
                    times, 0, 1, where=mask, transform=ax.get_xaxis_transform(), color=color, alpha=0.12, lw=0
                )
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    fig.suptitle(title + (f" — FELL: {trace.fallen}" if trace.fallen else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
