"""The faults of one run: when each starts and ends, what it is told, and the fault log.

The rig calls `update(t)` once per tick, right after the plant's step (docs/rig.md, One tick): faults whose
window opens start (plant and process faults act from here), those whose window closed or that were
cleared end, live requests queued by other threads are taken in. In between, the rig hands its samples,
frames and puts to the hooks of the faults active now. Random streams are per fault and seeded from the
run's seed, so a faulty lockstep run is as reproducible as a healthy one.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import TYPE_CHECKING, NamedTuple, cast

import can
import msgspec
import numpy as np

from drivers.schemas import TesWrench
from hil.faults.base import FaultAction, FaultError, FaultEvent, FaultSpec, FaultState, FaultTarget
from hil.faults.frames import RX_MESSAGES, Babble, BusOff, CanFault
from hil.faults.processes import ProcessFault
from hil.faults.sensors import Readings, SensorFault
from hil.faults.topics import TopicFault
from plant.sensors import DriveFeedback, ImuSample, TesSample

if TYPE_CHECKING:
    from plant.core import PlantCore

log = logging.getLogger(__name__)

MAX_FAULTS = 256
"""Faults one run holds, its scenario's and live ones: each keeps a random stream and its log lines, so a
session injecting without end must not grow a run's memory without end."""


class _Clear(NamedTuple):
    """A live request to end fault number `fault` (None: all of them)."""

    fault: int | None


