"""Bench parts as plugs (docs/architecture.md, "Parts"): the controller under test (drivers/dut.py) and the
supervisor are found by name in their entry-point groups (drivers/registry.py, the one registry), and
started from a spec that says where everything is. The same plug runs in the rig's process (embedded) or,
from its spec serialised to JSON, in a child process the rig starts (`pure-hil part KIND PLUGIN SPEC.json`).

    start_dut(name, spec) -> DutHandle (drivers/dut.py)
    start_supervisor(name, spec, link) -> SupervisorHandle (below)

What the rig may use of a supervisor it drives in its own tick is `Supervisor` below, its handle's `node`:
the rig, its loop, the faults and the live view use nothing else (hil/ imports no supervisor's code).

The device profiles are plugs of the same registry: their emulations on the rig's side (hil/devices/), their
hosts on the controller's and the supervisor's (drivers/devices/). So are the plants (hil/run/plants.py) and
the fault families (hil/faults/), whose contracts live with their types (plant/core.py, hil/faults/base.py):
they never leave the rig's process.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import msgspec

from drivers.bus_config import BusConfig
from drivers.devices import Devices
from drivers.registry import SUPERVISORS, find_plug
from drivers.vocabulary import Event, OperatorRecord
from drivers.zenoh_access import ZenohAccess

if TYPE_CHECKING:  # zenoh only where a supervisor starts
    import can
    import zenoh

    from drivers.zenoh_link import ZenohLink


class SupervisorSpec(msgspec.Struct, frozen=True, kw_only=True):
    """Where a supervisor plug finds its bus and zenoh, and what it enforces."""

    can: BusConfig
    zenoh: ZenohAccess = ZenohAccess()
    devices: Devices = Devices()
    robot: str
    """Robot TOML of its geometry (drive limits, encoders, wheels)."""
    rules: dict[str, Any] = {}
    """Its rules file's content with the scenario's `[safety]` overrides merged key by key (hil.run.build
    supervisor_rules), as written: the plug applies its own defaults (drivers/rules.py)."""
    tick_hz: float = 400.0
    lockstep: bool = True
    """It decides once per SYNC (lockstep) or on its own timer (real time)."""
    driven: bool = False
    """The rig updates it from its own tick (embedded): no thread of its own, and the rig hands it the zenoh
    link whose puts the lockstep fence counts."""


@dataclass(frozen=True, slots=True)
class SupervisorReport:
    """What a supervisor says of its run at the end, for summary.json (docs/outputs.md)."""

    identity_rejected: dict[str, int] = field(default_factory=dict)
    """SC requests and resets it ignored for want of an operator's identity, per kind."""
    diagnostics: dict[str, float] = field(default_factory=dict)
    """Each check's largest |residual| / bound over the run (1 would trip)."""
    sc_arbitration: dict[str, object] = field(default_factory=dict)
    """Its SC sources: accepted and refused requests per source, conflicts."""


class Supervisor(Protocol):
    """A supervisor the rig drives from its tick (`SupervisorSpec.driven`): the handle's `node`."""

    @property
    def events(self) -> Sequence[Event]:
        """Its transitions and refused resets so far, in order."""
        ...

    @property
    def operator_actions(self) -> Sequence[OperatorRecord]:
        """The operator's commands it took in (at most OPERATOR_ACTIONS_KEPT)."""
        ...

    @property
    def operator_actions_dropped(self) -> int: ...

    @property
    def fence_misses(self) -> int:
        """Lockstep updates that went ahead without the rig's fence of their tick."""
        ...

    on_put: Callable[[str, bytes], None] | None
    """Called with each zenoh put it makes (the rig records them, and its lockstep fence counts them)."""

    def update(self, t: float, fence: int | None = None) -> object:
        """Decide at simulated time `t` (s) on the frames and zenoh inputs so far; `fence`: the rig's tick,
        whose zenoh inputs must all be in first. Sends its frame."""
        ...

    def observed_speed(self) -> float | None:
        """The ground speed it judged at its last update, m/s (None before one, or when it cannot tell)."""
        ...

    def report(self) -> SupervisorReport: ...


class SupervisorHandle(Protocol):
    """What a supervisor plug's `start(spec, link=None)` returns: the rig stops it at the end of the run.
    `link`: the rig's zenoh link, lent to a driven supervisor (its puts count in the lockstep fence); None:
    it opens its own."""

    @property
    def node(self) -> Supervisor:
        """What the rig updates from its tick when it drives it, and whose events `pure-hil supervisor`
        prints at the end."""
        ...

    def stop(self) -> None: ...


@runtime_checkable
class Watched(Protocol):
    """A part's handle that can tell whether the part still runs on its own thread (a controller's or a
    supervisor's may offer it): a command that runs a part until Ctrl-C ends when it stops on an error."""

    def alive(self) -> bool: ...


class NodeThread:
    """A plug's node on a thread of its own: `run(stop_event, *args)`, which returns once `stop()` sets the
    event (daemon: a node that will not end does not hold up its process's exit)."""

    def __init__(self, run: Callable[..., None], name: str, *args: object):
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=run, args=(self.stop_event, *args), name=name, daemon=True)

    def start(self) -> NodeThread:
        self.thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self.stop_event.set()
        self.thread.join(timeout)


class NodeHandle:
    """What the reference plugs' handles hold and how they shut down, written once for the controller
    (controller/embedded.py) and the supervisor (safety/embedded.py): the node on a `NodeThread` (None when
    the rig drives it from its tick), its bus, and a zenoh session of its own with the link on it, or a link
    the rig lent (`session` None), which stays the rig's to close."""

    bus: can.BusABC
    thread: NodeThread | None = None
    session: zenoh.Session | None = None
    link: ZenohLink | None = None
    _stopped = False

    def alive(self) -> bool:
        """Its thread still runs (an error that ended it is on stderr); driven: the rig's thread is its."""
        return self.thread is None or self.thread.thread.is_alive()

    def stop(self) -> None:
        """Once: the thread first, so that the node no longer uses what is closed after it."""
        if self._stopped:
            return
        self._stopped = True
        if self.thread is not None:
            self.thread.stop()
        self.close()

    def close(self) -> None:
        """Close what it opened: also what a start that failed part way had opened so far."""
        if self.session is not None:  # its own link and session; a lent link stays its owner's
            if self.link is not None:
                self.link.close()
            self.session.close()
        self.bus.shutdown()


def start_supervisor(name: str, spec: SupervisorSpec, link: ZenohLink | None = None) -> SupervisorHandle:
    """The supervisor plug registered as `name` (drivers/registry.py), started from `spec`."""
    handle: SupervisorHandle = find_plug(SUPERVISORS, name, "supervisor")(spec, link=link)
    return handle
