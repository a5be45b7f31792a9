"""
Every use of mcap's private writer state, in one place.

The record packer (:mod:`det_sim_ros.io.log.packing`) appends Message records straight into
``mcap.Writer``'s chunk in progress and keeps the writer's statistics and chunk index as
``add_message`` would (1.5 instead of 6.5 us per message). That needs names mcap does not
publish: the writer's name-mangled ``__statistics``, ``__chunk_builder``,
``__maybe_finalize_chunk`` and ``__chunk_size``, and the chunk builder's record buffer. They are
read here only. :func:`attach` returns None when they are missing (the recorder then writes
through ``add_message``: the same bytes, slower); :func:`check` raises
:class:`McapInternalsChanged`, naming the installed mcap version and what is missing, so a test
says so loudly when an mcap upgrade changes them.
"""

from __future__ import annotations

import io
import itertools
import struct

__all__ = ['WriterInternals', 'McapInternalsChanged', 'attach', 'check', 'mcap_version',
           'MessageIndex']

_WRITER = ('_Writer__statistics', '_Writer__chunk_builder', '_Writer__maybe_finalize_chunk',
           '_Writer__chunk_size')
_STATISTICS = ('message_count', 'message_start_time', 'message_end_time',
               'channel_message_counts')
_CHUNK = ('message_indices', 'num_messages', 'message_start_time', 'message_end_time',
          'record_writer')


class McapInternalsChanged(RuntimeError):
    """The installed mcap does not have the writer internals the record packer uses."""


def mcap_version() -> str:
    """Return the installed mcap package's version."""
    try:
        from mcap import __version__
    except ImportError:   # pragma: no cover - mcap is a dependency
        return 'not installed'
    return __version__


def _missing(writer) -> list[str]:
    missing = [name for name in _WRITER if not hasattr(writer, name)]
    statistics = getattr(writer, _WRITER[0], None)
    chunk = getattr(writer, _WRITER[1], None)
    if statistics is not None:
        missing += [f'Statistics.{name}' for name in _STATISTICS
                    if not hasattr(statistics, name)]
    if chunk is not None:
        missing += [f'ChunkBuilder.{name}' for name in _CHUNK if not hasattr(chunk, name)]
        buffer = getattr(getattr(chunk, 'record_writer', None), '_buffer', None)
        if not callable(getattr(buffer, 'tell', None)):
            missing.append('ChunkBuilder.record_writer._buffer')
    return missing


def message_count(writer) -> int | None:
    """Return the messages ``writer``'s summary will count (None if this mcap hides it)."""
    return getattr(getattr(writer, _WRITER[0], None), 'message_count', None)


class WriterInternals:
    """
    The private state of one started ``mcap.Writer`` (chunked).

    :attr:`statistics`, the chunk builder :attr:`chunk`, :attr:`chunk_size`, :meth:`finalize`
    (end the chunk if it is full) and :meth:`buffer` (the chunk's record buffer; a new one after
    each chunk).
    """

    def __init__(self, writer):
        self.statistics = getattr(writer, '_Writer__statistics')
        self.chunk = getattr(writer, '_Writer__chunk_builder')
        self.finalize = getattr(writer, '_Writer__maybe_finalize_chunk')
        self.chunk_size = getattr(writer, '_Writer__chunk_size')

    def buffer(self):
        """Return the BytesIO that holds the records of the chunk in progress."""
        return self.chunk.record_writer._buffer


def attach(writer) -> WriterInternals | None:
    """
    Return the internals of ``writer``, or None when mcap does not have them.

    None also when the writer does not chunk.
    """
    if MessageIndex is None or _missing(writer) or getattr(writer, _WRITER[1]) is None:
        return None
    return WriterInternals(writer)


def check() -> None:
    """
    Raise :class:`McapInternalsChanged` if the record packer's internals are missing.

    That is, if the installed mcap's writer lacks an internal the record packer uses.
    """
    from mcap import writer as mcap_writer
    probe = mcap_writer.Writer(io.BytesIO())
    probe.start()
    missing = _missing(probe)
    if MessageIndex is None:
        missing.append('mcap.records.MessageIndex')
    if missing:
        raise McapInternalsChanged(
            f'mcap {mcap_version()} changed the writer internals '
            f'det_sim_ros.io.log.mcap_internals uses: {", ".join(missing)} missing (the '
            'recorder falls back to Writer.add_message; adapt this module to the new names)')


try:
    from mcap.records import MessageIndex as _McapMessageIndex

    class MessageIndex(_McapMessageIndex):
        """
        mcap's MessageIndex, written as one record of one pack.

        mcap writes an entry with two calls and a record's length by seeking back to it: then
        the index of a 50-sample chunk costs a quarter of the recording. The length is known
        (channel id, entries' length, 16 bytes per entry), so the head is packed with them.
        """

        def write(self, stream):
            """Write the record, as mcap writes it."""
            records, size = self.records, 16 * len(self.records)
            stream.write(struct.pack(f'<BQHI{2 * len(records)}Q', 0x07, 6 + size,  # MESSAGE_INDEX
                                     self.channel_id, size,
                                     *itertools.chain.from_iterable(records)))
except ImportError:  # pragma: no cover - mcap is a dependency; the recorder reports its absence
    MessageIndex = None
