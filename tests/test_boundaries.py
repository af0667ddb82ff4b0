"""The one-way import rules of docs/architecture.md, checked by parsing every module's imports."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"hil", "plant", "drivers", "safety", "controller"}
ALLOWED = {
    "hil": {"plant", "drivers"},  # the supervisor and the controller are plugs (drivers/plugs.py, dut.py)
    "controller": {"drivers"},
    "safety": {"drivers"},
    "drivers": set(),
    "plant": set(),
}
# plant/ is physics only: numerics and typed records, nothing that does I/O, threads or clocks.
PLANT_THIRD_PARTY = {"numpy", "scipy", "msgspec", "mypy_extensions", "mujoco"}  # mypy_extensions: @mypyc_attr
PLANT_FORBIDDEN_STDLIB = {"time", "threading", "socket", "os", "io", "asyncio", "subprocess", "pathlib"}
DECLARATIONS = "drivers.bounds"
"""The bounds of the numbers in the files every package reads, declared once (docs/architecture.md).
Declarations only: it imports nothing but typing and msgspec."""
SHARED = {
    DECLARATIONS: {"__future__", "typing", "msgspec"},
    "drivers.rotations": {"__future__", "math", "collections.abc"},  # arithmetic on plain floats
    "drivers.robot": {"__future__", "msgspec", DECLARATIONS},  # the robot file's sections several read
}
"""The modules of ours every package may import, the plant too, each with all it may import itself: nothing
that acts, nothing of ours."""


def imported_roots(source: str, own_package: str) -> set[str]:
    """The top-level packages `source` imports (SHARED, which anyone may import, not counted)."""
    tree = ast.parse(source)
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {alias.name.split(".")[0] for alias in node.names if alias.name not in SHARED}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module not in SHARED:
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
    assert not bad, "plant/ must stay numpy/scipy/MuJoCo-only with no I/O or clocks:\n" + "\n".join(bad)


VOCABULARY_HOME = "drivers.vocabulary"
SOURCES = (*sorted(OURS), "tests", "examples", "benchmarks")


def _names_from(source: str, prefix: str) -> list[tuple[int, str, str]]:
    """(line, module, name) of each name imported from a module under `prefix` (`import m` names '*')."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith(prefix):
            found += [(node.lineno, node.module, alias.name) for alias in node.names]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name, "*") for a in node.names if a.name.startswith(prefix)]
    return found


def vocabulary_imported_elsewhere(path: str, source: str) -> list[str]:
    """Where `source` imports a name of drivers/vocabulary.py through another of our modules (which has it
    only because it imported it: controller/core.py's own State, CONTROLLER_HEARTBEAT's, is another name)."""
    import importlib

    import drivers.vocabulary

    tree = ast.parse(Path(drivers.vocabulary.__file__).read_text())
    declared = {n.name for n in tree.body if isinstance(n, ast.ClassDef)} | {
        t.id for n in tree.body if isinstance(n, ast.Assign) for t in n.targets if isinstance(t, ast.Name)
    }
    return [
        f"{path}:{line} imports {name} from {module}: use {VOCABULARY_HOME}"
        for line, module, name in _names_from(source, "")
        if name in declared
        and module != VOCABULARY_HOME
        and module.split(".")[0] in OURS
        and getattr(importlib.import_module(module), name, None) is getattr(drivers.vocabulary, name)
    ]


def test_the_wires_vocabulary_is_imported_only_from_drivers():
    bad = [
        finding
        for package in SOURCES
        for path in modules(package)
        for finding in vocabulary_imported_elsewhere(str(path.relative_to(ROOT)), path.read_text())
    ]
    assert not bad, "\n".join(bad)


def test_positive_control_a_vocabulary_import_from_safety_is_seen():
    # What hil/ and tests did before drivers/vocabulary.py held the vocabulary, and drivers/rules.py the
    # limits the judge reads.
    source = (
        "from safety.machine import Cause, State\nfrom safety.node import OperatorRecord, SupervisorNode\n"
        "from safety.config import SupervisorConfig\n"
    )
    assert "safety" in imported_roots(source, "hil") - ALLOWED["hil"]
    assert len(vocabulary_imported_elsewhere("tests/x.py", source)) == 3


