"""Reading a flight recorder's MCAP files, damaged or cut, and recovering the `.part` a crash left.

Apart from the recorder, which writes: a reader reads without the library's index (a cut
file has none), record by record, and skips what it cannot read, saying so."""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import os
import struct
import zlib
from collections.abc import Callable, Collection, Iterable, Iterator
from pathlib import Path
from typing import Any, Final, NamedTuple

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Header, McapRecord, Message, Metadata, Schema

from hermsd.files import fsync_directory
from hermsd.log.mcap_writer import MCAP_MAGIC, LogWriter
from hermsd.log.topics import (
    CHANNELS_METADATA_NAME,
    CHUNK_SIZE,
    FILE_PREFIX,
    LIBRARY,
    PART_SUFFIX,
    RECOVERY_METADATA_NAME,
    TOPICS,
)


class RecordedMessage(NamedTuple):
    topic: str
    log_time_ns: int
    message: dict[str, Any]


class Damage(NamedTuple):
    """Part of a file that could not be read and was skipped; the records after it were read.

    `messages` is how many messages were lost with it, when that is known (a damaged chunk's
    message indexes say how many it held).
    """

    what: str  # "chunk at byte 1234", "bytes 1234 to 5678", "the summary"
    reason: str
    messages: int | None = None

    def describe(self) -> str:
        if self.messages is None:
            lost = ""
        else:
            lost = f" ({self.messages or 'no'} message{'' if self.messages == 1 else 's'} lost)"
        return f"{self.what} damaged ({self.reason}), skipped{lost}"


_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length of the body


_CHANNEL_HEAD = struct.Struct("<HHI")  # id, schema id, length of the topic


_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


_MESSAGE_INDEX_HEAD = struct.Struct("<HI")  # channel id, length of its (time, offset) pairs


_MESSAGE_INDEX_ENTRY_SIZE: Final = 16


_UINT32 = struct.Struct("<I")


_OP_HEADER: Final = 0x01


_OP_FOOTER: Final = 0x02


_OP_SCHEMA: Final = 0x03


_OP_CHANNEL: Final = 0x04


_OP_MESSAGE: Final = 0x05


_OP_CHUNK: Final = 0x06


_OP_MESSAGE_INDEX: Final = 0x07


_OP_METADATA: Final = 0x0C


_OP_DATA_END: Final = 0x0F


_OP_LAST_DEFINED: Final = 0x0F  # opcodes 0x10 to 0x7f are reserved; 0x80 and up are private


_OP_PRIVATE: Final = 0x80


_COPIED_OUTSIDE_CHUNKS: Final = (_OP_HEADER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_METADATA)


def _sift_chunk(
    data: bytes,
    channels: dict[int, str | None],
    topics: Collection[str] | None,
    into: list[tuple[int, int, str, bytes]],
    orphans: list[tuple[int, int, bytes]],
) -> int:
    """Add (log time, order, topic, data) of a run's messages on wanted topics to `into`.

    Channels defined in the run are added to `channels` (None for a topic not wanted), so
    the other messages are skipped unread (parsing by hand costs a fraction of building
    every record). A message on a channel not defined yet (its definition was in a damaged
    chunk) goes to `orphans` as (channel id, log time, data). Returns how many messages the
    run holds on any topic.
    """
    position, end, messages = 0, len(data), 0
    while position < end:
        opcode, length = _RECORD_HEAD.unpack_from(data, position)
        body = position + _RECORD_HEAD.size
        position = body + length
        if position > end:
            raise ValueError("a record runs past the end of its chunk")
        if opcode == _OP_MESSAGE:
            messages += 1
            channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack_from(data, body)
            topic = channels.get(channel_id)
            if topic is not None:
                into.append(
                    (log_time, len(into), topic, data[body + _MESSAGE_HEAD.size : position])
                )
            elif channel_id not in channels:
                orphans.append((channel_id, log_time, data[body + _MESSAGE_HEAD.size : position]))
        elif opcode == _OP_CHANNEL:
            channel_id, _, topic_length = _CHANNEL_HEAD.unpack_from(data, body)
            start = body + _CHANNEL_HEAD.size
            topic = data[start : start + topic_length].decode()
            (encoding_length,) = _UINT32.unpack_from(data, start + topic_length)
            encoding = data[start + topic_length + 4 : start + topic_length + 4 + encoding_length]
            wanted = encoding == b"json" and (topics is None or topic in topics)
            channels.setdefault(channel_id, topic if wanted else None)
    return messages


