"""An MCAP file (mcap.dev/spec) written chunk by chunk, cheaply enough for a real-time loop.

The `mcap` package's `Writer` costs ~4.4 µs a message and ~8 ms to close a 1 MB chunk (it builds every
record, message indexes included, field by field in Python), about 90 µs a tick for run.mcap's ~16
messages a tick, measured on a 2-core machine where a lockstep tick costs 410-1200 µs. Here a message is
one `struct.pack` into the open chunk (~0.6 µs) and a channel's message index one `pack` when the chunk
closes; every other record is the package's own (`mcap.records`), and tests read the files back with its
reader, CRCs checked. Schemas and channels go into the open chunk
(a reader meets them before their messages) and again into the summary, as the package's writer does.

Memory stays flat in a file's length: the open chunk, and the schemas and channels; the summary's chunk
indexes (one per chunk) wait in a temporary file until close() copies them in.
"""

from __future__ import annotations

import struct
import tempfile
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
CHUNK = 512 << 10
"""Bytes of records per chunk before it is compressed (zstd level 1) and written: ~1.3 ms of the tick that
fills it, about every 0.45 s of a 400 Hz run (measured as above)."""
_MESSAGE = struct.Struct("<BQHIQQ")
"""A message record's head: opcode, record length, channel, sequence, log time, publish time."""
_MESSAGE_INDEX = struct.Struct("<BQHI")
"""A message index record's head: opcode, record length, channel, byte length of its (time, offset) pairs."""


def _record(record) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


