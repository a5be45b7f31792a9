"""
Record packing: McapWriter.add_message for many messages at once.

The same Message records, chunk message index and statistics as ``add_message``, written with
one struct pack per message (:meth:`RecordPacker.add`, a fraction of mcap's record classes'
cost: docs/performance.md) or, for the
samples of the node's outputs, packed in C (``_ckernel.pack_records``, through
:mod:`det_sim_ros.core.kernel`) a run of samples at a time (:meth:`RecordPacker.add_run`), into
the :class:`~det_sim_ros.io.log.writer.McapWriter`'s open chunk.
"""

from __future__ import annotations

from .format import MESSAGE_HEAD, MESSAGE_HEAD_LENGTH, OP_MESSAGE
from .writer import McapWriter
from ...core.kernel import pack_records

__all__ = ['RecordPacker', 'sample_bytes', 'layout_segments']


def sample_bytes(sizes) -> int:
    """Return the bytes of one sample's Message records, for payloads of ``sizes``."""
    return sum(sizes) + MESSAGE_HEAD.size * len(sizes)


def layout_segments(items, i: int, plans, room: int) -> list:
    """
    Return the queued samples from items[i] that fit in ``room`` bytes, in segments of one layout.

    ``items`` are (log time, topics, payloads, types); ``plans`` map a layout (topics tuple) to
    its plan. A segment is (plan, payload sizes, samples). A layout without a plan ends the
    segments, and so does the first sample that does not fit; a sensor's dropped sample (a
    layout without its topic) is a segment of its own, not the end of the run.
    """
    segments, n = [], len(items)
    while i < n:
        topics = items[i][1]
        key = topics if type(topics) is tuple else tuple(topics)
        plan = plans.get(key)
        if plan is None:
            break
        sizes = tuple(map(len, items[i][2]))
        step = sample_bytes(sizes)
        end, last = i + 1, min(n, i + room // step)
        while end < last and (items[end][1] is topics or tuple(items[end][1]) == key):
            end += 1   # (the node gives the same topics object for a layout)
        if end > last:   # not even one sample of this layout fits
            break
        segments.append((plan, sizes, items[i:end]))
        room -= (end - i) * step
        if end == last:
            break
        i = end
    return segments


def _cover(record, empty: bool, log_time: int) -> None:
    """
    Widen ``record``'s message time range to ``log_time``.

    The range is message_start_time..message_end_time, of the file's statistics or the chunk's;
    ``empty``: it has no message yet.
    """
    if empty or log_time < record.message_start_time:
        record.message_start_time = log_time
    if log_time > record.message_end_time:
        record.message_end_time = log_time


class RecordPacker:
    """Message records into one started McapWriter's chunks (see the module docstring)."""

    def __init__(self, writer: McapWriter):
        self._writer = writer
        self.chunk_size = writer.chunk_size
        self._sample_offsets = {}   # (channel ids, payload sizes) -> _layout

    def chunk_used(self) -> int:
        """Bytes in the chunk in progress."""
        return len(self._writer.chunk.records)

    def room(self, sizes) -> int:
        """Return how many samples of payload ``sizes`` fit in the chunk in progress."""
        return (self.chunk_size - self.chunk_used()) // sample_bytes(sizes)

    def add(self, items, log_time: int) -> None:
        """
        Write (channel id, sequence, data) items, all at ``log_time``, as add_message would.

        A chunk ends after the message that makes it exceed the chunk size.
        """
        writer = self._writer
        stats = writer.statistics
        _cover(stats, stats.message_count == 0, log_time)
        counts, pack = stats.channel_message_counts, MESSAGE_HEAD.pack
        for channel_id, sequence, data in items:
            chunk = writer.chunk    # a new one when a chunk ends
            _cover(chunk, chunk.num_messages == 0, log_time)
            records = chunk.records
            chunk.index(channel_id).records.append((log_time, len(records)))
            records += pack(OP_MESSAGE, MESSAGE_HEAD_LENGTH + len(data), channel_id,
                            sequence, log_time, log_time)
            records += data
            counts[channel_id] += 1
            stats.message_count += 1
            chunk.num_messages += 1
            writer.end_chunk_if_full()

    def _layout(self, channel_ids: tuple, sizes: tuple) -> tuple:
        """
        Return ((channel id, record offset), ...), the bytes and the messages of one sample.

        A sample's payload sizes are fixed for a model, so this is computed once per layout.
        """
        layout = self._sample_offsets.get((channel_ids, sizes))
        if layout is None:
            starts, at = [], 0
            for size in sizes:
                starts.append(at)
                at += MESSAGE_HEAD.size + size
            layout = self._sample_offsets[(channel_ids, sizes)] = (
                tuple(zip(channel_ids, starts)), at, len(sizes))
        return layout

    def add_sample(self, channel_ids: tuple, sequences, payloads, log_time: int) -> None:
        """
        Write the messages of one sample as one write.

        One message per channel, all at ``log_time``: a run of one (:meth:`add_run`). A sample that
        would end the chunk, or whose payloads are not ``bytes``, goes message by message
        (:meth:`add`), so chunks end where add_message ends them.
        """
        sizes = tuple(map(len, payloads))
        if self.chunk_used() + sample_bytes(sizes) <= self.chunk_size:
            records, count = pack_records(channel_ids, sequences, (log_time,), (payloads,),
                                          sizes)
            if count:
                self.add_run(channel_ids, sizes, records, (log_time,))
                return
        self.add(list(zip(channel_ids, sequences, payloads)), log_time)

    def add_run(self, channel_ids: tuple, sizes: tuple, records: bytes, times) -> None:
        """
        Write consecutive samples of one layout, as add_sample would one by one.

        ``records`` are their Message records (``pack_records``: a sample's records in channel
        order, ``sizes`` its payload sizes), ``times`` their log times. The caller guarantees the
        run fits in the chunk, so no message ends it.
        """
        writer = self._writer
        stats, chunk = writer.statistics, writer.chunk
        chunk_records = chunk.records
        base = len(chunk_records)
        _cover(stats, stats.message_count == 0, times[0])
        _cover(stats, False, times[-1])
        _cover(chunk, chunk.num_messages == 0, times[0])
        _cover(chunk, False, times[-1])
        chunk_records += records
        offsets, step, width = self._layout(channel_ids, sizes)
        k, counts = len(times), stats.channel_message_counts
        for channel_id, offset in offsets:
            start = base + offset
            entries = chunk.index(channel_id).records
            if k == 1:   # (add_sample, or a sensor's dropped sample inside a run)
                entries.append((times[0], start))
            else:
                entries.extend(zip(times, range(start, start + k * step, step)))
            counts[channel_id] += k
        stats.message_count += k * width
        chunk.num_messages += k * width
        writer.end_chunk_if_full()

    def pack_run(self, channel_ids, firsts, times, rows, sizes) -> int:
        """
        Pack and write the samples ``rows`` at ``times``; return how many were written.

        ``rows`` hold the payloads per channel; sequences count from ``firsts``. The run stops
        before a row of other payload sizes.
        """
        records, count = pack_records(channel_ids, firsts, times, rows, sizes)
        if count:
            self.add_run(channel_ids, sizes, records, times[:count])
        return count