_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, summary offset start, CRC


_FOOTER_LENGTH: Final = _FOOTER.size - _RECORD_HEAD.size


_FOOTER_CRC_SIZE: Final = 4  # the CRC covers the footer up to, not including, itself


def _is_finished(path: Path) -> bool:
    """Whether `path` ends with a footer and a whole summary (it was closed properly).

    The summary is checked against the CRC in the footer, not parsed: it indexes every chunk,
    tens of thousands of records for a day logged a chunk per flush.
    """
    tail_size = _FOOTER.size + len(MCAP_MAGIC)
    try:
        with path.open("rb") as f:
            size = f.seek(0, os.SEEK_END)
            if size < len(MCAP_MAGIC) + tail_size:
                return False
            f.seek(0)
            head = f.read(len(MCAP_MAGIC))
            footer_at = f.seek(size - tail_size)
            tail = f.read(tail_size)
            opcode, length, summary_start, _, summary_crc = _FOOTER.unpack_from(tail)
            if (
                head != MCAP_MAGIC
                or tail[_FOOTER.size :] != MCAP_MAGIC
                or (opcode, length) != (_OP_FOOTER, _FOOTER_LENGTH)
                or not len(MCAP_MAGIC) <= summary_start < footer_at  # 0: no summary
            ):
                return False
            if summary_crc == 0:  # written without CRCs
                return True
            f.seek(summary_start)
            covered = f.read(footer_at - summary_start + _FOOTER.size - _FOOTER_CRC_SIZE)
            return zlib.crc32(covered) == int(summary_crc)
    except OSError:
        return False


_CHUNK_HEAD = struct.Struct("<16xQII")  # (times,) uncompressed size and CRC, name length


_LENGTH = struct.Struct("<Q")


_DATA_END = struct.Struct("<I")  # CRC of the data section


# A zstd chunk, as hermsd writes them, has its compression's name this far into the record:
# opcode and length (9 bytes), start and end time (16), size (8) and CRC (4) of its records.
_ZSTD_NAME: Final = _UINT32.pack(4) + b"zstd"


_ZSTD_NAME_AT: Final = _RECORD_HEAD.size + _CHUNK_HEAD.size - _UINT32.size


class _Damaged(Exception):
    """A record that cannot be read whole."""


