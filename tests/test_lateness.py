"""A run the rig itself made late is INCONCLUSIVE, never the controller's fault (issue 50; docs/rig.md "When
the rig is late"): the ledger that tells the rig's late ticks from the controller's (hil/run/lateness.py),
and the verdict it leads to, on synthetic traces (every branch, no timing)."""

from __future__ import annotations

from hil.run.drives_port import TickStats
from hil.run.judge import EXIT_CODES
from hil.run.lateness import TAIL_TICKS, WINDOWS_KEPT, Lateness
from hil.run.scenario import Criterion
from tests.test_verdicts import judged, stop, trace

DT = 0.0025


def late_at(*ticks: int, by: float = 0.001) -> Lateness:
    ledger = Lateness()
    for k in range(1, max(ticks) + 10):
        ledger.sync(k, k * DT, DT, by if k in ticks else -0.0005)
    return ledger


def test_a_late_sync_and_its_tail_are_the_rigs_and_the_ticks_around_them_are_not():
    ledger = late_at(100)
    assert ledger.ticks == 1 and ledger.worst == 0.001
    assert [ledger.owns(k) for k in (99, 100, 100 + TAIL_TICKS, 101 + TAIL_TICKS)] == [
        False,
        True,
        True,
        False,
    ]
    assert ledger.windows == [[100 * DT, (100 + TAIL_TICKS) * DT]]


def test_a_late_command_is_the_rigs_when_its_tag_is_a_late_tick_also_after_the_tick_counter_wraps():
    ledger = late_at(65535)
    assert ledger.owns_tag(65537, 65535)  # the tick after: 65537 mod 65536 = 1, its tag 65535
    assert not ledger.owns_tag(65537, 65530)


def test_late_ticks_close_together_make_one_window_and_far_apart_two():
    assert len(late_at(100, 100 + TAIL_TICKS + 1).windows) == 1
    assert len(late_at(100, 100 + TAIL_TICKS + 2).windows) == 2


def test_a_long_run_keeps_at_most_its_windows_and_counts_the_rest():
    ledger = Lateness()
    for n in range(WINDOWS_KEPT + 5):
        k = 10 * n
        ledger.sync(k, k * DT, DT, 0.001)
        ledger.sync(k + 1, (k + 1) * DT, DT, 0.001)  # extends the window it opened, kept or not
    assert len(ledger.windows) == WINDOWS_KEPT and ledger.windows_dropped == 5
    assert ledger.windows[-1][1] == ((10 * (WINDOWS_KEPT - 1) + 1) * DT + TAIL_TICKS * DT)


def realtime(lateness: Lateness, missing: int = 0, late: int = 0, **changes):
    stats = TickStats(ticks=800, missing_commands=missing, late_commands=late)
    return trace(stats=stats, lateness=lateness, **changes)


def test_commands_the_rig_cost_make_the_run_inconclusive_and_the_controllers_own_fail_it():
    bounded = {"criteria": [Criterion(metric="missing_commands", equals=0)]}
    on_time = judged(realtime(Lateness()), **bounded)
    assert on_time.verdict == "PASSED"  # the positive control
    ledger = late_at(100)
    ledger.missing = 3
    rigs = judged(realtime(ledger, missing=3), **bounded)
    assert rigs.verdict == "INCONCLUSIVE" and EXIT_CODES[rigs.verdict] == 4
    assert "cost the controller 3 missing and 0 late commands" in rigs.rig_was_late()[0]
    assert (rigs.verdicts[0].value, rigs.verdicts[0].passed) == (0.0, True)  # nothing missed of its own
    own = judged(realtime(Lateness(), missing=3), **bounded)
    assert own.verdict == "FAILED"
    # Late but costless: nothing to hold against either side.
    assert judged(realtime(late_at(100)), **bounded).verdict == "PASSED"


def test_a_supervisor_stop_in_or_just_after_a_late_window_is_the_rigs_and_one_long_after_is_not():
    ledger = late_at(400)  # 1.0 s
    near = judged(realtime(ledger, safety_events=[stop(1.05, "IMU_SILENT")]))
    assert near.verdict == "INCONCLUSIVE"
    assert "IMU_SILENT at 1.050 s" in near.rig_was_late()[0]
    far = judged(realtime(ledger, safety_events=[stop(1.5, "IMU_SILENT")]))
    assert far.verdict == "FAILED"  # an unplanned stop nothing of the rig explains


def test_a_run_stopped_early_stays_stopped_whatever_the_rig_cost():
    ledger = late_at(100)
    ledger.missing = 1
    assert judged(realtime(ledger, missing=1, stopped_early=True)).verdict == "STOPPED"
    assert judged(realtime(ledger, missing=1)).verdict == "INCONCLUSIVE"


