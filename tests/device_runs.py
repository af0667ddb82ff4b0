"""The whole rig on a device profile's bench: `speed_limiting` passes, runs deterministically and replays byte
for byte; `balance` with a lab's example controller. Shared by the profiles' tests (tests/test_devices_*.py,
tests/test_xsens_client.py)."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from pathlib import Path

import msgspec

from hil.bench.bench import Bench
from hil.pipeline import load_scenario, run
from hil.run.judge import RunResult
from hil.suites.replay import ReplayResult, replay
from tests.zenoh_helpers import private_bench

AGAIN = 3.0
"""s of speed_limiting run a second time and replayed: its hold and most of the lean to speed, 1200 ticks of
every frame the profile speaks. A lockstep run does not know its duration until it ends, so the shorter run's
frames are the whole run's first ones; determinism and replay are mechanisms, checked on these."""


def frames(folder: Path) -> list[str]:
    """A run folder's CAN frames as `id#data`, in order, without their wall-clock stamps."""
    return [line.split()[2] for line in (folder / "can.log").read_text().splitlines()]


def speed_limiting_on(
    bench: str, out: Path, devices: dict[str, str], contract: dict[str, str]
) -> ReplayResult:
    """speed_limiting on `bench` passes; run again for its first AGAIN s it sends the whole run's first
    frames; that run replays byte for byte on the bench's `devices`, and not read as the `contract`'s own
    (the test of the test). The whole run's folder is out/"whole"; the replay's result is returned."""
    scenario = load_scenario("speed_limiting")
    whole, again = out / "whole", out / "again"
    result = run(scenario, private_bench(bench), out=whole)
    assert result.passed, [v for v in result.verdicts if not v.passed]
    run(msgspec.structs.replace(scenario, duration=AGAIN), private_bench(bench), out=again)
    repeated = frames(again)
    assert len(repeated) < len(frames(whole)) and frames(whole)[: len(repeated)] == repeated
    summary = json.loads((whole / "summary.json").read_text())
    assert devices.items() <= summary["bench"]["devices"].items()
    assert summary["bus"]["malformed"] == {}
    replayed = replay(again, private_bench())
    assert replayed.identical, replayed.mismatches[:3]
    summary = json.loads((again / "summary.json").read_text())
    summary["bench"]["devices"] = contract
    (again / "summary.json").write_text(json.dumps(summary))
    assert not replay(again, private_bench(), limit=50).identical
    return replayed


def balance_with_example(bench: Bench, out: Path, example: Callable[[threading.Event], object]) -> RunResult:
    """`balance` on `bench`, its controller external: an example of examples/, `example(stop)`, on a thread of
    this process on the in-process bus. The example must end once told to after the run."""
    stop = threading.Event()
    thread = threading.Thread(target=example, args=(stop,), daemon=True)
    thread.start()
    try:
        result = run(load_scenario("balance"), bench, out=out)
    finally:
        stop.set()
        thread.join(timeout=10)
    assert not thread.is_alive(), "the example did not end when told to"
    return result
