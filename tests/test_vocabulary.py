"""The wire's vocabulary is declared once (drivers/vocabulary.py, drivers/schemas.py): the supervisor's states
and causes are exactly the CAN database's value tables, and the SC request, its mode and the cap rule have no
second definition anywhere in the source tree."""

import ast
import typing
from pathlib import Path

import pytest

from drivers.can_codec import Catalog, MessageName
from drivers.schemas import ScCommand, ScMode, ScRequest
from drivers.vocabulary import Cause, ControllerState, OperatorCommand, ReactionStateName, State, StateName

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("hil", "plant", "drivers", "safety", "controller", "examples", "benchmarks")

MODES = set(typing.get_args(ScMode))
SC_FIELDS = ({"mode", "cap"}, {"mode", "speed_cap"})
"""A class that declares one of these pairs is an SC request record."""
HOME = "drivers/schemas.py"
"""Where the SC request (ScRequest, ScCommand its forwarded form), ScMode and the cap rule are declared."""
FILE_FORMATS = {
    "hil/run/scenario.py:ScEntry",
    "hil/faults/topics.py:ScFlood",
    "hil/faults/topics.py:ScConflict",
}
"""Records of files people write (a scenario's [[sc]], the SC faults' parameters) that spell a request as
`mode` and `cap`: they keep their file's spelling, take `mode` as ScMode, and become an ScRequest to be
sent."""


def _value_table(signal: str, message: str = MessageName.SUPERVISOR_ESTOP) -> dict[str, int]:
    choices = Catalog()[message].message.get_signal_by_name(signal).choices or {}
    return {str(name): int(value) for value, name in choices.items()}


@pytest.mark.parametrize(
    ("enum", "signal", "message"),
    [
        (State, "State", MessageName.SUPERVISOR_ESTOP),
        (Cause, "Reason", MessageName.SUPERVISOR_ESTOP),
        (ControllerState, "State", MessageName.CONTROLLER_HEARTBEAT),
    ],
)
def test_states_and_causes_are_exactly_the_dbcs_value_tables(enum, signal, message):
    assert {m.name: m.value for m in enum} == _value_table(signal, message)


def test_state_names_are_states():
    assert typing.get_args(StateName) == tuple(State.__members__)
    assert typing.get_args(ReactionStateName) == tuple(s.name for s in State if s is not State.NORMAL)


def test_the_cap_rule():
    def request(mode, cap=0.7):
        return ScRequest(seq=0, stamp=0.0, mode=mode, speed_cap=cap, source="agent")

    assert request("idle").speed_limit() == 0.0
    assert request("limit").speed_limit() == 0.7
    assert request("free").speed_limit() == float("inf")
    forwarded = ScCommand(seq=0, stamp=0.0, mode="limit", speed_cap=0.3, source="agent", reason="")
    assert forwarded.speed_limit() == 0.3


# ------------------------------------------------------------------------ one definition of each
def _literal_modes(node: ast.AST) -> set[str]:
    """The SC modes a `Literal[...]` spells (empty for any other node, and for a lone "free": a plant's
    fixture is free too)."""
    if not isinstance(node, ast.Subscript):
        return set()
    name = node.value.attr if isinstance(node.value, ast.Attribute) else getattr(node.value, "id", "")
    if name != "Literal":
        return set()
    modes = {n.value for n in ast.walk(node.slice) if isinstance(n, ast.Constant) and n.value in MODES}
    return modes if modes - {"free"} else set()


def _declared_fields(cls: ast.ClassDef) -> set[str]:
    """What a class declares: its annotated class-level names and its __init__'s parameters."""
    names = {s.target.id for s in cls.body if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)}
    for s in cls.body:
        if isinstance(s, ast.FunctionDef) and s.name == "__init__":
            names |= {a.arg for a in s.args.args + s.args.kwonlyargs}
    return names


def _mode_annotation(cls: ast.ClassDef) -> str:
    for s in cls.body:
        if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name) and s.target.id == "mode":
            return ast.unparse(s.annotation)
    return ""


def _compares_mode_with_idle(node: ast.AST) -> bool:
    """The cap rule's mark: a mode compared with "idle" (idle -> 0)."""
    if not isinstance(node, ast.Compare):
        return False
    sides = [node.left, *node.comparators]
    named_mode = any(
        (isinstance(s, ast.Attribute) and s.attr == "mode") or (isinstance(s, ast.Name) and s.id == "mode")
        for s in sides
    )
    return named_mode and any(isinstance(s, ast.Constant) and s.value == "idle" for s in sides)


def _writes_cap_rule(node: ast.AST) -> bool:
    return isinstance(node, ast.FunctionDef) and any(_compares_mode_with_idle(n) for n in ast.walk(node))


