"""
A chunked MCAP writer on mcap's public record classes, with the chunk in progress in the open.

:class:`McapWriter` writes the bytes ``mcap.writer.Writer`` writes with its defaults (every
index, schemas and channels repeated in the summary, statistics, summary offsets, the summary
CRC, no data-section CRC): the same records (``mcap.records``, written through
``mcap.data_stream.RecordBuilder``), in the same order, with the same offsets. What it adds is
the chunk in progress as its own public state (:class:`OpenChunk`) and the file's
:attr:`McapWriter.statistics`, so the record packer (:mod:`~det_sim_ros.io.log.packing`)
appends Message records to the chunk and keeps its index and the statistics as
:meth:`McapWriter.add_message` would, without reaching into mcap's writer.

Why not mcap's Writer: it keeps its chunk in progress private, and the packer is the speed of the
log, a fraction of ``mcap.writer.Writer.add_message``'s cost per sample (docs/logging.md, "mcap's
Writer and readers, and this package's"; ``bench/mcap_library.py``). mcap's Writer serves where no
open chunk is needed: :func:`~.reader.recover` writes with it. Crash safety and flush control do
not need a writer of its own (:class:`~.tail_stream.TailStream` under either writer; both end a
chunk at ``flush``).
"""

from __future__ import annotations

import collections
import itertools
import struct
import zlib

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Attachment, AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd,
                          Footer, Header, Message, MessageIndex as _MessageIndex, Metadata,
                          MetadataIndex, Schema, Statistics, SummaryOffset)

from .compression import Compression
from .format import MAGIC, OP_FOOTER, OP_MESSAGE_INDEX

__all__ = ['McapWriter', 'OpenChunk', 'MessageIndex']


class MessageIndex(_MessageIndex):
    """
    mcap's MessageIndex, written as one record of one pack.

    mcap writes an entry with two calls and a record's length by seeking back to it. The length
    is known (channel id, entries' length, 16 bytes per entry), so the head is packed with them:
    a fifth to a third of the packed paths' cost (docs/logging.md, mcap's Writer and readers).
    """

    def write(self, stream):
        """Write the record, as mcap writes it."""
        records, size = self.records, 16 * len(self.records)
        stream.write(struct.pack(f'<BQHI{2 * len(records)}Q', OP_MESSAGE_INDEX, 6 + size,
                                 self.channel_id, size,
                                 *itertools.chain.from_iterable(records)))


class OpenChunk:
    """
    The chunk in progress: its records and what its Chunk record and message indexes will say.

    :attr:`records` (a bytearray) holds the Schema, Channel and Message records written since
    the last chunk ended; :attr:`message_indices` maps a channel id to its
    :class:`MessageIndex` (entries: log time, offset in :attr:`records`).
    """

    def __init__(self):
        self.records = bytearray()
        self.message_indices: dict[int, MessageIndex] = {}
        self.num_messages = 0
        self.message_start_time = 0
        self.message_end_time = 0

    def index(self, channel_id: int) -> MessageIndex:
        """Return the message index of ``channel_id`` in this chunk (a new one on first use)."""
        index = self.message_indices.get(channel_id)
        if index is None:
            index = self.message_indices[channel_id] = MessageIndex(channel_id=channel_id,
                                                                    records=[])
        return index

    def take(self) -> bytes:
        """Return the records and start an empty chunk."""
        data = bytes(self.records)
        self.records = bytearray()
        self.message_indices = {}
        self.num_messages = self.message_start_time = self.message_end_time = 0
        return data


def _record(record) -> bytes:
    """Return the bytes of one mcap record."""
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