class _Walk:
    """The readable records of an MCAP file, as runs of records for `_sift_chunk`.

    A chunk's run is its records, decompressed, yielded only if they match the chunk's size
    and CRC; a header, schema, channel, message or metadata record outside chunks is a run of
    its own; other records are skipped by their length, unread. A damaged chunk is skipped
    (`damaged` says where and why) and reading goes on after it: at its end, when a record
    plausibly starts there, else at the next zstd chunk further on. Where no readable record
    follows, the file is cut: `cut_at` says where, `cut_reason` why (None: the file simply
    ended there). After the data section only channel and schema records are yielded (the
    summary repeats them: the definitions a damaged first chunk took with it).
    Reading by hand costs a fraction of what mcap's StreamReader does (an object for each of
    the chunks, message indexes and chunk indexes of a day, a decompressor per chunk).
    """

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.cut_at: int | None = None
        self.cut_reason: str | None = None
        self.damaged: list[Damage] = []
        self.footer_read = False
        self.metadata: dict[str, dict[str, str]] = {}  # by name, a later record winning
        self.messages_found = False  # a whole chunk, or a message outside chunks, was read
        self._resume_at = 0  # where `_resume_after` found readable records again

    def runs(self) -> Iterator[bytes]:
        data = self.data
        if not data.startswith(MCAP_MAGIC):
            self.cut_at, self.cut_reason = 0, "the file does not start with the MCAP magic"
            return
        view = memoryview(data)
        decompressor = zstandard.ZstdDecompressor()
        position, size = len(MCAP_MAGIC), len(data)
        in_summary = False
        skipped_chunk: int | None = None  # index in `damaged` of a chunk just skipped
        head = _RECORD_HEAD
        while position < size:
            body = position + head.size
            opcode, end = head.unpack_from(data, position) if body <= size else (0, 0)
            end += body
            if end > size or opcode == 0 or _OP_LAST_DEFINED < opcode < _OP_PRIVATE:
                try:
                    self._record_at(position)  # for the reason
                except _Damaged as exc:
                    if not self._resume_after(position, str(exc), in_summary):
                        return
                position = self._resume_at
                continue
            if opcode == _OP_MESSAGE_INDEX:  # the commonest record: several after each chunk
                if skipped_chunk is not None:
                    damage = self.damaged[skipped_chunk]
                    lost = (end - body - _MESSAGE_INDEX_HEAD.size) // _MESSAGE_INDEX_ENTRY_SIZE
                    counted = (damage.messages or 0) + lost
                    self.damaged[skipped_chunk] = damage._replace(messages=counted)
                position = end
                continue
            skipped_chunk = None
            if opcode == _OP_CHUNK:
                try:
                    records = _chunk_records(view[body:end], decompressor)
                except (_Damaged, zstandard.ZstdError, struct.error) as exc:
                    reason = _describe(exc)
                    if not self._follows_a_record(end):
                        if not self._resume_after(position, reason, in_summary):
                            return
                        position = self._resume_at
                        continue
                    skipped_chunk = len(self.damaged)
                    self.damaged.append(Damage(f"chunk at byte {position}", reason, 0))
                else:
                    self.messages_found = True
                    yield records
            elif opcode in _COPIED_OUTSIDE_CHUNKS:
                if not in_summary or opcode in (_OP_SCHEMA, _OP_CHANNEL):
                    if opcode == _OP_METADATA:
                        self._note_metadata(view[body:end])
                    self.messages_found |= opcode == _OP_MESSAGE
                    yield data[position:end]
            elif opcode == _OP_DATA_END:
                (crc,) = _DATA_END.unpack_from(view[body:end])
                if crc != 0 and zlib.crc32(view[:position]) != crc:
                    self.cut_at, self.cut_reason = (
                        position,
                        "the data section does not match its CRC",
                    )
                    return
                in_summary = True
            elif opcode == _OP_FOOTER:
                if data[end : end + len(MCAP_MAGIC)] != MCAP_MAGIC:
                    self.cut_at = end  # the footer was whole
                    self.cut_reason = "the footer is not followed by the MCAP magic"
                    return
                self.footer_read = True
                return
            position = end

    def _record_at(self, position: int) -> tuple[int, int, int]:
        """(opcode, start of body, end) of the record at `position`; _Damaged if none is."""
        size = len(self.data)
        if position + _RECORD_HEAD.size > size:
            raise _Damaged("the file ends inside a record")
        opcode, length = _RECORD_HEAD.unpack_from(self.data, position)
        if opcode == 0 or _OP_LAST_DEFINED < opcode < _OP_PRIVATE:
            raise _Damaged(f"no record starts there (opcode {opcode:#04x})")
        body = position + _RECORD_HEAD.size
        if body + length > size:
            raise _Damaged("the file ends inside a record")
        return opcode, body, body + length

    def _follows_a_record(self, position: int) -> bool:
        """Whether the end of a damaged chunk is plausibly the start of the next record."""
        if position == len(self.data):
            return True
        try:
            opcode, body, end = self._record_at(position)
        except _Damaged:
            return False
        if opcode == _OP_MESSAGE_INDEX:
            if end - body < _MESSAGE_INDEX_HEAD.size:
                return False
            _, pairs = _MESSAGE_INDEX_HEAD.unpack_from(self.data, body)
            return bool(end - body == _MESSAGE_INDEX_HEAD.size + pairs)
        if opcode == _OP_DATA_END:
            return end - body == _DATA_END.size
        return bool(opcode in (_OP_CHUNK, _OP_METADATA))

    def _resume_after(self, position: int, reason: str, in_summary: bool) -> bool:
        """Find where to read on after unreadable bytes at `position`; False: nowhere (a cut).

        In the summary nothing more is needed: its damage is noted and reading stops.
        """
        if in_summary:
            self.damaged.append(Damage(f"the summary at byte {position}", reason, 0))
            return False
        found = self.data.find(_ZSTD_NAME, position + 1 + _ZSTD_NAME_AT)
        while found != -1:
            start = found - _ZSTD_NAME_AT
            try:
                opcode, _, _ = self._record_at(start)
            except _Damaged:
                opcode = 0
            if opcode == _OP_CHUNK:
                self.damaged.append(Damage(f"bytes {position} to {start}", reason))
                self._resume_at = start
                return True
            found = self.data.find(_ZSTD_NAME, found + 1)
        self.cut_at, self.cut_reason = position, reason
        return False

    def _note_metadata(self, body: memoryview) -> None:
        try:
            name, values = _metadata(bytes(body))
        except (struct.error, UnicodeDecodeError, ValueError, EOFError):
            return
        self.metadata[name] = values

    @property
    def channel_topics(self) -> dict[int, str]:
        """Channel id → topic, from the hermsd.channels metadata (none in older files)."""
        named = self.metadata.get(CHANNELS_METADATA_NAME, {})
        return {int(key): topic for key, topic in named.items() if key.isdigit()}


