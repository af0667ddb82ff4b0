"""Type checking (issue 29): mypy, with the project's own configuration ([tool.mypy] in pyproject.toml),
finds no error in the packages it checks; and the few facts its casts take on trust hold at run time.

mypy runs here rather than as a step of its own in .ci/run, with the project's cache (.mypy_cache in the
checkout, which .gitignore keeps out of git): 31 s from a cold cache, as on a fresh clone, and 0.9 s with
it, back to back at load ~3 (2026-11-29; about 10 s cold on a quiet machine).
"""

import typing
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


NUMPY_TYPED = (2, 3)
"""numpy before 2.3 declares ndarray without defaults for its type parameters, so every bare `np.ndarray`
is an error under disallow_any_generics: the code is typed against 2.3 and newer (numpy's run-time lower
bound stays older; `python3 tools/deps.py oldest` runs the rest of the suite there)."""


def test_mypy_finds_no_error(monkeypatch):
    import numpy as np

    api = pytest.importorskip("mypy.api", reason="mypy is not installed (it is in the dev extra: .[dev])")
    if tuple(int(x) for x in np.__version__.split(".")[:2]) < NUMPY_TYPED:
        pytest.skip(f"numpy {np.__version__}: its ndarray has no type defaults (NUMPY_TYPED)")
    monkeypatch.chdir(ROOT)  # [tool.mypy]'s files and cache are the project's
    stdout, stderr, status = api.run(["--config-file", str(ROOT / "pyproject.toml")])
    assert status == 0, stdout + stderr


# ------------------------------------------------------------------------- what the casts rely on
def test_the_supervisor_states_are_the_wire_names():
    # safety/node.py publishes State's name as SafetyState.state (a StateName).
    from drivers.vocabulary import State, StateName

    assert {s.name for s in State} == set(typing.get_args(StateName))


def test_every_fault_kind_is_a_str_tag():
    # hil/faults/base.py kind_of() reads a fault class's msgspec tag as a str.
    from hil.faults import CATALOG
    from hil.faults.base import kind_of

    for kind, cls in CATALOG.items():
        assert isinstance(cls.__struct_config__.tag, str)
        assert kind_of(cls) == kind


def test_the_types_built_at_run_time_are_what_the_checker_is_told():
    # The checker sees str for a sensor Channel and FaultSpec for a Fault; msgspec validates against these.
    from hil.faults import CATALOG, Fault, FaultSpec
    from hil.faults.sensors import CHANNELS, Channel

    assert set(typing.get_args(Channel)) == set(CHANNELS)
    assert set(typing.get_args(Fault)) == set(CATALOG.values())
    assert all(issubclass(cls, FaultSpec) for cls in CATALOG.values())
