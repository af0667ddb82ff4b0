"""`pure-hil serve`: the long-running rig for bench work, controlled over zenoh queryables.

    pure/rig/status   -> JSON: state (idle | running), scenario, simulated time, the last run's result
    pure/rig/start    <- a scenario: a file path, or the TOML text itself; runs it in the background
    pure/rig/stop     -> ends the current run early
    pure/rig/intent   <- JSON {"pitch": [...], "roll": [...], "twist": [...]}: the running rider's intent from
                         now on, within their reach (hil/run/scenario.py Intent.check_reach)
    pure/rig/fault/inject <- JSON fault {"kind": "sensor.stuck", "channel": "imu.pitch", ...}: into the
                         running run, `at` counted from the tick that takes it in (docs/faults.md)
    pure/rig/fault/clear  <- a fault's number, or nothing for all: ends it (them) at the next tick
    pure/rig/history  <- JSON {"limit": N, "before": RUN} or nothing -> the runs it made, newest first
    pure/rig/file     <- JSON {"run": RUN, "name": "plots.png", "offset": BYTES} -> that file's bytes from
                         `offset` (at most CHUNK of them; the attachment says the size), or an error reply
    pure/rig/live     -> about 20 samples a second of wall time while a run goes (hil/live.py)

Every reply is JSON with "ok" and either the result or an "error" that says what was wrong, with
"refused": true when the request itself is wrong (a bad file, parameter or fault number: a client exits 2;
a file's bytes are the one exception: raw, with the JSON in the attachment; its errors are error replies).
`stop` ends a run at its next tick, also under any fault (no wait for a frame outlasts hil/run/drives_port.py
STOP_POLL); `close()` waits until its folder is written. Queryable
callbacks only validate and hand over; runs happen on a worker thread, so zenoh's threads never block.
Every run is written to the output folder's history (hil/history.py) as it begins and ends.
"""

from __future__ import annotations

import json
import os
import threading
import time
from contextlib import ExitStack
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import zenoh

from drivers.config import ConfigError, decode_toml
from drivers.keys import Keys
from drivers.resources import find, shipped
from hil.bench.bench import Bench, load_bench
from hil.bench.rigs import RigCard, announce
from hil.faults import FaultSet, parse_fault
from hil.history import History, NotServed
from hil.live import LiveStream
from hil.pipeline import check_start, describe, load_scenario, run
from hil.run.build import RunOptions, RunStatus, clock_of, law_of
from hil.run.scenario import Intent, Scenario
from plant.core import PlantCore, RiderIntent
from plant.params import RiderParams

if TYPE_CHECKING:  # imported where used: rerun loads only for a service with a live view
    from hil.outputs.recording import LiveView

NO_FAULTS = "bench {bench} says a person is on the robot (rider_on_board): fault injection is refused"
CHUNK = 1 << 19
"""Bytes of a file per pure/rig/file reply: a large recording crosses in pieces, never whole in memory."""