def _metadata(body: bytes) -> tuple[str, dict[str, str]]:
    """The name and the key-value pairs of a metadata record's body."""
    stream = ReadDataStream(io.BytesIO(body))
    record = Metadata.read(stream)
    return record.name, dict(record.metadata)


def _chunk_records(chunk: memoryview, decompressor: zstandard.ZstdDecompressor) -> bytes:
    """The records in a chunk's body, decompressed; _Damaged unless they match its size and CRC."""
    size, crc, name_length = _CHUNK_HEAD.unpack_from(chunk)
    name_end = _CHUNK_HEAD.size + name_length
    compression = bytes(chunk[_CHUNK_HEAD.size : name_end])
    (length,) = _LENGTH.unpack_from(chunk, name_end)
    start = name_end + _LENGTH.size
    if start + length != len(chunk):
        raise _Damaged("a chunk's records do not fill it")
    compressed = chunk[start : start + length]
    if compression == b"zstd":
        records = decompressor.decompress(compressed, max_output_size=size)
    elif compression == b"":
        records = bytes(compressed)
    else:
        raise _Damaged(f"chunks compressed with {compression!r} are not supported")
    if len(records) != size:
        raise _Damaged(f"a chunk holds {len(records)} bytes, not the {size} it declares")
    if crc != 0 and zlib.crc32(records) != crc:
        raise _Damaged("a chunk does not match its CRC")
    return records


