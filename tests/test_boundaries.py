"""The one-way import rules of docs/architecture.md, checked by parsing every module's imports."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"hil", "plant", "drivers", "safety", "controller"}
ALLOWED = {
    "hil": {"plant", "drivers", "safety"},
    "controller": {"drivers"},
    "safety": {"drivers"},
    "drivers": set(),
    "plant": set(),
}
# plant/ is physics only: numerics and typed records, nothing that does I/O, threads or clocks.
PLANT_THIRD_PARTY = {"numpy", "scipy", "msgspec"}
PLANT_FORBIDDEN_STDLIB = {"time", "threading", "socket", "os", "io", "asyncio", "subprocess", "pathlib"}


def imported_roots(source: str, own_package: str) -> set[str]:
    tree = ast.parse(source)
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            roots.add(node.module.split(".")[0])
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            roots.add(own_package)  # a relative import stays inside its package
    return roots


def modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", sorted(OURS))
def test_imports_flow_one_way(package):
    bad = []
    for path in modules(package):
        for root in imported_roots(path.read_text(), package) & OURS - {package}:
            if root not in ALLOWED[package]:
                bad.append(f"{path.relative_to(ROOT)} imports {root}")
    assert not bad, "forbidden imports (docs/architecture.md):\n" + "\n".join(bad)


def test_plant_uses_only_numerics():
    import sys

    stdlib = set(sys.stdlib_module_names)
    bad = []
    for path in modules("plant"):
        for root in imported_roots(path.read_text(), "plant") - {"plant", "__future__"}:
            if root in PLANT_FORBIDDEN_STDLIB or (root not in stdlib and root not in PLANT_THIRD_PARTY):
                bad.append(f"{path.relative_to(ROOT)} imports {root}")
    assert not bad, "plant/ must stay numpy/scipy-only with no I/O or clocks:\n" + "\n".join(bad)


def test_checker_sees_a_violation():
    # Test the test: the same parser finds forbidden imports in every import form.
    source = "from plant.ballbot import Plant\nimport hil.cli as c\nfrom . import sibling\n"
    roots = imported_roots(source, "controller")
    assert {"plant", "hil", "controller"} <= roots
    assert roots & OURS - {"controller"} - ALLOWED["controller"] == {"plant", "hil"}
