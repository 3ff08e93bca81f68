"""Reading one MCAP file record by record, with byte offsets for every failure.

The mcap library's readers are built for well-formed files; a recording cut short by a
crash or a full disk has no summary and ends in the middle of a record. This module reads
such files as far as they go: an indexed file (with a summary and chunk indexes) is read
chunk by chunk in log-time order, anything else linearly in file order, and a break in
either raises BagError naming the file, the byte offset of the broken record, and how
many messages were read before it. Memory stays bounded by one or a few chunks.
"""

from __future__ import annotations

import heapq
import io
import struct
from collections.abc import Callable, Collection, Iterator
from pathlib import Path
from typing import Any, BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, ChunkIndex, Message, Schema
from mcap.stream_reader import breakup_chunk
from mcap.summary import Summary

from artcal_ros.core.errors import BagError

MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, payload length
SQLITE_MAGIC = b"SQLite format 3\x00"

MessageTuple = tuple[Schema | None, Channel, Message]


def _opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"unknown opcode 0x{opcode:02x}"


class McapFile:
    """One open MCAP file: its summary (if readable) and lazy message iteration.

    Args:
        path: the .mcap file.

    Raises:
        BagError: the file cannot be opened or does not start with the MCAP magic bytes.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self._fh: BinaryIO = open(path, "rb")  # noqa: SIM115 - closed by close()
        except OSError as err:
            raise BagError(f"{path}: cannot open: {err.strerror or err}") from err
        self.size = path.stat().st_size
        head = self._fh.read(len(MAGIC))
        if head != MAGIC:
            self._fh.close()
            if head.startswith(SQLITE_MAGIC[: len(head)]) and len(head) == len(MAGIC):
                raise BagError(
                    f"{path}: this is an sqlite3 bag file; artcal reads MCAP bags only. "
                    "Convert it with `ros2 bag convert` (storage_id: mcap) or record with "
                    "`ros2 bag record -s mcap`"
                )
            raise BagError(
                f"{path}: not an MCAP file (the first {len(head)} bytes are {head!r}, "
                f"expected {MAGIC!r})"
            )
        self.summary, self.summary_problem = self._read_summary()

    def close(self) -> None:
        self._fh.close()

    # -- summary ---------------------------------------------------------------------------

    def _read_summary(self) -> tuple[Summary | None, str]:
        """The summary section, or None and why it is not usable."""
        if self.size < 2 * len(MAGIC) + 1:
            return None, "the file is too short to hold a footer"
        self._fh.seek(-len(MAGIC), io.SEEK_END)
        if self._fh.read(len(MAGIC)) != MAGIC:
            return None, "the file does not end with the MCAP magic (truncated, or still open)"
        try:
            self._fh.seek(0)
            summary = SeekingReader(self._fh).get_summary()
        except Exception as err:  # a corrupt footer can fail in many ways; fall back
            return None, f"its summary section is unreadable ({err})"
        if summary is None:
            return None, "it has no summary section"
        return summary, ""

    def channels(self) -> dict[int, tuple[Channel, Schema | None]]:
        """Every channel with its schema, from the summary or, without one, a scan."""
        if self.summary is not None and self.summary.channels:
            return {
                cid: (ch, self.summary.schemas.get(ch.schema_id))
                for cid, ch in self.summary.channels.items()
            }
        found: dict[int, tuple[Channel, Schema | None]] = {}
        schemas: dict[int, Schema] = {}
        try:
            for record, _offset in self._linear_records():
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    found[record.id] = (record, schemas.get(record.schema_id))
        except BagError:
            pass  # a broken tail: the channels seen so far are all there is
        return found

    def message_count(self) -> int | None:
        if self.summary is not None and self.summary.statistics is not None:
            return int(self.summary.statistics.message_count)
        return None

    # -- messages --------------------------------------------------------------------------

    def messages(self, topics: Collection[str] | None = None) -> Iterator[MessageTuple]:
        """Messages in log-time order when indexed, else in file order.

        Raises:
            BagError: at the first broken record, after yielding every message before it.
        """
        if self.summary is not None and self.summary.chunk_indexes:
            yield from self._indexed_messages(topics)
        else:
            yield from self._linear_messages(topics)

    def _indexed_messages(self, topics: Collection[str] | None) -> Iterator[MessageTuple]:
        summary = self.summary
        assert summary is not None
        wanted = {
            cid for cid, ch in summary.channels.items() if topics is None or ch.topic in topics
        }
        chunk_indexes = [
            ci
            for ci in summary.chunk_indexes
            if not ci.message_index_offsets or wanted.intersection(ci.message_index_offsets)
        ]
        chunk_indexes.sort(key=lambda ci: (ci.message_start_time, ci.chunk_start_offset))
        # k-way merge: a pending message can be released once no later chunk may hold an
        # earlier one, so only chunks that overlap in time are held at once.
        pending: list[tuple[int, int, int, Message]] = []
        count = 0
        for ci in chunk_indexes:
            while pending and pending[0][0] < ci.message_start_time:
                yield self._resolve(heapq.heappop(pending)[3], summary, count)
                count += 1
            for index, record in enumerate(self._read_chunk(ci, count)):
                if isinstance(record, Message) and record.channel_id in wanted:
                    heapq.heappush(
                        pending, (record.log_time, ci.chunk_start_offset, index, record)
                    )
        while pending:
            yield self._resolve(heapq.heappop(pending)[3], summary, count)
            count += 1

    def _resolve(self, message: Message, summary: Summary, count: int) -> MessageTuple:
        channel = summary.channels.get(message.channel_id)
        if channel is None:
            raise BagError(
                f"{self.path}: message {count} refers to channel {message.channel_id}, "
                "which the summary does not list; the file is corrupt"
            )
        return summary.schemas.get(channel.schema_id), channel, message

    def _read_chunk(self, ci: ChunkIndex, count: int) -> list[Any]:
        offset = ci.chunk_start_offset
        where = f"{self.path}: chunk at byte offset {offset} (after {count} messages)"
        if offset + ci.chunk_length > self.size:
            raise BagError(f"{where} extends past the end of the file ({self.size} bytes)")
        self._fh.seek(offset)
        head = self._fh.read(_RECORD_HEAD.size)
        opcode, length = _RECORD_HEAD.unpack(head)
        if opcode != Opcode.CHUNK or length + _RECORD_HEAD.size != ci.chunk_length:
            raise BagError(f"{where} is not where the chunk index says; the file is corrupt")
        return self._parse(opcode, self._fh.read(length), where)

    def _linear_messages(self, topics: Collection[str] | None) -> Iterator[MessageTuple]:
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        yielded = [0]  # read by the record loop for its error messages
        for record, offset in self._linear_records(lambda: yielded[0]):
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    raise BagError(
                        f"{self.path}: message at byte offset {offset} (after {yielded[0]} "
                        f"messages) uses channel {record.channel_id} before it is defined"
                    )
                if topics is not None and channel.topic not in topics:
                    continue
                yield schemas.get(channel.schema_id), channel, record
                yielded[0] += 1

    def _linear_records(
        self, messages_so_far: Callable[[], int] = lambda: 0
    ) -> Iterator[tuple[Any, int]]:
        """(record, byte offset of the enclosing top-level record) in file order."""
        offset = len(MAGIC)
        while True:
            # seek every time: the caller may read this file elsewhere between records
            self._fh.seek(offset)
            head = self._fh.read(_RECORD_HEAD.size)
            after = f"after {messages_so_far()} messages"
            if len(head) < _RECORD_HEAD.size:
                raise BagError(
                    f"{self.path}: truncated at byte offset {offset} ({after}): the file ends "
                    f"without a footer ({self.summary_problem or 'no data end record'})"
                )
            opcode, length = _RECORD_HEAD.unpack(head)
            payload_offset = offset + _RECORD_HEAD.size
            if length > self.size - payload_offset:
                raise BagError(
                    f"{self.path}: truncated at byte offset {offset} ({after}): a "
                    f"{_opcode_name(opcode)} record of {length} bytes starts there but the "
                    f"file has only {self.size - payload_offset} bytes left"
                )
            self._fh.seek(payload_offset)
            payload = self._fh.read(length)
            where = f"{self.path}: {_opcode_name(opcode)} record at byte offset {offset} ({after})"
            for record in self._parse(opcode, payload, where):
                yield record, offset
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                return  # the summary section repeats schemas and channels; no messages
            offset = payload_offset + length

    @staticmethod
    def _parse(opcode: int, payload: bytes, where: str) -> list[Any]:
        """Records in one top-level record (a chunk expands to its contents)."""
        stream = ReadDataStream(io.BytesIO(payload))
        try:
            if opcode == Opcode.CHUNK:
                return list(breakup_chunk(Chunk.read(stream), validate_crc=True))
            if opcode == Opcode.MESSAGE:
                return [Message.read(stream, len(payload))]
            if opcode == Opcode.SCHEMA:
                return [Schema.read(stream)]
            if opcode == Opcode.CHANNEL:
                return [Channel.read(stream)]
        except Exception as err:  # decompression, CRC, struct and Unicode errors alike
            raise BagError(f"{where} is corrupt: {type(err).__name__}: {err}") from err
        return []  # indexes, statistics, attachments, metadata: nothing to yield
