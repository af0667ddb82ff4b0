"""The run's rows, one per tick (the plant's truth beside what the supervisor and the controller said): the
run folder's trace.npy, a plain numpy file (`np.load("trace.npy")`, columns in `COLUMNS`, SI units).

With a run folder the rows stream to disk in blocks as the run goes and the run's Trace reads them back
through a read-only memory map: file pages the kernel may drop, not memory the process holds, so a run of
hours keeps its memory flat. The controller's telemetry for a tick can arrive ticks later, so a block is
written only once the block after it is full. Without a folder the rows stay in memory.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

COLUMNS = (
    "t",
    "velocity.forward",
    "velocity.left",
    "tilt.pitch",
    "tilt.roll",
    "lean.pitch",
    "lean.roll",
    "position.x",
    "position.y",
    "yaw_rate",
    "ball_rate.pitch",
    "ball_rate.roll",
    "motor_torque.1",
    "motor_torque.2",
    "motor_torque.3",
    "safety_state",
    "safety_speed",
    "powered",
    "resting",
    # From the controller's telemetry (NaN: none for that tick).
    "command_speed.pitch",
    "command_speed.roll",
    "tilt_command.pitch",
    "tilt_command.roll",
)
TELEMETRY = COLUMNS.index("command_speed.pitch")
"""Columns before this one come from the rig each tick; the rest from the controller's telemetry."""
BLOCK = 1024
"""Rows per write (188 kB, 2.6 s of a 400 Hz run; a write costs ~0.2 ms of the tick that makes it)."""
HEADER = 128
"""Bytes of the .npy header, fixed so the row count can be written last (NPY format 1.0: magic, version,
header length, then a Python dict literal padded with spaces and ended by a newline)."""


def _header(rows: int) -> bytes:
    text = f"{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {len(COLUMNS)}), }}"
    text = text.ljust(HEADER - 10 - 1) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text.encode("latin1")


class TraceLog:
    def __init__(self, ticks: int, path: Path | None = None, block: int | None = None):
        self.path = path
        self.rows = 0
        self._first = 0  # the row index of the buffer's first row
        self._block = block = block or BLOCK
        self._file = None
        if path is None:
            self._buffer = np.full((ticks, len(COLUMNS)), np.nan)
        else:
            self._buffer = np.full((2 * block, len(COLUMNS)), np.nan)
            self._file = open(path, "wb")  # noqa: SIM115 (closed by close(), also on a failed run)
            self._file.write(_header(0))

    def append(self, values) -> None:
        """The rig's columns of the next tick (everything before the telemetry's)."""
        i = self.rows - self._first
        if i == len(self._buffer):
            self._write(self._block)
            i -= self._block
        self._buffer[i, :TELEMETRY] = values
        self.rows += 1

    def telemetry(self, row: int, command_speed, tilt_command) -> None:
        """The controller's telemetry for row `row`; dropped if that row is on disk already (it stays NaN:
        counted as missing telemetry)."""
        i = row - self._first
        if 0 <= i < self.rows - self._first:
            self._buffer[i, TELEMETRY:] = (*command_speed, *tilt_command)

    def last_told(self) -> bool:
        """The last row has the controller's telemetry."""
        i = self.rows - 1 - self._first
        return i >= 0 and not np.isnan(self._buffer[i, TELEMETRY])

    def _write(self, count: int) -> None:
        self._file.write(memoryview(self._buffer[:count]))
        self._buffer[: len(self._buffer) - count] = self._buffer[count:]
        self._buffer[len(self._buffer) - count :] = np.nan
        self._first += count

    def close(self) -> np.ndarray:
        """Every row: (rows, len(COLUMNS)), the file's memory map when streamed."""
        if self._file is None:
            return self._buffer[: self.rows]
        if not self._file.closed:
            self._file.write(memoryview(self._buffer[: self.rows - self._first]))
            self._file.seek(0)
            self._file.write(_header(self.rows))
            self._file.close()
        if not self.rows:
            return np.zeros((0, len(COLUMNS)))
        return np.load(self.path, mmap_mode="r")