class McapFile:
    """Write with `schema()`, `channel()`, `message()`, `metadata()`; `close()` writes the summary."""

    def __init__(self, path: Path, library: str, chunk_size: int = CHUNK):
        self.chunk_size = chunk_size
        self._file = open(path, "wb")  # noqa: SIM115 (closed by close())
        self._offset = 0
        self._compress: Callable[[bytes | bytearray], bytes] = zstandard.ZstdCompressor(level=1).compress
        self._chunk = bytearray()
        self._index: dict[int, list[int]] = {}
        """channel -> its messages in the open chunk, flat (log time, offset in the chunk) pairs."""
        self._schemas: list[bytes] = []
        self._channels: list[bytes] = []
        self._chunk_indexes = tempfile.TemporaryFile()  # noqa: SIM115 (closed by close())
        """The summary's chunk indexes, one per closed chunk: on disk until the summary copies them."""
        self._chunk_count = 0
        self._metadata_indexes: list[bytes] = []
        self._counts: dict[int, int] = {}
        self._start: int | None = None
        self._end: int | None = None
        """The first and last log time (ns) of the messages in closed chunks; None before the first."""
        self._write(MAGIC + _record(Header(profile="", library=library)))

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id = len(self._schemas) + 1
        record = _record(Schema(id=schema_id, data=data, encoding=encoding, name=name))
        self._schemas.append(record)
        self._chunk += record
        return schema_id

    def channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        channel_id = len(self._channels) + 1
        record = _record(
            Channel(
                id=channel_id,
                topic=topic,
                message_encoding=message_encoding,
                metadata={},
                schema_id=schema_id,
            )
        )
        self._channels.append(record)
        self._chunk += record
        self._counts[channel_id] = 0
        return channel_id

    def message(self, channel: int, time: int, data: bytes) -> None:
        """One message on `channel` at `time` (ns; log and publish time)."""
        self.messages(time, (channel,), (data,))

    def messages(self, time: int, channels: Sequence[int], messages: Sequence[bytes]) -> None:
        """Messages at one `time` (ns; log and publish time), each on its channel, in one call (a tick's
        frames)."""
        chunk, index, pack, size = self._chunk, self._index, _MESSAGE.pack, self.chunk_size
        for channel, data in zip(channels, messages, strict=True):
            pairs = index.get(channel)
            if pairs is None:
                pairs = index[channel] = []
            pairs += (time, len(chunk))
            chunk += pack(Opcode.MESSAGE, 22 + len(data), channel, 0, time, time)
            chunk += data
            if len(chunk) >= size:
                self._close_chunk()
                chunk, index = self._chunk, self._index

    def metadata(self, name: str, values: dict[str, str]) -> None:
        self._close_chunk()  # a metadata record sits between chunks
        record = _record(Metadata(name=name, metadata=values))
        self._metadata_indexes.append(
            _record(MetadataIndex(offset=self._offset, length=len(record), name=name))
        )
        self._write(record)

    def close(self) -> None:
        """The last chunk, then the summary (schemas, channels, statistics, chunk and metadata indexes, their
        offsets) and the footer: the file is complete."""
        if self._file.closed:
            return
        try:
            self._close_chunk()
            self._write(_record(DataEnd(data_section_crc=0)))
            summary_start = self._offset
            statistics = Statistics(
                attachment_count=0,
                channel_count=len(self._channels),
                channel_message_counts=self._counts,
                chunk_count=self._chunk_count,
                message_count=sum(self._counts.values()),
                message_end_time=self._end or 0,
                message_start_time=self._start or 0,
                metadata_count=len(self._metadata_indexes),
                schema_count=len(self._schemas),
            )
            self._chunk_indexes.seek(0)
            groups = (
                (Opcode.SCHEMA, self._schemas),
                (Opcode.CHANNEL, self._channels),
                (Opcode.STATISTICS, [_record(statistics)]),
                (Opcode.CHUNK_INDEX, iter(lambda: self._chunk_indexes.read(1 << 16), b"")),
                (Opcode.METADATA_INDEX, self._metadata_indexes),
            )
            crc, offsets = 0, bytearray()
            for opcode, parts in groups:
                start = self._offset
                for part in parts:
                    crc = zlib.crc32(part, crc)
                    self._write(part)
                if self._offset > start:
                    group = SummaryOffset(
                        group_opcode=opcode, group_start=start, group_length=self._offset - start
                    )
                    offsets += _record(group)
            offsets_start = self._offset
            crc = zlib.crc32(offsets, crc)
            self._write(offsets)
            crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offsets_start), crc)
            footer = Footer(summary_start=summary_start, summary_offset_start=offsets_start, summary_crc=crc)
            self._write(_record(footer) + MAGIC)
        finally:
            self._chunk_indexes.close()
            self._file.close()

    def _close_chunk(self) -> None:
        """Compress the open chunk and write it with its message indexes (a chunk without messages waits:
        its schemas and channels go with the next one, and are in the summary anyway)."""
        index = self._index
        if not index:
            return
        data = self._chunk
        start = min(min(pairs[0::2]) for pairs in index.values())
        end = max(max(pairs[0::2]) for pairs in index.values())
        compressed = self._compress(data)
        chunk = _record(
            Chunk(
                compression="zstd",
                data=compressed,
                message_end_time=end,
                message_start_time=start,
                uncompressed_crc=zlib.crc32(data),
                uncompressed_size=len(data),
            )
        )
        chunk_start = self._offset
        self._write(chunk)
        indexes, offsets, at = [], {}, self._offset
        for channel, pairs in index.items():
            record = _MESSAGE_INDEX.pack(Opcode.MESSAGE_INDEX, 6 + 8 * len(pairs), channel, 8 * len(pairs))
            record += struct.pack(f"<{len(pairs)}Q", *pairs)
            offsets[channel] = at
            at += len(record)
            indexes.append(record)
            self._counts[channel] += len(pairs) // 2
        self._write(b"".join(indexes))
        self._chunk_count += 1
        self._chunk_indexes.write(
            _record(
                ChunkIndex(
                    chunk_length=len(chunk),
                    chunk_start_offset=chunk_start,
                    compression="zstd",
                    compressed_size=len(compressed),
                    message_end_time=end,
                    message_index_length=at - (chunk_start + len(chunk)),
                    message_index_offsets=offsets,
                    message_start_time=start,
                    uncompressed_size=len(data),
                )
            )
        )
        self._start = start if self._start is None else min(self._start, start)
        self._end = end if self._end is None else max(self._end, end)
        self._chunk = bytearray()
        self._index = {}

    def _write(self, data: bytes | bytearray) -> None:
        self._file.write(data)
        self._offset += len(data)
