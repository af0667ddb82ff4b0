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


def test_lockstep_clock_never_waits():
    clock = LockstepClock(0.0025, command_guard=0.5)
    clock.start()
    t0 = time.perf_counter()
    for _ in range(1000):
        clock.wait_next()
    assert time.perf_counter() - t0 < 0.5
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
