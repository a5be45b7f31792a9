"""
The chunk compressions: each one's name in a Chunk record and its two directions.

:data:`COMPRESSIONS` is the one map of them (the Recorder's ``compression`` choices).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

__all__ = ['Compression', 'COMPRESSIONS', 'compression', 'chunk_compression']


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
