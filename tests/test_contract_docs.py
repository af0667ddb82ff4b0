"""docs/contract.md, docs/schemas/ and docs/configuration.md's bounds say what the code does: generated parts
current, every number a controller author relies on recomputed from the code, nothing pointing outside the
repository."""

from __future__ import annotations

import re

import msgspec
import numpy as np

from drivers.can_bus import CanNode
from drivers.config import load_toml
from drivers.keys import Keys
from drivers.robot import RobotModel
from hil.contract import PAYLOADS, json_schemas, render
from safety.config import SupervisorConfig
from safety.diagnostics import motor_jacobian
from tests.helpers import ROOT

CONTRACT = ROOT / "docs/contract.md"
REGENERATE = "regenerate with: python -m hil.contract docs"


def test_generated_tables_and_schemas_are_current():
    text = CONTRACT.read_text()
    assert render(text) == text, REGENERATE
    for name, data in json_schemas().items():
        assert (ROOT / "docs/schemas" / name).read_bytes() == data, f"docs/schemas/{name}: {REGENERATE}"
    assert {p.name for p in (ROOT / "docs/schemas").glob("*.json")} == set(json_schemas())


def test_the_configuration_pages_bounds_are_the_declarations():
    from hil.config_bounds import PAGE, render

    page = ROOT / PAGE
    assert render(page.read_text()) == page.read_text(), (
        f"regenerate with: python -m hil.config_bounds {PAGE}"
    )
    # Positive control: a bound that changed would be caught.
    stale = page.read_text().replace(
        "| `body.mass` | 5 <= mass <= 200 |", "| `body.mass` | 5 <= mass <= 300 |"
    )
    assert stale != page.read_text() and render(stale) != stale


def rules_table(text: str) -> list[str]:
    section = text[text.index("## What the supervisor stops for") :]
    section = section[: section.index("\n## ", 3)]
    return [line for line in section.splitlines() if line.startswith("| `")]


def wrong_numbers(rows: list[str], config: SupervisorConfig) -> list[str]:
    """Rows in which a rule's default value is not among the row's numbers."""
    defaults = msgspec.to_builtins(config)
    wrong = []
    for row in rows:
        numbers = {float(x) for x in re.findall(r"\d+(?:\.\d+)?", row.split("|", 2)[2])}
        for name in re.findall(r"`(\w+)\.(\w+)`", row.split("|")[1]):
            value = float(defaults[name[0]][name[1]])
            if value not in numbers:
                wrong.append(f"{'.'.join(name)} = {value:g} is not in: {row}")
    return wrong


def test_every_rule_the_contract_states_is_the_supervisors_default():
    rows = rules_table(CONTRACT.read_text())
    assert len(rows) >= 10
    assert wrong_numbers(rows, SupervisorConfig()) == []
    assert load_toml(ROOT / "configs/safety/default.toml", SupervisorConfig) == SupervisorConfig()
    # Positive control: a default that changed would be caught.
    changed = msgspec.structs.replace(
        SupervisorConfig(), watchdogs=msgspec.structs.replace(SupervisorConfig().watchdogs, heartbeat=0.07)
    )
    assert any("watchdogs.heartbeat" in w for w in wrong_numbers(rows, changed))


def test_the_geometry_and_its_worked_examples_are_the_robot_files():
    text = CONTRACT.read_text()
    g = motor_jacobian(load_toml(ROOT / "configs/robot/pure.toml", RobotModel))
    to_motors = np.linalg.inv(g.T)
    for value in [*g.ravel(), *to_motors.ravel()]:
        assert f"{value:.4f}".replace("-0.0000", "0.0000") in text
    assert f"{(to_motors @ [0, 10, 0])[2]:.3f}" == "0.557" and f"{(to_motors @ [5, 0, 2])[0]:.3f}" == "-0.257"
    rates = g @ [0, 1 / 0.1145, 0]
    assert f"{rates[2]:.2f}" == "78.38" and "78.38" in text
    assert f"{(g @ [0, 0, -0.5])[0]:.2f}" == "-5.18" and "-5.18" in text


def test_the_e2e_worked_example_is_what_a_node_sends():
    node = CanNode(None)
    first = node.message("DRIVE1_COMMAND", {"Torque": 1.234, "Tick": 1000, "Enable": 1})
    second = node.message("DRIVE1_COMMAND", {"Torque": 1.234, "Tick": 1001, "Enable": 1})
    text = CONTRACT.read_text()
    for frame in (first, second):
        assert bytes(frame.data).hex(" ").upper() in text


def test_every_key_and_payload_is_in_the_contract():
    text = CONTRACT.read_text()
    keys = Keys()
    for name in vars(keys):
        if name not in ("prefix", "everything"):
            key = getattr(keys, name)
            if not key.startswith("pure/rig/status"):
                assert f"`{key}`" in text, key
    for payload in PAYLOADS:
        assert f"`{payload.__name__}`" in text


def project_files() -> list:
    """Every text file of the project (not the venv, git, build or run outputs)."""
    skip = {".git", ".venv", "runs", "build", "dist", "__pycache__", ".pytest_cache", ".ruff_cache"}
    return [
        path
        for path in sorted(ROOT.rglob("*"))
        if path.is_file()
        and path.suffix in {".md", ".py", ".toml", ".json5", ".dbc", ".cfg", ".txt"}
        and not skip.intersection(path.relative_to(ROOT).parts)
        and not any(part.endswith(".egg-info") for part in path.relative_to(ROOT).parts)
    ]


def test_nothing_points_outside_the_repository():
    # The team's background notes are not shipped: what a user needs from them is in docs/ (physics.md).
    outside = re.compile(r"\.\./shared|shared/\w+\.md|\b(?:DESIGN|stack|netns)\.md")
    files = project_files()
    assert ROOT / "docs/contract.md" in files and ROOT / "hil/run/rig.py" in files
    hits = [
        f"{path.relative_to(ROOT)}:{n}"
        for path in files
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if outside.search(line)
    ]
    assert hits == []


def test_every_cited_section_of_the_physics_page_exists():
    headings = set(re.findall(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", (ROOT / "docs/physics.md").read_text(), re.M))
    assert {"1.3", "2.4", "4.2", "5.3", "8"} <= headings
    cited = {
        (f"{path.relative_to(ROOT)}", section)
        for path in project_files()
        for line in path.read_text().splitlines()
        for ref in re.findall(r"physics\.md[^§\n]{0,12}((?:§\s?\d+(?:\.\d+)?(?:,\s*)?)+)", line)
        for section in re.findall(r"§\s?(\d+(?:\.\d+)?)", ref)
    }
    assert len(cited) > 20
    assert sorted(c for c in cited if c[1] not in headings) == []
