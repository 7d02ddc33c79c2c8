"""Finishing an MCAP file its writer never finished (a killed recorder, a write that failed), so
every reader opens it, the `mcap` package's default one too.

A writer that dies leaves the records it had written up to a cut: no data end, no summary, no
footer. The `mcap` package's ``make_reader(f).iter_messages()`` looks for the footer at the
file's end and, without it, reads the file through and raises at the cut, before it has yielded
a message (it sorts them by time first). :func:`repair` keeps every complete record before the
cut (a chunk is whole or dropped: at most the chunk being written is lost), drops the rest and
writes what :meth:`mcap.writer.Writer.finish` would have: a ``cut`` metadata record saying what
happened, the data end, the summary (schemas, channels, statistics, the chunk, attachment and
metadata indexes) and the footer.

Its cost grows with the file (each chunk is decompressed to find its schemas, channels and
message counts): it runs in the recorder's process or a client's, never in the loop's.
"""
from __future__ import annotations

import io
import struct
import time
import zlib
from collections import defaultdict
from dataclasses import dataclass

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (Attachment, AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd, Footer, Metadata,
                          MetadataIndex, Schema, Statistics, SummaryOffset)
from mcap.stream_reader import get_chunk_data_stream

MAGIC = b"\x89MCAP0\r\n"
CUT = "cut"  # the metadata record a repaired file carries: cause, repaired_unix_s, dropped_bytes, last_log_time_ns
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4  # opcode, length, summary start, summary offset start, crc
_READ = {Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.ATTACHMENT, Opcode.METADATA,
         Opcode.MESSAGE_INDEX}  # the records whose contents the summary needs


@dataclass
class Repaired:
    """What :func:`repair` kept and dropped."""

    messages: int
    dropped_bytes: int  # of the cut record (and anything after it)
    last_log_time_ns: int  # the last message kept [ns] (0: none)


def finished(path) -> bool:
    """Whether the file ends with a footer and the magic (a writer finished it)."""
    with open(path, "rb") as f:
        size = f.seek(0, io.SEEK_END)
        if size < 2 * len(MAGIC) + _FOOTER_BYTES:
            return False
        f.seek(size - len(MAGIC) - _FOOTER_BYTES)
        tail = f.read()
    return tail[0] == Opcode.FOOTER and tail[-len(MAGIC):] == MAGIC


def repair(path, cause: str) -> Repaired | None:
    """Finish the MCAP file at ``path`` in place, cut where its last complete record ends, with
    a ``cut`` metadata record holding ``cause``; None if it was finished already. ValueError if
    it is no MCAP file; OSError if it cannot be written (it is then left cut, which the readers
    here still read)."""
    if finished(path):
        return None
    with open(path, "r+b") as f:
        size = f.seek(0, io.SEEK_END)
        f.seek(0)
        if f.read(len(MAGIC)) != MAGIC:
            raise ValueError(f"{path}: not an MCAP file")
        summary = _Summary()
        end = len(MAGIC)
        while True:
            head = f.read(9)
            if len(head) < 9:
                break
            opcode, length = struct.unpack("<BQ", head)
            if opcode in (0, Opcode.DATA_END, Opcode.FOOTER) or end + 9 + length > size:
                break  # the cut (or a data end a repair that was itself cut had written)
            if opcode in _READ:
                body = f.read(length)
                if not summary.take(opcode, end, body):
                    break
            else:
                f.seek(length, io.SEEK_CUR)
            end += 9 + length
        f.seek(end)
        f.truncate()
        f.write(summary.tail(end, {"cause": cause, "repaired_unix_s": f"{time.time():.3f}",
                                   "dropped_bytes": str(size - end),
                                   "last_log_time_ns": str(summary.statistics.message_end_time)}))
    return Repaired(summary.statistics.message_count, size - end, summary.statistics.message_end_time)


