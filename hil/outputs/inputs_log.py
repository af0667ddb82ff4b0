"""What the controller was told over zenoh, (tick, key, payload) in the order it could see them: the run
folder's zenoh_inputs.msgpack, which `pure-hil replay` replays.

With a run folder the log streams to disk as the run goes (memory stays flat over hours): the file is one
msgpack array whose 32-bit length is written last, so it stays a single msgpack document that any msgpack
reader decodes at once. Without a folder the entries stay in memory (`entries`).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path

import msgspec

ARRAY32 = b"\xdd"
"""msgpack's array header with a 32-bit big-endian length (msgpack spec, "array 32")."""


class InputsLog:
    def __init__(self, path: Path | None = None, also: Callable[[int, str, bytes], None] | None = None):
        """also: handed every entry too, as it is logged (the run's MCAP)."""
        self.path = path
        self.also = also
        self.entries: list[tuple[int, str, bytes]] = []
        """In memory only (no path)."""
        self.count = 0
        self._encode = msgspec.msgpack.Encoder().encode
        self._file = None
        if path is not None:
            self._file = open(path, "wb")  # noqa: SIM115 (closed by close(), also on a failed run)
            self._file.write(ARRAY32 + struct.pack(">I", 0))

    def append(self, tick: int, key: str, data: bytes) -> None:
        self.count += 1
        if self.also is not None:
            self.also(tick, key, data)
        if self._file is None:
            self.entries.append((tick, key, data))
        else:
            self._file.write(self._encode((tick, key, data)))

    def close(self) -> None:
        """Write the array's length: the file is complete (called once the run's inputs are all in)."""
        if self._file is None or self._file.closed:
            return
        self._file.seek(1)
        self._file.write(struct.pack(">I", self.count))
        self._file.close()