# ------------------------------------------------------------------------------- a real run, held back
TICK_HZ = 100.0
"""The held runs tick at 100 Hz (the slowest the drives' 20 ms command watchdog allows), their SYNC due 0.9
of a period after each tick's start: a loaded test machine then rarely delays a SYNC past it, and the runs'
verdicts do not hang on it (see held_run)."""
HELD = range(50, 52)
"""Ticks (at 0.5 s) in which the controller does not answer: the rig holds their SYNC back HOLD first, or
not (the controller's own lateness)."""
HOLD = 0.012
"""s: longer than a tick."""


def held_run(monkeypatch, *, hold: bool, silent: range = HELD):
    """bench_smoke for 1 s in real time on the embedded bench, its criteria the controller's own commands,
    the controller on a thread of its own (its own clock, as a lab's in-process plug without `poll`).

    The test keeps the run's timing out of its verdict: after each tick the loop waits until the controller
    has answered that tick's SYNC, so no command is missing by chance. In HELD's ticks the controller is
    paused until the next tick starts, so their commands go missing by construction; with `hold`, the rig
    also sleeps HOLD before those ticks' SYNC (its own lateness, the controller's budget gone). `silent`:
    those ticks (HELD; none for the twin)."""
    import dataclasses
    import threading
    import time

    import msgspec

    import hil.run.build as build_module
    from hil.pipeline import load_scenario, run
    from hil.run.build import RunOptions
    from hil.run.drives_port import DrivesPort
    from hil.run.rig import Rig
    from tests.zenoh_helpers import private_bench

    class HeldRig(Rig):
        def __init__(self, parts):
            super().__init__(parts)
            self.poll_dut = None  # the controller answers from its own thread

        def _send_sensors(self, k, *args):
            if k in silent:
                duts[0].pause()  # it will not answer this tick's SYNC
                if hold:
                    time.sleep(HOLD)  # the rig's own work made long: its SYNC goes out late
            super()._send_sensors(k, *args)

    class HeldPort(DrivesPort):
        def close_tick(self, take_queued=True):
            super().close_tick(take_queued)
            duts[0].resume()

    monkeypatch.setattr(build_module, "Rig", HeldRig)
    monkeypatch.setattr(build_module, "DrivesPort", HeldPort)
    spec_of = build_module.controller_spec
    monkeypatch.setattr(
        build_module, "controller_spec", lambda b, s, at: spec_of(b, s, dataclasses.replace(at, driven=False))
    )
    duts = []
    answered = threading.Condition()
    last = [-1]
    """The last SYNC's tick the controller answered."""
    start_dut = build_module.start_dut

    def keep(name, spec):
        duts.append(dut := start_dut(name, spec))
        on_sync = dut.node.on_sync

        def told(raw_tick):
            out = on_sync(raw_tick)
            with answered:
                last[0] = raw_tick
                answered.notify_all()
            return out

        dut.node.on_sync = told
        return dut

    monkeypatch.setattr(build_module, "start_dut", keep)

    def on_tick(plant):
        if plant.tick not in silent:
            with answered:
                done = answered.wait_for(lambda: last[0] == plant.tick % 65536, timeout=10.0)
            assert done, f"the controller never answered tick {plant.tick}"

    scenario = msgspec.structs.replace(
        load_scenario("bench_smoke"),
        duration=1.0,
        tick_hz=TICK_HZ,
        criteria=[Criterion(metric=m, equals=0) for m in ("missing_commands", "late_commands")],
    )
    bench = private_bench(clock="realtime")
    bench = msgspec.structs.replace(
        bench, realtime=msgspec.structs.replace(bench.realtime, sync_allowance=0.9)
    )
    return run(scenario, bench, options=RunOptions(on_tick=on_tick))


def test_a_run_whose_rig_is_held_back_is_inconclusive_and_the_same_silence_on_time_is_the_controllers(
    monkeypatch,
):
    """The same silence of the controller (HELD's ticks unanswered) is the rig's when the rig held their SYNC
    back (INCONCLUSIVE) and the controller's when it did not (FAILED on its own commands)."""
    held = held_run(monkeypatch, hold=True)
    late = held.trace.lateness
    assert held.verdict == "INCONCLUSIVE", [v for v in held.verdicts if not v.passed]
    assert late.ticks >= len(HELD) and late.missing == 3 * len(HELD), late.as_dict()
    assert any(a <= HELD[0] / TICK_HZ <= b for a, b in late.windows), late.windows
    own = {v.criterion: v for v in held.verdicts}
    assert own["missing_commands"].passed, "the controller lost nothing of its own"
    on_time = held_run(monkeypatch, hold=False)
    assert on_time.verdict == "FAILED", on_time.rig_was_late()
    missing = next(v for v in on_time.verdicts if v.criterion == "missing_commands")
    assert (missing.value, missing.passed) == (3 * len(HELD), False)


def test_the_same_run_without_the_silence_passes(monkeypatch):
    twin = held_run(monkeypatch, hold=False, silent=range(0))
    assert twin.verdict == "PASSED", twin.rig_was_late() or [v for v in twin.verdicts if not v.passed]
