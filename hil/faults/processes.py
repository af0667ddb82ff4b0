"""Process and timing faults: the controller or the supervisor dies or hangs, the control loop runs late.

Kill and hang act on the in-process controller (the embedded reference, or any controller plugin whose
handle offers `pause()`/`resume()` for a hang) and the embedded supervisor; external processes are killed
from outside (tests/socketcan does it with SIGKILL). Loop delay and jitter are modelled as actuation
delay in simulated time: the commands of tick k reach the drives `delay` seconds later (whole ticks), so
they mean the same in lockstep and in real time.
"""

from __future__ import annotations

import math
from typing import Literal

from drivers.dut import PausableDut
from hil.faults.base import FaultSpec, FaultState, FaultTarget, Hold


class ProcessFault(FaultSpec, frozen=True, kw_only=True):
    def delay_ticks(self, rig: FaultTarget, state: FaultState) -> int:
        """How many ticks this tick's commands wait before the drives get them."""
        return 0


class Kill(ProcessFault, frozen=True, tag="process.kill"):
    """`target` stops dead, without a word (no further frames or puts)."""

    target: Literal["controller", "supervisor"] = "controller"

    def validate(self, rig: FaultTarget) -> None:
        if self.target == "controller" and rig.dut is None:
            raise ValueError("process.kill: the controller is external (kill it from outside)")
        if self.target == "supervisor" and rig.supervisor is None:
            raise ValueError("process.kill: the supervisor is external (kill it from outside)")

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        if self.target == "controller":
            assert rig.dut is not None  # validate() refused a rig without one
            rig.dut.stop()
        else:
            rig.supervisor = None


class Hang(ProcessFault, frozen=True, tag="process.hang"):
    """The controller stops answering for the fault's duration but stays alive; afterwards it works
    through what queued up meanwhile (its late commands are counted and never applied)."""

    target: Literal["controller"] = "controller"

    def validate(self, rig: FaultTarget) -> None:
        _pausable(rig)

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        _pausable(rig).pause()

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        _pausable(rig).resume()


def _pausable(rig: FaultTarget) -> PausableDut:
    if not isinstance(rig.dut, PausableDut):
        raise ValueError("process.hang: the controller's handle has no pause()/resume() (drivers/dut.py)")
    return rig.dut


class LoopDelay(ProcessFault, frozen=True, tag="process.loop_delay"):
    """The control loop runs `delay` seconds late: every command reaches the drives that much later."""

    delay: Hold

    def delay_ticks(self, rig: FaultTarget, state: FaultState) -> int:
        return math.ceil(self.delay / rig.plant.dt - 1e-9)


class Jitter(ProcessFault, frozen=True, tag="process.jitter"):
    """The control loop's latency varies uniformly in [0, `jitter`] seconds per tick (a command never
    overtakes an earlier one: the drives keep the newest that has arrived)."""

    jitter: Hold

    def delay_ticks(self, rig: FaultTarget, state: FaultState) -> int:
        return math.floor(state.rng.uniform(0.0, self.jitter) / rig.plant.dt + 0.5)


FAULTS: tuple[type[ProcessFault], ...] = (Kill, Hang, LoopDelay, Jitter)
