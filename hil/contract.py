"""The wire contract as data, for docs/contract.md and docs/schemas/: every CAN message and signal from the
DBC, a JSON Schema per zenoh payload from its msgspec type, and the planar model for the shipped riders from
the plant. Generated, never hand-copied:

    python -m hil.contract docs        # rewrites docs/schemas/*.json and the tables in docs/contract.md

tests/test_contract_docs.py fails when the docs drift from the code.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import msgspec

from drivers.can_codec import Catalog, MessageName
from drivers.config import load_toml
from drivers.keys import PAYLOADS as KEY_PAYLOADS
from drivers.schemas import json_schema

ROOT = Path(__file__).resolve().parents[1]

PAYLOADS = tuple(KEY_PAYLOADS.values())
"""Every zenoh payload type (drivers/schemas.py)."""

BEGIN, END = "<!-- generated: {name} (python -m hil.contract docs) -->", "<!-- /generated: {name} -->"


def json_schemas() -> dict[str, bytes]:
    """File name -> JSON Schema (draft 2020-12, as msgspec writes it) of each payload."""
    return {
        f"{t.__name__}.json": msgspec.json.format(msgspec.json.encode(json_schema(t)), indent=2) + b"\n"
        for t in PAYLOADS
    }


def signal_table(catalog: Catalog | None = None) -> str:
    """One row per signal of the DBC: message, id, sender, rate, signal, bits, resolution, range, unit,
    receivers, value table or comment."""
    catalog = catalog or Catalog()
    period = "every SYNC tick"
    rows = [
        "| message | id | sender | rate | signal | bits | resolution | range | unit | read by | values |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for codec in sorted(catalog, key=lambda c: c.frame_id):
        m = codec.message
        rate = f"{1000 / codec.cycle_time_ms:g} Hz" if codec.cycle_time_ms else period
        if m.name == MessageName.OPERATOR_ESTOP:
            rate = "event"
        head = [m.name, f"0x{m.frame_id:03X}", ", ".join(m.senders), rate]
        for i, s in enumerate(m.signals):
            bits = f"{s.start}..{s.start + s.length - 1}" + (" s" if s.is_signed else " u")
            values = ", ".join(f"{raw} {name}" for raw, name in sorted((s.choices or {}).items()))
            if len(values) > 120:
                values = "the DBC's value table"
            comment = (s.comment or "").replace("|", "/")
            cells = [
                *(head if i == 0 else [""] * 4),
                s.name,
                bits,
                f"{s.scale:g}",
                f"{s.minimum:.10g}..{s.maximum:.10g}",
            ]
            cells += [s.unit or "", ", ".join(s.receivers), values or comment]
            rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)


def model_table(root: Path = ROOT) -> str:
    """Per shipped rider and plane, the linearised planar model about upright rest (rider rigid with the
    chassis): the nonzero entries of A and B for s = [θ, φ, θ̇, φ̇], input the plane's ball torque."""
    from hil.run.truth_balancer import linearise_plane
    from plant.ballbot import plane_params
    from plant.params import RiderParams, RobotParams

    robot = load_toml(root / "configs/robot/pure.toml", RobotParams)
    rows = [
        "| rider | plane | a20 | a22 | a23 | a30 | a32 | a33 | b2 | b3 |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for path in sorted((root / "configs/riders").glob("*.toml")):
        rider = load_toml(path, RiderParams)
        for plane in ("pitch", "roll"):
            a, b = linearise_plane(plane_params(robot, rider, plane, torso=False))
            cells = [a[2, 0], a[2, 2], a[2, 3], a[3, 0], a[3, 2], a[3, 3], b[2, 0], b[3, 0]]
            rows.append(f"| {path.stem} | {plane} | " + " | ".join(f"{x:.3f}" for x in cells) + " |")
    return "\n".join(rows)


def version_table() -> str:
    """Each contract version and what it changed (drivers/contract.py)."""
    from drivers.contract import CHANGES, CONTRACT_VERSION

    rows = [
        f"This page is contract **{CONTRACT_VERSION}** (`drivers/contract.py`).",
        "",
        "| version | what changed |",
        "|---|---|",
        "| 1 | the first contract: the frames, the tick, E2E, the zenoh keys |",
    ]
    return "\n".join(rows + [f"| {v} | {CHANGES[v]} |" for v in sorted(CHANGES)])


def sections() -> dict[str, str]:
    """The generated sections of docs/contract.md by name."""
    return {"signals": signal_table(), "models": model_table(), "versions": version_table()}


def render(text: str) -> str:
    """`text` (docs/contract.md) with every generated section replaced by its current content."""
    for name, body in sections().items():
        text = _replace_section(text, name, body)
    return text


def _replace_section(text: str, name: str, body: str) -> str:
    begin, end = BEGIN.format(name=name), END.format(name=name)
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise ValueError(f"docs/contract.md has no generated section {name!r} ({begin} ... {end})")
    replacement = f"{begin}\n{body}\n{end}"
    return pattern.sub(lambda _: replacement, text)  # a function: the body's backslashes stay as written


def write(docs: Path) -> None:
    schemas = docs / "schemas"
    schemas.mkdir(parents=True, exist_ok=True)
    for name, data in json_schemas().items():
        (schemas / name).write_bytes(data)
    contract = docs / "contract.md"
    contract.write_text(render(contract.read_text()))


if __name__ == "__main__":
    folder = Path(sys.argv[1] if len(sys.argv) > 1 else "docs")
    try:
        write(folder)
    except OSError as exc:
        sys.exit(f"{folder}: cannot rewrite contract.md: {exc.strerror or exc}")