@pytest.mark.parametrize("module", sorted(SHARED))
def test_the_modules_everyone_imports_import_nothing_that_acts(module):
    path = ROOT / (module.replace(".", "/") + ".py")
    assert _imported_modules(path.read_text()) <= SHARED[module]


def test_positive_control_the_shared_modules_own_imports_are_seen():
    assert _imported_modules("import numpy\nfrom drivers.config import load_toml\n") == {
        "numpy",
        "drivers.config",
    }


def test_positive_control_the_plant_importing_any_other_module_of_drivers_is_forbidden():
    source = "from drivers.bounds import BallMass\nfrom drivers.config import load_toml\n"
    assert imported_roots(source, "plant") == {"drivers"}
    assert imported_roots("from drivers.bounds import BallMass\n", "plant") == set()
    assert imported_roots("from drivers.rotations import rotate\n", "plant") == set()
    assert imported_roots("import drivers.robot as robot_file\n", "plant") == set()


def test_checker_sees_a_violation():
    # Test the test: the same parser finds forbidden imports in every import form.
    source = "from plant.ballbot import Plant\nimport hil.cli as c\nfrom . import sibling\n"
    roots = imported_roots(source, "controller")
    assert {"plant", "hil", "controller"} <= roots
    assert roots & OURS - {"controller"} - ALLOWED["controller"] == {"plant", "hil"}


def _message_names() -> set[str]:
    from drivers.can_codec import Catalog

    return {codec.name for codec in Catalog()}


