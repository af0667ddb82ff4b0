"""What a run leaves behind, tick by tick: the truth of the plant beside what the rig and the supervisor saw
(`Trace`), and why a run stopped before its end (`Failure`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drivers.bus_config import BusConfigError
from drivers.config import ConfigError
from drivers.registry import PlugNotFound
from drivers.vocabulary import Event, OperatorRecord
from drivers.zenoh_link import ZenohConfigError
from hil.faults import FaultError, FaultEvent, FaultSpec
from hil.outputs.bodies import Poses
from hil.run.clock import TimingStats
from hil.run.drives_port import TickStats
from hil.run.lateness import Lateness


class ControllerUnavailable(RuntimeError):
    """The controller under test (or the supervisor) never showed up."""


CONFIG_ERRORS = (FaultError, PlugNotFound, BusConfigError, ConfigError, ZenohConfigError)
"""What the user fixes in a file or an option (a command exits 2 for them)."""


def reason(exc: BaseException) -> str:
    """An exception as a failure's one line: ours already say what went wrong, others get their type."""
    ours = isinstance(exc, (ControllerUnavailable, *CONFIG_ERRORS))
    return str(exc) if ours else f"{type(exc).__name__}: {exc}"


@dataclass(frozen=True, slots=True)
class Failure:
    """Why a run stopped before its end: where (`stage`: build, start-up, tick N, an output) and what."""

    stage: str
    error: str
    config: bool = False
    """A configuration error (a fault that cannot act on this rig, an unknown controller, a bad bus)."""


@dataclass(slots=True)
class Trace:
    """Per-tick records of a run (SI units; planes ordered pitch, roll). A field per column group of the
    run's rows, of the same name (hil/outputs/trace_log.py COLUMNS; `velocity` is velocity.forward and
    velocity.left), read by that name (hil/run/loop.py)."""

    t: np.ndarray
    velocity: np.ndarray
    """(n, 2) forward, left."""
    tilt: np.ndarray
    lean: np.ndarray
    position: np.ndarray
    yaw_rate: np.ndarray
    ball_rate: np.ndarray
    """(n, 2) φ̇ per plane, rad/s."""
    command_speed: np.ndarray
    """(n, 2) the controller's command speed (pitch fwd, roll fwd = −y), m/s; NaN if not received."""
    tilt_command: np.ndarray
    fallen: str | None
    stats: TickStats
    controller_telemetry_missing: int
    timing: TimingStats
    bus: dict
    """The rig node's CAN statistics (sent, received, E2E events, malformed frames)."""
    motor_torque: np.ndarray
    """(n, 3) motor torques the drives produced, Nm."""
    zenoh_inputs: list[tuple[int, str, bytes]] | None
    """What the controller was sent on zenoh: (tick, key, msgpack payload); None: streamed to the run
    folder's zenoh_inputs.msgpack as the run went (hil/outputs/inputs_log.py)."""
    safety_state: np.ndarray
    """(n,) the supervisor's state per tick as on the bus (SUPERVISOR_ESTOP.State; -1: no frame yet)."""
    safety_speed: np.ndarray
    """(n,) the embedded supervisor's own speed estimate, m/s (NaN: none)."""
    powered: np.ndarray
    """(n,) any drive's power stage on."""
    resting: np.ndarray
    """(n,) powered off at standstill, held by the rider's feet or the stand."""
    safety_events: list[Event]
    """The embedded supervisor's transitions and refused resets."""
    fence_misses: int = 0
    identity_rejected: dict[str, int] = field(default_factory=dict)
    """SC requests and resets the embedded supervisor ignored for want of an operator's identity."""
    diagnostics: dict[str, float] = field(default_factory=dict)
    """The embedded supervisor's checks: each one's largest |residual| / bound over the run."""
    sc_arbitration: dict = field(default_factory=dict)
    """The embedded supervisor's SC sources: accepted and refused requests per source, conflicts."""
    faults: list[FaultSpec] = field(default_factory=list)
    """Every fault of the run, scheduled and injected live, by number."""
    fault_events: list[FaultEvent] = field(default_factory=list)
    fault_windows: list[tuple[float, float] | None] = field(default_factory=list)
    """Per fault: (start, end) of the time it acted, None if it never started."""
    operator_actions: list[OperatorRecord] = field(default_factory=list)
    """Every operator e-stop, category-0 cut and reset the supervisor took in (the scenario's own among
    them), whatever its state, and every press of a wired e-stop button."""
    operator_actions_dropped: int = 0
    """Operator actions beyond the record's length (safety/node.py OPERATOR_ACTIONS_KEPT): counted only."""
    failure: Failure | None = None
    """Why the run stopped before its end (None: it ran to the end, or to a fall)."""
    stopped_early: bool = False
    """Its caller stopped it (an operator's Ctrl-C, the service's stop) before the scenario's end."""
    outputs_failed: dict[str, str] = field(default_factory=dict)
    """Logs the run streamed that failed as it wrote them (can.log, run.mcap), and why."""
    poses: Poses | None = None
    """The bodies' poses for the recording's 3-D view (hil/outputs/bodies.py); None: none were kept."""
    lateness: Lateness = field(default_factory=Lateness)
    """Real time: the ticks the rig itself was late in, and what that cost the controller."""

    @classmethod
    def empty(cls, failure: Failure) -> Trace:
        """A run that failed before its first tick."""
        none, pair = np.zeros(0), np.zeros((0, 2))
        return cls(
            t=none,
            velocity=pair,
            tilt=pair,
            lean=pair,
            position=pair,
            yaw_rate=none,
            ball_rate=pair,
            command_speed=pair,
            tilt_command=pair,
            fallen=None,
            stats=TickStats(),
            controller_telemetry_missing=0,
            timing=TimingStats(0, 0.0, 0.0),
            bus={},
            motor_torque=np.zeros((0, 3)),
            zenoh_inputs=[],
            safety_state=np.zeros(0, int),
            safety_speed=none,
            powered=np.zeros(0, bool),
            resting=np.zeros(0, bool),
            safety_events=[],
            failure=failure,
        )
