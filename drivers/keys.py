"""zenoh key expressions of the rig (docs/zenoh.md), all under one configurable prefix."""

from __future__ import annotations

from typing import Final

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
"""Each key (a `Keys` attribute) that carries a payload -> its payload type (drivers/schemas.py)."""


class Keys:
    """Every key of the rig under `prefix`, formatted once (nodes read them on every tick)."""

    def __init__(self, prefix: str = DEFAULT_PREFIX) -> None:
        p = prefix
        if not p or p.startswith("/") or p.endswith("/") or any(c in p for c in "*$?#"):
            raise ValueError(f"zenoh key prefix {p!r}: expected a plain path like 'pure' or 'bench2/pure'")
        self.prefix: Final[str] = prefix
        self.tes_wrench: Final[str] = f"{prefix}/tes/wrench"
        """TesWrench: the rider's wrench on the seat, from the emulated TES."""
        self.sc_request: Final[str] = f"{prefix}/sc/request"
        """ScRequest: what a shared-controller agent asks for."""
        self.sc_command: Final[str] = f"{prefix}/sc/command"
        """ScCommand: what the supervisor lets through; the only SC input the controller reads."""
        self.safety_state: Final[str] = f"{prefix}/safety/state"
        """SafetyState: the supervisor's state on every transition and periodically."""
        self.safety_alert: Final[str] = f"{prefix}/safety/alert"
        """SafetyAlert: what the rider is told (slow down, stop and sit up)."""
        self.safety_estop: Final[str] = f"{prefix}/safety/estop"
        """EstopCommand: operator e-stop and reset."""
        self.controller_command: Final[str] = f"{prefix}/controller/command"
        """ControllerCommand: operator enable/disable of the controller (enable is needed after an e-stop)."""
        self.controller_telemetry: Final[str] = f"{prefix}/controller/telemetry"
        """ControllerTelemetry: the controller's internal commands per tick, for recording and metrics."""
        self.rig_tick: Final[str] = f"{prefix}/rig/tick"
        """RigTick: lockstep only, the rig has put every zenoh input of a tick (the nodes' fence)."""
        self.rig_status: Final[str] = f"{prefix}/rig/status"
        """Queryable: the rig service's status."""
        self.rig_live: Final[str] = f"{prefix}/rig/live"
        """JSON, about 20 Hz of wall time while the service runs a scenario: what the console draws
        (hil/live.py)."""
        self.rig_history: Final[str] = f"{prefix}/rig/history"
        """Queryable: the service's past runs (hil/history.py)."""
        self.rig_file: Final[str] = f"{prefix}/rig/file"
        """Queryable: a file of a past run's folder, in chunks (hil/service.py)."""
        self.everything: Final[str] = f"{prefix}/**"

    def rig(self, name: str) -> str:
        """Queryables and topics of the rig service's control API (start, stop, intent, ...)."""
        return f"{self.prefix}/rig/{name}"

    # A value, made of its prefix alone: equal, hashed, shown and pickled by it (Final: mypy refuses any
    # later assignment, so the keys and the hash cannot drift from it).
    def __eq__(self, other: object) -> bool:
        return self.prefix == other.prefix if other.__class__ is self.__class__ else NotImplemented

    def __hash__(self) -> int:
        return hash(self.prefix)

    def __repr__(self) -> str:
        return f"Keys(prefix={self.prefix!r})"

    def __reduce__(self) -> tuple[type[Keys], tuple[str]]:
        return Keys, (self.prefix,)
