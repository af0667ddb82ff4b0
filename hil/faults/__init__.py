"""The fault catalog (docs/faults.md): every fault a scenario, a campaign or a live session can inject.

One module per family, as python-can keeps one module per interface: sensors, frames (CAN), topics
(zenoh), actuators (drives and the world), processes (and timing), devices (a device profile's own
protocol). Each family is a plug of the entry-point group `pure_hil.faults` (drivers/registry.py), this
package's six registered the same way as a lab's own (pyproject.toml): its name, and a tuple of its fault
classes. Each fault is a typed msgspec Struct tagged by `kind` ("sensor.stuck", "can.drop", ...); `Fault`
is their union, so a TOML table or a JSON object decodes to the right one with a clear error for a wrong
field. Every installed family is imported with this package: a scenario's faults decode through the union of
all their kinds.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar, Union

import msgspec

from drivers.config import ConfigError, load_toml
from drivers.registry import FAULT_FAMILIES, BrokenPlug, find_plug, installed
from hil.faults.base import Expect, FaultError, FaultEvent, FaultSpec, FaultState, kind_of
from hil.faults.runtime import FaultSet


def _families() -> dict[str, tuple[type[FaultSpec], ...]]:
    """Each installed family's fault classes, by the family's name; BrokenPlug names a family that is not a
    tuple of fault classes, or a kind two families declare."""
    families: dict[str, tuple[type[FaultSpec], ...]] = {}
    declared: dict[str, str] = {}
    for name in installed(FAULT_FAMILIES):
        classes: object = find_plug(FAULT_FAMILIES, name, "fault family")  # a tuple, not a callable
        if not (
            isinstance(classes, tuple)
            and classes
            and all(isinstance(c, type) and issubclass(c, FaultSpec) for c in classes)
        ):
            raise BrokenPlug(f"fault family {name!r}: its entry point is not a tuple of FaultSpec classes")
        for cls in classes:
            kind = kind_of(cls)
            if kind in declared:
                raise BrokenPlug(f"fault family {name!r}: kind {kind!r} is fault family {declared[kind]!r}'s")
            declared[kind] = name
        families[name] = classes
    return families


FAMILIES = _families()
"""The installed fault families, by name (sorted), each its fault classes."""
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


T = TypeVar("T")
UNKNOWN_TAG = re.compile(r"Invalid value '(?P<kind>[^']*)' - at `(?P<at>\$[^`]*\.kind)`")
"""msgspec's words for a tag (a fault's `kind`) that no member of a tagged union has."""


def load_with_faults(path: Path | str, type_: type[T]) -> T:
    """A config file that holds faults (a scenario, a campaign) as `load_toml` reads it; a fault of an
    unknown kind is named with the fault families installed and their kinds."""
    try:
        return load_toml(path, type_)
    except ConfigError as exc:
        unknown = UNKNOWN_TAG.fullmatch(exc.detail)
        if unknown is None:
            raise
        raise ConfigError(
            path,
            f"no fault kind {unknown['kind']!r} in the fault families installed ({', '.join(FAMILIES)}): "
            f"expected one of {', '.join(sorted(CATALOG))} - at `{unknown['at']}`",
        ) from exc


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
    "load_with_faults",
    "parse_fault",
]
