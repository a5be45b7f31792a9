"""
Reading MCAP run logs, finished or not, message by message or in blocks.

One scanning path for messages one by one (:meth:`LogReader.messages`) and for messages as
blocks of records (:meth:`LogReader.blocks`, the column reader of ``det_sim plot`` builds on
it), both from finished and unfinished files; :func:`recover` and :func:`recover_unfinished`
rewrite unfinished files as finished, indexed ones.

The file is read here once, record by record (their lengths only); mcap's
record classes parse the few records the reader needs (header, schemas, channels, metadata,
attachments, chunks, footer), indexes and statistics are skipped. A chunk is decompressed,
checked against its CRC and walked the same way, so its messages are sliced, not parsed.

Why not mcap's readers: a torn file (cut inside a record) gives every message before the cut
here and nothing else to handle; mcap's seeking reader gives none of it (it needs the summary)
and its non-seeking one raises ``EndOfFile`` after them. Read in full, ``messages`` is cheaper
per message than mcap's readers, and ``blocks`` (the plot's columns, which mcap has no
counterpart of) cheaper still (docs/logging.md, "mcap's Writer and readers, and this
package's"; ``bench/mcap_library.py``).
"""

from __future__ import annotations

import dataclasses
import io
import logging
import os
import struct
from typing import Iterable, Iterator, NamedTuple
import zlib

import numpy as np

from .compression import chunk_compression, compression as compression_kind
from .format import (LIBRARY, MAGIC, MESSAGE_FIELDS, MESSAGE_HEAD, MESSAGE_HEAD_LENGTH,
                     METADATA_NAME, OP_ATTACHMENT, OP_CHANNEL, OP_CHUNK, OP_DATA_END,
                     OP_FOOTER, OP_HEADER, OP_MESSAGE, OP_METADATA, OP_SCHEMA, RECORD_HEAD,
                     SCENE_ATTACHMENT)
from .sniff import is_torn
from ..cdr import deserialize
from ..schemas import qos_profiles_yaml

__all__ = ['LogReader', 'LogMessage', 'RecordBlock', 'MessageColumns', 'log_files', 'recover',
           'recover_unfinished']

_logger = logging.getLogger('det_sim_ros.io.log')
_FIELD = MESSAGE_FIELDS
_PAYLOAD = MESSAGE_FIELDS['payload']
_BYTES = np.arange(8)   # the bytes of a little-endian integer field, as offsets


@dataclasses.dataclass(frozen=True)
class LogMessage:
    """One logged message: CDR ``data`` of ``type_name`` on ``topic``."""

    topic: str
    type_name: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes

    def decode(self):
        """Return the rosidl message (no rclpy needed)."""
        return deserialize(self.type_name, self.data)


@dataclasses.dataclass(frozen=True)
class RecordBlock:
    """
    Message records in file order, with the byte offset of each.

    ``raw``: the bytes (a chunk's records, or one record); ``positions``: the byte offset of
    each Message record in it; ``place``: where its record starts in the log, (index in
    :attr:`LogReader.files`, byte offset in that file), for :meth:`LogReader.blocks`
    ``start``.
    """

    raw: bytes
    positions: list
    place: tuple[int, int] = (0, 0)

    def columns(self) -> MessageColumns:
        """
        Return the fields of the block's messages as numpy columns, in file order.

        Read at the message offsets in one pass each (a plot's millions of messages are not
        parsed one by one); payload ``k`` is ``raw[payload_start[k]:][:payload_size[k]]``.
        """
        arr = np.frombuffer(self.raw, dtype=np.uint8)
        at = np.array(self.positions, dtype=np.int64)[:, None]
        length = arr[at + _FIELD['length'] + _BYTES].view('<u8').reshape(-1)
        return MessageColumns(
            channel=arr[at + _FIELD['channel'] + _BYTES[:2]].view('<u2').reshape(-1),
            log_time=arr[at + _FIELD['log_time'] + _BYTES].view('<u8').reshape(-1),
            payload_start=at[:, 0] + _FIELD['payload'],
            payload_size=(length - MESSAGE_HEAD_LENGTH).astype(np.int64))


class MessageColumns(NamedTuple):
    """The messages of a :class:`RecordBlock` as columns (numpy arrays, one entry each)."""

    channel: object         # channel id (uint16)
    log_time: object        # log time (ns, uint64)
    payload_start: object   # offset of the payload in the block's ``raw`` (int64)
    payload_size: object    # payload bytes (int64)


