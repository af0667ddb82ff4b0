"""The optional compiled build (setup.py, PURE_HIL_MYPYC=1; docs/performance.md "Compiled build").

.ci/run builds the compiled wheel, installs it into a fresh venv and runs COMPILED_SUITE below against it
from a copy of tests/ outside the source tree, with PURE_HIL_COMPILED=1: there every module of setup.py's
COMPILED must be a C extension, or the suite would test the pure code and pass for nothing. Elsewhere (the
README's commands, an editable install) none of them may be.
"""

from __future__ import annotations

import ast
import importlib
import os

import pytest

from tests.helpers import ROOT

COMPILED_SUITE = (
    # Every compiled module is exercised by at least one of these (test_every_compiled_module_is_covered).
    "tests/test_compiled.py",
    "tests/test_lock.py",  # the wheel's venv holds the locked set, and its metadata the lower bounds
    "tests/test_can.py",  # drivers/can_codec.py, drivers/e2e.py, drivers/can_bus.py
    "tests/test_can_decode_cache.py",  # the codecs shared by the nodes of one DBC, compiled
    "tests/test_run_logs.py",  # the logs' own process, which imports the compiled codec
    "tests/test_shared_bus.py",  # drivers/shared_bus.py (Python) under the compiled CanNode
    "tests/test_zenoh.py",  # drivers/zenoh_link.py
    "tests/test_rotations.py",  # drivers/rotations.py
    "tests/test_safety_machine.py",  # safety/machine.py, safety/reactions.py, safety/observation.py
    "tests/test_safety_monitors.py",  # safety/monitors.py, safety/drive_monitor.py
    "tests/test_e2e_window.py",  # safety/e2e_window.py
    "tests/test_safety_diagnostics.py",  # safety/diagnostics.py
    "tests/test_safety_arbiter.py",  # safety/arbiter.py
    "tests/test_failop.py",  # safety/estimator.py and recovery.py, and the Rig's takeover paths
    "tests/test_safety_node.py",  # safety/node.py standalone, on its own timer and on SYNC
    "tests/test_controller_units.py",  # controller/estimator.py, controller/balance.py, controller/core.py
    "tests/test_controller_closed_loop.py",
    "tests/test_plant_dynamics.py",  # plant/plane.py
    "tests/test_plant3d.py",  # plant/ballbot3d.py (Python) on the compiled PlantCore, drives, sensors
    "tests/test_sensors.py",  # plant/sensors.py
    "tests/test_omniwheel.py",  # plant/omniwheel.py
    "tests/test_rider.py",
    # End to end: every shipped scenario, determinism, replay, faults on the wire (hil/run/rig.py), the
    # supervisor's and the controller's nodes (safety/node.py, controller/node.py) on their paths.
    "tests/test_scenarios.py",
    "tests/test_agents.py",  # hil/run/agents.py
    "tests/test_faults_wire.py",
    "tests/test_safety_e2e.py",
)
"""What .ci/run runs against the compiled build (about a minute and a half of tests here)."""


def compiled_modules() -> list[str]:
    """setup.py's COMPILED, as module names (read from the file: setup.py is not importable)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "COMPILED" for t in node.targets):
            paths = ast.literal_eval(node.value)
            return [p.removesuffix(".py").replace("/", ".") for p in paths]
    raise AssertionError("setup.py declares no COMPILED list")


@pytest.mark.parametrize("name", compiled_modules())
def test_the_compiled_modules_are_what_this_build_says(name):
    module = importlib.import_module(name)
    path = module.__file__ or ""
    if os.environ.get("PURE_HIL_COMPILED") == "1":
        assert path.endswith(".so"), f"{name} imported from {path}, not the compiled build"
        assert not path.startswith(str(ROOT)), f"{name} imported from the source tree"
    else:
        assert path.endswith(".py"), f"{name} is compiled ({path}): the default build is pure Python"


def test_every_compiled_module_is_covered_by_the_compiled_suite():
    # Covered: a test file of the suite imports the module itself (the end-to-end files run them all too).
    imported = set()
    for test in COMPILED_SUITE:
        for node in ast.walk(ast.parse((ROOT / test).read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                imported.add(node.module)
            elif isinstance(node, ast.Import):
                imported.update(alias.name for alias in node.names)
    assert set(compiled_modules()) <= imported, set(compiled_modules()) - imported
    assert all((ROOT / test).is_file() for test in COMPILED_SUITE)