class McapWriter:
    """
    Write one chunked MCAP file to ``stream`` (``write``, ``tell``, ``flush``).

    The methods are mcap.Writer's (see the module docstring). The chunk in progress is
    :attr:`chunk`; a chunk ends when its records exceed ``chunk_size`` bytes
    (:meth:`end_chunk_if_full`, after each record added to it) and at every :meth:`flush`.
    """

    def __init__(self, stream, *, chunk_size: int, compression: Compression):
        self._stream = stream
        self._builder = RecordBuilder()
        self.chunk_size = int(chunk_size)
        self._compression = compression
        self.chunk = OpenChunk()
        self.statistics = Statistics(
            attachment_count=0, channel_count=0, chunk_count=0, message_count=0,
            metadata_count=0, message_start_time=0, message_end_time=0, schema_count=0,
            channel_message_counts=collections.defaultdict(int))
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []

    def _write_built(self) -> None:
        self._stream.write(self._builder.end())

    def start(self, profile: str, library: str) -> None:
        """Write the magic and the Header record."""
        self._stream.write(MAGIC)
        Header(profile, library).write(self._builder)
        self._write_built()

    def add_metadata(self, name: str, data: dict) -> None:
        """Write a Metadata record (indexed in the summary)."""
        offset = self._stream.tell()
        self.statistics.metadata_count += 1
        Metadata(name=name, metadata=data).write(self._builder)
        self._metadata_indexes.append(
            MetadataIndex(offset=offset, length=self._builder.count, name=name))
        self._write_built()

    def add_attachment(self, create_time: int, log_time: int, name: str, media_type: str,
                       data: bytes) -> None:
        """Write an Attachment record (indexed in the summary)."""
        offset = self._stream.tell()
        self.statistics.attachment_count += 1
        Attachment(create_time=create_time, log_time=log_time, name=name,
                   media_type=media_type, data=data).write(self._builder)
        self._attachment_indexes.append(AttachmentIndex(
            offset=offset, length=self._builder.count, create_time=create_time,
            log_time=log_time, data_size=len(data), name=name, media_type=media_type))
        self._write_built()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a Schema record into the chunk; return its id."""
        schema = Schema(id=len(self._schemas) + 1, data=data, encoding=encoding, name=name)
        self._schemas[schema.id] = schema
        self.statistics.schema_count += 1
        self.chunk.records += _record(schema)
        self.end_chunk_if_full()
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict) -> int:
        """Write a Channel record into the chunk; return its id."""
        channel = Channel(id=len(self._channels) + 1, topic=topic,
                          message_encoding=message_encoding, schema_id=schema_id,
                          metadata=metadata)
        self._channels[channel.id] = channel
        self.statistics.channel_count += 1
        self.chunk.records += _record(channel)
        self.end_chunk_if_full()
        return channel.id

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                    sequence: int = 0) -> None:
        """Write a Message record into the chunk (mcap's record class writes it)."""
        stats, chunk = self.statistics, self.chunk
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        stats.message_end_time = max(log_time, stats.message_end_time)
        stats.channel_message_counts[channel_id] += 1
        stats.message_count += 1
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        chunk.message_end_time = max(log_time, chunk.message_end_time)
        chunk.index(channel_id).records.append((log_time, len(chunk.records)))
        chunk.num_messages += 1
        chunk.records += _record(Message(channel_id=channel_id, log_time=log_time, data=data,
                                         publish_time=publish_time, sequence=sequence))
        self.end_chunk_if_full()

    def end_chunk_if_full(self) -> None:
        """End the chunk if its records exceed the chunk size."""
        if len(self.chunk.records) > self.chunk_size:
            self._end_chunk()

    def _end_chunk(self) -> None:
        """Write the chunk in progress and its message indexes (nothing without messages)."""
        chunk = self.chunk
        if chunk.num_messages == 0:
            return
        self.statistics.chunk_count += 1
        start, end, indexes = (chunk.message_start_time, chunk.message_end_time,
                               chunk.message_indices)
        data = chunk.take()
        compressed = self._compression.compress(data)
        stream, builder = self._stream, self._builder
        chunk_offset = stream.tell()
        Chunk(compression=self._compression.field, data=compressed, message_start_time=start,
              message_end_time=end, uncompressed_crc=zlib.crc32(data),
              uncompressed_size=len(data)).write(builder)
        chunk_length = builder.count
        self._write_built()
        index_start, offsets = stream.tell(), {}
        for channel_id, index in indexes.items():
            offsets[channel_id] = index_start + builder.count
            index.write(builder)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end, chunk_start_offset=chunk_offset,
            chunk_length=chunk_length, message_index_offsets=offsets,
            message_index_length=builder.count, compression=self._compression.field,
            compressed_size=len(compressed), uncompressed_size=len(data)))
        self._write_built()

    def flush(self) -> None:
        """End the chunk in progress and flush the stream."""
        self._end_chunk()
        self._stream.flush()

    def finish(self) -> None:
        """End the chunk; write DataEnd, the summary and the Footer (the stream stays open)."""
        self._end_chunk()
        DataEnd(0).write(self._builder)
        self._write_built()
        summary_start = self._stream.tell()
        summary = RecordBuilder()
        groups = ((Opcode.SCHEMA, self._schemas.values()),
                  (Opcode.CHANNEL, self._channels.values()),
                  (Opcode.STATISTICS, (self.statistics,)),
                  (Opcode.CHUNK_INDEX, self._chunk_indexes),
                  (Opcode.ATTACHMENT_INDEX, self._attachment_indexes),
                  (Opcode.METADATA_INDEX, self._metadata_indexes))
        offsets = []
        for opcode, records in groups:
            group_start = summary.count
            for record in records:
                record.write(summary)
            offsets.append(SummaryOffset(group_opcode=opcode,
                                         group_start=summary_start + group_start,
                                         group_length=summary.count - group_start))
        offset_start = summary_start + summary.count
        for offset in offsets:
            offset.write(summary)
        data = summary.end()
        summary_start = summary_start if data else 0
        crc = zlib.crc32(struct.pack('<BQQQ', OP_FOOTER, 20, summary_start, offset_start),
                         zlib.crc32(data))
        self._stream.write(data)
        Footer(summary_start=summary_start, summary_offset_start=offset_start,
               summary_crc=crc).write(self._builder)
        self._write_built()
        self._stream.write(MAGIC)