def second_definitions(path: str, source: str) -> list[str]:
    """Where `source` (the file at `path`) defines again what drivers/schemas.py defines once."""
    tree = ast.parse(source)
    found = []
    for node in ast.walk(tree):
        where = f"{path}:{getattr(node, 'lineno', 0)}"
        if _literal_modes(node):
            declaration = (
                isinstance(node, ast.Subscript) and path == HOME and node.lineno == _scmode_line(tree)
            )
            if not declaration:
                found.append(f"{where}: a second Literal of SC modes: use drivers.schemas.ScMode")
        if isinstance(node, ast.ClassDef) and any(pair <= _declared_fields(node) for pair in SC_FIELDS):
            if f"{path}:{node.name}" in FILE_FORMATS:
                if _mode_annotation(node) != "ScMode":
                    found.append(f"{where}: {node.name}.mode must be drivers.schemas.ScMode")
            elif not (path == HOME and node.name == "ScRequest"):
                found.append(
                    f"{where}: {node.name} is a second SC request record: use drivers.schemas.ScRequest"
                )
        if _writes_cap_rule(node) and not (path == HOME and getattr(node, "name", "") == "speed_limit"):
            found.append(
                f"{where}: {getattr(node, 'name', '')} writes the cap rule again: use ScRequest.speed_limit()"
            )
    return found


def _scmode_line(tree: ast.Module) -> int:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "ScMode" for t in node.targets):
            return node.value.lineno
    return -1


def search_sources(finder) -> list[str]:
    """`finder(path, source)`'s findings over every module of the source tree."""
    return [
        finding
        for package in SOURCES
        for path in sorted((ROOT / package).rglob("*.py"))
        for finding in finder(str(path.relative_to(ROOT)), path.read_text())
    ]


def test_the_sc_request_its_mode_and_the_cap_rule_are_defined_once():
    found = search_sources(second_definitions)
    assert not found, "\n".join(found)


def test_the_home_declares_each_once():
    # Test the test: the search above would pass on an empty tree; the one definitions are where it looks.
    source = (ROOT / HOME).read_text()
    tree = ast.parse(source)
    assert _scmode_line(tree) > 0
    assert sum(bool(_literal_modes(n)) for n in ast.walk(tree)) == 1
    rules = [n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and _writes_cap_rule(n)]
    assert rules == ["speed_limit"]
    assert not second_definitions(HOME, source)


def test_positive_control_the_search_finds_what_main_had_before():
    # The record types and cap rules as they were spelled before drivers/ held them (safety/machine.py,
    # safety/arbiter.py, controller/core.py, hil/faults/topics.py, hil/run/rig.py).
    before = """
@dataclass(frozen=True, slots=True)
class Request:
    mode: str
    cap: float
    source: str

class Forward:
    def __init__(self, mode: Literal["idle", "limit"], cap: float, source: str, reason: str):
        self.mode = mode

class ScInput:
    def __init__(self, mode: str, speed_cap: float, stamp: float):
        self.mode, self.speed_cap, self.stamp = mode, speed_cap, stamp

def cap_of(request: Request) -> float:
    if request.mode == "idle":
        return 0.0
    return request.cap if request.mode == "limit" else math.inf

class ScFlood(TopicFault, frozen=True, tag="zenoh.sc_flood"):
    mode: Literal["free", "idle", "limit"] = "free"
    cap: Cap = 0.0
"""
    found = second_definitions("hil/faults/topics.py", before)
    assert any("Request is a second SC request record" in f for f in found)
    assert any("Forward is a second SC request record" in f for f in found)
    assert any("ScInput is a second SC request record" in f for f in found)
    assert any("cap_of writes the cap rule again" in f for f in found)
    assert any("ScFlood.mode must be drivers.schemas.ScMode" in f for f in found)
    assert sum("a second Literal of SC modes" in f for f in found) == 2


def literals_of_operator_commands(path: str, source: str) -> list[str]:
    """Each `Literal[...]` in `source` that spells "cut_power": the operator's commands, whose one
    declaration is drivers.vocabulary.OperatorCommand."""
    found = []
    for node in ast.walk(ast.parse(source)):
        literal = isinstance(node, ast.Subscript) and ast.unparse(node.value).endswith("Literal")
        if literal and any(isinstance(n, ast.Constant) and n.value == "cut_power" for n in ast.walk(node)):
            found.append(f"{path}:{node.lineno}")
    return found


def test_the_operators_commands_are_spelled_once():
    found = search_sources(literals_of_operator_commands)
    assert len(found) == 1 and found[0].startswith("drivers/vocabulary.py:"), found
    assert typing.get_args(OperatorCommand) == ("estop", "cut_power", "reset")
    # Positive control: how hil/bench/operator.py and drivers/schemas.py spelled them before.
    before = 'Action = Literal["estop", "cut_power", "reset"]\nx: typing.Literal["reset", "cut_power"]\n'
    assert literals_of_operator_commands("hil/x.py", before) == ["hil/x.py:1", "hil/x.py:2"]
