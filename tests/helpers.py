"""Builders shared by the tests."""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

import msgspec

from plant.params import Friction, RiderParams, RobotParams, SimParams

NO_FRICTION = Friction(
    rolling_viscous=0.0,
    drivetrain_viscous=0.0,
    drivetrain_coulomb=0.0,
    drivetrain_stiction=0.0,
    yaw_viscous=0.0,
    yaw_coulomb=0.0,
    yaw_stiction=0.0,
)
ROOT = Path(__file__).resolve().parents[1]
RIDER_75 = RiderParams(name="winter_75kg_175", mass=75.0, height=1.75)
"""The worked example of docs/physics.md §5.2 / §6.1."""


def robot(**sections) -> RobotParams:
    return msgspec.structs.replace(RobotParams(), **sections)


def sim(**fields) -> SimParams:
    return msgspec.structs.replace(SimParams(), **fields)


def deg(x: float) -> float:
    return math.radians(x)


def wait_for(predicate, timeout: float = 5.0, step: float = 0.01):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    return predicate()


@contextmanager
def serving(tmp_path: Path, endpoint: str, env: dict[str, str] | None = None) -> Iterator[subprocess.Popen]:
    """`pure-hil serve` on the hub `endpoint`, its rig card in tmp_path/"rigs", its runs in tmp_path/"runs",
    up (it said its hub); killed on the way out unless the test ended it. `env`: the process's own."""
    pure_hil = str(Path(sys.executable).with_name("pure-hil"))
    env = env or {**os.environ, "PURE_HIL_RIGS": str(tmp_path / "rigs"), "PURE_HIL_HUB": endpoint}
    serve = subprocess.Popen(
        [pure_hil, "serve", "--hub", endpoint, "--out", str(tmp_path / "runs")],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        first = serve.stdout.readline() if serve.stdout else ""
        assert f"hub {endpoint}" in first, first
        yield serve
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.communicate()


TWO_CASES = f"""
name = "two_cases"
scenarios = ["{ROOT / "configs/scenarios/bench_smoke.toml"}"]
[[fault]]
name = "seat_silent"
[[fault.inject]]
kind = "zenoh.wrench_dropout"
at = 1.0
expect = {{ state = "STOPPING", cause = "WRENCH_SILENT", within = 0.15, fall = false }}
"""
"""A campaign of two passing cases of bench_smoke, fault-free and with a reaction to expect: what a case
carries to a worker and back, and enough for a progress bar to count, at a third of the smoke campaign's
cost."""


def load_example(name: str) -> ModuleType:
    """examples/NAME.py as a fresh module (the examples are scripts, not a package: a test may change a
    module's constants without reaching another test's)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
