"""zenoh key expressions of the rig (docs/zenoh.md), all under one configurable prefix."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.schemas import (
    ControllerCommand,
    ControllerTelemetry,
    EstopCommand,
    Payload,
    RigTick,
    SafetyAlert,
    SafetyState,
    ScCommand,
    ScRequest,
    TesWrench,
)

DEFAULT_PREFIX = "pure"

PAYLOADS: dict[str, type[Payload]] = {
    "tes_wrench": TesWrench,
    "sc_request": ScRequest,
    "sc_command": ScCommand,
    "safety_state": SafetyState,
    "safety_alert": SafetyAlert,
    "safety_estop": EstopCommand,
    "controller_command": ControllerCommand,
    "controller_telemetry": ControllerTelemetry,
    "rig_tick": RigTick,
}
"""Each key (a `Keys` property) that carries a payload -> its payload type (drivers/schemas.py)."""


@dataclass(frozen=True, slots=True)
class Keys:
    prefix: str = DEFAULT_PREFIX

    def __post_init__(self) -> None:
        p = self.prefix
        if not p or p.startswith("/") or p.endswith("/") or any(c in p for c in "*$?#"):
            raise ValueError(f"zenoh key prefix {p!r}: expected a plain path like 'pure' or 'bench2/pure'")

    @property
    def tes_wrench(self) -> str:
        """TesWrench: the rider's wrench on the seat, from the emulated TES."""
        return f"{self.prefix}/tes/wrench"

    @property
    def sc_request(self) -> str:
        """ScRequest: what a shared-controller agent asks for."""
        return f"{self.prefix}/sc/request"

    @property
    def sc_command(self) -> str:
        """ScCommand: what the supervisor lets through; the only SC input the controller reads."""
        return f"{self.prefix}/sc/command"

    @property
    def safety_state(self) -> str:
        """SafetyState: the supervisor's state on every transition and periodically."""
        return f"{self.prefix}/safety/state"

    @property
    def safety_alert(self) -> str:
        """SafetyAlert: what the rider is told (slow down, stop and sit up)."""
        return f"{self.prefix}/safety/alert"

    @property
    def safety_estop(self) -> str:
        """EstopCommand: operator e-stop and reset."""
        return f"{self.prefix}/safety/estop"

    @property
    def controller_command(self) -> str:
        """ControllerCommand: operator enable/disable of the controller (enable is needed after an e-stop)."""
        return f"{self.prefix}/controller/command"

    @property
    def controller_telemetry(self) -> str:
        """ControllerTelemetry: the controller's internal commands per tick, for recording and metrics."""
        return f"{self.prefix}/controller/telemetry"

    @property
    def rig_tick(self) -> str:
        """RigTick: lockstep only, the rig has put every zenoh input of a tick (the nodes' fence)."""
        return f"{self.prefix}/rig/tick"

    @property
    def rig_status(self) -> str:
        """Queryable: the rig service's status."""
        return f"{self.prefix}/rig/status"

    @property
    def rig_live(self) -> str:
        """JSON, about 20 Hz of wall time while the service runs a scenario: what the console draws
        (hil/live.py)."""
        return f"{self.prefix}/rig/live"

    @property
    def rig_history(self) -> str:
        """Queryable: the service's past runs (hil/history.py)."""
        return f"{self.prefix}/rig/history"

    @property
    def rig_file(self) -> str:
        """Queryable: a file of a past run's folder, in chunks (hil/service.py)."""
        return f"{self.prefix}/rig/file"

    def rig(self, name: str) -> str:
        """Queryables and topics of the rig service's control API (start, stop, intent, ...)."""
        return f"{self.prefix}/rig/{name}"

    @property
    def everything(self) -> str:
        return f"{self.prefix}/**"
