"""docs/faults.md's bounds tables, generated from the catalog's declarations (each parameter's `Bound` or
msgspec constraint in its type, hil/faults/base.py), so the page and the checks cannot disagree.

python -m hil.faults.bounds docs/faults.md      # rewrite its generated sections
"""

from __future__ import annotations

import math
import re
import sys
import typing
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import msgspec

from drivers.can_codec import Catalog
from hil.faults import FAMILIES
from hil.faults.base import Bound, FaultSpec, FaultTarget, bounds_of, number
from hil.faults.sensors import CHANNELS, SATURATION, channel_range
from plant.params import RobotParams, SimParams

BEGIN, END = "<!-- generated: {name} (python -m {generator}) -->", "<!-- /generated: {name} -->"
COMMON = ("at", "duration")
"""Every fault's own fields, listed once."""
REFERENCE_BITRATE = 1_000_000
"""The bus of the examples (the contract's 1 Mbit/s; the embedded bench's)."""


def reference_rig() -> FaultTarget:
    """What a bound that depends on the rig needs of one, at the contract's bus and PURE's defaults."""
    plant = SimpleNamespace(sim=SimParams(), robot=RobotParams())
    return cast(
        FaultTarget,
        SimpleNamespace(plant=plant, bitrate=REFERENCE_BITRATE, can=SimpleNamespace(catalog=Catalog())),
    )


def _hint(cls: type[FaultSpec], name: str) -> Any:
    return typing.get_type_hints(cls, include_extras=True)[name]


def _meta(hint: Any) -> msgspec.Meta | None:
    for meta in getattr(hint, "__metadata__", ()):
        if isinstance(meta, msgspec.Meta):
            return meta
    for arg in typing.get_args(hint):
        found = _meta(arg)
        if found is not None:
            return found
    return None


def _choices(hint: Any) -> tuple[str, ...]:
    if typing.get_origin(hint) is typing.Literal:
        return tuple(str(c) for c in typing.get_args(hint))
    for arg in typing.get_args(hint):
        found = _choices(arg)
        if found:
            return found
    return ()


def _example(cls: type[FaultSpec], name: str, bound: Bound) -> str:
    """A rig-dependent bound's value for the fault's defaults on the reference rig ('' if it needs more)."""
    if bound.limit is None:
        return ""
    try:
        found = bound.limit(cls(), reference_rig())
    except (TypeError, msgspec.ValidationError, KeyError):  # a required parameter: no default fault
        return ""
    return "" if found is None else f" (the default fault's on the embedded bench: {number(found[0])})"


def describe(cls: type[FaultSpec], name: str) -> tuple[str, str]:
    """(the bound, why) of one parameter, from its declaration."""
    bound = bounds_of(cls).get(name)
    if bound is not None:
        numeric = bound.low is not None or bound.high is not None or bound.limit is not None
        text = bound.text(name) + _example(cls, name, bound) if numeric else bound.limit_text
        return text, bound.why
    hint = _hint(cls, name)
    choices = _choices(hint)
    if choices:
        shown = ", ".join(f"`{c}`" for c in choices)
        return ("one of the channels below" if len(choices) > 8 else f"one of {shown}"), ""
    meta = _meta(hint)
    if meta is not None and meta.max_length is not None:
        return f"{meta.min_length or 0}..{meta.max_length} characters", meta.description or ""
    raise TypeError(f"{cls.__name__}.{name} declares no bound (hil/faults/base.py Bound)")


def parameter_table() -> str:
    """Every parameter of every kind: its bound and why."""
    rows = ["| kind | parameter | bound | why |", "|---|---|---|---|"]
    first = FAMILIES["sensors"][0]
    for name in COMMON:
        bound, why = describe(first, name)
        rows.append(f"| every kind | `{name}` | {_cell(bound)} | {_cell(why)} |")
    for classes in FAMILIES.values():
        for cls in classes:
            for field in msgspec.structs.fields(cls):
                if field.name in (*COMMON, "expect"):
                    continue
                bound, why = describe(cls, field.name)
                rows.append(
                    f"| `{cls.__struct_config__.tag}` | `{field.name}` | {_cell(bound)} | {_cell(why)} |"
                )
    return "\n".join(rows)


def channel_table() -> str:
    """Each sensor channel's range on the wire: where a faulty value saturates (an encoder's count wraps)."""
    robot = RobotParams()
    rows = ["| channel | carried in | range on the wire |", "|---|---|---|"]
    for channel, wire in CHANNELS.items():
        where = "the seat's payload (`Force`)" if wire.frame == "tes" else f"`{wire.frame}.{wire.signal}`"
        low, high = cast(tuple[float, float], channel_range(channel, robot.encoder))
        if SATURATION[channel] is None:
            turns = (high - low) / (2 * math.pi)
            span = (
                f"wraps every {number(turns)} turns ({robot.encoder.word_bits}-bit count at the robot's "
                f"{robot.encoder.counts_per_rev} counts/rev)"
            )
        else:
            span = f"{number(low)} .. {number(high)} {wire.unit}, saturating"
        rows.append(f"| `{channel}` | {where} | {span} |")
    return "\n".join(rows)


def _replacement(text: str) -> typing.Callable[[re.Match[str]], str]:
    """A function, not a string: the body's backslashes stay as written."""
    return lambda _: text


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def sections() -> dict[str, str]:
    return {"fault bounds": parameter_table(), "channel ranges": channel_table()}


def render(text: str) -> str:
    """`text` (docs/faults.md) with its generated sections current."""
    return replace_sections(text, sections(), "hil.faults.bounds", "docs/faults.md")


def replace_sections(text: str, bodies: dict[str, str], generator: str, page: str) -> str:
    """`text` (the page `page`) with each of its sections that `generator` generates replaced by its body."""
    for name, body in bodies.items():
        begin, end = BEGIN.format(name=name, generator=generator), END.format(name=name)
        pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
        if not pattern.search(text):
            raise ValueError(f"{page} has no generated section {name!r} ({begin} ... {end})")
        text = pattern.sub(_replacement(f"{begin}\n{body}\n{end}"), text)
    return text


if __name__ == "__main__":
    page = Path(sys.argv[1] if len(sys.argv) > 1 else "docs/faults.md")
    try:
        page.write_text(render(page.read_text()))
    except OSError as exc:
        sys.exit(f"{page}: cannot rewrite: {exc.strerror or exc}")
