"""The run's rows, one per tick (the plant's truth beside what the supervisor and the controller said): the
run folder's trace.npy, a plain numpy file (`np.load("trace.npy")`, columns in `COLUMNS`, SI units). The
run's summary.json names the columns, their units and the supervisor's state codes (`trace`, `describe`).

With a run folder the rows stream to disk in blocks as the run goes and the run's Trace reads them back
through a read-only memory map: file pages the kernel may drop, not memory the process holds, so a run of
hours keeps its memory flat. The controller's telemetry for a tick can arrive ticks later, so a block is
written only once the block after it is full. Without a folder the rows stay in memory.
"""

from __future__ import annotations

import operator
import struct
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from drivers.vocabulary import State


class Column(NamedTuple):
    name: str
    unit: str
    """SI; "" for a code or a flag (0/1)."""
    meaning: str


COLUMNS = (
    Column("t", "s", "simulated time"),
    Column("velocity.forward", "m/s", "ground speed, heading frame"),
    Column("velocity.left", "m/s", "ground speed, heading frame"),
    Column("tilt.pitch", "rad", "chassis tilt"),
    Column("tilt.roll", "rad", "chassis tilt"),
    Column("lean.pitch", "rad", "torso lean relative to the chassis"),
    Column("lean.roll", "rad", "torso lean relative to the chassis"),
    Column("position.x", "m", "ball contact point from the start, world frame"),
    Column("position.y", "m", "ball contact point from the start, world frame"),
    Column("yaw_rate", "rad/s", "chassis yaw rate"),
    Column("ball_rate.pitch", "rad/s", "ball rate"),
    Column("ball_rate.roll", "rad/s", "ball rate"),
    Column("motor_torque.1", "Nm", "torque drive 1 produced"),
    Column("motor_torque.2", "Nm", "torque drive 2 produced"),
    Column("motor_torque.3", "Nm", "torque drive 3 produced"),
    Column("safety_state", "", "the supervisor's state as on the bus (SAFETY_STATES)"),
    Column("safety_speed", "m/s", "the embedded supervisor's speed estimate (NaN: none)"),
    Column("powered", "", "1: a drive's power stage on"),
    Column("resting", "", "1: powered off at standstill, held by the rider's feet or the stand"),
    # From the controller's telemetry (NaN: none for that tick).
    Column("command_speed.pitch", "m/s", "the controller's command speed (its telemetry; NaN: none)"),
    Column("command_speed.roll", "m/s", "the controller's command speed (its telemetry; NaN: none)"),
    Column("tilt_command.pitch", "rad", "the controller's tilt command θ_EQ (its telemetry; NaN: none)"),
    Column("tilt_command.roll", "rad", "the controller's tilt command θ_EQ (its telemetry; NaN: none)"),
)
SAFETY_STATES = {-1: "no frame yet", **{s.value: s.name for s in State}}
"""The `safety_state` column's codes (SUPERVISOR_ESTOP.State, drivers/vocabulary.py)."""
Reorder = Callable[[tuple[float, ...]], tuple[float, ...]]
"""What puts a writer's values into the declared order."""
TOLD = ("command_speed", "tilt_command")
"""The groups of the controller's telemetry, in the order `TraceLog.telemetry` takes them; a row's last
columns, the rig's before them."""


class Layout:
    """Where a declaration of columns puts each one, looked up by name once (not per tick). A group is the
    columns named `group.part` (its parts in the declared order, side by side), or one column named `group`:
    `span("velocity")` is the slice of velocity.forward and velocity.left, `span("t")` the index of t."""

    def __init__(self, columns: Sequence[Column]):
        self.columns = tuple(columns)
        names = [c.name for c in self.columns]
        self.spans: dict[str, int | slice] = {}
        """Each group's columns, in the declared order."""
        for i, name in enumerate(names):
            group, dot, _ = name.partition(".")
            if group in self.spans:
                known = self.spans[group]
                if not dot or not isinstance(known, slice) or known.stop != i:
                    raise ValueError(f"trace column {name!r}: its group {group!r} is not side by side")
                self.spans[group] = slice(known.start, i + 1)
            else:
                self.spans[group] = slice(i, i + 1) if dot else i
        told = sorted(self._indices(TOLD))
        if told != list(range(len(names) - len(told), len(names))):
            raise ValueError(f"trace columns: the controller's telemetry {TOLD} must be the last columns")
        self.telemetry = len(names) - len(told)
        """Columns before this one come from the rig each tick; the rest from the controller's telemetry."""

    def span(self, group: str) -> int | slice:
        try:
            return self.spans[group]
        except KeyError:
            raise ValueError(f"no trace column {group!r} (known: {', '.join(self.spans)})") from None

    def _indices(self, groups: Sequence[str]) -> list[int]:
        indices: list[int] = []
        for group in groups:
            span = self.span(group)
            indices += [span] if isinstance(span, int) else range(span.start, span.stop)
        return indices

    def order(self, groups: Sequence[str]) -> Reorder | None:
        """How a writer's values, group after group (each group's parts in the declared order), go into the
        columns they fill, the rig's or the telemetry's: None when they are in the declared order already
        (the shipped writers: no cost), else the reordering (a declaration whose columns moved)."""
        indices = self._indices(groups)
        width = len(self.columns)
        if sorted(indices) not in (list(range(self.telemetry)), list(range(self.telemetry, width))):
            raise ValueError(
                f"trace columns: {', '.join(groups)} fill neither the rig's columns nor the telemetry's"
            )
        if indices == sorted(indices):
            return None
        # The value written k-th goes to column indices[k]: column j takes the value written at[j]-th.
        at = sorted(range(len(indices)), key=indices.__getitem__)
        return operator.itemgetter(*at)  # at has two values or more: the getter gives a tuple


