"""An MCAP writer whose memory does not grow with the file: the chunk index is kept on disk.

The recorder closes a chunk at every flush (every 2 s: what a crash may lose), some 43,000
chunks in a day's file. A finished file indexes every chunk in its summary, so a reader
(Foxglove, mcap's indexed reader) can seek by time; `mcap.writer.Writer` keeps those
entries as Python objects until the file is finished, about 0.6 kB each: 1.1 MB of
memory an hour, for months. This writer appends each chunk's index record, as it will
stand in the summary, to an unnamed temporary file beside the log (gone with the process
if it dies, about 120 bytes a chunk) and copies it into the summary piece by piece when the
file is finished. Everything else is as `mcap.writer.Writer` writes it (zstd chunks,
message indexes, schemas and channels repeated in the summary, statistics, CRCs of chunks
and summary): the files read the same with mcap's reader and with hermsd's own.
"""

from __future__ import annotations

import struct
import tempfile
import zlib
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import BinaryIO, Final

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
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
COPY_PIECE: Final = 64 * 1024  # the chunk index copied into the summary this much at a time
_FOOTER_HEAD = struct.Struct("<BQQQ")  # opcode, length, summary start, summary offset start


class LogWriter:
    """Writes one MCAP file to `stream`; chunks close at `flush` or past `chunk_size` bytes.

    `spill` makes the temporary file the chunk index waits in (the default: an unnamed one
    in `directory`), at the first chunk.
    """

    def __init__(
        self,
        stream: BinaryIO,
        directory: Path,
        *,
        chunk_size: int,
        spill: Callable[[Path], BinaryIO] | None = None,
    ) -> None:
        self._stream = stream
        self._chunk_size = chunk_size
        self._directory = directory
        self._spill = spill or _unnamed_file
        self._index: BinaryIO | None = None  # made at the first chunk: a failure is a write's
        self._index_size = 0
        self._compressor = zstandard.ZstdCompressor()
        self._chunk = RecordBuilder()
        self._chunk_messages: dict[int, list[tuple[int, int]]] = {}  # channel → (time, offset)
        self._chunk_start_time = self._chunk_end_time = 0
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._metadata_indexes: list[MetadataIndex] = []  # one per config record: a few
        self._statistics = Statistics(
            message_count=0,
            schema_count=0,
            channel_count=0,
            attachment_count=0,
            metadata_count=0,
            chunk_count=0,
            message_start_time=0,
            message_end_time=0,
            channel_message_counts={},
        )

    def start(self, profile: str, library: str) -> None:
        self._stream.write(MCAP_MAGIC)
        self._write_record(Header(profile=profile, library=library))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._statistics.schema_count += 1
        self._add_to_chunk(schema)
        return schema.id

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: dict[str, str] | None = None,
    ) -> int:
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=metadata or {},
        )
        self._channels.append(channel)
        self._statistics.channel_count += 1
        self._add_to_chunk(channel)
        return channel.id

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int
    ) -> None:
        stats = self._statistics
        if stats.message_count == 0:
            stats.message_start_time = stats.message_end_time = log_time
        stats.message_start_time = min(stats.message_start_time, log_time)
        stats.message_end_time = max(stats.message_end_time, log_time)
        stats.message_count += 1
        counts = stats.channel_message_counts
        counts[channel_id] = counts.get(channel_id, 0) + 1
        if not self._chunk_messages:
            self._chunk_start_time = self._chunk_end_time = log_time
        self._chunk_start_time = min(self._chunk_start_time, log_time)
        self._chunk_end_time = max(self._chunk_end_time, log_time)
        offsets = self._chunk_messages.setdefault(channel_id, [])
        offsets.append((log_time, self._chunk.count))
        message = Message(channel_id, log_time, data, publish_time, sequence)
        self._add_to_chunk(message)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record, written at once outside chunks (and indexed in the summary)."""
        offset = self._stream.tell()
        length = self._write_record(Metadata(name=name, metadata=data))
        self._statistics.metadata_count += 1
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))

    def flush(self) -> None:
        """Close the open chunk (if it holds a message) and hand everything to the OS."""
        self._close_chunk()
        self._stream.flush()

    def finish(self) -> None:
        """Write the last chunk, the summary and the footer (the stream stays open)."""
        self._close_chunk()
        self._write_record(DataEnd(data_section_crc=0))
        summary_start = self._stream.tell()
        written = crc = 0
        offsets: list[SummaryOffset] = []

        def put(piece: bytes) -> None:
            nonlocal written, crc
            self._stream.write(piece)
            crc = zlib.crc32(piece, crc)
            written += len(piece)

        def group(opcode: Opcode, pieces: Iterable[bytes]) -> None:
            start = written
            for piece in pieces:
                put(piece)
            offsets.append(SummaryOffset(opcode, summary_start + start, written - start))

        group(Opcode.SCHEMA, [_records(self._schemas)])
        group(Opcode.CHANNEL, [_records(self._channels)])
        group(Opcode.STATISTICS, [_records([self._statistics])])
        index = self._index
        if index is not None:
            index.seek(0)
            group(Opcode.CHUNK_INDEX, iter(lambda: index.read(COPY_PIECE), b""))
        if self._metadata_indexes:
            group(Opcode.METADATA_INDEX, [_records(self._metadata_indexes)])
        summary_offset_start = summary_start + written
        put(_records(offsets))
        head = _FOOTER_HEAD.pack(Opcode.FOOTER, 20, summary_start, summary_offset_start)
        self._write_record(Footer(summary_start, summary_offset_start, zlib.crc32(head, crc)))
        self._stream.write(MCAP_MAGIC)
        self.close_index()

    def close_index(self) -> None:
        """Let the temporary chunk index go (at the end, or when the file is abandoned)."""
        if self._index is not None:
            self._index.close()

    def _add_to_chunk(self, record: Schema | Channel | Message) -> None:
        record.write(self._chunk)
        if self._chunk.count > self._chunk_size:
            self._close_chunk()

    def _close_chunk(self) -> None:
        if not self._chunk_messages:
            return  # schemas and channels wait for the first message
        records: bytes = self._chunk.end()  # type: ignore[no-untyped-call]
        compressed = self._compressor.compress(records)
        chunk = Chunk(
            compression="zstd",
            data=compressed,
            message_start_time=self._chunk_start_time,
            message_end_time=self._chunk_end_time,
            uncompressed_crc=zlib.crc32(records),
            uncompressed_size=len(records),
        )
        chunk_start = self._stream.tell()
        chunk_length = self._write_record(chunk)
        builder = RecordBuilder()
        index_offsets: dict[int, int] = {}
        for channel_id, entries in self._chunk_messages.items():
            index_offsets[channel_id] = chunk_start + chunk_length + builder.count
            MessageIndex(channel_id=channel_id, records=entries).write(builder)
        indexes: bytes = builder.end()  # type: ignore[no-untyped-call]
        self._stream.write(indexes)
        entry = ChunkIndex(
            message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time,
            chunk_start_offset=chunk_start,
            chunk_length=chunk_length,
            message_index_offsets=index_offsets,
            message_index_length=len(indexes),
            compression=chunk.compression,
            compressed_size=len(compressed),
            uncompressed_size=chunk.uncompressed_size,
        )
        spilled = _records([entry])
        if self._index is None:
            self._index = self._spill(self._directory)
        self._index.write(spilled)
        self._index_size += len(spilled)
        self._statistics.chunk_count += 1
        self._chunk_messages = {}

    def _write_record(self, record: McapRecord) -> int:
        """Write one record outside chunks; its length in bytes."""
        data = _records([record])
        self._stream.write(data)
        return len(data)


def _records(records: Sequence[McapRecord]) -> bytes:
    builder = RecordBuilder()
    for record in records:
        record.write(builder)
    data: bytes = builder.end()  # type: ignore[no-untyped-call]
    return data


def _unnamed_file(directory: Path) -> BinaryIO:
    """A temporary file in `directory` that no name points to: nothing is left if we die."""
    return tempfile.TemporaryFile(dir=directory)
