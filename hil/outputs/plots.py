"""plots.png: what a person looks at first after a run (speed, tilt, torso lean, motor torques)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np


def write_plots(path: Path, trace, title: str, sc_cap: float | None = None) -> None:
    t = trace.t
    fig, axes = plt.subplots(4, 1, figsize=(10, 10), sharex=True)
    ax = axes[0]
    ax.plot(t, trace.velocity[:, 0], label="speed (forward)")
    ax.plot(t, trace.command_speed[:, 0], "--", label="command speed")
    if sc_cap is not None:
        ax.axhline(sc_cap, color="red", lw=0.8, ls=":", label=f"SC cap {sc_cap:g} m/s")
    ax.set_ylabel("m/s")
    ax = axes[1]
    ax.plot(t, np.degrees(trace.tilt[:, 0]), label="chassis tilt (pitch)")
    ax.plot(t, np.degrees(trace.tilt_command[:, 0]), "--", label="θ_EQ command")
    ax.plot(t, np.degrees(trace.tilt[:, 1]), lw=0.8, label="chassis tilt (roll)")
    ax.set_ylabel("deg")
    ax = axes[2]
    ax.plot(t, np.degrees(trace.lean[:, 0]), label="torso lean (pitch)")
    ax.plot(t, np.degrees(trace.lean[:, 1]), lw=0.8, label="torso lean (roll)")
    ax.set_ylabel("deg")
    ax = axes[3]
    for i in range(3):
        ax.plot(t, trace.motor_torque[:, i], lw=0.8, label=f"motor {i + 1}")
    ax.set_ylabel("Nm")
    ax.set_xlabel("simulated time (s)")
    # Shade the supervisor's interventions: limiting (yellow), stopping (orange), e-stop (red).
    state = np.asarray(trace.safety_state)
    for value, color in ((1, "gold"), (2, "orange"), (3, "red")):
        mask = state == value
        if mask.any():
            for ax in axes:
                ax.fill_between(
                    t, 0, 1, where=mask, transform=ax.get_xaxis_transform(), color=color, alpha=0.12, lw=0
                )
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    fig.suptitle(title + (f" — FELL: {trace.fallen}" if trace.fallen else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
