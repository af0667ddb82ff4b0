"""The two modes of time (docs/architecture.md): lockstep (simulated time, as fast as the loop goes)
and real time (wall-clock pacing: sleep, then spin the last stretch; overruns counted, period jitter
measured)."""

from __future__ import annotations

import gc
import os
import time
from dataclasses import dataclass

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

    @property
    def speed(self) -> float:
        """Simulated seconds per wall second."""
        return self.sim_time / self.wall_time if self.wall_time > 0 else 0.0


class LockstepClock:
    name = "lockstep"

    def __init__(self, period: float, command_guard: float = 1.0):
        self.period, self.command_guard = period, command_guard
        self.ticks = 0

    def start(self) -> None:
        self._t0 = time.perf_counter()

    def wait_next(self) -> None:
        self.ticks += 1

    def stop(self) -> None:
        pass

    def command_deadline(self) -> float:
        """Wall-clock (monotonic) time until which the rig waits for this tick's commands."""
        return time.monotonic() + self.command_guard

    def stats(self) -> TimingStats:
        return TimingStats(self.ticks, time.perf_counter() - self._t0, self.ticks * self.period)


class RealtimeClock:
    name = "realtime"

    def __init__(self, period: float, fifo: bool = False, cpu: int | None = None, margin: float = 0.0003):
        self.period, self.fifo, self.cpu, self.margin = period, fifo, cpu, margin
        self.ticks = 0
        self.overruns = 0
        self._wakes: list[float] = []
        self.policy = "SCHED_OTHER"

    def start(self) -> None:
        # Collect once, then freeze what start-up allocated: a gen-2 collection in the loop stalls ~100 ms.
        gc.collect()
        gc.freeze()
        if self.cpu is not None:
            try:
                os.sched_setaffinity(0, {self.cpu})
            except OSError:
                self.policy += f" (affinity to cpu {self.cpu} refused)"
        if self.fifo:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
                self.policy = self.policy.replace("SCHED_OTHER", "SCHED_FIFO")
            except OSError:
                self.policy += " (SCHED_FIFO refused)"
        self._t0 = time.perf_counter()
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
        self._wakes.append(time.perf_counter())
        self.ticks += 1

    def stop(self) -> None:
        gc.unfreeze()  # a long-running service must not keep every run's start-up objects forever

    def command_deadline(self) -> float:
        """Commands must arrive before the next tick starts (less a margin for the rig's own work)."""
        return time.monotonic() + max(self._next + self.period - time.perf_counter() - self.margin, 0.0)

    def stats(self) -> TimingStats:
        import numpy as np

        jitter = None
        if len(self._wakes) > 2:
            periods = np.diff(np.asarray(self._wakes))
            dev = np.sort(np.abs(periods - self.period)) * 1e6
            pick = lambda q: float(dev[min(len(dev) - 1, int(q * len(dev)))])  # noqa: E731
            jitter = {"p50": pick(0.5), "p99": pick(0.99), "p99.9": pick(0.999), "max": float(dev[-1])}
        return TimingStats(
            self.ticks,
            time.perf_counter() - self._t0,
            self.ticks * self.period,
            self.overruns,
            jitter,
            self.policy,
        )
