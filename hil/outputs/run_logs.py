"""The logs a run streams as it goes, can.log (python-can's candump writer) and run.mcap (mcap_log.py), behind
one object the run feeds: every frame the CAN log's recorder takes (a python-can `Listener`), every zenoh
input the controller was sent (`zenoh`), every tick's trace row (`trace`), the bodies and their poses for
run.mcap's 3-D view (`bodies` once, then `poses`; `takes_poses`: only with run.mcap), the run's events as it
ends (`event`), then `stop()`.

They are written in a process of their own (`LogProcess`), not on the tick's thread: together they cost
about a fifth of a compiled lockstep tick (docs/performance.md), and in their own process they cost the tick
only the hand-over (the calls, batched, pickled down a pipe). The process replays the calls in their order
into the same writers (`LocalLogs`), so both files are byte for byte those an in-process writer makes.
`LocalLogs` runs on the tick's thread instead in a daemonic process (a Dask worker) and when asked
(`RunOptions.logs_in_process`: a test that makes a writer fail on purpose, the benchmark that times them).

The process is `python -m hil.outputs.run_logs` (the run's interpreter, importing the same pure-hil; started
as the run is built, its ~0.25 s of imports overlap the run's start-up): a fresh interpreter, never a fork
of a process that runs zenoh's threads, and nothing of the caller's `__main__` re-run. The pipe holds the run
back only if the process falls more than its buffer behind (a core busy with something else). It runs in a
session of its own (a terminal's Ctrl-C is the run's: the run stops it, and its files end complete) and ends
when its input closes, also when the run's process dies. Writing never fails a run: an output that fails,
or a writer process that dies, is in `failed` after stop(), which the run's summary lists in
`outputs_failed`.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import multiprocessing
import operator
import os
import pickle
import signal
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol

import can

from drivers.keys import Keys
from drivers.shared_bus import MESSAGE_FIELDS
from hil.outputs.bodies import Body
from hil.outputs.mcap_log import McapLog

log = logging.getLogger(__name__)

FRAME, ZENOH, TRACE, EVENT, BODIES, POSES = 0, 1, 2, 3, 4, 5
"""What a call handed over is: a frame the recorder took (at simulated time t), a zenoh input, a trace row,
an event, the bodies the poses name, a row of poses."""
BATCH_TICKS = 16
"""Ticks handed over in one write to the pipe in lockstep (a write and the process's wake-up per tick cost
more than the pickling)."""
REALTIME_BATCH_TICKS = 4
"""The same in real time, where a hand-over's pickle and write are one lump on the tick that makes it: 16
ticks' took ~550 µs of that tick against ~120 for the others, and most of an in-process run's overruns fell
on those ticks; 4 ticks' ~170 µs (docs/performance.md "Real time", 2026-12-07)."""
STOP_TIMEOUT = 60.0
"""s stop() waits for the process to finish the files (it is behind by at most a pipe's buffer)."""
PIPE_BYTES = 1 << 20
"""The pipe's buffer, asked for (64 kB otherwise; 1 MB is Linux's default pipe-max-size, the most an
unprivileged process may ask): ~800 ticks of calls, so the run is held back only when the process falls
behind for longer than that."""
CAN_LOG, MCAP = "can.log", "run.mcap"