class RigService:
    def __init__(
        self,
        session: zenoh.Session,
        bench: Bench | None = None,
        out_root: Path = Path("runs"),
        view=None,
    ):
        """`session`: the rig's own (the loopback hub, or its router client); `view`: a rerun sink (e.g.
        `rr.GrpcSink(url)` to the operator's own viewer) that receives every run live; None: no live view
        (the run folder's recording.rrd is always written)."""
        self.session, self.bench = session, bench or load_bench()
        self.keys = Keys(self.bench.zenoh.prefix)
        self.view_sink = view
        self._view: LiveView | None = None
        self._views: dict[str, LiveView] = {}
        """One live recording per scenario name, kept for the service's life: rerun never drops a stream
        created from Python (rerun-io/rerun#2116), so a stream per run would leak its threads."""
        self.out_root = out_root
        self.state = "idle"
        self.scenario: Scenario | None = None
        self.sim_time = 0.0
        self.last: dict | None = None
        self.run_id: int | None = None
        """The history's id of the current (or last) run."""
        self.scenarios = tuple(dict.fromkeys([*shipped("scenarios"), *self.bench.scenarios]))
        """What a console offers to start: the shipped scenarios by name, and the bench's own."""
        self.history = History(out_root)
        self._live = LiveStream(session, self.keys)
        self._stop = threading.Event()
        self._pending_intent: RiderIntent | None = None
        self._rider: tuple[RiderParams, str] | None = None
        """The rider of the run in progress, and their file: a live intent stays within their reach."""
        self._lock = threading.Lock()
        self._worker: threading.Thread | None = None
        self._queryables = [
            session.declare_queryable(self.keys.rig(name), handler)
            for name, handler in (
                ("status", self._status),
                ("start", self._start),
                ("stop", self._stop_run),
                ("intent", self._intent),
                ("fault/inject", self._fault_inject),
                ("fault/clear", self._fault_clear),
                ("history", self._history),
                ("file", self._file),
            )
        ]
        self._faults: FaultSet | None = None
        self._announced = ExitStack()
        if self.bench.zenoh.mode == "loopback":  # operators' clients find it (hil/bench/rigs.py)
            self.endpoint = self.bench.zenoh.hub_endpoint()
            self.card = self._announced.enter_context(
                announce(session, self.keys.prefix, self.bench.name, self.endpoint, "serve")
            )
        else:
            self.endpoint = self.bench.zenoh.endpoint or "the bench router"
            self.card = RigCard(self.bench.name, self.endpoint, os.getpid(), "serve", time.time())
        """Who answers: a console pins itself to this card's id (docs/rig.md, "The console")."""

    # ---------------------------------------------------------------------------------- queryables
    def _reply(self, query: zenoh.Query, body: dict) -> None:
        query.reply(query.key_expr, json.dumps(body))

    def _refuse(self, query: zenoh.Query, error: str) -> None:
        """The request itself is wrong (what was sent, not the rig's state): the client exits 2."""
        self._reply(query, {"ok": False, "error": error, "refused": True})

    def _status(self, query: zenoh.Query) -> None:
        self._reply(query, {"ok": True, **self.status()})

    def _running(self) -> Scenario | None:
        """The scenario of the run in progress (None: idle)."""
        return self.scenario if self.state == "running" else None

    def status(self) -> dict:
        return {
            "state": self.state,
            "scenario": self.scenario.name if self.scenario else None,
            "sim_time": round(self.sim_time, 3),
            "faults": self._fault_status(),
            "last": self.last,
            "run": self.run_id,
            "bench": {
                **describe(self.bench),
                "description": self.bench.description,
            },
            "scenarios": list(self.scenarios),
            "card": asdict(self.card),
        }

    def _fault_status(self) -> list[dict]:
        faults = self._faults
        if faults is None:
            return []
        return [
            {"number": n, "fault": spec.describe(), "active": state.active, "started": state.started}
            for n, (spec, state) in enumerate(zip(list(faults.specs), list(faults.states), strict=False))
        ]

    def _start(self, query: zenoh.Query) -> None:
        text = query.payload.to_string() if query.payload is not None else ""
        try:
            scenario, rider = self._scenario(text)
        except ConfigError as exc:
            self._refuse(query, str(exc))
            return
        if scenario.faults and self.bench.rider_on_board:
            self._reply(query, {"ok": False, "error": NO_FAULTS.format(bench=self.bench.name)})
            return
        with self._lock:
            running = self._running()
            if running is not None:
                self._reply(query, {"ok": False, "error": f"already running {running.name}"})
                return
            self.state, self.scenario, self.sim_time = "running", scenario, 0.0
            self._rider = rider
            self._stop.clear()
            # The run's faults exist before the reply: an injection right after "running" is never lost.
            self._faults = FaultSet(scenario.faults, scenario.seed)
            self._faults.on_event = self._fault_event
            out = self._fresh_folder(scenario.name)
            self.run_id = self.history.begin(
                out,
                scenario.name,
                self.bench.name,
                self._controller(scenario),
                clock_of(self.bench, scenario),
            )
            self._live.begin(scenario.name, self._faults, self.run_id)
            self._worker = threading.Thread(
                target=self._run, args=(scenario, out, self.run_id), name="rig-run", daemon=True
            )
            self._worker.start()
        self._reply(query, {"ok": True, "scenario": scenario.name, "out": str(out), "run": self.run_id})

    def _controller(self, scenario: Scenario) -> str:
        """Where the controller runs and its law, for the history: 'embedded reference ihacs'."""
        part = self.bench.controller
        plugin = [part.plugin] if part.where == "embedded" else []
        return " ".join([part.where, *plugin, law_of(self.bench, scenario)])

    def _fresh_folder(self, name: str) -> Path:
        """NAME-TIMESTAMP, or NAME-TIMESTAMP-2, ... when runs of one scenario start within a second."""
        stem = self.out_root / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
        out, n = stem, 1
        while out.exists():
            n += 1
            out = stem.with_name(f"{stem.name}-{n}")
        out.mkdir(parents=True)
        return out

    def _scenario(self, text: str) -> tuple[Scenario, tuple[RiderParams, str]]:
        """The scenario a start request names, and its rider and their file, once it can start."""
        text = text.strip()
        if not text:
            raise ConfigError("pure/rig/start", "expected a scenario file path or its TOML text")
        origin = "pure/rig/start payload"
        if "\n" not in text and "=" not in text:
            scenario, origin = load_scenario(text), text  # a path or a shipped scenario's short name
        else:
            scenario = decode_toml(text, Scenario, origin)
        rider = check_start(scenario, self.bench, origin)  # a robot that starts fallen tests nothing
        return scenario, (rider, str(find(scenario.rider, "riders")))

    def _stop_run(self, query: zenoh.Query) -> None:
        running = self.state == "running"
        self._stop.set()
        self._reply(query, {"ok": True, "stopping": running})

    def _intent(self, query: zenoh.Query) -> None:
        text = query.payload.to_string() if query.payload is not None else ""
        try:
            intent = msgspec.json.decode(text, type=Intent)
        except (msgspec.ValidationError, msgspec.DecodeError) as exc:
            self._refuse(query, f"pure/rig/intent payload: {exc}")
            return
        running, rider = self._running(), self._rider
        if running is None or rider is None:  # whose reach it must be within is not known
            self._reply(query, {"ok": False, "error": "no run in progress: start one first"})
            return
        try:
            intent.check_reach(*rider, where="pure/rig/intent")
        except ValueError as exc:
            self._refuse(query, str(exc))
            return
        self._pending_intent = RiderIntent(list(intent.pitch), list(intent.roll), list(intent.twist))
        self._reply(query, {"ok": True, "applies_to": running.name})

    def _fault_inject(self, query: zenoh.Query) -> None:
        text = query.payload.to_string() if query.payload is not None else ""
        try:
            obj = json.loads(text)
            spec = parse_fault(obj, "pure/rig/fault/inject payload")
        except (ValueError, json.JSONDecodeError) as exc:
            self._refuse(query, str(exc))
            return
        if self.bench.rider_on_board:
            self._reply(query, {"ok": False, "error": NO_FAULTS.format(bench=self.bench.name)})
            return
        faults, running = self._faults, self._running()
        if running is None or faults is None:
            self._reply(query, {"ok": False, "error": "no run in progress: start one first"})
            return
        try:
            faults.inject(spec)
        except ValueError as exc:  # a bound of this rig's, a message it lacks, a run full of faults
            self._refuse(query, str(exc))
            return
        self._reply(query, {"ok": True, "fault": spec.describe(), "scenario": running.name})

    def _fault_clear(self, query: zenoh.Query) -> None:
        text = (query.payload.to_string() if query.payload is not None else "").strip()
        faults = self._faults
        if self.state != "running" or faults is None:
            self._reply(query, {"ok": False, "error": "no run in progress"})
            return
        try:
            number = int(text) if text else None
        except ValueError:
            self._refuse(query, f"expected a fault number or nothing, got {text!r}")
            return
        try:
            faults.clear(number)
        except ValueError as exc:  # a number this run never gave
            self._refuse(query, str(exc))
            return
        self._reply(query, {"ok": True, "cleared": "all" if number is None else number})

    def _history(self, query: zenoh.Query) -> None:
        text = (query.payload.to_string() if query.payload is not None else "").strip()
        try:
            asked = json.loads(text) if text else {}
            if not isinstance(asked, dict) or set(asked) - {"limit", "before"}:
                raise ValueError('expected {"limit": N, "before": RUN} or nothing')
            limit, before = asked.get("limit", 50), asked.get("before")
            for name, value in (("limit", limit), ("before", before)):
                if value is not None and (type(value) is not int or value < 1):
                    raise ValueError(f"{name}: expected a whole number >= 1, got {value!r}")
        except ValueError as exc:
            self._reply(query, {"ok": False, "error": f"pure/rig/history payload: {exc}"})
            return
        runs = self.history.runs(limit, before)
        self._reply(query, {"ok": True, "runs": runs, "total": self.history.count()})

    def _file(self, query: zenoh.Query) -> None:
        text = query.payload.to_string() if query.payload is not None else ""
        try:
            asked = json.loads(text)
            run_id, name, offset = asked["run"], asked["name"], asked.get("offset", 0)
            if type(run_id) is not int or type(offset) is not int or offset < 0:
                raise ValueError("run and offset: whole numbers")
            path = self.history.file(run_id, name)
            size = path.stat().st_size
            with path.open("rb") as f:
                f.seek(offset)
                data = f.read(CHUNK)
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            expected = '{"run": N, "name": FILE, "offset": BYTES}'
            query.reply_err(
                json.dumps({"ok": False, "error": f"pure/rig/file payload: expected {expected} ({exc})"})
            )
            return
        except (NotServed, OSError) as exc:
            query.reply_err(json.dumps({"ok": False, "error": str(exc)}))
            return
        query.reply(query.key_expr, data, attachment=json.dumps({"ok": True, "size": size, "offset": offset}))

    # ----------------------------------------------------------------------------------------- runs
    def _on_tick(self, plant: PlantCore) -> None:
        self.sim_time = plant.t
        if self._live.due():
            self._live.put(plant)
        if self._view is not None:
            self._view.add(plant.truth())
        intent, self._pending_intent = self._pending_intent, None
        if intent is not None:
            plant.set_intent(intent)

    def _run(self, scenario: Scenario, out: Path, run_id: int) -> None:
        if self.view_sink is not None:
            from hil.outputs.recording import LiveView

            if scenario.name not in self._views:
                self._views[scenario.name] = LiveView(self.view_sink, scenario.name)
            self._view = self._views[scenario.name]
            self._view.mark(0.0, f"run {scenario.name} started")
        try:
            result = run(
                scenario,
                self.bench,
                out=out,
                options=RunOptions(
                    on_tick=self._on_tick,
                    stop=self._stop,
                    session=self.session,
                    fault_set=self._faults,
                    progress=self._progress,
                ),
            )
            self.last = {
                "scenario": scenario.name,
                "passed": result.passed,
                "verdict": result.verdict,
                "fallen": result.trace.fallen is not None,
                "fall_cause": result.trace.fallen,
                "stopped_early": self._stop.is_set(),
                "out": str(out),
                "metrics": result.metrics,
                "failure": None
                if result.trace.failure is None
                else msgspec.to_builtins(result.trace.failure),
                "fault_events": [msgspec.to_builtins(e) for e in result.trace.fault_events],
                "operator_actions": result.operator_actions(),
            }
            transitions = [e for e in result.trace.safety_events if e.kind == "transition"]
            failure = result.trace.failure
            self.history.end(
                run_id,
                result.verdict,
                transitions[0].cause if transitions else None,
                None if failure is None else f"{failure.stage}: {failure.error}",
            )
        except Exception as exc:  # a failed run is reported on status, never kills the service
            self.last = {"scenario": scenario.name, "passed": False, "error": f"{type(exc).__name__}: {exc}"}
            self.history.end(run_id, "ERROR", error=self.last["error"])
        finally:
            if self._view is not None:
                self._view.mark(self.sim_time, f"run {scenario.name} ended: {self.last}")
                self._view.flush()
                self._view = None
            self.state = "idle"

    def _progress(self, status: RunStatus) -> None:
        self._live.status = status

    def _fault_event(self, event) -> None:
        if self._view is not None:
            self._view.mark(
                event.t, f"fault {event.fault} {event.action}: {event.kind} {event.detail}", "WARN"
            )

    def wait_idle(self, timeout: float | None = None) -> bool:
        worker = self._worker
        if worker is not None:
            worker.join(timeout)
        return self.state == "idle"

    def interrupt(self, why: str) -> None:
        """The process is leaving at once (a second Ctrl-C while `close` waits): the run in progress is
        INTERRUPTED in the history now, its folder as far as it got."""
        if self.state == "running" and self.run_id is not None:
            self.history.interrupt(self.run_id, why)

    def close(self) -> None:
        """End the run in progress (at its next tick) and wait until its folder is written, then leave."""
        self._stop.set()
        self.wait_idle()
        for q in self._queryables:
            q.undeclare()
        self._announced.close()
        self._live.close()
        self.history.close()
        for view in self._views.values():
            view.close()
