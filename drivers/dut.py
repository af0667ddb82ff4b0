"""How the rig starts a controller under test that runs in its own process space or thread.

A controller package registers a start function under the entry-point group `pure_hil.controllers`
(the reference controller: `reference = "controller.embedded:start"`). The rig looks it up by name, as
python-can picks a backend by name, and hands it a `DutSpec`: where the bus and zenoh are and which
robot and rider files describe the world. The rig never imports a controller.
"""

from __future__ import annotations

from typing import Literal, Protocol, runtime_checkable

import msgspec

from drivers.bus_config import BusConfig
from drivers.devices import Devices
from drivers.registry import CONTROLLERS, find_plug
from drivers.zenoh_access import ZenohAccess


class DutSpec(msgspec.Struct, frozen=True, kw_only=True):
    can: BusConfig
    zenoh: ZenohAccess = ZenohAccess()
    """How to join the rig's zenoh (open sessions with `zenoh.open(identity)`)."""
    identity: str = "controller"
    """Its certificate's role on a secured bench (a router)."""
    mode: Literal["hacs", "ihacs"] = "hacs"
    robot: str
    """Robot TOML the controller builds its model from (may differ from the plant's: model mismatch)."""
    rider: str
    devices: Devices = Devices()
    """How the drives and the IMU speak on the bus (the bench's device profile, docs/devices.md)."""
    controller_config: str | None = None
    lockstep: bool = True
    tick_hz: float = 400.0
    driven: bool = False
    """The rig asks to drive the controller from its own thread (lockstep, in-process): no thread of the
    controller's own; the rig calls the handle's `poll()` right after every SYNC, and the controller answers
    any SYNC it finds queued before returning. A plugin that cannot be driven ignores it and offers no
    `poll()`: the rig then waits for its answer on the bus as for any other."""


class DutHandle(Protocol):
    """What a controller plug's `start(spec)` returns: the rig stops it at the end of the run. A handle may
    offer more, which the rig and the faults look for: `DrivenDut`, `PausableDut`."""

    def stop(self) -> None: ...


@runtime_checkable
class DrivenDut(DutHandle, Protocol):
    """A controller the rig can drive from its own tick (`DutSpec.driven`)."""

    def poll(self) -> None:
        """Take in what is queued and answer any SYNC among it, before returning."""
        ...


@runtime_checkable
class PausableDut(DutHandle, Protocol):
    """A controller that can hang and go on (the `process.hang` fault)."""

    def pause(self) -> None:
        """Stop handling frames (they queue up on the bus) until `resume()`."""
        ...

    def resume(self) -> None: ...


def start_dut(name: str, spec: DutSpec) -> DutHandle:
    handle: DutHandle = find_plug(CONTROLLERS, name, "controller")(spec)
    return handle
