"""The clocks: real-time pacing and overrun counting (no timing assertions beyond what cannot flake)."""

import time

from hil.run.clock import LockstepClock, RealtimeClock


def test_realtime_clock_paces_and_measures_jitter():
    clock = RealtimeClock(0.004)
    clock.start()
    t0 = time.perf_counter()
    for _ in range(50):
        clock.wait_next()
    elapsed = time.perf_counter() - t0
    stats = clock.stats()
    assert elapsed >= 50 * 0.004 * 0.999  # never early
    assert stats.ticks == 50 and set(stats.jitter_us) == {"p50", "p99", "p99.9", "max"}
    assert stats.sim_time == 50 * 0.004


def test_realtime_clock_counts_overruns_and_skips_lost_ticks():
    clock = RealtimeClock(0.002)
    clock.start()
    clock.wait_next()
    time.sleep(0.011)  # a tick's work took more than five periods
    clock.wait_next()
    assert clock.overruns == 1
    # Back on the grid: the missed ticks are skipped, so the next deadline is ahead of now, not behind.
    assert clock._next > time.perf_counter() - 0.002


def test_lockstep_clock_never_waits(monkeypatch):
    slept = []
    monkeypatch.setattr(time, "sleep", slept.append)
    clock = LockstepClock(0.0025, command_guard=0.5)
    clock.start()
    for _ in range(1000):
        clock.wait_next()
    assert set(slept) <= {0}, "at most a yield of the GIL, never a wait"
    assert clock.stats().sim_time == 2.5
    assert clock.command_deadline() - time.monotonic() > 0.4


def test_jitter_percentiles_match_the_sorted_samples_within_a_bin():
    import numpy as np

    from hil.run.clock import JitterHistogram

    rng = np.random.default_rng(3)
    period = 0.0025
    devs_us = np.concatenate([rng.exponential(20.0, 5000), [850.0, 3200.0, 45000.0]])  # one beyond 20 ms
    hist, now = JitterHistogram(period), 0.0
    hist.wake(now)
    for d in devs_us:
        now += period + d * 1e-6
        hist.wake(now)
    got = hist.percentiles()
    ordered = np.sort(devs_us)
    for name, q in (("p50", 0.5), ("p99", 0.99), ("p99.9", 0.999)):
        exact = ordered[min(int(q * len(ordered)), len(ordered) - 1)]
        assert exact <= got[name] <= exact + 1.0 + 1e-6, name
    assert abs(got["max"] - 45000.0) < 1e-3  # the maximum is exact, even beyond the last bin
    assert len(hist.counts) == 20_000  # bounded, whatever the run's length


def _locked_kb() -> int:
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmLck:"))


def test_realtime_settings_hold_for_the_loop_and_end_with_it_or_say_they_were_refused():
    """SCHED_FIFO and mlockall for the loop, where the machine permits them; the policy line says which
    held, and stop() gives the thread back its normal scheduler and unlocks the memory (a service runs many
    runs in one process)."""
    import gc
    import os

    plain = RealtimeClock(0.004)
    plain.start()
    assert os.sched_getscheduler(0) == os.SCHED_OTHER and not gc.isenabled()  # control: nothing asked
    plain.stop()
    assert gc.isenabled()

    clock = RealtimeClock(0.004, priority=10, lock_memory=True)
    clock.start()
    try:
        during = os.sched_getscheduler(0), _locked_kb()
        clock.wait_next()
    finally:
        clock.stop()
    policy = clock.stats().realtime_policy
    if "SCHED_FIFO refused" in policy:
        assert during[0] == os.SCHED_OTHER
    else:
        assert policy.startswith("SCHED_FIFO 10") and during[0] == os.SCHED_FIFO
    if "mlockall refused" in policy:
        assert during[1] == 0
    else:
        assert "memory locked" in policy and during[1] > 0
    assert os.sched_getscheduler(0) == os.SCHED_OTHER and _locked_kb() == 0
