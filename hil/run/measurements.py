"""Every measurement of a run, declared once: its name, unit, meaning and computation (after OpenHTF).

A scenario's criteria name a measurement and bound it (hil/run/scenario.py), the summary reports the ones
marked `in_summary` for both planes, `pure-hil compare` tabulates them, the pytest helpers read them. The
iHACS paper's task metrics are here too (docs/metrics.md): max |torso lean|, max |chassis tilt|,
max |speed| and the command-speed RMSE, the latter both as the paper's equation (2) and conventionally.

A measurement sees a `Window` of the run: from `after` on, one plane (its forward speed, lean, tilt) or the
whole robot. NaN means there was nothing to measure; `unavailable` says why.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from hil.run.trace import Trace

STOPPED = 0.1
"""m/s below which the robot counts as stopped (stop_time)."""
PLANES = ("pitch", "roll")


def paper_rmse(t: np.ndarray, commanded_rate: np.ndarray, rate: np.ndarray, time_unit: float = 1e-3) -> float:
    """The paper's equation (2) as written: (1 / (t_f − t_0)) · √(Σ (φ̇_c − φ̇)²), with t expressed in
    `time_unit` seconds (default milliseconds, which puts the magnitudes near the paper's table)."""
    span = (t[-1] - t[0]) / time_unit
    return float(math.sqrt(np.sum((commanded_rate - rate) ** 2)) / span) if span > 0 else math.nan


def rmse(commanded_rate: np.ndarray, rate: np.ndarray) -> float:
    """The conventional root-mean-square error, rad/s."""
    return float(np.sqrt(np.mean((commanded_rate - rate) ** 2)))


@dataclass(frozen=True)
class Window:
    """The part of a run one measurement sees: ticks from `after` on, of one plane (None: the robot)."""

    trace: Trace
    plane: str | None = None
    after: float = 0.0
    cause: str = ""
    ball_radius: float = math.nan

    @cached_property
    def mask(self) -> np.ndarray:
        return self.trace.t >= self.after

    @property
    def empty(self) -> bool:
        return not self.mask.any()

    @property
    def plane_index(self) -> int:
        return PLANES.index(self.plane or "pitch")

    @cached_property
    def speed(self) -> np.ndarray:
        """Ground speed along the plane's forward direction (the roll plane's forward is −y), whole run."""
        v = self.trace.velocity
        return v[:, 0] if self.plane_index == 0 else -v[:, 1]

    def rates(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, commanded ball rate, ball rate) over the window where the controller's command is known."""
        command = self.trace.command_speed[:, self.plane_index]
        told = self.mask & ~np.isnan(command)
        r = self.ball_radius
        return self.trace.t[told], command[told] / r, self.speed[told] / r

    def largest(self, values: np.ndarray) -> float:
        return math.nan if self.empty else float(np.abs(values[self.mask]).max())


def with_unit(number: str, unit: str) -> str:
    """A measured or limiting number as reports write it: with its unit, or alone for a unitless
    measurement (a count, a flag), never followed by a stray space ("measured 2 , limit")."""
    return f"{number} {unit}" if unit else number


@dataclass(frozen=True)
class Measurement:
    name: str
    unit: str
    doc: str
    compute: Callable[[Window], float]
    per_plane: bool = False
    """Measured per plane; a criterion on `both` planes takes the larger."""
    in_summary: bool = False
    """Reported in every run's summary (per plane: for both)."""
    needs_telemetry: bool = False
    """Needs the controller's command speed (pure/controller/telemetry)."""


def _rmse_paper(w: Window) -> float:
    t, commanded, rate = w.rates()
    return 1e3 * paper_rmse(t, commanded, rate) if len(t) else math.nan


def _rmse(w: Window) -> float:
    _, commanded, rate = w.rates()
    return rmse(commanded, rate) if len(rate) else math.nan


def _stop_time(w: Window) -> float:
    if w.empty:
        return math.nan
    moving = np.nonzero(w.mask & (np.abs(w.speed) > STOPPED))[0]
    return 0.0 if len(moving) == 0 else float(w.trace.t[moving[-1]] - w.after)


def _safety_reaction(w: Window) -> float:
    times = [
        e.t for e in w.trace.safety_events if e.kind == "transition" and e.cause == w.cause and e.t >= w.after
    ]
    return times[0] - w.after if times else math.nan


def _drives_off_after(w: Window) -> float:
    tr = w.trace
    on = np.nonzero(w.mask & tr.powered)[0]
    last_on = on[-1] if len(on) else np.searchsorted(tr.t, w.after) - 1
    return math.nan if last_on + 1 >= len(tr.t) else float(tr.t[last_on + 1] - w.after)


def _last(values: np.ndarray, empty: float = math.nan) -> float:
    return float(values[-1]) if len(values) else empty


MEASUREMENTS: dict[str, Measurement] = {
    m.name: m
    for m in (
        Measurement(
            "max_speed",
            "m/s",
            "largest |ground speed| along the plane",
            lambda w: w.largest(w.speed),
            True,
            True,
        ),
        Measurement(
            "final_speed",
            "m/s",
            "|ground speed| along the plane at the end",
            lambda w: math.nan if w.empty else abs(_last(w.speed)),
            True,
        ),
        Measurement(
            "max_tilt_deg",
            "deg",
            "largest |chassis tilt|",
            lambda w: w.largest(np.degrees(w.trace.tilt[:, w.plane_index])),
            True,
            True,
        ),
        Measurement(
            "max_lean_deg",
            "deg",
            "largest |torso lean| relative to the chassis",
            lambda w: w.largest(np.degrees(w.trace.lean[:, w.plane_index])),
            True,
            True,
        ),
        Measurement(
            "max_torso_deg",
            "deg",
            "largest |torso angle| from the vertical, as a chest IMU sees it (chassis tilt + lean): the "
            "paper's ζ",
            lambda w: w.largest(np.degrees(w.trace.tilt[:, w.plane_index] + w.trace.lean[:, w.plane_index])),
            True,
            True,
        ),
        Measurement(
            "rmse", "rad/s", "RMSE of the ball rate against the commanded rate", _rmse, True, True, True
        ),
        Measurement(
            "rmse_paper",
            "E-3",
            "the paper's equation (2) as written, t in ms, x1e3 as in its table (docs/metrics.md)",
            _rmse_paper,
            True,
            True,
            True,
        ),
        Measurement("stop_time", "s", f"from `after` until below {STOPPED} m/s for good", _stop_time, True),
        Measurement(
            "distance",
            "m",
            "distance from the start at the end",
            lambda w: float(np.hypot(*w.trace.position[-1])) if len(w.trace.t) else math.nan,
            in_summary=True,
        ),
        Measurement(
            "max_yaw_rate",
            "rad/s",
            "largest |yaw rate|",
            lambda w: w.largest(w.trace.yaw_rate),
            in_summary=True,
        ),
        Measurement("fallen", "", "1 if the robot fell", lambda w: float(w.trace.fallen is not None)),
        Measurement(
            "missing_commands",
            "",
            "the controller's drive commands that never arrived for their tick (in real time: not counting "
            "the ticks the rig itself was late in, docs/rig.md)",
            lambda w: float(w.trace.stats.missing_commands - w.trace.lateness.missing),
        ),
        Measurement(
            "late_commands",
            "",
            "the controller's drive commands that arrived after their tick was over (not counting the ticks "
            "the rig itself was late in)",
            lambda w: float(w.trace.stats.late_commands - w.trace.lateness.late),
        ),
        Measurement(
            "safety_reaction",
            "s",
            "from `after` to the supervisor's first transition for `cause`",
            _safety_reaction,
        ),
        Measurement(
            "drives_off_after", "s", "from `after` until every drive is off for good", _drives_off_after
        ),
        Measurement(
            "safety_state",
            "",
            "the supervisor's state at the end (0 NORMAL .. 3 ESTOP)",
            lambda w: _last(w.trace.safety_state),
        ),
        Measurement(
            "resting",
            "",
            "1 if the robot ends powered off at rest",
            lambda w: float(bool(_last(w.trace.resting, 0.0))),
        ),
    )
}


def measure(
    trace: Trace,
    name: str,
    plane: str = "pitch",
    after: float = 0.0,
    cause: str = "",
    ball_radius: float = math.nan,
) -> float:
    """One measurement of a run; `plane` "both" takes the larger of the two planes."""
    m = MEASUREMENTS[name]
    planes = PLANES if plane == "both" else (plane,)
    values = [m.compute(Window(trace, p if m.per_plane else None, after, cause, ball_radius)) for p in planes]
    return max(values)


def summary_metrics(trace: Trace, ball_radius: float) -> dict[str, float]:
    """The measurements every summary reports (NaN: nothing to measure; `unavailable` says why)."""
    out: dict[str, float] = {}
    for m in MEASUREMENTS.values():
        if m.in_summary:
            for plane in PLANES if m.per_plane else (None,):
                name = f"{plane}.{m.name}" if plane else m.name
                out[name] = round(m.compute(Window(trace, plane, ball_radius=ball_radius)), 9)
    return out


def release_end(trace: Trace, initial_tilt_deg: tuple[float, float]) -> float | None:
    """When the release ended (s): the first tick by which every plane the robot was released tilted in
    has come back through upright (its tilt reached 0 or changed sign). Until then the tilt is the
    release's, decaying from where the scenario put it; after it, every tilt is the run's own. 0.0 for a
    release upright; None if the robot never came back through upright (the release never ended)."""
    ends = [0.0]
    for plane, released in enumerate(initial_tilt_deg):
        if released:
            back = np.nonzero(trace.tilt[:, plane] * np.sign(released) <= 0.0)[0]
            if not len(back):
                return None
            ends.append(float(trace.t[back[0]]))
    return max(ends)


def unavailable(trace: Trace, name: str) -> str:
    """Why a measurement of this run is NaN ('' if it is not, or not for a reason of the run's)."""
    if not len(trace.t):
        return "unavailable (the run never ticked)"
    m = MEASUREMENTS.get(name.split(".")[-1])
    if m is not None and m.needs_telemetry and trace.controller_telemetry_missing == len(trace.t):
        return "unavailable (no controller telemetry)"
    return ""