class LogFile:
    """One hermsd MCAP file, finished or cut short, read in log-time order.

    Every file is read record by record up to its end or its cut, a finished one too (its
    index would only say where the same chunks are). After `messages()` has run, `count`
    says how many messages it yielded, `recovered` how many its readable records hold on
    any topic, `damaged` which parts were skipped and why (reading went on after them) and,
    unless the file was finished and read whole, `cut_at` up to which byte it held readable
    records and `cut_reason` why the next one could not be read (None: the file simply
    ended there).
    """

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.finished = _is_finished(self.path)
        self.count = 0
        self.recovered = 0
        self.cut_at: int | None = None
        self.cut_reason: str | None = None
        self.damaged: list[Damage] = []
        self.metadata_read: dict[str, dict[str, str]] = {}  # by `messages()`, as `metadata()`
        self.size = self.path.stat().st_size

    def messages(self, topics: Collection[str] | None = None) -> Iterator[RecordedMessage]:
        """The messages in log-time order; only those on `topics`, when given, are decoded.

        ValueError: the file holds records that pass their CRC but cannot be decoded.
        """
        self.count = self.recovered = 0
        channels: dict[int, str | None] = {}
        pending: list[tuple[int, int, str, bytes]] = []
        orphans: list[tuple[int, int, bytes]] = []
        content = self.path.read_bytes()  # tens of MB for a day: read at once, walked by hand
        self.size = len(content)  # a file being written may have grown since it was opened
        walk = _Walk(content)
        try:
            for run in walk.runs():
                self.recovered += _sift_chunk(run, channels, topics, pending, orphans)
        except (struct.error, UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f"{self.path}: damaged MCAP data: {_describe(exc)}") from exc
        self.damaged = walk.damaged
        self.metadata_read = walk.metadata
        unknown = 0
        channel_topics = walk.channel_topics
        for channel_id, log_time, data in orphans:  # their channel was in a damaged chunk
            topic = channels.get(channel_id) or channel_topics.get(channel_id)
            if topic is None and channel_id not in channels:
                unknown += 1
            elif topic is not None and (topics is None or topic in topics):
                pending.append((log_time, len(pending), topic, data))
        if unknown:
            reason = "their channel was defined in a damaged chunk"
            self.damaged.append(Damage(f"{unknown} messages", reason))
        if walk.footer_read and not self.finished:
            self.damaged.append(Damage("the summary", "it does not match its CRC", 0))
        if not (self.finished and walk.cut_at is None):
            self.cut_at = self.size if walk.cut_at is None else walk.cut_at
            self.cut_reason = walk.cut_reason
        pending.sort()
        for log_time, _, topic, data in pending:
            try:
                message = json.loads(data)
            except ValueError as exc:
                raise ValueError(f"{self.path}: a message is not JSON: {exc}") from exc
            self.count += 1
            yield RecordedMessage(topic, log_time, message)

    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records by name (a later record of the same name wins)."""
        walk = _Walk(self.path.read_bytes())
        for _ in walk.runs():
            pass
        return walk.metadata


def read_messages(paths: Iterable[Path | str]) -> Iterator[RecordedMessage]:
    """Every message of `paths`, file after file, each file in log-time order."""
    for path in paths:
        yield from LogFile(path).messages()


def _records(runs: Iterable[bytes]) -> Iterator[McapRecord]:
    """The header, schema, channel, message and metadata records of runs, as mcap's objects."""
    readers: dict[int, Callable[[ReadDataStream, int], McapRecord]] = {
        _OP_HEADER: lambda stream, _: Header.read(stream),
        _OP_SCHEMA: lambda stream, _: Schema.read(stream),
        _OP_CHANNEL: lambda stream, _: Channel.read(stream),
        _OP_MESSAGE: Message.read,
        _OP_METADATA: lambda stream, _: Metadata.read(stream),
    }
    for run in runs:
        position = 0
        while position < len(run):
            opcode, length = _RECORD_HEAD.unpack_from(run, position)
            body = position + _RECORD_HEAD.size
            position = body + length
            reader = readers.get(opcode)
            if reader is not None:
                yield reader(ReadDataStream(io.BytesIO(run[body:position])), length)


class NotRecovered(ValueError):
    """No log was made from a `.part` (no message in it could be read): it is left as it is."""

    def __init__(self, part: Path, why: str) -> None:
        super().__init__(f"{why}; left as it is, no log made from it")
        self.part = part


class Recovery(NamedTuple):
    """What `recover` made of a `.part`: the brewer is told how much of it was kept."""

    path: Path
    source: str  # the .part's name
    messages: int
    source_bytes: int
    complete_bytes: int  # up to where its records could be read (the rest is lost)
    damaged: tuple[Damage, ...]

    def describe(self) -> str:
        if self.complete_bytes == self.source_bytes:
            read = f"read to the end of its {self.source_bytes} bytes"
        else:
            read = f"read to byte {self.complete_bytes} of its {self.source_bytes} (the rest lost)"
        damaged = "".join(f"; {damage.describe()}" for damage in self.damaged)
        return f"{self.path} from {self.source}: {self.messages} messages, {read}{damaged}"


