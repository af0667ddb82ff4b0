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
from collections.abc import Iterable

import can
import msgspec
import numpy as np

from drivers.schemas import TesWrench
from hil.faults.base import FaultError, FaultEvent, FaultSpec, FaultState, FaultTarget
from hil.faults.frames import RX_MESSAGES, Babble, BusOff, CanFault
from hil.faults.processes import ProcessFault
from hil.faults.sensors import Readings, SensorFault
from hil.faults.topics import TopicFault

log = logging.getLogger(__name__)


class FaultSet:
    def __init__(self, faults: Iterable[FaultSpec] = (), seed: int = 0):
        self.seed = seed
        self.tick_hz = 400.0
        """Set by attach() from the rig's plant: the rate scheduled times become ticks at."""
        self.specs: list[FaultSpec] = []
        self.states: list[FaultState] = []
        self.events: list[FaultEvent] = []
        self._cleared: set[int] = set()
        self._requests: list[tuple[str, FaultSpec | int | None]] = []
        self._lock = threading.Lock()
        self.rig: FaultTarget | None = None
        self.on_event = None
        """Called with every FaultEvent as it happens (the service marks the live view)."""
        self._active: list[int] = []
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
                spec.validate(rig)
            except ValueError as exc:
                raise FaultError(f"fault {n} ({spec.describe()}): {exc}") from None
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
    def inject(self, spec: FaultSpec) -> None:
        """From any thread: add `spec`, its `at` counted from the tick that takes it in. Raises ValueError
        if it cannot act on this rig."""
        if self.rig is not None:
            spec.validate(self.rig)
        with self._lock:
            self._requests.append(("inject", spec))

    def clear(self, fault: int | None = None) -> None:
        """From any thread: end fault number `fault` (None: every fault active or still to come)."""
        with self._lock:
            self._requests.append(("clear", fault))

    def _take_requests(self, k: int, t: float) -> None:
        with self._lock:
            requests, self._requests = self._requests, []
        for action, arg in requests:
            if action == "inject":
                # Recorded with its absolute start; scheduled from tick 0, so `at` counts once from this tick.
                spec = msgspec.structs.replace(arg, at=t + arg.at)  # type: ignore[type-var]
                try:
                    spec.validate(self.rig)
                except ValueError as exc:  # queued before the rig was there to check it
                    log.error("live fault %s refused: %s", spec.describe(), exc)
                    continue
                n = self._add(spec)
                self._schedule(n)
                self._log(t, n, "inject", spec.describe())
            else:
                targets = range(len(self.specs)) if arg is None else [arg]
                for n in targets:
                    if 0 <= n < len(self.specs) and n not in self._cleared:
                        self._cleared.add(n)
                        self._log(t, n, "clear", "")

    # -------------------------------------------------------------------------------------- ticks
    def update(self, k: int, t: float) -> None:
        """Start and end faults for tick k (at time t)."""
        if self._requests:
            self._take_requests(k, t)
        rig = self.rig
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
        for n in self._babblers:
            self.specs[n].babble(rig)  # type: ignore[attr-defined]

    def _index(self) -> None:
        specs, active = self.specs, self._active
        self._sensors = [n for n in active if isinstance(specs[n], SensorFault)]
        self._topics = [n for n in active if isinstance(specs[n], TopicFault)]
        self._processes = [n for n in active if isinstance(specs[n], ProcessFault)]
        self._frames = [n for n in active if isinstance(specs[n], CanFault)]
        self._babblers = [n for n in active if isinstance(specs[n], Babble)]
        self._bus_off = any(isinstance(specs[n], BusOff) for n in active)
        rig = self.rig
        saturating = [specs[n].can_id for n in self._babblers if specs[n].saturates(rig)]  # type: ignore[attr-defined]
        self._starve_above = min(saturating) if saturating else None
        """Frames with a higher id lose every arbitration to a babbler that fills the bus."""
        if rig is not None:
            hooked = bool(self._frames or self._babblers or self._bus_off)
            rig.can.tx_hook = self.tx if hooked else None
            rig.can.rx_hook = self.rx if hooked else None

    def _log(self, t: float, n: int, action: str, detail: str) -> None:
        spec = self.specs[n]
        self.events.append(FaultEvent(round(t, 9), n, spec.kind, action, detail))  # type: ignore[arg-type]
        if self.on_event is not None:
            self.on_event(self.events[-1])
        log.warning("fault %d %s at t=%.3f: %s", n, action, t, detail or spec.kind)

    def finish(self, k: int, t: float) -> None:
        """End of the run (tick k, time t): requests already acknowledged are logged, every fault still
        active ends (held frames are sent, processes resume)."""
        if self._requests:
            self._take_requests(k, t)
        for n in self._active:
            state = self.states[n]
            state.active, state.ended = False, t
            self.specs[n].stop(self.rig, state)
            self._log(t, n, "end", "run over")
        self._active = []
        self._index()

    # ------------------------------------------------------------------------------------ sensors
    def sensors(self, plant, feedback, imu, tes):
        """The tick's samples as the faulty sensors report them, and the frames that stay silent."""
        readings = Readings.of(plant, feedback, imu, tes)
        for n in self._sensors:
            self.specs[n].apply(readings, plant.t, self.states[n])  # type: ignore[attr-defined]
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
    def _frame_faults(self, name: str):
        for n in self._frames:
            spec, state = self.specs[n], self.states[n]
            if spec.message == name and state.remaining != 0:  # type: ignore[attr-defined]
                if state.remaining is not None:
                    state.remaining -= 1
                yield spec, state

    def _starved(self, msg: can.Message) -> bool:
        return self._bus_off or (self._starve_above is not None and msg.arbitration_id > self._starve_above)

    def tx(self, name: str, msg: can.Message) -> list[can.Message]:
        if self._starved(msg):
            return []
        out = [msg]
        for spec, state in self._frame_faults(name):
            out = [m for frame in out for m in spec.tx(frame, self.rig, state)]  # type: ignore[attr-defined]
        return out

    def rx(self, msg: can.Message) -> can.Message | None:
        if self._starved(msg):
            return None
        codec = self.rig.can.catalog.by_id(msg.arbitration_id)
        if codec is None or codec.name not in RX_MESSAGES:
            return msg
        for spec, state in self._frame_faults(codec.name):
            msg = spec.rx(msg, self.rig, state)  # type: ignore[attr-defined]
            if msg is None:
                return None
        return msg

    def flush(self, t: float) -> None:
        """Frames held back (delay) that are due by t go out now."""
        for n in self._frames:
            self.specs[n].flush(self.rig, self.states[n], t)  # type: ignore[attr-defined]

    # ------------------------------------------------------------------------------------- topics
    def wrench(self, payload: TesWrench, data: bytes) -> list[bytes]:
        out = [data]
        for n in self._topics:
            out = [d for x in out for d in self.specs[n].wrench(payload, x, self.states[n])]  # type: ignore[attr-defined]
        return out

    def extra_puts(self) -> list[tuple[str, bytes]]:
        return [p for n in self._topics for p in self.specs[n].extra(self.rig, self.states[n])]  # type: ignore[attr-defined]

    # ---------------------------------------------------------------------------------- processes
    def command_delay(self) -> int:
        """Ticks the commands of this tick wait before the drives get them."""
        return max(
            (self.specs[n].delay_ticks(self.rig, self.states[n]) for n in self._processes),  # type: ignore[attr-defined]
            default=0,
        )

    # ------------------------------------------------------------------------------------- report
    def window(self, n: int, end: float) -> tuple[float, float] | None:
        """When fault n acted: (start, end), None if it never started."""
        state = self.states[n]
        if state.started is None:
            return None
        return state.started, state.ended if state.ended is not None else end