def _spelled_names(source: str, names: set[str]) -> list[tuple[int, str]]:
    """Where code (not a docstring) spells a CAN message name: a string literal, or an f-string whose
    fixed parts with anything in its holes could be one (f"DRIVE{i}_COMMAND")."""
    tree = ast.parse(source)
    skip = {  # docstrings are prose; the fixed parts of an f-string are judged with it
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    found = []
    for node in ast.walk(tree):
        fixed = [p.value for p in getattr(node, "values", ()) if isinstance(p, ast.Constant)]
        if isinstance(node, ast.JoinedStr) and any(re.search("[A-Z]{3}", str(part)) for part in fixed):
            pattern = "".join(
                re.escape(part.value) if isinstance(part, ast.Constant) else ".+" for part in node.values
            )
            found += [(node.lineno, n) for n in names if re.fullmatch(pattern, n)]
        if isinstance(node, ast.JoinedStr):
            skip.update(id(part) for part in node.values)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            found += [(node.lineno, node.value)] if node.value in names else []
    return found


def test_can_message_names_are_spelled_only_in_drivers():
    names = _message_names()
    bad = [
        f"{path.relative_to(ROOT)}:{line} spells {name!r}: use drivers.can_codec.MessageName"
        for package in sorted(OURS - {"drivers"})
        for path in modules(package)
        for line, name in _spelled_names(path.read_text(), names)
    ]
    assert not bad, "\n".join(bad)


def test_positive_control_the_name_check_sees_each_way_of_spelling_a_name():
    names = _message_names()
    source = '''"""SYNC in a docstring is prose."""
a = "SYNC"
b = {"DRIVE1_COMMAND": 0}
c = [f"DRIVE{i}_TORQUE" for i in (1, 2, 3)]
d = "SYNCHRONISED"
'''
    assert sorted(_spelled_names(source, names)) == [
        (2, "SYNC"),
        (3, "DRIVE1_COMMAND"),
        (4, "DRIVE1_TORQUE"),
        (4, "DRIVE2_TORQUE"),
        (4, "DRIVE3_TORQUE"),
    ]


# ------------------------------------------------------------------------------------- hil's rooms
FLOORS = (
    {"faults", "outputs", "devices"},  # the fault catalog, what streams during a run, the emulated devices
    {"bench"},  # the bench file, the machine's rigs
    {"run"},  # one run: build, tick loop, judge
    {"report", "contract", "config_bounds"},  # the run folder's summary and plots; generated doc tables
    {"pipeline", "live", "history"},  # build -> tick loop -> judge -> write; the service's stream and history
    {"service", "suites"},  # `pure-hil serve`; many runs
    {"console"},  # the rig's screen: a client of the service
    {"commands"},  # each `pure-hil` command's options and handler
    {"cli"},
    {"cli_reference"},
)
"""hil's rooms (a sub-package, or a top-level module) from the ground floor up: a room imports only rooms
on floors below its own (docs/architecture.md)."""
FLOOR = {room: n for n, rooms in enumerate(FLOORS) for room in rooms}


def hil_imports() -> dict[str, set[str]]:
    """Each hil module (dotted name) and the hil modules it imports, whatever the import form."""
    graph = {}
    for path in modules("hil"):
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        graph[name] = {m for m in _imported_modules(path.read_text()) if m.startswith("hil.")}
    return graph


def _imported_modules(source: str) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
    return found


def room(module: str) -> str:
    return module.split(".")[1]


def upward(graph: dict[str, set[str]]) -> list[str]:
    return [
        f"{m} imports {i}: {room(i)} is not below {room(m)}"
        for m, imports in graph.items()
        for i in imports
        if room(i) != room(m) and FLOOR[room(i)] >= FLOOR[room(m)]
    ]


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles among modules: strongly connected components of more than one (a package that
    imports its own submodules by its name is no circle)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue  # a package's name imported as itself, or an outside module
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_every_room_of_hil_is_on_a_floor():
    rooms = {room(m) for m in hil_imports() if m != "hil"}
    assert rooms == set(FLOOR), f"rooms without a floor: {rooms - set(FLOOR)}; gone: {set(FLOOR) - rooms}"


def test_hil_imports_only_downwards_and_has_no_import_circle():
    graph = hil_imports()
    graph.pop("hil", None)
    assert not upward(graph), "\n".join(upward(graph))
    assert not circles(graph), circles(graph)


def test_positive_control_an_upward_import_and_a_circle_are_seen():
    graph = {
        "hil.faults.base": {"hil.run.rig"},  # what the faults once did
        "hil.run.rig": {"hil.faults.base"},
        "hil.suites.campaign": {"hil.suites.cluster"},
        "hil.suites.cluster": {"hil.suites.campaign"},
    }
    assert upward(graph) == ["hil.faults.base imports hil.run.rig: run is not below faults"]
    assert sorted(circles(graph)) == [
        ["hil.faults.base", "hil.run.rig"],
        ["hil.suites.campaign", "hil.suites.cluster"],
    ]


DECLARED_ONCE = ("G0", "Positive", "NonNegative")
"""Names every package uses, declared in DECLARATIONS and nowhere else (issue 48: one name, declared once)."""


def top_level_assignments(source: str, names: tuple[str, ...]) -> list[tuple[int, str]]:
    """(line, name) of each module-level assignment to one of `names`."""
    found = []
    for node in ast.parse(source).body:
        targets = (
            node.targets
            if isinstance(node, ast.Assign)
            else [node.target]
            if isinstance(node, ast.AnnAssign)
            else []
        )
        found += [(node.lineno, t.id) for t in targets if isinstance(t, ast.Name) and t.id in names]
    return found


def test_shared_constants_and_bounds_are_declared_once():
    home = ROOT / (DECLARATIONS.replace(".", "/") + ".py")
    where = {
        f"{path.relative_to(ROOT)}:{line} {name}"
        for package in SOURCES
        for path in modules(package)
        for line, name in top_level_assignments(path.read_text(), DECLARED_ONCE)
    }
    assert {w.split(":")[0] for w in where} == {str(home.relative_to(ROOT))}, sorted(where)
    assert len(where) == len(DECLARED_ONCE), sorted(where)


def test_positive_control_a_second_declaration_is_seen():
    source = "G0 = 9.81\nPositive: object = float\ndef f():\n    G0 = 1\n"
    assert top_level_assignments(source, DECLARED_ONCE) == [(1, "G0"), (2, "Positive")]


ROTATIONS = (
    "quaternion_zyx",
    "euler_zyx",
    "matrix_zyx",
    "euler_rates",
    "rotate",
    "multiply",
    "heading_frame",
    "body_frame",
    "body_up",
    "chassis_axis",
    "tilt_quaternion",
    "tilt_rotation",
)
"""The rotations and Euler conventions, defined in drivers/rotations.py only (issue 48; the last two are
names they once had)."""


def top_level_functions(source: str, names: tuple[str, ...]) -> list[tuple[int, str]]:
    """(line, name) of each module-level function named one of `names`."""
    tree = ast.parse(source)
    return [(n.lineno, n.name) for n in tree.body if isinstance(n, ast.FunctionDef) and n.name in names]


def test_rotations_are_defined_once():
    where = sorted(
        f"{path.relative_to(ROOT)}:{line} {name}"
        for package in SOURCES
        for path in modules(package)
        for line, name in top_level_functions(path.read_text(), ROTATIONS)
    )
    assert {w.split(":")[0] for w in where} == {"drivers/rotations.py"}, where


def test_positive_control_a_second_rotation_is_seen():
    source = "def euler_rates(rate, roll, pitch):\n    pass\nclass A:\n    def rotate(self):\n        pass\n"
    assert top_level_functions(source, ROTATIONS) == [(1, "euler_rates")]


DRIVE_WRITES = ("set_command", "set_commands", "set_permission", "set_contactor")
"""What reaches the plant's drives (plant/drives.py): a command, the supervisor's permission, a contactor."""
DRIVE_WRITERS = {
    ("hil/run/drives_port.py", "DrivesPort.__init__"): {"set_permission", "set_contactor"},
    ("hil/run/drives_port.py", "DrivesPort._drive"): {"set_command"},
    ("hil/run/drives_port.py", "DrivesPort.apply_permission"): {"set_permission", "set_contactor"},
    ("hil/run/truth_balancer.py", "TruthBalancer.drive"): {"set_commands"},  # the plant-only demo: no wire
}
"""Every place in hil/ that writes the drives (docs/architecture.md "Two walks"): in a run only the drives'
port, a command only through `_drive` (the controller's and the recovery law's torques alike)."""


def drive_writes(source: str) -> list[tuple[int, str, str]]:
    """(line, enclosing Class.function, method) of each call of a DRIVE_WRITES method in `source`."""
    found: list[tuple[int, str, str]] = []

    def visit(node: ast.AST, where: tuple[str, ...]) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                visit(child, (*where, child.name))
                continue
            if (
                isinstance(child, ast.Call)
                and isinstance(child.func, ast.Attribute)
                and child.func.attr in DRIVE_WRITES
            ):
                found.append((child.lineno, ".".join(where), child.func.attr))
            visit(child, where)

    visit(ast.parse(source), ())
    return found


def test_only_the_drives_port_writes_the_drives_in_a_run():
    found: dict[tuple[str, str], set[str]] = {}
    for path in modules("hil"):
        for _, where, method in drive_writes(path.read_text()):
            found.setdefault((str(path.relative_to(ROOT)), where), set()).add(method)
    assert found == DRIVE_WRITERS


def test_positive_control_a_second_writer_of_a_drive_is_seen():
    source = (
        "class Rig:\n"
        "    def tick(self):\n"
        "        self.plant.drives.motors[0].set_command(1.0, True, 0.0)\n"
        "        if self.lost:\n"
        "            self.plant.drives.set_permission(False)\n"
    )
    assert drive_writes(source) == [(3, "Rig.tick", "set_command"), (5, "Rig.tick", "set_permission")]


MAX_LINES = 600
"""Issue 48, modules that each hold one thing: past this many lines a module of ours holds more than one
(hil/devices/cia402/, hil/suites/campaign_*.py and safety/'s drive_monitor.py and reactions.py were split
off at it)."""


def lines_over(paths: list[Path], limit: int = MAX_LINES) -> dict[str, int]:
    """The modules longer than `limit` lines (by path: relative to the repository, or as given): lengths."""
    found = {}
    for path in paths:
        n = len(path.read_text().splitlines())
        if n > limit:
            found[str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path)] = n
    return found


def test_no_module_is_over_600_lines():
    over = lines_over([path for package in sorted(OURS) for path in modules(package)])
    assert not over, f"over {MAX_LINES} lines (split each into modules that hold one thing): {over}"


def test_positive_control_a_module_over_600_lines_is_seen(tmp_path):
    at, over = tmp_path / "at.py", tmp_path / "over.py"
    at.write_text("x = 0\n" * MAX_LINES)
    over.write_text("x = 0\n" * (MAX_LINES + 1))
    assert lines_over([at, over]) == {str(over): MAX_LINES + 1}
