"""Diagnostic coverage: each faulty run classed against its fault-free twin (docs/safety.md "Coverage").

- DETECTED: the supervisor's first transition after the fault started (after the demand, for a latent
  fault: its first e-stop) names a cause of its own evidence (a watchdog, E2E, a diagnostic), before any
  hazard, within the fault kind's bound (250 ms; a drive's fault 50 ms). A supervisor that cannot act (it
  was killed, or its frames are lost) is replaced by the drives' own watchdog on its frame: their
  permission timing out (the mode SUPERVISOR_LOST: they follow the controller's own stop) counts as the
  reaction PERMISSION_TIMEOUT.
- LATE: the same, after the bound.
- BENIGN: no such reaction, no hazard, and the run stays within `benign_speed` and `benign_tilt_deg` of
  its twin's peak speed and tilt from the fault's start on. A disturbance (a push, the rider's weight
  shifting) is not a fault of the robot: it is BENIGN when it is ridden through without a hazard.

The bound counts from the fault's onset: its start, or the moment the faulty run first departs from its
twin (speed by `onset_speed`, tilt by `onset_tilt_deg`) if that is later. A fault that changes nothing yet
(a stuck encoder on a wheel that does not turn) has no evidence to see and does no harm until it does.
- After a detection, what the robot did: AT_REST (standstill and upright at the end), FELL, or MOVING
  (upright, not at rest: a rider still driving it); with the time from the fault to rest, the peak speed and
  tilt after the detection, the supervisor's modes (e.g. NORMAL>RECOVERY>ESTOP) and who held the drives (the
  controller, the supervisor's recovery law, or nobody: power cut in motion). A fall after a detection fails
  the case unless the campaign names the fault unrecoverable in that scenario (a measurement shows that
  nothing can balance the robot; docs/safety.md lists each).
- MISSED: anything else: a hazard (a fall, the speed above the supervisor's cap plus its margin, a drive
  powered longer than `powered_after_estop` after an e-stop) or a departure from the twin beyond the
  benign bound, with no reaction of the supervisor's own before it. Reactions to consequences (tilt,
  speed, a stop that does not stop) do not count as seeing the fault.

A fault-free run in which the supervisor acts on its own (any transition but an operator's) is a false trip.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import numpy as np

from drivers.vocabulary import OPERATOR_STOPS, Cause

if TYPE_CHECKING:
    from hil.run.judge import RunResult

SUPERVISOR_LOST = "SUPERVISOR_LOST"
"""The mode in a run's path when the supervisor's frame went silent (the drives' own evidence)."""
OWN_EVIDENCE = frozenset(
    {
        Cause.HEARTBEAT_LOST,
        Cause.CONTROLLER_FAULT,
        Cause.DRIVES_SILENT,
        Cause.IMU_SILENT,
        Cause.WRENCH_SILENT,
        Cause.SC_SILENT,
        Cause.E2E_ERRORS,
        Cause.TORQUE_RANGE,
        Cause.SENSOR_STUCK,
        Cause.SENSOR_DISAGREE,
        Cause.WRENCH_IMPLAUSIBLE,
        Cause.DRIVE_FAULT,
        Cause.ACTUATOR_MISMATCH,
        Cause.DRIVE_NOT_DISABLED,
        Cause.CONTACTOR_FAULT,
    }
)
"""Causes that see a fault itself; the others see its consequence (TILT, speed, a stop that fails) or are
an operator's action."""
_OWN_EVIDENCE = frozenset(c.name for c in OWN_EVIDENCE) | {"PERMISSION_TIMEOUT"}


class Bounds(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """How a coverage campaign judges (the `[coverage]` table of a campaign file)."""

    benign_speed: float = 0.25
    """m/s: a fault whose run's peak ground speed stays this close to its twin's is benign ..."""
    benign_tilt_deg: float = 3.0
    """... and its peak chassis tilt this close, deg."""
    powered_after_estop: float = 0.05
    """s: a drive still powered this long after the supervisor's e-stop is a hazard."""
    wall_ratio: float = 2.0
    """A faulty run may take at most this many times its twin's wall time."""
    benign_yaw_rate: float = 0.3
    """rad/s: ... and its peak yaw rate this close."""
    onset_speed: float = 0.05
    """m/s: the faulty run departs from its twin when its ground speed differs this much ..."""
    onset_tilt_deg: float = 0.5
    """... or its chassis tilt this much, deg ..."""
    onset_yaw_rate: float = 0.1
    """... or its yaw rate this much, rad/s."""


@dataclass(slots=True)
class Outcome:
    """What a run did, compact enough to travel back from a worker process."""

    t: list[float]
    """Decimated to 100 Hz: time, ground speed, largest tilt and yaw rate of the truth."""
    speed: list[float]
    tilt_deg: list[float]
    yaw_rate: list[float]
    transitions: list[tuple[float, str, str]] = field(default_factory=list)
    """(t, state, cause) of every supervisor transition, and PERMISSION_TIMEOUT when the drives lost their
    permission without an e-stop before it."""
    fell_at: float | None = None
    fault_start: float | None = None
    fault_kinds: list[str] = field(default_factory=list)
    latent: bool = False
    disturbance: bool = False
    detect_within: float = 0.25
    powered_after_estop: float = 0.0
    """s: the longest a drive stayed powered after an e-stop was entered."""
    hazard_speed: float = math.inf
    """m/s above which the speed is a hazard: the supervisor's absolute cap plus its margin."""
    standstill_speed: float = 0.05
    """m/s at or below which the robot is at rest (the supervisor's)."""
    unrecoverable: str = ""
    """Why nothing can balance the robot after this fault in this scenario ('' : it must end upright)."""

    def departs(self, twin: Outcome, start: float, bounds: Bounds) -> float | None:
        """When this run first departs from its twin after `start` (None: never)."""
        n = min(len(self.t), len(twin.t))
        for i in range(n):
            if self.t[i] < start - 1e-9:
                continue
            if (
                abs(self.speed[i] - twin.speed[i]) > bounds.onset_speed
                or abs(self.tilt_deg[i] - twin.tilt_deg[i]) > bounds.onset_tilt_deg
                or abs(self.yaw_rate[i] - twin.yaw_rate[i]) > bounds.onset_yaw_rate
            ):
                return self.t[i]
        return None

    def peaks_after(self, start: float) -> tuple[float, float, float]:
        """Peak ground speed, tilt and |yaw rate| from `start` on."""
        after = np.asarray(self.t) >= start - 1e-9
        if not after.any():
            return 0.0, 0.0, 0.0
        speed, tilt, yaw_rate = (
            float(np.abs(np.asarray(x)[after]).max()) for x in (self.speed, self.tilt_deg, self.yaw_rate)
        )
        return speed, tilt, yaw_rate


def outcome(result: RunResult) -> Outcome:
    tr = result.trace
    speed = np.hypot(tr.velocity[:, 0], tr.velocity[:, 1]) if len(tr.t) else np.zeros(0)
    tilt = np.degrees(np.abs(tr.tilt).max(axis=1)) if len(tr.t) else np.zeros(0)
    every = max(round(result.scenario.tick_hz / 100.0), 1)
    windows = [w for w in tr.fault_windows if w is not None]
    faults = [f for f, w in zip(tr.faults, tr.fault_windows, strict=True) if w is not None]
    safety = result.safety.speed
    fell = None
    if tr.fallen is not None and len(tr.t):
        fell = float(tr.t[-1])
    return Outcome(
        t=tr.t[::every].round(4).tolist(),
        speed=speed[::every].round(4).tolist(),
        tilt_deg=tilt[::every].round(3).tolist(),
        yaw_rate=tr.yaw_rate[::every].round(4).tolist(),
        transitions=_reactions(tr),
        fell_at=fell,
        fault_start=min((w[0] for w in windows), default=None),
        fault_kinds=[f.kind for f in faults],
        latent=any(f.latent for f in faults),
        disturbance=bool(faults) and all(f.disturbance for f in faults),
        detect_within=min((f.detect_within for f in faults), default=0.25),
        powered_after_estop=_powered_after_estop(tr),
        hazard_speed=safety.absolute_cap + safety.margin,
        standstill_speed=result.safety.stop.standstill_speed,
    )


def _reactions(tr) -> list[tuple[float, str, str]]:
    out = [(e.t, e.to_state, e.cause) for e in tr.safety_events if e.kind == "transition"]
    for lost in tr.stats.supervisor_lost_at:
        # The supervisor cannot act (killed, or its frames lost): the drives see its permission time out
        # and follow the controller's own stop (docs/safety.md "Fail-operational").
        out.append((lost, SUPERVISOR_LOST, "PERMISSION_TIMEOUT"))
    return sorted(out)


def _powered_after_estop(tr) -> float:
    """The longest stretch a drive stayed powered after the supervisor entered ESTOP (as its frame says)."""
    estop = tr.safety_state == 3
    longest, entered = 0.0, None
    for i in range(len(tr.t)):
        if estop[i] and entered is None:
            entered = tr.t[i]
        elif not estop[i]:
            entered = None
        if entered is not None and tr.powered[i]:
            longest = max(longest, float(tr.t[i] - entered))
    return longest


UPRIGHT_DEG = 5.0
"""deg: at rest means within this of upright (the rider's feet and the stand catch the robot there)."""


@dataclass(frozen=True, slots=True)
class Aftermath:
    """What the robot did after the supervisor saw the fault."""

    ended: str
    """AT_REST, FELL or MOVING."""
    to_rest: float | None
    """s from the fault's start until the robot stood still to the end (None: it did not)."""
    peak_speed: float
    peak_tilt_deg: float
    peak_yaw_rate: float
    """rad/s: how fast it turned after the detection (two wheels turn it as they balance)."""
    modes: str
    """The supervisor's modes from the one the fault met on, e.g. NORMAL>RECOVERY>ESTOP."""
    held_by: str
    """Who held the drives: controller, recovery law, or nobody (power cut in motion)."""
    excused: str = ""
    """Why a fall does not fail the case: the fault is unrecoverable in this scenario."""


def aftermath(o: Outcome, start: float, seen: float) -> Aftermath:
    t, speed, tilt = np.asarray(o.t), np.asarray(o.speed), np.asarray(o.tilt_deg)
    moving = np.nonzero(speed > o.standstill_speed)[0]
    rest = o.fell_at is None and len(t) and speed[-1] <= o.standstill_speed and tilt[-1] <= UPRIGHT_DEG
    to_rest = None
    if rest:
        last = moving[-1] + 1 if len(moving) else 0
        to_rest = max(float(t[min(last, len(t) - 1)]) - start, 0.0)
    peak_speed, peak_tilt, peak_yaw = o.peaks_after(seen)
    after = [(when, state) for when, state, _ in o.transitions if when >= start - 1e-9]
    before = [state for when, state, _ in o.transitions if when < start - 1e-9]
    # The path of modes from the one the fault met: a state entered again for another cause is one mode.
    path = [before[-1] if before else "NORMAL", *(state for _, state in after)]
    modes = ">".join(state for state, _ in itertools.groupby(path))
    if any(state == "RECOVERY" for _, state in after):
        held_by = "recovery law"
    else:
        cut = next((when for when, state in after if state == "ESTOP"), None)
        i = None if cut is None else min(int(np.searchsorted(t, cut)), len(t) - 1)
        held_by = "nobody" if i is not None and speed[i] > o.standstill_speed else "controller"
    ended = "FELL" if o.fell_at is not None else "AT_REST" if rest else "MOVING"
    excused = o.unrecoverable if ended == "FELL" else ""
    return Aftermath(ended, to_rest, peak_speed, peak_tilt, peak_yaw, modes, held_by, excused)


@dataclass(frozen=True, slots=True)
class Classification:
    label: str
    """DETECTED, LATE, BENIGN or MISSED."""
    cause: str = ""
    reaction: float | None = None
    """s from the fault's start (or the demand) to the supervisor's reaction."""
    departed: float | None = None
    """s from the fault's start (or the demand) to the run's departure from its twin, if that came first."""
    note: str = ""
    after: Aftermath | None = None
    """DETECTED and LATE: what the robot did after the detection."""

    @property
    def passed(self) -> bool:
        fell = self.after is not None and self.after.ended == "FELL" and not self.after.excused
        return self.label in ("DETECTED", "BENIGN") and not fell

    @property
    def name(self) -> str:
        """The class with what followed a detection: DETECTED+AT_REST, DETECTED+FELL, ..."""
        return self.label if self.after is None else f"{self.label}+{self.after.ended}"


OPERATOR_CAUSES = frozenset(c.name for c in (*OPERATOR_STOPS, Cause.RESET))
"""What an operator does to the supervisor: never a trip of its own."""
ESCALATIONS = frozenset(
    c.name for c in (Cause.STOP_TIMEOUT, Cause.STOP_INEFFECTIVE, Cause.MOTION_AFTER_STANDSTILL)
)
"""A stop under way that does not take is handed to the recovery law: after an operator's stop, that is the
operator's stop carried out, not a trip of the supervisor's own."""


def false_trip(o: Outcome) -> str:
    """Why a fault-free run counts as a false trip ('' if it does not): the supervisor acted on its own."""
    stopped = False
    own = []
    for x in o.transitions:
        stopped = stopped or x[2] in OPERATOR_CAUSES - {Cause.RESET.name}
        if x[2] not in OPERATOR_CAUSES and not (stopped and x[2] in ESCALATIONS):
            own.append(x)
    if own:
        t, state, cause = own[0]
        return f"{state}/{cause} at {t:.3f} s without a fault"
    if o.fell_at is not None:
        return f"fell at {o.fell_at:.3f} s without a fault"
    return ""


def classify(o: Outcome, twin: Outcome, bounds: Bounds) -> Classification:
    if o.fault_start is None:
        return Classification("MISSED", note="the fault never started")
    start = o.fault_start
    if o.latent:  # detection time counts from the demand: the first e-stop after the fault started
        start = next((t for t, state, _ in o.transitions if state == "ESTOP" and t >= start - 1e-9), start)
    hazard_t, hazard = _hazard(o, bounds)
    reaction = next(
        ((t, cause) for t, state, cause in o.transitions if t >= start - 1e-9 and cause in _OWN_EVIDENCE),
        None,
    )
    if reaction is not None and (hazard_t is None or reaction[0] <= hazard_t + 1e-9):
        seen, cause = reaction
        departed = o.departs(twin, start, bounds)
        # Seen before the run departed from its twin is seen before any consequence, whenever that was;
        # after it, the bound counts from the later of the fault's start and the departure.
        if departed is None or departed > seen:
            late, onset = False, None
        else:
            late, onset = seen - max(start, departed) > o.detect_within + 1e-9, departed - start
        note = f"then {hazard}" if hazard else ""
        return Classification(
            "LATE" if late else "DETECTED",
            cause,
            seen - start,
            onset,
            note,
            aftermath(o, start, seen),
        )
    if hazard:
        return Classification("MISSED", note=f"{hazard} with no reaction of the supervisor's own before it")
    if o.disturbance:
        return Classification("BENIGN", note="a disturbance, ridden through without a hazard")
    d_speed, d_tilt, d_yaw = np.subtract(o.peaks_after(start), twin.peaks_after(start))
    differs = f"peak speed {d_speed:+.2f} m/s, tilt {d_tilt:+.1f} deg, yaw rate {d_yaw:+.2f} rad/s vs twin"
    if (
        d_speed <= bounds.benign_speed
        and d_tilt <= bounds.benign_tilt_deg
        and d_yaw <= bounds.benign_yaw_rate
    ):
        return Classification("BENIGN", note=differs)
    return Classification("MISSED", note=f"{differs}: beyond the benign bound, unseen")


def _hazard(o: Outcome, bounds: Bounds) -> tuple[float | None, str]:
    """The first hazard of a run after its fault started: (time, what)."""
    start = o.fault_start or 0.0
    found: list[tuple[float, str]] = []
    if o.fell_at is not None:
        found.append((o.fell_at, "fell"))
    for t, v in zip(o.t, o.speed, strict=True):
        if t >= start and v > o.hazard_speed:
            found.append((t, f"speed {v:.2f} m/s above {o.hazard_speed:.2f}"))
            break
    if o.powered_after_estop > bounds.powered_after_estop:
        found.append((math.inf, f"a drive powered {o.powered_after_estop:.2f} s after the e-stop"))
    if not found:
        return None, ""
    return min(found)


# ------------------------------------------------------------------------------------ the table of docs
ENDED = {"AT_REST": "at rest", "MOVING": "upright, moving", "FELL": "fell"}


def cell(coverage: dict) -> str:
    """One faulty case of a campaign's report.json as docs/safety.md's coverage table shows it: the first
    reaction and its delay, the modes from the fault on, how the run ended."""
    kind = coverage["class"]
    if kind == "BENIGN":
        return "benign"
    if kind == "MISSED":
        return f"MISSED: {coverage['note']}"
    after = coverage["after"] or {}
    late = " (LATE)" if kind.startswith("LATE") else ""
    ended = ENDED.get(after.get("ended", ""), after.get("ended", "?"))
    if ended == "fell" and after.get("excused"):
        ended += " (unrecoverable)"
    ms = round(coverage["reaction"] * 1e3, 1)  # ticks are 2.5 ms: 47.5, not 47 or 48
    return f"{coverage['cause']} {ms:g} ms{late}; {after.get('modes', '')}; {ended}"


def table(report: dict, scenarios: tuple[str, ...] = ("speed_limiting", "slalom", "balance")) -> str:
    """docs/safety.md's coverage table from a coverage campaign's report.json: a row per fault set, a
    column per scenario."""
    cells: dict[str, dict[str, str]] = {}
    for case in report["cases"]:
        if case["role"] != "faulty" or not case.get("coverage"):
            continue
        scenario = Path(case["scenario"]).stem
        fault_set = case["case"].removeprefix(f"{scenario}-").rsplit("-seed", 1)[0]
        cells.setdefault(fault_set, {})[scenario] = cell(case["coverage"])
    head = ["fault set", *scenarios]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for fault_set in sorted(cells):
        row = [f"`{fault_set}`", *(cells[fault_set].get(s, "") for s in scenarios)]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


DEAD_DRIVES = {"plant.drive_torque": "drive 1", "plant.drive_torque-drive2": "drive 2"}
"""The diagnostics campaign's dead-drive fault sets (docs/safety.md "A dead drive")."""


def dead_drives(report: dict, scenarios: tuple[str, ...] = ("speed_limiting", "slalom", "balance")) -> str:
    """docs/safety.md's dead-drive table from a diagnostics campaign's report.json: per dead drive and
    scenario, how the run ended and the peak yaw rate after the detection."""
    cells: dict[str, dict[str, str]] = {}
    for case in report["cases"]:
        coverage = case.get("coverage") or {}
        after = coverage.get("after")
        scenario = Path(case["scenario"]).stem
        fault_set = case["case"].removeprefix(f"{scenario}-").rsplit("-seed", 1)[0]
        if case["role"] != "faulty" or fault_set not in DEAD_DRIVES or not after:
            continue
        ended = ENDED.get(after["ended"], after["ended"])
        if after["ended"] == "FELL":  # "fell: foot right touched the floor at 5.4 s", from the fault at 3 s
            how = (case.get("fall_cause") or "").split(" at t=")
            ended += f": {how[0]} at {float(how[1].split()[0]):.1f} s" if len(how) == 2 else ""
            ended += " (unrecoverable)" if after.get("excused") else ""
        yaw = f"{after['peak_yaw_rate']:.1f} rad/s"
        cells.setdefault(DEAD_DRIVES[fault_set], {})[scenario] = f"{yaw}; {ended}"
    head = ["dead drive", *scenarios]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for drive in sorted(cells):
        lines.append("| " + " | ".join([drive, *(cells[drive].get(s, "") for s in scenarios)]) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """`python -m hil.suites.coverage REPORT.json`: the coverage tables of docs/safety.md from a campaign's
    report."""
    import argparse
    import json
    import sys

    parser = argparse.ArgumentParser(
        prog="python -m hil.suites.coverage", description="docs/safety.md's coverage tables from a report"
    )
    parser.add_argument("report", help="a coverage campaign's REPORT.json")
    args = parser.parse_args(argv)
    try:
        report = json.loads(Path(args.report).read_text())
        print(table(report))
        print()
        print(dead_drives(report))
    except OSError as exc:
        print(f"{args.report}: cannot read: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except (ValueError, KeyError, TypeError) as exc:
        print(
            f"{args.report}: not a coverage campaign's report ({type(exc).__name__}: {exc})", file=sys.stderr
        )
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
