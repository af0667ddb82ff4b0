import os
import tempfile

# Tiny LAPACK calls (LQR) are 10-20x slower with OpenBLAS's thread pool: keep tests on one thread.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# The rigs a test starts announce themselves in a folder of this test process's own (hil/bench/rigs.py):
# an operator's client in a test never finds a rig of the machine's or of another test worker.
os.environ["PURE_HIL_RIGS"] = tempfile.mkdtemp(prefix="pure-hil-test-rigs-")


import pytest

pytest_plugins = ["pytester"]  # tests of the HIL pytest plugin run pytest inside pytest


@pytest.fixture(scope="session")
def shipped(tmp_path_factory):
    """Every shipped scenario run once in lockstep (speed_limiting with its run folder): (results, folder)."""
    from drivers.config import load_toml
    from hil.pipeline import run
    from hil.run.scenario import Scenario
    from tests.helpers import ROOT
    from tests.zenoh_helpers import private_bench

    out = tmp_path_factory.mktemp("runs")
    results = {}
    for path in sorted((ROOT / "configs/scenarios").glob("*.toml")):
        scenario = load_toml(path, Scenario)
        folder = out / scenario.name if scenario.name == "speed_limiting" else None
        results[scenario.name] = run(scenario, private_bench(), out=folder)
    return results, out