class FaultSet:
    def __init__(self, faults: Iterable[FaultSpec] = (), seed: int = 0):
        self.seed = seed
        self.tick_hz = 400.0
        """Set by attach() from the rig's plant: the rate scheduled times become ticks at."""
        self.specs: list[FaultSpec] = []
        self.states: list[FaultState] = []
        self.events: list[FaultEvent] = []
        self._cleared: set[int] = set()
        self._requests: list[FaultSpec | _Clear] = []
        """Live requests (a fault to inject, or one to clear), queued by other threads until the next tick."""
        self._lock = threading.Lock()
        self.rig: FaultTarget | None = None
        """The rig the faults act on, from attach(). Before it the hooks are handed None for the rig: only
        faults that touch no rig can run so (unit tests of the timing do)."""
        self.on_event: Callable[[FaultEvent], None] | None = None
        """Called with every FaultEvent as it happens (the service marks the live view)."""
        self._active: list[int] = []
        # The active faults by family, with their states (_index): what the rig's hooks run each tick.
        self._sensors: list[tuple[SensorFault, FaultState]] = []
        self._topics: list[tuple[TopicFault, FaultState]] = []
        self._processes: list[tuple[ProcessFault, FaultState]] = []
        self._frames: list[tuple[CanFault, FaultState]] = []
        self._babblers: list[Babble] = []
        self._bus_off = False
        self._starve_above: int | None = None
        """Frames with a higher id lose every arbitration to a babbler that fills the bus."""
        for spec in faults:
            self._add(spec)
        self._index()

    def __bool__(self) -> bool:
        return bool(self.specs) or bool(self._requests)

    # ------------------------------------------------------------------------------------ set-up
    def attach(self, rig: FaultTarget) -> None:
        """Check every fault against the rig it will act on (unknown messages, missing processes)."""
        self.rig = rig
        self.tick_hz = rig.plant.sim.tick_hz
        for n, spec in enumerate(self.specs):
            try:
                spec.check(rig)
            except ValueError as exc:
                said = str(exc).removeprefix(f"{spec.kind}: ")  # describe() names the kind
                raise FaultError(f"fault {n} ({spec.describe()}): {said}") from None
            self._schedule(n)

    def _add(self, spec: FaultSpec) -> int:
        n = len(self.specs)
        self.specs.append(spec)
        self.states.append(FaultState(np.random.default_rng([self.seed, n])))
        self._schedule(n)
        return n

    def _schedule(self, n: int, now: int = 0) -> None:
        state = self.states[n]
        state.first_tick, state.end_tick = self.specs[n].ticks(self.tick_hz, now)

    # ----------------------------------------------------------------------------------- live use
    def inject(self, spec: FaultSpec) -> int:
        """From any thread: add `spec`, its `at` counted from the tick that takes it in; its number in the
        run. Raises ValueError if it cannot act on this rig (a bound of the rig's, an unknown message) or
        the run holds MAX_FAULTS already."""
        if self.rig is not None:
            spec.check(self.rig)
        with self._lock:
            number = self._numbered()
            if number >= MAX_FAULTS:
                raise ValueError(f"this run holds {MAX_FAULTS} faults already, the most one run may hold")
            self._requests.append(spec)
        return number

    def clear(self, fault: int | None = None) -> None:
        """From any thread: end fault number `fault` (None: every fault active or still to come). Raises
        ValueError for a number the run has not given."""
        with self._lock:
            known = self._numbered()
            if fault is not None and not 0 <= fault < known:
                faults = "none" if not known else f"0..{known - 1}"
                raise ValueError(f"no fault {fault} in this run (its faults: {faults}; pure-hil rig status)")
            self._requests.append(_Clear(fault))

    def _numbered(self) -> int:
        """Numbers given so far: the run's faults and the injections queued for the next tick (they are
        numbered in the order they came). Called under the lock."""
        return len(self.specs) + sum(isinstance(r, FaultSpec) for r in self._requests)

    def _take_requests(self, k: int, t: float) -> None:
        with self._lock:
            requests, self._requests = self._requests, []
        rig = cast(FaultTarget, self.rig)  # None before attach(): see `rig`
        for request in requests:
            if isinstance(request, FaultSpec):
                # Recorded with its absolute start; scheduled from tick 0, so `at` counts once from this tick.
                try:
                    spec = msgspec.structs.replace(request, at=t + request.at)
                    spec.check(rig)
                except ValueError as exc:  # queued before the rig was there to check it, or past a day
                    log.error("live fault %s refused: %s", request.describe(), exc)
                    continue
                n = self._add(spec)
                self._schedule(n)
                self._log(t, n, "inject", spec.describe())
            else:
                targets = range(len(self.specs)) if request.fault is None else [request.fault]
                for n in targets:
                    if 0 <= n < len(self.specs) and n not in self._cleared:
                        self._cleared.add(n)
                        self._log(t, n, "clear", "")

    # -------------------------------------------------------------------------------------- ticks
    def update(self, k: int, t: float) -> None:
        """Start and end faults for tick k (at time t)."""
        if self._requests:
            self._take_requests(k, t)
        rig = cast(FaultTarget, self.rig)  # None before attach(): see `rig`
        active = []
        changed = False
        for n, (spec, state) in enumerate(zip(self.specs, self.states, strict=True)):
            within = state.first_tick <= k and (state.end_tick is None or k < state.end_tick)
            on = within and n not in self._cleared and state.remaining != 0
            if on and not state.active:
                state.active, state.started = True, t
                if isinstance(spec, CanFault):
                    state.remaining = spec.count
                spec.start(rig, state)
                self._log(t, n, "start", spec.describe())
                changed = True
            elif not on and state.active:
                state.active, state.ended = False, t
                spec.stop(rig, state)
                self._log(t, n, "end", "")
                changed = True
            if state.active:
                active.append(n)
        if changed:
            self._active = active
            self._index()
        for babbler in self._babblers:
            babbler.babble(rig)

    def _index(self) -> None:
        active = [(self.specs[n], self.states[n]) for n in self._active]
        self._sensors = [(spec, state) for spec, state in active if isinstance(spec, SensorFault)]
        self._topics = [(spec, state) for spec, state in active if isinstance(spec, TopicFault)]
        self._processes = [(spec, state) for spec, state in active if isinstance(spec, ProcessFault)]
        self._frames = [(spec, state) for spec, state in active if isinstance(spec, CanFault)]
        self._babblers = [spec for spec, _ in active if isinstance(spec, Babble)]
        self._bus_off = any(isinstance(spec, BusOff) for spec, _ in active)
        rig = self.rig
        saturating = [b.can_id for b in self._babblers if b.saturates(cast(FaultTarget, rig))]
        self._starve_above = min(saturating) if saturating else None
        if rig is not None:
            hooked = bool(self._frames or self._babblers or self._bus_off)
            rig.can.tx_hook = self.tx if hooked else None
            rig.can.rx_hook = self.rx if hooked else None

    def _log(self, t: float, n: int, action: FaultAction, detail: str) -> None:
        spec = self.specs[n]
        self.events.append(FaultEvent(round(t, 9), n, spec.kind, action, detail))
        if self.on_event is not None:
            self.on_event(self.events[-1])
        log.warning("fault %d %s at t=%.3f: %s", n, action, t, detail or spec.kind)

    def finish(self, k: int, t: float) -> None:
        """End of the run (tick k, time t): requests already acknowledged are logged, every fault still
        active ends (held frames are sent, processes resume)."""
        if self._requests:
            self._take_requests(k, t)
        rig = cast(FaultTarget, self.rig)  # None before attach(): see `rig`
        for n in self._active:
            state = self.states[n]
            state.active, state.ended = False, t
            self.specs[n].stop(rig, state)
            self._log(t, n, "end", "run over")
        self._active = []
        self._index()

    # ------------------------------------------------------------------------------------ sensors
    def sensors(
        self, plant: PlantCore, feedback: Sequence[DriveFeedback], imu: ImuSample, tes: TesSample
    ) -> tuple[tuple[DriveFeedback, ...], ImuSample, TesSample, set[str]]:
        """The tick's samples as the faulty sensors report them, and the frames that stay silent."""
        readings = Readings.of(plant, feedback, imu, tes)
        for spec, state in self._sensors:
            spec.apply(readings, plant.t, state)
        return (
            readings.feedback(plant.robot.encoder),
            readings.imu(),
            readings.tes(plant, tes),
            readings.silent,
        )

    @property
    def sensing(self) -> bool:
        return bool(self._sensors)

    @property
    def topical(self) -> bool:
        return bool(self._topics)

    # ------------------------------------------------------------------------------------- frames
    def _frame_faults(self, name: str) -> Iterator[tuple[CanFault, FaultState]]:
        for spec, state in self._frames:
            if spec.message == name and state.remaining != 0:
                if state.remaining is not None:
                    state.remaining -= 1
                yield spec, state

    def _starved(self, msg: can.Message) -> bool:
        return self._bus_off or (self._starve_above is not None and msg.arbitration_id > self._starve_above)

    def tx(self, name: str, msg: can.Message) -> list[can.Message]:
        if self._starved(msg):
            return []
        rig = cast(FaultTarget, self.rig)  # installed on the rig's node by _index: attached
        out = [msg]
        for spec, state in self._frame_faults(name):
            out = [m for frame in out for m in spec.tx(frame, rig, state)]
        return out

    def rx(self, msg: can.Message) -> can.Message | None:
        if self._starved(msg):
            return None
        rig = cast(FaultTarget, self.rig)  # installed on the rig's node by _index: attached
        codec = rig.can.catalog.by_id(msg.arbitration_id)
        if codec is None or codec.name not in RX_MESSAGES:
            return msg
        for spec, state in self._frame_faults(codec.name):
            out = spec.rx(msg, rig, state)
            if out is None:
                return None
            msg = out
        return msg

    def flush(self, t: float) -> None:
        """Frames held back (delay) that are due by t go out now."""
        rig = cast(FaultTarget, self.rig)  # None before attach(): see `rig`
        for spec, state in self._frames:
            spec.flush(rig, state, t)

    # ------------------------------------------------------------------------------------- topics
    def wrench(self, payload: TesWrench, data: bytes) -> list[bytes]:
        out = [data]
        for spec, state in self._topics:
            out = [d for x in out for d in spec.wrench(payload, x, state)]
        return out

    def extra_puts(self) -> list[tuple[str, bytes]]:
        rig = cast(FaultTarget, self.rig)  # None before attach(): see `rig`
        return [p for spec, state in self._topics for p in spec.extra(rig, state)]

    # ---------------------------------------------------------------------------------- processes
    def command_delay(self) -> int:
        """Ticks the commands of this tick wait before the drives get them."""
        return max(
            (spec.delay_ticks(cast(FaultTarget, self.rig), state) for spec, state in self._processes),
            default=0,
        )

    # ------------------------------------------------------------------------------------- report
    def window(self, n: int, end: float) -> tuple[float, float] | None:
        """When fault n acted: (start, end), None if it never started."""
        state = self.states[n]
        if state.started is None:
            return None
        return state.started, state.ended if state.ended is not None else end
