"""docs/configuration.md's bounds tables, generated from the declarations (each field's `msgspec.Meta`:
drivers/bounds.py for the robot and the rider, beside the field elsewhere), so the page and the checks
cannot disagree. The same walk lists the bounded fields tests/test_config_bounds.py sets out of bounds.

python -m hil.config_bounds docs/configuration.md      # rewrite its generated sections
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import msgspec
import msgspec.inspect as mi

from drivers.bus_config import BusConfig
from hil.faults.base import number
from hil.faults.bounds import replace_sections
from plant.params import RiderParams, RobotParams
from plant.rider import Segment

PAGE = "docs/configuration.md"
REACH = (
    "|{name}| <= the rider file's max_lean_deg (a lean) or max_twist_torque (a twist)",
    "no rider reaches past their own limits (plant/rider.py `beyond_reach`, checked with the rider known)",
)
"""The bound of a segment's numbers that depend on the rider, and why."""


@dataclass(frozen=True, slots=True)
class FieldBound:
    """A numeric field's declared bound, where it sits in its file."""

    path: str
    """As the refusal names it: `body.mass` (`$.body.mass`)."""
    whole: bool
    """An integer field."""
    low: float | None
    low_open: bool
    high: float | None
    high_open: bool
    why: str
    choices: tuple[object, ...] = ()
    """The values each item may take (a tuple of Literals: `motor_sign`), instead of a range."""

    @property
    def bounded(self) -> bool:
        return self.low is not None or self.high is not None or bool(self.choices)

    def text(self) -> str:
        """`0.05 <= radius <= 0.5`, or `each of motor_sign: -1 or 1`."""
        name = self.path.rsplit(".", 1)[-1]
        if self.choices:
            return f"each of {name}: {' or '.join(str(c) for c in self.choices)}"
        lower = "" if self.low is None else f"{number(self.low)} {'<' if self.low_open else '<='} "
        upper = "" if self.high is None else f" {'<' if self.high_open else '<='} {number(self.high)}"
        return f"{lower}{name}{upper}"


def _bound(path: str, t: mi.Type) -> FieldBound | None:
    why = ""
    if isinstance(t, mi.TupleType) and t.item_types:  # a tuple of choices (motor_sign)
        item = t.item_types[0]
        if isinstance(item, mi.Metadata):
            why, item = (item.extra_json_schema or {}).get("description", ""), item.type
        if isinstance(item, mi.LiteralType):
            return FieldBound(path, True, None, False, None, False, why, item.values)
        return None
    if isinstance(t, mi.UnionType):  # `X | None`: the bound of X
        found = [_bound(path, u) for u in t.types if not isinstance(u, mi.NoneType)]
        return found[0] if len(found) == 1 else None
    if isinstance(t, mi.Metadata):
        why = (t.extra_json_schema or {}).get("description", "")
        t = t.type
    if not isinstance(t, (mi.FloatType, mi.IntType)):
        return None
    low, high = (t.gt if t.gt is not None else t.ge), (t.lt if t.lt is not None else t.le)
    return FieldBound(path, isinstance(t, mi.IntType), low, t.gt is not None, high, t.lt is not None, why)


def bounds(cls: type[msgspec.Struct], prefix: str = "") -> list[FieldBound]:
    """Every numeric field of `cls` and of the records in it, in order, with its bound (None: unbounded)."""
    found = []
    info = mi.type_info(cls)
    assert isinstance(info, mi.StructType)
    for field in info.fields:
        path, t = f"{prefix}{field.name}", field.type
        if isinstance(t, mi.StructType):
            found += bounds(t.cls, f"{path}.")
            continue
        bound = _bound(path, t)
        if bound is not None or _numeric(t):
            found.append(bound or FieldBound(path, False, None, False, None, False, ""))
    return found


def _numeric(t: mi.Type) -> bool:
    if isinstance(t, mi.UnionType):
        return any(_numeric(u) for u in t.types)
    return isinstance(t, (mi.FloatType, mi.IntType))


def segment_kinds() -> list[type[msgspec.Struct]]:
    return list(Segment.__args__)


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def file_table(cls: type[msgspec.Struct]) -> str:
    rows = ["| field | bound | why |", "|---|---|---|"]
    rows += [f"| `{b.path}` | {_cell(b.text())} | {_cell(b.why)} |" for b in bounds(cls)]
    return "\n".join(rows)


def intent_table() -> str:
    rows = ["| segment | field | bound | why |", "|---|---|---|---|"]
    for kind in segment_kinds():
        tag = kind.__struct_config__.tag
        for b in bounds(kind):
            text, why = (b.text(), b.why) if b.bounded else (REACH[0].format(name=b.path), REACH[1])
            rows.append(f"| `{tag}` | `{b.path}` | {_cell(text)} | {_cell(why)} |")
    return "\n".join(rows)


def bench_table() -> str:
    rows = ["| field | bound | why |", "|---|---|---|"]
    for b in bounds(BusConfig):
        if b.bounded:
            rows.append(f"| `can.{b.path}` | {_cell(b.text())} | {_cell(b.why)} |")
    return "\n".join(rows)


def sections() -> dict[str, str]:
    return {
        "robot bounds": file_table(RobotParams),
        "rider bounds": file_table(RiderParams),
        "intent bounds": intent_table(),
        "bench bounds": bench_table(),
    }


def render(text: str) -> str:
    """`text` (docs/configuration.md) with its generated sections current."""
    return replace_sections(text, sections(), "hil.config_bounds", PAGE)


if __name__ == "__main__":
    page = Path(sys.argv[1] if len(sys.argv) > 1 else PAGE)
    try:
        page.write_text(render(page.read_text()))
    except OSError as exc:
        sys.exit(f"{page}: cannot rewrite: {exc.strerror or exc}")
