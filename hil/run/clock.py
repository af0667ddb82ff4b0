"""The two modes of time (docs/architecture.md): lockstep (simulated time, as fast as the loop goes)
and real time (wall-clock pacing: sleep, then spin the last stretch; overruns counted, period jitter
measured)."""

from __future__ import annotations

import contextlib
import ctypes
import gc
import math
import os
import threading
import time
from dataclasses import dataclass

JITTER_BINS = 20_000
"""Period jitter is counted in 1 us bins up to 20 ms (the last bin takes everything beyond; the maximum is
kept exactly): memory does not grow with a run's length."""

SPIN = 0.0002
"""Sleep until this long before the deadline, then busy-wait: removes timer slack and wake-up latency."""


@dataclass(frozen=True, slots=True)
class TimingStats:
    ticks: int
    wall_time: float
    sim_time: float
    overruns: int = 0
    jitter_us: dict[str, float] | None = None
    """Period jitter |period − nominal| percentiles (real time only)."""
    realtime_policy: str = ""
    started: float = 0.0
    """time.time() when the first tick started (a process's start-up ends there)."""

    @property
    def speed(self) -> float:
        """Simulated seconds per wall second."""
        return self.sim_time / self.wall_time if self.wall_time > 0 else 0.0


class LockstepClock:
    name = "lockstep"

    def __init__(self, period: float, command_guard: float = 1.0):
        self.period, self.command_guard = period, command_guard
        self.ticks = 0
        self.started = 0.0

    def start(self) -> None:
        self._t0, self.started = time.perf_counter(), time.time()

    def wait_next(self) -> None:
        self.ticks += 1
        # With a driven controller the loop never blocks: another Python thread of this process (a supervisor
        # beside the rig, the service's handlers) would wait for the interpreter's 5 ms switch interval, ticks
        # behind. Yield the GIL once a tick then (sleep(0) costs ~50 us of timer slack: only when needed).
        if threading.active_count() > 1:
            time.sleep(0)

    def stop(self) -> None:
        pass

    def command_deadline(self) -> float:
        """Wall-clock (monotonic) time until which the rig waits for this tick's commands."""
        return time.monotonic() + self.command_guard

    def sync_due(self) -> float:
        """Lockstep has no wall-clock due time: a SYNC is never late."""
        return math.inf

    def stats(self) -> TimingStats:
        return TimingStats(
            self.ticks, time.perf_counter() - self._t0, self.ticks * self.period, started=self.started
        )


class RealtimeClock:
    name = "realtime"

    def __init__(
        self,
        period: float,
        priority: int = 0,
        cpu: int | None = None,
        lock_memory: bool = False,
        sync_allowance: float = 0.001,
    ):
        """priority: SCHED_FIFO priority of the calling thread (0: the normal scheduler); cpu: pin it there;
        lock_memory: mlockall for the loop. Each falls back, and `policy` says so, where refused.
        sync_allowance: how long after a tick's scheduled start its SYNC may go out (hil/run/lateness.py)."""
        self.period, self.priority, self.cpu = period, priority, cpu
        self.sync_allowance = sync_allowance
        self.lock_memory = lock_memory
        self._locked = False
        self.ticks = 0
        self.started = 0.0
        self.overruns = 0
        self.jitter = JitterHistogram(period)
        self.policy = "SCHED_OTHER"

    def start(self) -> None:
        # Collect once, freeze what start-up allocated and stop collecting: a gen-2 collection in the loop
        # stalls ~100 ms. The tick builds no reference cycles (the soak's flat memory says so).
        gc.collect()
        gc.freeze()
        gc.disable()
        if self.cpu is not None:
            try:
                os.sched_setaffinity(0, {self.cpu})
            except OSError:
                self.policy += f" (affinity to cpu {self.cpu} refused)"
        if self.priority:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.priority))
                self.policy = self.policy.replace("SCHED_OTHER", f"SCHED_FIFO {self.priority}")
            except OSError as exc:
                self.policy += f" (SCHED_FIFO refused: {exc.strerror})"
        if self.lock_memory:
            self._locked = _mlockall()
            self.policy += " memory locked" if self._locked else " (mlockall refused)"
        self._t0, self.started = time.perf_counter(), time.time()
        self._next = self._t0

    def wait_next(self) -> None:
        """Sleep-then-spin until the next tick's start."""
        self._next += self.period
        now = time.perf_counter()
        if now > self._next:
            self.overruns += 1
            missed = int((now - self._next) / self.period)
            self._next += missed * self.period  # skip the ticks that can no longer be on time
        else:
            if self._next - now > SPIN:
                time.sleep(self._next - now - SPIN)
            while time.perf_counter() < self._next:
                pass
        self.jitter.wake(time.perf_counter())
        self.ticks += 1

    def stop(self) -> None:
        gc.enable()
        gc.unfreeze()  # a long-running service must not keep every run's start-up objects forever
        if self.priority:
            with contextlib.suppress(OSError):  # refused at start: it never left SCHED_OTHER
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        if self._locked:
            _LIBC.munlockall()
            self._locked = False

    def command_deadline(self) -> float:
        """Nothing is waited for: the next tick takes what the controller answered by its start."""
        return time.monotonic()

    def sync_due(self) -> float:
        """The monotonic time by which this tick's SYNC is due: its scheduled start plus the allowance."""
        return time.monotonic() + (self._next + self.sync_allowance - time.perf_counter())

    def stats(self) -> TimingStats:
        return TimingStats(
            self.ticks,
            time.perf_counter() - self._t0,
            self.ticks * self.period,
            self.overruns,
            self.jitter.percentiles(),
            self.policy,
            self.started,
        )


_LIBC = ctypes.CDLL(None, use_errno=True)
MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4
"""mlockall flags (<sys/mman.h>; MCL_ONFAULT since Linux 4.4)."""


Clock = LockstepClock | RealtimeClock
"""What the tick loop runs under: the scenario's (or the bench's) clock."""


def _mlockall() -> bool:
    """Keep every page the process touches in memory, now and later: no page of the loop is swapped out.
    ON_FAULT, because locking what is merely mapped faults it all in: 143 MB -> 1.6 GB resident for the
    rig's process (zenoh, rerun and numpy reserve far more than they use), never given back."""
    return _LIBC.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0


class JitterHistogram:
    """|period - nominal| of successive wake-ups, in 1 us bins (JITTER_BINS)."""

    def __init__(self, period: float):
        self.period = period
        self.counts = [0] * JITTER_BINS
        self.max_us = 0.0
        self._last: float | None = None

    def wake(self, now: float) -> None:
        if self._last is not None:
            dev_us = abs(now - self._last - self.period) * 1e6
            self.counts[min(int(dev_us), JITTER_BINS - 1)] += 1
            self.max_us = max(self.max_us, dev_us)
        self._last = now

    def percentiles(self) -> dict[str, float] | None:
        """p50, p99, p99.9 (the upper edge of their 1 us bin, never above the maximum) and the maximum."""
        total = sum(self.counts)
        if total < 2:
            return None
        out, seen, bins = {}, 0, iter(enumerate(self.counts))
        for name, q in (("p50", 0.5), ("p99", 0.99), ("p99.9", 0.999)):
            rank = min(int(q * total), total - 1)  # as the sorted-array pick it replaces
            while seen <= rank:
                edge, count = next(bins)
                seen += count
            out[name] = min(edge + 1.0, self.max_us)
        out["max"] = self.max_us
        return out
