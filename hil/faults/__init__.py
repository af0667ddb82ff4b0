"""The fault catalog (docs/faults.md): every fault a scenario, a campaign or a live session can inject.

One module per family, as python-can keeps one module per interface: sensors, frames (CAN), topics
(zenoh), actuators (drives and the world), processes (and timing), devices (a device profile's own
protocol). Each fault is a typed msgspec Struct
tagged by `kind` ("sensor.stuck", "can.drop", ...); `Fault` is their union, so a TOML table or a JSON
object decodes to the right one with a clear error for a wrong field.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Union

import msgspec

from hil.faults import actuators, devices, frames, processes, sensors, topics
from hil.faults.base import Expect, FaultError, FaultEvent, FaultSpec, FaultState, kind_of
from hil.faults.runtime import FaultSet

FAMILIES: dict[str, tuple[type[FaultSpec], ...]] = {
    "sensors": sensors.FAULTS,
    "frames": frames.FAULTS,
    "topics": topics.FAULTS,
    "actuators": actuators.FAULTS,
    "processes": processes.FAULTS,
    "devices": devices.FAULTS,
}
CATALOG: dict[str, type[FaultSpec]] = {kind_of(cls): cls for family in FAMILIES.values() for cls in family}
"""kind -> fault class."""

if TYPE_CHECKING:
    Fault = FaultSpec  # a checker cannot evaluate the Union below; every member is a FaultSpec
else:
    Fault = Union[tuple(CATALOG.values())]  # noqa: UP007
"""Any fault of the catalog (decode with msgspec.convert(obj, Fault))."""


def parse_fault(obj: dict[str, Any], where: str = "fault") -> FaultSpec:
    """A fault from a plain mapping (TOML table, JSON object); ValueError names what was wrong: `where`, the
    kind, the parameter and its bound."""
    kind = obj.get("kind") if isinstance(obj, dict) else None
    if kind not in CATALOG:
        raise ValueError(f"{where}: unknown kind {kind!r}: expected one of {', '.join(sorted(CATALOG))}")
    try:
        return msgspec.convert(obj, CATALOG[kind])
    except msgspec.ValidationError as exc:
        said = str(exc)  # a bound's message names the kind already; msgspec's own do not
        raise ValueError(f"{where}: {said if said.startswith(kind) else f'{kind}: {said}'}") from None


def describe_catalog() -> str:
    """One line per fault: kind, parameters with defaults, and what it does."""
    lines = []
    for family, classes in FAMILIES.items():
        lines.append(f"{family}:")
        for cls in classes:
            tag = cls.__struct_config__.tag
            params = []
            for f in msgspec.structs.fields(cls):
                if f.name in ("at", "duration", "expect"):
                    continue
                params.append(f.name if f.default is msgspec.NODEFAULT else f"{f.name}={f.default!r}")
            doc = " ".join((cls.__doc__ or "").split())
            lines.append(f"  {tag:28s} {' '.join(params)}")
            lines.append(f"      {doc}")
    return "\n".join(lines)


__all__ = [
    "CATALOG",
    "Expect",
    "Fault",
    "FaultError",
    "FaultEvent",
    "FaultSet",
    "FaultSpec",
    "FaultState",
    "parse_fault",
]
