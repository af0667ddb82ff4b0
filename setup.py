"""The optional compiled build (issue 29): pyproject.toml holds every piece of the package's metadata; this
file only adds, when asked, the hot modules compiled to C extensions by mypyc (docs/performance.md,
"Compiled build").

    PURE_HIL_MYPYC=1 pip install .            # or: PURE_HIL_MYPYC=1 pip wheel --no-deps -w dist .

Without PURE_HIL_MYPYC=1 (README's commands, the editable dev install) nothing is compiled and no
compiler or mypy is needed. With it, pip installs mypy and the run-time dependencies into the build's own
environment (mypyc type-checks the modules against numpy's, msgspec's, python-can's and cantools' types);
with --no-build-isolation they must be installed already.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

COMPILED = [
    # The frames: every CAN frame is encoded, sealed, checked and decoded through these, and sent and
    # received by a CanNode (drivers/can_bus.py; its BusConfig, a msgspec Struct, is drivers/bus_config.py).
    "drivers/can_codec.py",
    "drivers/e2e.py",
    "drivers/can_bus.py",
    # zenoh: every node's subscriptions, puts and the lockstep fence (the bench's ZenohAccess, a msgspec
    # Struct, is drivers/zenoh_access.py).
    "drivers/zenoh_link.py",
    # Rotations and Euler angles: the 3-D plant's and the supervisor's ticks call them (drivers/rotations.py).
    "drivers/rotations.py",
    # Not drivers/shared_bus.py: compiled, its SharedBus (a python-can BusABC) is not cleared from the weak
    # references its channel holds when it is collected, and the next look at them crashed the interpreter
    # (tests/test_shared_bus.py, a bus never shut down).
    # The supervisor: its state machine and what it observes, monitors (one per drive too), diagnostics,
    # recovery law, SC arbiter, node and E2E windows.
    "safety/machine.py",
    "safety/reactions.py",
    "safety/observation.py",
    "safety/monitors.py",
    "safety/drive_monitor.py",
    "safety/diagnostics.py",
    "safety/estimator.py",
    "safety/recovery.py",
    "safety/arbiter.py",
    "safety/node.py",
    "safety/e2e_window.py",
    # The reference controller: its estimator, balancer, commanded speed and yaw, step and node
    # (controller/embedded.py, its handle, stays Python: benchmarks/lockstep.py times its poll by wrapping
    # it).
    "controller/estimator.py",
    "controller/balance.py",
    "controller/command.py",
    "controller/core.py",
    "controller/node.py",
    # The rig's tick and its drives' port (Rig and DrivesPort allow Python subclasses, which tests and the
    # benchmarks use).
    "hil/run/rig.py",
    "hil/run/drives_port.py",
    "hil/run/agents.py",
    # The plant: every plant's base (PlantCore, plant/core.py), its tick and outputs, drives, rider's torso,
    # planar dynamics, sensors and wheel maps (PlantCore, Plant and MotorDrive allow Python subclasses, which
    # a lab's plant, benchmarks/lockstep.py and tests/test_failop.py use: @mypyc_attr). Not plant/rider.py:
    # msgspec does not see the class keywords (tag=..., frozen=True) of a Struct compiled by mypyc, and the
    # rider's segments are a tagged union (its per-tick maths is plant/torso.py). The 3-D plant's tick
    # (plant/ballbot3d.py) too: MuJoCo's step is C, the Python around it is most of the rest of its tick.
    "plant/core.py",
    "plant/ballbot.py",
    "plant/ballbot3d.py",
    "plant/drives.py",
    "plant/torso.py",
    "plant/plane.py",
    "plant/sensors.py",
    "plant/omniwheel.py",
]
"""The modules the compiled build compiles, declared once (tests/test_compiled.py reads this list)."""

ROOT = Path(__file__).resolve().parent
WANTED = os.environ.get("PURE_HIL_MYPYC", "") == "1"

try:
    from mypyc.build import mypycify
except ImportError:  # the pure build, or the first pass of an isolated build (which installs mypy)
    mypycify = None


class BuildPy(build_py):
    def run(self) -> None:
        if WANTED and mypycify is None:
            raise SystemExit(
                "PURE_HIL_MYPYC=1 needs mypy (mypyc) in the build environment: pip installs it there unless "
                "--no-build-isolation is given; then `pip install mypy` and the run-time dependencies first"
            )
        super().run()


def build_requires() -> list[str]:
    """mypy, and the run-time dependencies whose types mypyc compiles against (pyproject.toml's list)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    mypy = next(d for d in project["optional-dependencies"]["dev"] if d.startswith("mypy"))
    return [mypy, *project["dependencies"]]


compiled = WANTED and mypycify is not None
setup(
    # group_name: the modules' shared C library is pure_hil_native__mypyc.*.so in the wheel (not a hash);
    # target_dir: mypyc's generated C.
    ext_modules=(
        mypycify(COMPILED, opt_level="3", group_name="pure_hil_native", target_dir="build/mypyc")
        if compiled
        else []
    ),
    setup_requires=build_requires() if WANTED else [],
    cmdclass={"build_py": BuildPy},
    # The compiled build stages its files apart (build/mypyc/, not build/lib...): a pure build run later in
    # the same tree must not pick up the compiled build's .so files left there.
    options={"build": {"build_base": "build/mypyc"}} if WANTED else {},
)