def _background(pid: int) -> None:
    """The writer under the real-time clock: SCHED_IDLE (lowering a process's own child needs no privilege).
    It only has to keep up on average (its pipe holds ~200 real-time hand-overs), so it takes what CPU the
    rig, the controller and the supervisor leave. At niceness 10 a hand-over's write woke it onto the rig's
    core ahead of the rig (that write took 1.8 ms at p90 instead of ~50 µs); a SCHED_IDLE task woken never
    preempts a normal one.
    Niceness 19 where the policy is missing. Set by the run's process as it starts the writer, so the
    writer is in the background before the run's first tick."""
    try:
        os.sched_setscheduler(pid, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        with contextlib.suppress(OSError):  # gone already: stop() names what it left unwritten
            os.setpriority(os.PRIO_PROCESS, pid, 19)


_fields = operator.attrgetter(*MESSAGE_FIELDS)
_LENGTH = struct.Struct("<I")
"""A message down the pipe: its length, then its pickle."""


class McapSpec:
    """What run.mcap's writer is made of (picklable: the writer process makes its own)."""

    def __init__(self, path: Path, tick_hz: float, zenoh_prefix: str, metadata: dict[str, str]):
        self.path, self.tick_hz, self.zenoh_prefix, self.metadata = path, tick_hz, zenoh_prefix, metadata

    def open(self) -> McapLog:
        return McapLog(self.path, self.tick_hz, Keys(self.zenoh_prefix), self.metadata)


class LocalLogs(can.Listener):
    """The writers on the caller's thread. `clock`: simulated time now, s (when the recorder took a frame)."""

    def __init__(self, can_log: Path | None, mcap: McapSpec | None):
        self.clock: Callable[[], float] = lambda: 0.0
        self.failed: dict[str, str] = {}
        """An output that stopped, and why (run.mcap's errors are in its file too: its check reads them)."""
        self._mcap: McapLog | None = None
        self._writer: can.Listener | None = None
        self.takes_poses = mcap is not None
        """run.mcap is written: it wants the bodies and their poses."""
        if mcap is not None:
            try:
                self._mcap = mcap.open()
                self._mcap.clock = lambda: self.clock()
            except Exception as exc:  # can.log is still written
                self._fail(MCAP, exc)
        if can_log is not None:
            try:
                self._writer = can.Logger(str(can_log))
            except Exception as exc:
                self._fail(CAN_LOG, exc)

    def on_message_received(self, msg: can.Message) -> None:
        if self._writer is not None:
            try:
                self._writer.on_message_received(msg)
            except Exception as exc:  # the run goes on; the log stops here
                self._fail(CAN_LOG, exc)
        if self._mcap is not None:
            self._mcap.on_message_received(msg)

    def zenoh(self, tick: int, key: str, data: bytes) -> None:
        if self._mcap is not None:
            self._mcap.zenoh(tick, key, data)

    def trace(self, row: tuple[float, ...]) -> None:
        if self._mcap is not None:
            self._mcap.trace(row)

    def event(self, topic: str, t: float, message: dict) -> None:
        if self._mcap is not None:
            self._mcap.event(topic, t, message)

    def bodies(self, bodies: tuple[Body, ...]) -> None:
        if self._mcap is not None:
            self._mcap.bodies(bodies)

    def poses(self, t: float, row: list[float]) -> None:
        if self._mcap is not None:
            self._mcap.poses(t, row)

    def stop(self) -> None:
        writer, mcap, self._writer, self._mcap = self._writer, self._mcap, None, None
        if writer is not None:
            try:
                writer.stop()  # flushes and closes the file
            except Exception as exc:
                self._fail(CAN_LOG, exc)
        if mcap is not None:
            mcap.stop()  # completes the file, also after an error (recorded in it)

    def _fail(self, name: str, exc: Exception) -> None:
        if name not in self.failed:
            self.failed[name] = f"{type(exc).__name__}: {exc}"
            log.warning("%s stopped: %s", name, self.failed[name])
        if name == CAN_LOG:
            self._writer = None
        else:
            self._mcap = None


class LogProcess(can.Listener):
    """The same calls as `LocalLogs`, handed to a `LocalLogs` in a process of its own."""

    def __init__(self, can_log: Path | None, mcap: McapSpec | None, realtime: bool = False):
        """realtime: the run's clock is real time (the writer in the background, smaller hand-overs)."""
        self.clock: Callable[[], float] = lambda: 0.0
        self.failed: dict[str, str] = {}
        self.cpu_s = 0.0
        """The writer process's CPU time, s (after stop())."""
        self._names = [name for name, on in ((CAN_LOG, can_log), (MCAP, mcap)) if on is not None]
        self.takes_poses = mcap is not None
        self._calls: list[tuple[Any, ...]] = []
        self._ticks = 0
        self._batch = REALTIME_BATCH_TICKS if realtime else BATCH_TICKS
        self._broken: str | None = None
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": _import_path()}
        self._process = subprocess.Popen(
            [sys.executable, "-P", "-m", __name__],  # -P: not the working directory's modules, the run's
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
            start_new_session=True,  # a terminal's Ctrl-C is the run's to handle: it stops us, files complete
        )
        if realtime:
            _background(self._process.pid)
        self._stopped = False
        assert self._process.stdin is not None  # Popen(stdin=PIPE)
        self._pipe: IO[bytes] = self._process.stdin
        with contextlib.suppress(OSError, AttributeError):  # Linux only; a smaller buffer only holds less
            fcntl.fcntl(self._pipe.fileno(), fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        self._send((can_log, mcap))

    @property
    def pid(self) -> int:
        return self._process.pid

    def on_message_received(self, msg: can.Message) -> None:
        self._calls.append((FRAME, self.clock(), _fields(msg)))

    def zenoh(self, tick: int, key: str, data: bytes) -> None:
        self._calls.append((ZENOH, tick, key, data))

    def trace(self, row: tuple[float, ...]) -> None:
        self._calls.append((TRACE, row))
        self._ticks += 1
        if self._ticks % self._batch == 0:
            self._hand_over()

    def event(self, topic: str, t: float, message: dict) -> None:
        self._calls.append((EVENT, topic, t, message))

    def bodies(self, bodies: tuple[Body, ...]) -> None:
        self._calls.append((BODIES, bodies))

    def poses(self, t: float, row: list[float]) -> None:
        self._calls.append((POSES, t, row))

    def stop(self) -> None:
        """Hand over what is left, wait for the files to be finished, and take the process's report."""
        if self._stopped:
            return
        self._stopped = True
        process = self._process
        self._hand_over()
        self._send(None)  # the end
        assert process.stdout is not None  # Popen(stdout=PIPE)
        with contextlib.suppress(OSError):
            self._pipe.close()
        report = None
        try:
            process.wait(STOP_TIMEOUT)
            report = _read(process.stdout)  # its last word, written as it ended (a pipe's buffer holds it)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            self._broken = self._broken or f"it did not finish within {STOP_TIMEOUT:g} s"
        finally:
            process.stdout.close()
        if report is None:
            why = self._broken or "it ended without its report"
            if process.returncode:
                why += f" (it ended with {_exit_reason(process.returncode)})"
            self.failed.update({name: f"the writer process stopped: {why}" for name in self._names})
        else:
            self.failed.update(report["failed"])
            self.cpu_s = report["cpu_s"]

    def _hand_over(self) -> None:
        calls, self._calls = self._calls, []
        if calls:
            self._send(calls)

    def _send(self, message: object) -> None:
        if self._broken is not None:
            return
        data = pickle.dumps(message, pickle.HIGHEST_PROTOCOL)
        try:
            self._pipe.write(_LENGTH.pack(len(data)) + data)
            self._pipe.flush()
        except OSError as exc:  # the process is gone: the run goes on, stop() names the files
            self._broken = f"{type(exc).__name__}: {exc}"
            log.warning("the run's log writer process is gone (%s): can.log and run.mcap stop here", exc)


class RunLogs(Protocol):
    """What a run feeds the outputs it streams (can.log, run.mcap), on whichever side of the pipe they are
    written (`LocalLogs`, `LogProcess`): the calls, in the run's order, then `stop()`, after which `failed`
    names each output that stopped and why."""

    clock: Callable[[], float]
    """Simulated time now, s: when the recorder took a frame (set by the run once its plant exists)."""
    failed: dict[str, str]

    @property
    def takes_poses(self) -> bool:
        """run.mcap is written: it wants the bodies and their poses."""
        ...

    def on_message_received(self, msg: can.Message) -> None: ...

    def zenoh(self, tick: int, key: str, data: bytes) -> None: ...

    def trace(self, row: tuple[float, ...]) -> None: ...

    def event(self, topic: str, t: float, message: dict) -> None: ...

    def bodies(self, bodies: tuple[Body, ...]) -> None: ...

    def poses(self, t: float, row: list[float]) -> None: ...

    def stop(self) -> None: ...


if TYPE_CHECKING:
    _CHECKED: tuple[type[RunLogs], ...] = (LocalLogs, LogProcess)


def open_logs(
    can_log: Path | None, mcap: McapSpec | None, in_process: bool = False, realtime: bool = False
) -> RunLogs | None:
    """The run's logs: None when it writes neither; on the caller's thread when asked or in a daemonic
    process (a Dask worker); else in a process of their own (in the background under the real-time clock)."""
    if can_log is None and mcap is None:
        return None
    if in_process or multiprocessing.current_process().daemon:
        return LocalLogs(can_log, mcap)
    return LogProcess(can_log, mcap, realtime)


def _import_path() -> str:
    """PYTHONPATH for the writer process: where this pure-hil was imported from first, so it imports the
    same one (a source tree ahead of an installed build, as the run's own process does)."""
    root = str(Path(__file__).resolve().parents[2])
    return os.pathsep.join([root, *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))])