def log_files(paths) -> list[str]:
    """Expand files and directories (their ``*.mcap``, sorted) into a list of MCAP files."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    files = []
    for path in map(os.fspath, paths):
        if os.path.isdir(path):
            files += sorted(os.path.join(path, f) for f in os.listdir(path) if f.endswith('.mcap'))
        else:
            files.append(path)
    if not files:
        raise FileNotFoundError(f'no MCAP files in {list(map(os.fspath, paths))}')
    return files


def _fully_qualified(topic: str) -> str:
    return topic if topic.startswith('/') else '/' + topic


_RECORDS = {OP_HEADER: 'Header', OP_FOOTER: 'Footer', OP_SCHEMA: 'Schema',
            OP_CHANNEL: 'Channel', OP_METADATA: 'Metadata', OP_ATTACHMENT: 'Attachment'}


def _stream(body: bytes):
    from mcap.data_stream import ReadDataStream
    return ReadDataStream(io.BytesIO(body))


def _top_records(stream, start: int = 0) -> Iterator[tuple[int, bytes, int]]:
    """
    Yield (opcode, the bytes after its length, its byte offset) of each record up to the Footer.

    The records are read in turn from the file's start, or from the record at byte ``start``;
    the data section's CRC is checked at DataEnd (when read from the start).

    :raises ValueError: no magic, a torn record (EOFError), a CRC mismatch.
    """
    if stream.read(len(MAGIC)) != MAGIC:
        raise ValueError('not an MCAP file (no magic)')
    crc, at, size = zlib.crc32(MAGIC), len(MAGIC), os.fstat(stream.fileno()).st_size
    if start > at:
        stream.seek(start)
        crc, at = None, start
    while True:
        head = stream.read(RECORD_HEAD.size)
        op, length = RECORD_HEAD.unpack(head) if len(head) == RECORD_HEAD.size else (0, -1)
        if length < 0 or at + len(head) + length > size:   # (a torn length is not allocated)
            raise EOFError(f'the file ends inside a record (at byte {at} of {size})')
        body = stream.read(length)
        if op == OP_DATA_END and crc is not None:
            (expected,) = struct.unpack_from('<I', body)
            if expected and crc != expected:
                raise ValueError('data section CRC mismatch (a damaged file)')
        if crc is not None:
            crc = zlib.crc32(body, zlib.crc32(head, crc))
        yield op, body, at
        at += len(head) + length
        if op == OP_FOOTER:
            return


def _chunk_data(chunk) -> bytes:
    """Return a chunk's records, decompressed and checked against its CRC."""
    data = chunk_compression(chunk.compression).decompress(chunk.data, chunk.uncompressed_size)
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError('chunk CRC mismatch (a damaged chunk)')
    return data