class _Summary:
    """The summary of the records taken so far, as a writer keeps it."""

    def __init__(self):
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.statistics = Statistics(attachment_count=0, channel_count=0, channel_message_counts=defaultdict(int),
                                     chunk_count=0, message_count=0, message_end_time=0, message_start_time=0,
                                     metadata_count=0, schema_count=0)
        self.chunks: list[ChunkIndex] = []
        self._in_chunk: list[set[int]] = []  # the channels each chunk holds messages of
        self.attachments: list[AttachmentIndex] = []
        self.metadata: list[MetadataIndex] = []

    def take(self, opcode: int, offset: int, body: bytes) -> bool:
        """One complete record at ``offset``; False if it cannot be read (the file is cut there)."""
        record = 9 + len(body)
        try:
            stream = ReadDataStream(io.BytesIO(body))
            if opcode == Opcode.CHUNK:
                return self._chunk(Chunk.read(stream), offset, record)
            if opcode == Opcode.MESSAGE_INDEX and self.chunks:  # the chunk before it's index, per channel
                chunk = self.chunks[-1]
                chunk.message_index_offsets[struct.unpack_from("<H", body)[0]] = offset
                chunk.message_index_length = offset + record - (chunk.chunk_start_offset + chunk.chunk_length)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._definition(Schema.read(stream) if opcode == Opcode.SCHEMA else Channel.read(stream))
            elif opcode == Opcode.MESSAGE:
                channel_id, _, log_time = struct.unpack_from("<HIQ", body)
                self._messages({channel_id: 1}, log_time, log_time)
            elif opcode == Opcode.ATTACHMENT:
                a = Attachment.read(stream)
                self.attachments.append(AttachmentIndex(offset=offset, length=record, log_time=a.log_time,
                                                        create_time=a.create_time, data_size=len(a.data),
                                                        name=a.name, media_type=a.media_type))
            elif opcode == Opcode.METADATA:
                self.metadata.append(MetadataIndex(offset=offset, length=record, name=Metadata.read(stream).name))
        except (McapError, ValueError, struct.error, UnicodeDecodeError):
            return False
        return True

    def _chunk(self, chunk: Chunk, offset: int, length: int) -> bool:
        stream, size = get_chunk_data_stream(chunk)
        data = stream.read(size)
        at, end, counts = 0, len(data) - 9, defaultdict(int)  # messages per channel in this chunk
        head, channel_of, message = struct.Struct("<BQ").unpack_from, struct.Struct("<H").unpack_from, Opcode.MESSAGE
        while at <= end:  # (the per-message work kept to the least: it is most of a repair's time)
            opcode, body_length = head(data, at)
            if opcode == message:
                counts[channel_of(data, at + 9)[0]] += 1
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                stream = ReadDataStream(io.BytesIO(data[at + 9:at + 9 + body_length]))
                self._definition(Schema.read(stream) if opcode == Opcode.SCHEMA else Channel.read(stream))
            at += 9 + body_length
        channels = set(counts)
        if counts:  # the chunk's own time range stands for its messages' (a writer keeps it so)
            self._messages(counts, chunk.message_start_time, chunk.message_end_time)
        self.statistics.chunk_count += 1
        self.chunks.append(ChunkIndex(message_start_time=chunk.message_start_time,
                                      message_end_time=chunk.message_end_time, chunk_start_offset=offset,
                                      chunk_length=length, message_index_offsets={}, message_index_length=0,
                                      compression=chunk.compression, compressed_size=len(chunk.data),
                                      uncompressed_size=chunk.uncompressed_size))
        self._in_chunk.append(channels)
        return True

    def _definition(self, record: Schema | Channel) -> None:
        if isinstance(record, Schema):
            self.schemas[record.id] = record
        else:
            self.channels[record.id] = record

    def _messages(self, counts: dict[int, int], first: int, last: int) -> None:
        """``counts`` messages per channel, logged from ``first`` to ``last`` [ns]."""
        s = self.statistics
        s.message_start_time = first if s.message_count == 0 else min(s.message_start_time, first)
        s.message_end_time = max(s.message_end_time, last)
        for channel_id, n in counts.items():
            s.message_count += n
            s.channel_message_counts[channel_id] += n

    def tail(self, data_end: int, cut: dict[str, str]) -> bytes:
        """The bytes after the last complete record: the ``cut`` metadata, the data end, the
        summary and the footer (as :meth:`mcap.writer.Writer.finish` writes them)."""
        data = RecordBuilder()
        Metadata(name=CUT, metadata=cut).write(data)
        self.metadata.append(MetadataIndex(offset=data_end, length=data.count, name=CUT))
        DataEnd(data_section_crc=0).write(data)  # 0: no CRC (the cut part is gone)
        head = data.end()
        for chunk, channels in zip(self.chunks, self._in_chunk):
            if set(chunk.message_index_offsets) != channels:  # its message indexes were cut: none, so a
                chunk.message_index_offsets, chunk.message_index_length = {}, 0  # reader scans the chunk
        s = self.statistics
        s.schema_count, s.channel_count = len(self.schemas), len(self.channels)
        s.attachment_count, s.metadata_count = len(self.attachments), len(self.metadata)
        start = data_end + len(head)
        out, offsets = RecordBuilder(), []
        for opcode, records in ((Opcode.SCHEMA, self.schemas.values()), (Opcode.CHANNEL, self.channels.values()),
                                (Opcode.STATISTICS, [s]), (Opcode.CHUNK_INDEX, self.chunks),
                                (Opcode.ATTACHMENT_INDEX, self.attachments), (Opcode.METADATA_INDEX, self.metadata)):
            group = out.count
            for record in records:
                record.write(out)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=start + group, group_length=out.count - group))
        offset_start = start + out.count
        for offset in offsets:
            offset.write(out)
        summary = out.end()
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, start, offset_start), zlib.crc32(summary))
        footer = RecordBuilder()
        Footer(summary_start=start, summary_offset_start=offset_start, summary_crc=crc).write(footer)
        return head + summary + footer.end() + MAGIC