def _read(stream: IO[bytes]) -> Any:
    """The next message, or None at the end of the stream."""
    head = stream.read(_LENGTH.size)
    if len(head) < _LENGTH.size:
        return None
    (length,) = _LENGTH.unpack(head)
    data = stream.read(length)
    return pickle.loads(data) if len(data) == length else None


def _message(values: tuple[Any, ...]) -> can.Message:
    msg = can.Message.__new__(can.Message)
    for name, value in zip(MESSAGE_FIELDS, values, strict=True):
        setattr(msg, name, value)
    return msg


def _exit_reason(code: int) -> str:
    if code >= 0:
        return f"exit code {code}"
    try:
        return f"signal {signal.Signals(-code).name}"
    except ValueError:  # a real-time signal has no name
        return f"signal {-code}"


def _serve(calls: IO[bytes], report: IO[bytes]) -> None:
    """The writer process: replay every call handed over into a `LocalLogs` until the end (None) or the
    end of the input (the run's process died); then finish the files and report."""
    spec = _read(calls)
    if spec is None:  # the run's process died before it said what to write
        return
    logs = LocalLogs(*spec)
    now = 0.0
    logs.clock = lambda: now
    while (batch := _read(calls)) is not None:
        for call in batch:
            kind = call[0]
            if kind == FRAME:
                now = call[1]
                logs.on_message_received(_message(call[2]))
            elif kind == ZENOH:
                logs.zenoh(call[1], call[2], call[3])
            elif kind == EVENT:
                logs.event(call[1], call[2], call[3])
            elif kind == TRACE:
                logs.trace(call[1])
            elif kind == POSES:
                logs.poses(call[1], call[2])
            else:
                logs.bodies(call[1])
    logs.stop()
    with contextlib.suppress(OSError):  # nobody may be waiting for it any more
        data = pickle.dumps({"failed": logs.failed, "cpu_s": time.process_time()})
        report.write(_LENGTH.pack(len(data)) + data)
        report.flush()


if __name__ == "__main__":
    report = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # a stray print goes to stderr, not into the report
    _serve(sys.stdin.buffer, report)
