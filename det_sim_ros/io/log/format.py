"""
The MCAP bytes this package writes and scans itself.

The magic, the opcodes it reads, the Message record's head (the one Python statement of the
layout ``core/_csrc`` ``pack_records`` writes), the chunk compressions (:data:`COMPRESSIONS`),
the provisional end written after every flush, the file that writes it (:class:`TailStream`),
and the check for a torn file (:func:`is_torn`).
"""

from __future__ import annotations

import dataclasses
import os
import struct
from typing import Callable

__all__ = ['MAGIC', 'MESSAGE_HEAD', 'MESSAGE_FIELDS', 'OP_HEADER', 'OP_FOOTER', 'OP_SCHEMA',
           'OP_CHANNEL', 'OP_MESSAGE', 'OP_CHUNK', 'OP_MESSAGE_INDEX', 'OP_ATTACHMENT',
           'OP_METADATA', 'OP_DATA_END', 'RECORD_HEAD', 'PROVISIONAL_END',
           'TailStream', 'is_torn', 'LIBRARY', 'METADATA_NAME', 'END_METADATA_NAME',
           'SCENE_ATTACHMENT', 'Compression', 'COMPRESSIONS', 'compression',
           'chunk_compression', 'file_kind']

LIBRARY = 'det_sim_ros'
METADATA_NAME = 'det_sim_ros'            # the run's metadata record, at the start of a file
END_METADATA_NAME = 'det_sim_ros.end'    # the counters, when a file is closed
SCENE_ATTACHMENT = 'scene.yaml'

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX = \
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
OP_ATTACHMENT, OP_METADATA, OP_DATA_END = 0x09, 0x0C, 0x0F
RECORD_HEAD = struct.Struct('<BQ')   # every record: opcode, length of the rest

# A Message record: opcode, length (22 + payload), channel id, sequence, log time, publish time,
# then the payload. MESSAGE_FIELDS: each field's byte offset in the record.
MESSAGE_HEAD = struct.Struct('<BQHIQQ')
MESSAGE_FIELDS = {'opcode': 0, 'length': 1, 'channel': 9, 'sequence': 11, 'log_time': 15,
                  'publish_time': 23, 'payload': MESSAGE_HEAD.size}
MESSAGE_HEAD_LENGTH = MESSAGE_HEAD.size - RECORD_HEAD.size   # the length field's part of it


@dataclasses.dataclass(frozen=True)
class Compression:
    """
    A chunk compression: its name in the Chunk record and its two directions.

    ``compress`` is the call ``mcap.writer.Writer`` makes (the same bytes); ``decompress``
    takes the compressed bytes and the uncompressed size the Chunk record states.
    """

    field: str
    compress: Callable[[bytes], bytes]
    decompress: Callable[[bytes, int], bytes]


def _zstd_compress(data: bytes) -> bytes:
    import zstandard
    return zstandard.compress(data)


def _zstd_decompress(data: bytes, size: int) -> bytes:
    import zstandard
    return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)


def _lz4_compress(data: bytes) -> bytes:
    import lz4.frame
    return lz4.frame.compress(data)


def _lz4_decompress(data: bytes, size: int) -> bytes:
    import lz4.frame
    return lz4.frame.decompress(data)


# the Recorder's compression names (the ``log.compression`` choices); '' is 'none'
COMPRESSIONS = {
    'zstd': Compression('zstd', _zstd_compress, _zstd_decompress),
    'lz4': Compression('lz4', _lz4_compress, _lz4_decompress),
    'none': Compression('', bytes, lambda data, size: bytes(data)),
}
_BY_FIELD = {kind.field: kind for kind in COMPRESSIONS.values()}


def compression(name: str) -> Compression:
    """
    Return the compression a Recorder ``name`` stands for ('' is 'none').

    :raises ValueError: an unknown name (the known ones listed).
    """
    kind = COMPRESSIONS.get(name or 'none')
    if kind is None:
        raise ValueError(f'unknown compression {name!r} (one of {", ".join(COMPRESSIONS)})')
    return kind


def chunk_compression(field: str) -> Compression:
    """
    Return the compression a Chunk record names in its ``compression`` field.

    :raises ValueError: a compression this package does not read.
    """
    kind = _BY_FIELD.get(field)
    if kind is None:
        raise ValueError(f'unknown chunk compression {field!r}')
    return kind


# DataEnd (opcode 0x0f, crc 0 = not computed) + Footer (0x02: summary_start 0 = no summary,
# summary_offset_start 0, crc 0) + magic: the smallest valid end of an MCAP file
_FOOTER_HEAD = bytes((OP_FOOTER,)) + (20).to_bytes(8, 'little')
PROVISIONAL_END = (bytes((OP_DATA_END,)) + (4).to_bytes(8, 'little') + bytes(4) + _FOOTER_HEAD
                   + bytes(20) + MAGIC)
_FOOTER_SIZE = len(_FOOTER_HEAD) + 20 + len(MAGIC)


class TailStream:
    """
    The writer's output file: records collected in memory, written at each flush.

    Each flush writes them in one ``pwrite``, followed by the provisional end, at the offset where
    the next flush continues (so the provisional end is overwritten by it). Between flushes the
    file on disk is always a complete MCAP. :meth:`finish` writes the writer's real end (after
    ``Writer.finish``).
    """

    def __init__(self, path: str):
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._committed = 0
        self._pending = bytearray()

    def write(self, data) -> int:
        """Collect ``data`` (written at the next flush)."""
        self._pending += data
        return len(data)

    def tell(self) -> int:
        """Return the file's size once what is collected is written."""
        return self._committed + len(self._pending)

    def _commit(self, tail: bytes) -> None:
        data = memoryview(bytes(self._pending) + tail)
        offset = self._committed
        while data:
            n = os.pwrite(self._fd, data, offset)
            offset += n
            data = data[n:]
        self._committed += len(self._pending)
        self._pending.clear()

    def flush(self) -> None:
        """Write what is collected and the provisional end after it."""
        self._commit(PROVISIONAL_END)

    def finish(self) -> None:
        """Write what is pending (the writer's real end) and cut off any stale bytes."""
        self._commit(b'')
        os.ftruncate(self._fd, self._committed)

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)


def is_torn(path: str) -> bool:
    """Return True for an MCAP file that does not end in a valid footer (a cut file)."""
    try:
        with open(path, 'rb') as stream:
            stream.seek(0, os.SEEK_END)
            size = stream.tell()
            if size < len(MAGIC) + _FOOTER_SIZE:
                return True
            stream.seek(0)
            if stream.read(len(MAGIC)) != MAGIC:
                return True
            stream.seek(size - _FOOTER_SIZE)
            end = stream.read(_FOOTER_SIZE)
    except OSError:
        return False
    return end[-len(MAGIC):] != MAGIC or end[:len(_FOOTER_HEAD)] != _FOOTER_HEAD


def file_kind(path) -> str:
    """
    Return 'mcap' for a file that starts with the MCAP magic, 'empty' or 'other'.

    :raises OSError: a missing or unreadable file.
    """
    with open(path, 'rb') as stream:
        head = stream.read(len(MAGIC))
    return 'mcap' if head == MAGIC else 'empty' if not head else 'other'
