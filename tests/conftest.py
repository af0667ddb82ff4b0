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
def shipped(tmp_path_factory, worker_id):
    """Every shipped scenario run once in lockstep (speed_limiting with its run folder): (results, folder).

    Once per session, not once per xdist worker: the workers share a folder (their base temp's parent) and
    split the runs, each taking a scenario no worker holds the lock of, then loading the others' (pickled)
    results once their locks are released."""
    import fcntl
    import pickle

    from drivers.config import load_toml
    from hil.pipeline import run
    from hil.run.scenario import Scenario
    from tests.helpers import ROOT
    from tests.zenoh_helpers import private_bench

    if worker_id == "master":  # not under xdist: nobody to share with
        out = tmp_path_factory.mktemp("runs")
    else:
        out = tmp_path_factory.getbasetemp().parent / "shipped"
        out.mkdir(exist_ok=True)
    runs, waiting = {}, []

    def take(path) -> None:
        """Under the scenario's lock: its result, run here unless another worker has saved it."""
        saved = out / f"{path.stem}.pickle"
        if saved.exists():
            runs[path] = pickle.loads(saved.read_bytes())
            return
        scenario = load_toml(path, Scenario)
        folder = out / scenario.name if scenario.name == "speed_limiting" else None
        runs[path] = run(scenario, private_bench(), out=folder)
        part = saved.with_suffix(".part")
        part.write_bytes(pickle.dumps(runs[path]))
        part.rename(saved)  # whole or absent to a reader

    for path in sorted((ROOT / "configs/scenarios").glob("*.toml")):
        lock = (out / f"{path.stem}.lock").open("w")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:  # another worker is running it: take it once that one is done
            waiting.append((path, lock))
            continue
        with lock:
            take(path)
    for path, lock in waiting:
        with lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            take(path)
    return {result.scenario.name: result for _, result in sorted(runs.items())}, out