def recover(path: Path | str) -> Recovery:
    """Turn a leftover `.mcap.part` into a finished `.mcap` holding every readable record.

    Damaged chunks are skipped (said in the recovery metadata and the returned Recovery),
    not the rest of the file. The new file is written beside it, synced and renamed into
    place before the `.part` is removed, so an interruption at any point leaves the data on
    disk (a rerun redoes it). NotRecovered, the `.part` untouched, when no message in it can
    be read: its bytes may still be worth a look, and an empty log in their place says
    nothing. Call it before a Recorder starts writing in the same directory.
    """
    part = Path(path)
    if not part.name.endswith(".mcap" + PART_SUFFIX):
        raise ValueError(f"recover: {part} is not a .mcap.part file")
    final = part.with_name(part.name.removesuffix(PART_SUFFIX))
    temporary = part.with_name(final.name + ".recovering")
    data = part.read_bytes()
    walk = _Walk(data)
    try:
        with temporary.open("wb") as target:
            writer = LogWriter(target, final.parent, chunk_size=CHUNK_SIZE)
            try:
                kept = _copy_records(_records(walk.runs()), writer, lambda: walk.channel_topics)
            except (struct.error, UnicodeDecodeError, ValueError, EOFError) as exc:
                raise NotRecovered(part, f"damaged MCAP data: {_describe(exc)}") from exc
            if not kept:
                why = "" if walk.cut_reason is None else f" ({walk.cut_reason})"
                raise NotRecovered(part, f"no message readable in its {len(data)} bytes{why}")
            complete = len(data) if walk.cut_at is None else walk.cut_at
            writer.add_metadata(
                RECOVERY_METADATA_NAME,
                {
                    "source": part.name,
                    "messages": str(kept),
                    "source_bytes": str(len(data)),
                    "complete_bytes": str(complete),
                    "cut": "no" if walk.cut_reason is None else walk.cut_reason,
                    "damaged": "; ".join(d.describe() for d in walk.damaged) or "no",
                },
            )
            writer.finish()
            target.flush()
            os.fsync(target.fileno())
        os.replace(temporary, final)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink(missing_ok=True)
        raise
    fsync_directory(final.parent)
    part.unlink()
    fsync_directory(final.parent)
    return Recovery(final, part.name, kept, len(data), complete, tuple(walk.damaged))


def recover_directory(directory: Path | str) -> list[Recovery | NotRecovered]:
    """Recover every leftover `.mcap.part` of the recorder in `directory`, oldest first.

    A `.part` with nothing readable stays as it is (its NotRecovered says why) and the
    others are still recovered. Disk errors propagate (the `.part` files stay for the next
    attempt).
    """
    outcomes: list[Recovery | NotRecovered] = []
    for part in sorted(Path(directory).glob(f"{FILE_PREFIX}*.mcap{PART_SUFFIX}")):
        try:
            outcomes.append(recover(part))
        except NotRecovered as error:
            outcomes.append(error)
    return outcomes


def _copy_records(
    records: Iterator[McapRecord], writer: LogWriter, channel_topics: Callable[[], dict[int, str]]
) -> int:
    """Write the schemas, channels, messages and metadata of `records` again; count messages.

    Schemas and channels repeated in a summary section are written once. A message whose
    channel was defined in a damaged chunk is kept when the summary defines it again, or
    when `channel_topics()` (hermsd's own metadata, once all is read) names one of
    hermsd's topics for it.
    """
    first = next(records, None)
    if isinstance(first, Header):
        writer.start(first.profile, first.library)
    else:
        writer.start("", LIBRARY)
        if first is not None:
            records = itertools.chain([first], records)
    schema_ids: dict[int, int] = {0: 0}
    channel_ids: dict[int, int] = {}
    orphans: list[Message] = []
    kept = 0
    for record in records:
        if isinstance(record, Schema) and record.id not in schema_ids:
            schema_ids[record.id] = writer.register_schema(
                record.name, record.encoding, record.data
            )
        elif (
            isinstance(record, Channel)
            and record.id not in channel_ids
            and record.schema_id in schema_ids
        ):
            channel_ids[record.id] = writer.register_channel(
                record.topic, record.message_encoding, schema_ids[record.schema_id], record.metadata
            )
        elif isinstance(record, Message):
            if record.channel_id in channel_ids:
                _copy_message(writer, channel_ids[record.channel_id], record)
                kept += 1
            else:
                orphans.append(record)
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, record.metadata)
    topics = channel_topics()
    for record in orphans:
        if record.channel_id not in channel_ids:
            spec = TOPICS.get(topics.get(record.channel_id, ""))
            if spec is None:
                continue
            schema = writer.register_schema(spec.schema_name, "jsonschema", spec.schema_bytes())
            topic = topics[record.channel_id]
            channel_ids[record.channel_id] = writer.register_channel(topic, "json", schema)
        _copy_message(writer, channel_ids[record.channel_id], record)
        kept += 1
    return kept


def _copy_message(writer: LogWriter, channel_id: int, record: Message) -> None:
    writer.add_message(
        channel_id, record.log_time, record.data, record.publish_time, record.sequence
    )


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror  # the file is named by the caller, once
    return str(exc) or type(exc).__name__