class LogReader:
    """
    Stream an MCAP log (one file, several split files or a directory of them) in file order.

    Works on finished and unfinished files alike: reading stops at the first record that is
    missing or torn (a file cut by SIGKILL or power loss), and :attr:`complete` then says
    False. Metadata, attachments and channels seen so far are available as attributes.
    """

    def __init__(self, paths):
        self.files = log_files(paths)
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.channels: dict[int, tuple[str, str, dict]] = {}  # per current file
        self.topics: dict[str, str] = {}                       # topic -> type name
        self.qos: dict[str, str] = {}                          # topic -> offered_qos_profiles
        self.definitions: dict[str, bytes] = {}                # type name -> schema data
        self.profile = ''
        self.complete = True
        self.errors: list[str] = []
        self._scanned = False
        self._schemas: dict[int, str] = {}
        self._file_channels: dict[str, dict] = {}   # path -> its channels, once read through

    # -- records ------------------------------------------------------------------------------
    def _schema(self, record) -> None:
        self._schemas[record.id] = record.name
        self.definitions.setdefault(record.name, record.data)

    def _channel(self, record) -> None:
        type_name = self._schemas.get(record.schema_id, '')
        self.channels[record.id] = (record.topic, type_name, dict(record.metadata))
        self.topics.setdefault(record.topic, type_name)
        if 'offered_qos_profiles' in record.metadata:
            self.qos.setdefault(record.topic, record.metadata['offered_qos_profiles'])

    def _walk_chunk(self, raw: bytes) -> RecordBlock:
        """Return the chunk's Message records as a block; its schemas and channels read."""
        from mcap.records import Channel, Schema
        positions, p, n = [], 0, len(raw)
        unpack, head = RECORD_HEAD.unpack_from, RECORD_HEAD.size
        while p < n:
            if p + head > n:
                raise ValueError('a torn record inside a chunk')
            op, length = unpack(raw, p)
            end = p + head + length
            if end > n:
                raise ValueError('a torn record inside a chunk')
            if op == OP_MESSAGE:
                positions.append(p)
            elif op in (OP_SCHEMA, OP_CHANNEL):
                body = _stream(raw[p + head:end])
                if op == OP_SCHEMA:
                    self._schema(Schema.read(body))
                else:
                    self._channel(Channel.read(body))
            p = end
        return RecordBlock(raw, positions)

    def _record(self, op: int, body: bytes) -> RecordBlock | bool | None:
        """
        Take one top-level record (opcode, bytes after its length).

        Return a block of messages, True for the Footer (False: a Footer without summary), else
        None.
        """
        from mcap import records
        if op == OP_CHUNK:
            return self._walk_chunk(_chunk_data(records.Chunk.read(_stream(body))))
        if op == OP_MESSAGE:   # a message outside chunks: a block of one
            return RecordBlock(RECORD_HEAD.pack(op, len(body)) + body, [0])
        kind = _RECORDS.get(op)
        if kind is None:       # indexes, statistics, summary: not needed to read the log
            return None
        record = getattr(records, kind).read(_stream(body))
        if op == OP_SCHEMA:
            self._schema(record)
        elif op == OP_CHANNEL:
            self._channel(record)
        elif op == OP_METADATA:
            self.metadata.setdefault(record.name, dict(record.metadata))
        elif op == OP_ATTACHMENT:
            self.attachments.setdefault(record.name, record.data)
        elif op == OP_HEADER:
            self.profile = record.profile
        else:   # the footer; no summary: a provisional end (the writer was killed after a flush)
            return record.summary_start != 0
        return None

    def _file_blocks(self, path: str, stop_at_message: bool = False, file: int = 0,
                     start: int = 0) -> Iterator[RecordBlock]:
        """
        Yield the message blocks of one file; the other records read into the attributes.

        From the record at byte ``start`` if this reader has read the file through before
        (its channels known), else from the file's start.
        """
        self._schemas, self.channels = {}, {}
        known = self._file_channels.get(path)
        if start and known is not None:
            self.channels = dict(known)
        else:
            start = 0
        finished = False
        with open(path, 'rb') as stream:   # a missing or unreadable file is the caller's error
            try:
                for op, body, at in _top_records(stream, start):
                    taken = self._record(op, body)
                    if isinstance(taken, RecordBlock):
                        if stop_at_message and taken.positions:
                            return
                        yield dataclasses.replace(taken, place=(file, at))
                    elif taken is not None:
                        finished = taken
                        if not finished and not stop_at_message:
                            self._error(f'{path}: unfinished (no summary: the writer '
                                        'stopped without closing the file)')
                        break
            except Exception as exc:  # noqa: BLE001 - the end of the readable data
                self._error(f'{path}: {type(exc).__name__}: {exc}')
        if not stop_at_message:
            self._file_channels[path] = dict(self.channels)
            if not finished:
                self.complete = False

    def _error(self, text: str) -> None:
        if text not in self.errors:   # (a file read again says the same)
            self.errors.append(text)

    def blocks(self, start: tuple[int, int] | None = None) -> Iterator[RecordBlock]:
        """
        Yield the Message records of all files as blocks, in file order.

        ``start``: a block's :attr:`RecordBlock.place` from an earlier pass of this reader:
        begin there (a seek), not at the first file's start. :attr:`channels` holds the
        channels of the block's file when it is yielded.
        """
        self.complete = True
        first, offset = start if start is not None else (0, 0)
        for file in range(first, len(self.files)):
            yield from self._file_blocks(self.files[file], file=file,
                                         start=offset if file == first else 0)
        self._scanned = True

    def scan_info(self) -> 'LogReader':
        """Read the header records of the first file (metadata, scene) without the messages."""
        if not self._scanned:
            for _ in self._file_blocks(self.files[0], stop_at_message=True):
                pass
            self._scanned = True
        return self

    def messages(self, topics: Iterable[str] | None = None,
                 start: tuple[int, int] | None = None) -> Iterator[LogMessage]:
        """
        Yield all readable messages of all files, in file order (= non-decreasing log time).

        ``start``: begin at a block's place, as :meth:`blocks` does.
        """
        wanted = None if topics is None else {_fully_qualified(t) for t in topics}
        unpack = MESSAGE_HEAD.unpack_from
        for block in self.blocks(start):
            raw, channels = block.raw, self.channels
            for p in block.positions:
                _, length, channel_id, sequence, log_time, publish_time = unpack(raw, p)
                channel = channels.get(channel_id)
                if channel is None or (wanted is not None and channel[0] not in wanted):
                    continue
                yield LogMessage(channel[0], channel[1], log_time, publish_time, sequence,
                                 raw[p + _PAYLOAD:p + RECORD_HEAD.size + length])

    @property
    def info(self) -> dict[str, str]:
        """Return the ``det_sim_ros`` metadata record (version, scene_yaml, stepper, ...)."""
        self.scan_info()
        return self.metadata.get(METADATA_NAME, {})

    @property
    def scene_yaml(self) -> str:
        """Return the scene YAML the run used ('' if the log has none)."""
        self.scan_info()
        data = self.attachments.get(SCENE_ATTACHMENT)
        return data.decode() if data is not None else self.info.get('scene_yaml', '')