LAYOUT = Layout(COLUMNS)
"""The shipped declaration's layout: what the rig writes and every reader reads by."""
TELEMETRY = LAYOUT.telemetry
"""The shipped rows' first telemetry column (Layout.telemetry)."""
BLOCK = 1024
"""Rows per write (188 kB, 2.6 s of a 400 Hz run; a write costs ~0.2 ms of the tick that makes it)."""
HEADER = 128
"""Bytes of the .npy header, fixed so the row count can be written last (NPY format 1.0: magic, version,
header length, then a Python dict literal padded with spaces and ended by a newline)."""


def _header(rows: int, width: int) -> bytes:
    text = f"{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {width}), }}"
    text = text.ljust(HEADER - 10 - 1) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text.encode("latin1")


class TraceLog:
    def __init__(
        self, ticks: int, path: Path | None = None, block: int | None = None, layout: Layout = LAYOUT
    ):
        self.path = path
        self.rows = 0
        self._first = 0  # the row index of the buffer's first row
        self._block = block = block or BLOCK
        self._width = width = len(layout.columns)
        self._telemetry = layout.telemetry
        self._told_order = layout.order(TOLD)
        self._file = None
        if path is None:
            self._buffer = np.full((ticks, width), np.nan)
        else:
            self._buffer = np.full((2 * block, width), np.nan)
            self._file = open(path, "wb")  # noqa: SIM115 (closed by close(), also on a failed run)
            self._file.write(_header(0, width))

    def append(self, values) -> None:
        """The rig's columns of the next tick (everything before the telemetry's), in the declared order."""
        i = self.rows - self._first
        if i == len(self._buffer):
            self._write(self._block)
            i -= self._block
        self._buffer[i, : self._telemetry] = values
        self.rows += 1

    def telemetry(self, row: int, command_speed, tilt_command) -> None:
        """The controller's telemetry for row `row`; dropped if that row is on disk already (it stays NaN:
        counted as missing telemetry)."""
        i = row - self._first
        if 0 <= i < self.rows - self._first:
            told = (*command_speed, *tilt_command)  # TOLD's order
            self._buffer[i, self._telemetry :] = told if self._told_order is None else self._told_order(told)

    def last_told(self) -> bool:
        """The last row has the controller's telemetry."""
        i = self.rows - 1 - self._first
        return i >= 0 and not np.isnan(self._buffer[i, self._telemetry])

    def _write(self, count: int) -> None:
        # Only a streamed log writes: in memory the buffer holds every tick the run can have.
        assert self._file is not None
        self._file.write(self._buffer[:count].data)
        self._buffer[: len(self._buffer) - count] = self._buffer[count:]
        self._buffer[len(self._buffer) - count :] = np.nan
        self._first += count

    def close(self) -> np.ndarray:
        """Every row: (rows, columns), the file's memory map when streamed."""
        if self._file is None or self.path is None:  # in memory (streamed, both are set)
            return self._buffer[: self.rows]
        if not self._file.closed:
            self._file.write(self._buffer[: self.rows - self._first].data)
            self._file.seek(0)
            self._file.write(_header(self.rows, self._width))
            self._file.close()
        if not self.rows:
            return np.zeros((0, self._width))
        return np.load(self.path, mmap_mode="r")


def describe(rows: int) -> dict:
    """trace.npy as summary.json names it: its shape, each column's name, unit and meaning, and the
    `safety_state` codes."""
    return {
        "file": "trace.npy",
        "rows": rows,
        "columns": [c._asdict() for c in COLUMNS],
        "safety_states": {str(code): name for code, name in SAFETY_STATES.items()},
    }