def _start_writer(stream, reader: LogReader, kind):
    """Return mcap's own Writer, started: recover needs no open chunk (McapWriter's bytes)."""
    from mcap.writer import CompressionType, Writer
    writer = Writer(stream, chunk_size=1024 * 1024,
                    compression=CompressionType[(kind.field or 'none').upper()])
    writer.start(profile=reader.profile or 'ros2', library=f'{LIBRARY} recover')
    return writer


def recover(source, target: str, compression: str = 'zstd') -> dict:
    """
    Rewrite the readable part of a (possibly unfinished) log into a finished, indexed MCAP.

    :returns: ``{'messages': n, 'complete': bool}`` (complete: the source was finished).
    """
    reader = LogReader(source)
    kind = compression_kind(compression)
    count = 0
    with open(target, 'wb') as stream:
        writer = None
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for message in reader.messages():
            if writer is None:
                writer = _start_writer(stream, reader, kind)
                for name, data in reader.metadata.items():
                    writer.add_metadata(name, data)
                for name, data in reader.attachments.items():
                    writer.add_attachment(0, 0, name, 'application/yaml', data)
            if message.topic not in channels:
                if message.type_name not in schemas:
                    schemas[message.type_name] = writer.register_schema(
                        message.type_name, 'ros2msg', reader.definitions[message.type_name])
                meta = {'offered_qos_profiles': reader.qos.get(message.topic,
                                                               qos_profiles_yaml())}
                channels[message.topic] = writer.register_channel(
                    message.topic, 'cdr', schemas[message.type_name], meta)
            writer.add_message(channels[message.topic], message.log_time, message.data,
                               message.publish_time, message.sequence)
            count += 1
        if writer is None:
            writer = _start_writer(stream, reader, kind)
        writer.finish()
    return {'messages': count, 'complete': reader.complete}


def recover_unfinished(folder: str, exclude: Iterable[str] = ()) -> list[tuple[str, dict]]:
    """
    Repair every torn ``*.mcap`` in ``folder`` in place.

    A torn file does not end in a valid footer (power loss, or a kill inside a flush's write):
    its readable part is rewritten as a finished, indexed file (:func:`recover`, through a
    temporary file and an atomic rename). Files that end in the writer's provisional end are
    valid MCAP already and left alone.

    :returns: ``[(path, {'messages': n, 'complete': False}), ...]`` for the repaired files.
    """
    done = []
    skip = {os.path.abspath(p) for p in exclude}
    if not os.path.isdir(folder):
        return done
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        if (not name.endswith('.mcap') or os.path.abspath(path) in skip
                or not os.path.isfile(path) or not is_torn(path)):
            continue
        temporary = path + '.recovering'
        try:
            outcome = recover(path, temporary)
            os.replace(temporary, path)
        except Exception as exc:  # noqa: BLE001 - a file we cannot repair is left as it is
            _logger.warning('cannot recover %s: %s', path, exc)
            try:
                os.remove(temporary)
            except OSError:
                pass
            continue
        done.append((path, outcome))
    return done
