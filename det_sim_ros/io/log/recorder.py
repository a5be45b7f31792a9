"""
The run recorder (the format and its crash safety: :mod:`det_sim_ros.io.log`).

The :class:`Recorder` keeps the run's order (sequence numbers, non-decreasing log times), its
counters and its fault, and hands the rest to collaborators: :class:`~.rotation.LogRotation`
(file names, splits, the bounded directory), :class:`~.file.LogFile` (one MCAP file and its
channels), :class:`~.packing.RecordPacker` (the records, packed in C for runs of
samples), :class:`~.flush_policy.FlushPolicy` (when to flush) and, with ``background=True``,
:class:`~.writer_thread.WriterThread` (the writer thread and its bounded queue), reached
through the recording mode (:mod:`~.write_modes`), which gets the recorder's writing steps as a
:class:`~.write_modes.WriteSteps` (so the recorder's public API stays ``record``,
``record_sample`` and ``new_file``: nothing outside can write past the writer thread).
"""

from __future__ import annotations

import atexit
import itertools
import logging
import time
from typing import Callable, Mapping, Sequence
import weakref

from .file import file_info, LogFile, package_version, scene_text
from .flush_policy import FlushPolicy
from .packing import layout_segments
from .rotation import LogRotation
from .write_modes import WriteBehind, WriteNow, WriteSteps
from ..cdr import serialize
from ..schemas import type_name_of

__all__ = ['Recorder']

_logger = logging.getLogger('det_sim_ros.io.log')


class Recorder:
    """
    Record ROS messages of one run to MCAP (see :mod:`det_sim_ros.io.log`).

    No ROS graph or rclpy needed (messages are given as CDR bytes or serialized by
    :mod:`det_sim_ros.io.cdr`).

    :param path: a ``.mcap`` file (or an existing non-directory such as a device), or a
        directory in which ``<prefix>_<date>-<time>_<pid>.mcap`` is created.
    :param scene: the :class:`~det_sim_ros.scenes.scene.Scene` (or its YAML text / mapping)
        stored in every file.
    :param qos_by_topic: topic -> QoS (``rclpy.qos.QoSProfile``, mapping or depth) for the
        ``offered_qos_profiles`` metadata; topics not listed get reliable, keep last 10.
    :param flush_period_s: wall time between flushes (ends the chunk and writes it out); bounds
        what a SIGKILL loses. 0 flushes after every message.
    :param flush_sim_s: log (sim) time between flushes; bounds what a SIGKILL loses in sim
        time whatever the speed (0: wall time only).
    :param max_total_mb: keep this recorder's files in the log directory under this many MiB
        in all (oldest deleted first; 0: no limit).
    :param max_files: keep at most this many of them (0: no limit).
    :param chunk_size: chunk size limit in bytes (a chunk also ends at every flush: at most
        50 ms of sim time at the default periods; why not mcap's 64 KiB: docs/logging.md).
    :param compression: 'zstd', 'lz4' or 'none'.
    :param split_mb: start a new file when the current one exceeds this many MiB (0: never).
    :param split_s: start a new file every this many seconds of log time (0: never).
    :param metadata: extra string key/values for the ``det_sim_ros`` metadata record (the
        stepper ``method`` and ``substeps``, the ``output_map``, ...).
    :param on_fault: called once with the fault text when recording stops on an error.
    :param clock: wall clock for the flush period (``time.monotonic``).
    :param namespace: the node namespace that relative topic names are resolved in.
    :param background: write from a writer thread: :meth:`record` and :meth:`record_sample`
        only queue the (already serialized) bytes, the thread writes, compresses and flushes
        them in order every ``drain_period_s``. Counters and :attr:`fault` are updated by the
        thread; :meth:`close` writes everything queued before it finishes the file.
    :param max_queue: background mode: when this many records wait, the recording thread
        writes the queue itself before it goes on (:mod:`det_sim_ros.io.log.writer_thread`).
    :param packing: write messages through the compiled record packer; False: one by one,
        each Message record written by mcap's record class (the same bytes, slower).
    """

    def __init__(self, path, scene=None, *, qos_by_topic: Mapping | None = None,
                 flush_period_s: float = 0.1, flush_sim_s: float = 0.05,
                 chunk_size: int = 1024 * 1024,
                 max_total_mb: float = 0.0, max_files: int = 0,
                 compression: str = 'zstd', split_mb: float = 0.0, split_s: float = 0.0,
                 metadata: Mapping[str, object] | None = None,
                 on_fault: Callable[[str], None] | None = None,
                 clock: Callable[[], float] = time.monotonic, prefix: str = 'det_sim',
                 namespace: str = '/', background: bool = False,
                 drain_period_s: float = 0.01, max_queue: int = 64,
                 packing: bool = True):
        self.fault = ''
        self.messages = 0       # messages written
        self._messages_before_file = 0
        self.bytes = 0          # serialized payload bytes written
        self.clamped = 0        # log times raised to keep them non-decreasing
        self.dropped = 0        # messages not written because of a fault
        self.flushes = 0
        self.flushed_messages = 0   # messages on disk at the last flush (a SIGKILL keeps them)
        self.record_time_s = 0.0  # wall time spent in record()
        self._ns = '/' + namespace.strip('/') + '/' if namespace.strip('/') else '/'
        self.qos_by_topic = {self._resolve(k): v for k, v in (qos_by_topic or {}).items()}
        self.chunk_size = int(chunk_size)
        self.on_fault = on_fault
        self.version = package_version()
        self._clock = clock
        self._flush_policy = FlushPolicy(flush_period_s, flush_sim_s, clock)
        self._compression = compression
        self._metadata = {str(k): str(v) for k, v in (metadata or {}).items()}
        self._file: LogFile | None = None
        self._packing = packing
        self._rotation: LogRotation | None = None
        self._last_t = 0
        self._types: dict[str, str] = {}       # topic -> type name (over all files)
        self._sequence: dict[str, int] = {}
        try:
            self.scene_yaml = scene_text(scene)
            self._rotation = LogRotation(path, prefix, split_mb=split_mb, split_s=split_s,
                                         max_total_mb=max_total_mb, max_files=max_files)
            self._open()
        except Exception as exc:  # noqa: BLE001 - a logging fault must not stop the simulation
            self._set_fault(exc)
        steps = WriteSteps(self._write, self._write_sample, self._write_sample_run,
                           self._new_file_now, self.maybe_flush, self._set_fault)
        self._mode = (WriteBehind(self, steps, drain_period_s, max_queue)
                      if background and self._file is not None else WriteNow(self, steps))
        _open_recorders.add(self)

    def _resolve(self, topic: str) -> str:
        return topic if topic.startswith('/') else self._ns + topic

    # -- the state the collaborators hold ----------------------------------------------------
    @property
    def paths(self) -> list[str]:
        """Return the files written, in order."""
        return self._rotation.paths if self._rotation is not None else []

    @property
    def deleted(self) -> list[str]:
        """Old files removed to respect max_total_mb / max_files."""
        return self._rotation.deleted if self._rotation is not None else []

    @property
    def flush_period_s(self) -> float:
        """Wall time between flushes (s)."""
        return self._flush_policy.period_s

    @property
    def caught_up(self) -> int:
        """Background mode: times the recording thread wrote the writer's queue itself."""
        return self._mode.caught_up

    @property
    def queued(self) -> int:
        """Background mode: items waiting for the writer thread."""
        return self._mode.queued

    @property
    def packing(self) -> bool:
        """Return whether the current file's messages go through the record packer."""
        return self._file is not None and self._file.packer is not None

    # -- files -------------------------------------------------------------------------------
    def _open(self) -> None:
        rotation = self._rotation
        path = rotation.next_path()
        file = LogFile(path, chunk_size=self.chunk_size, compression=self._compression,
                       packing=self._packing)
        rotation.add(path)
        try:
            file.start(self.version, file_info(self.version, self.scene_yaml,
                                               len(rotation.paths) - 1, self._metadata),
                       self.scene_yaml, self._last_t)
        except BaseException:
            file.abandon()
            raise
        self._file = file
        self._messages_before_file = self.messages
        self._flush_policy.restart(self._last_t)
        rotation.opened(path, file.size())

    def _close_file(self) -> None:
        file, self._file = self._file, None
        if file is None:
            return
        # the file's own count: a SIGINT (a KeyboardInterrupt between any two bytecodes) after
        # a message is written but before it is counted must not leave the counters one short
        self.messages = self._messages_before_file + file.message_count()
        file.finish(self.counters(strings=True))
        if self.paths:
            self._rotation.closed(self.paths[-1])

    def new_file(self) -> None:
        """Finish the current file and continue in a new one (e.g. when sim time restarts)."""
        self._mode.new_file()

    def _new_file_now(self) -> None:
        if self._file is None:
            return
        try:
            self._close_file()
            self._last_t = 0
            self._open()
        except Exception as exc:  # noqa: BLE001
            self._set_fault(exc)

    def _split_if_due(self, t: int) -> bool:
        """
        Continue in a new file when this one reached split_mb or its time span; True if so.

        ``t``: the log time being written.
        """
        rotation = self._rotation
        if rotation.starts(t) or not rotation.split_due(t, self._file.size()):
            return False
        self._close_file()
        self._open()
        rotation.starts(t)
        return True

    # -- flushing ----------------------------------------------------------------------------
    def _flush(self, now: float) -> None:
        self._file.flush()
        self.flushed_messages = self.messages
        self.flushes += 1
        self._flush_policy.done(now, self._last_t)
        if self._rotation.max_total_bytes:
            self._rotation.enforce(self._file.size())

    def maybe_flush(self) -> None:
        """Flush if the flush period has passed (call from a timer when messages are sparse)."""
        if self._file is None:
            return
        now = self._clock()
        if self._flush_policy.wall_due(now):
            try:
                self._flush(now)
            except Exception as exc:  # noqa: BLE001
                self._set_fault(exc)

    # -- recording ---------------------------------------------------------------------------
    def _clamp(self, log_time_ns: int, count: int) -> int:
        """Return the log time to write: never before the last one (counted in :attr:`clamped`)."""
        t = int(log_time_ns)
        if t < self._last_t:
            t = self._last_t
            self.clamped += count
        self._last_t = t
        return t

    def _next_sequences(self, names) -> list[int]:
        sequence = self._sequence
        firsts = [sequence.get(name, 0) for name in names]
        for name, first in zip(names, firsts):
            sequence[name] = first + 1
        return firsts

    def type_of(self, topic: str) -> str | None:
        """Return the type name recorded on ``topic`` (None before its first message)."""
        return self._types.get(topic)

    def _channel(self, topic: str, msg, type_name: str | None) -> int:
        type_name = type_name or self._types.get(topic) or type_name_of(msg)
        self._types[topic] = type_name
        return self._file.register(topic, type_name, self.qos_by_topic.get(topic))

    def record(self, topic: str, msg, log_time_ns: int, type_name: str | None = None) -> bool:
        """
        Write one message at sim time ``log_time_ns`` (also its publish time).

        :param msg: a rosidl message, or its CDR bytes (then give ``type_name`` on first use).
        :returns: True if written (queued, in background mode); False when recording has
            stopped on a fault.
        """
        return self._mode.message(topic, msg, log_time_ns, type_name)

    def record_sample(self, log_time_ns: int, topics: Sequence[str], data: Sequence[bytes],
                      types: Mapping[str, str]) -> bool:
        """
        Write one CDR message per topic, all at ``log_time_ns``.

        One sample of the node's outputs; ``types`` maps each topic to its type name.
        """
        return self._mode.sample(log_time_ns, topics, data, types)

    def _write(self, topic: str, msg, log_time_ns: int, type_name: str | None,
               flush: bool = True) -> bool:
        """
        Write one message; then a flush if one is due, unless not ``flush``.

        ``flush`` is False for a sample's messages but its last: a sample is never split by a
        flush.
        """
        if self._file is None:
            self.dropped += 1
            return False
        start = self._clock()
        try:
            topic = self._resolve(topic)
            t = self._clamp(log_time_ns, 1)
            data = bytes(msg) if isinstance(msg, (bytes, bytearray, memoryview)) \
                else serialize(msg)
            self._split_if_due(t)
            channel_id = self._file.channels.get(topic)
            if channel_id is None:
                channel_id = self._channel(topic, msg, type_name)
            self._file.add(channel_id, self._next_sequences((topic,))[0], data, t)
            self.messages += 1
            self.bytes += len(data)
            if flush and self._flush_policy.due(start, t):
                self._flush(start)
            return True
        except Exception as exc:  # noqa: BLE001 - never raise into the node
            self.dropped += 1
            self._set_fault(exc)
            return False
        finally:
            self.record_time_s += self._clock() - start

    def _sample_one_by_one(self, log_time_ns, topics, data, types, key) -> bool:
        """
        Write a sample message by message.

        The first of a layout registers its channels and plans the fast path; flushed after its
        last message.
        """
        ok = True
        last = len(data) - 1
        for j, (topic, payload) in enumerate(zip(topics, data)):
            ok = self._write(topic, payload, log_time_ns, types[topic], j == last) and ok
        file = self._file
        if file is not None and file.packer is not None:
            names = tuple(self._resolve(topic) for topic in key)
            if all(name in file.channels for name in names):
                file.sample_plans[key] = (names, tuple(file.channels[n] for n in names))
        return ok

    def _write_sample(self, log_time_ns, topics, data, types) -> bool:
        """Several messages at one log time: the checks once, then the packer."""
        key = topics if type(topics) is tuple else tuple(topics)
        file = self._file
        plan = file.sample_plans.get(key) if file is not None else None
        if plan is None or file.packer is None:
            return self._sample_one_by_one(log_time_ns, topics, data, types, key)
        start = self._clock()
        try:
            t = self._clamp(log_time_ns, len(data))
            if self._split_if_due(t):      # (the new file registers its channels again)
                return self._write_sample(log_time_ns, topics, data, types)
            names, channel_ids = plan
            file.packer.add_sample(channel_ids, self._next_sequences(names), data, t)
            self.bytes += sum(map(len, data))
            self.messages += len(names)
            if self._flush_policy.due(start, t):
                self._flush(start)
            return True
        except Exception as exc:  # noqa: BLE001 - never raise into the node
            self.dropped += len(data)
            self._set_fault(exc)
            return False
        finally:
            self.record_time_s += self._clock() - start

    def _write_sample_run(self, items) -> None:
        """
        Write consecutive samples from the writer's queue, in runs packed at once.

        The bytes are those _write_sample writes one by one. A run stops before a sample that
        would end the chunk, split the file or come after a due flush, so the lookups, checks and
        counters are done once per run (what that saves: docs/logging.md, mcap's Writer and
        readers).
        """
        i, n = 0, len(items)
        while i < n:
            start = self._clock()
            try:
                taken = self._pack_run(items, i, start)
            except Exception as exc:  # noqa: BLE001 - never raise into the node
                self.dropped += sum(len(item[2]) for item in items[i:])
                self._set_fault(exc)
                return
            finally:
                self.record_time_s += self._clock() - start
            if taken:
                i += taken
            else:   # a first sample, a chunk's end, a split or a flush: the one-by-one path
                self._write_sample(*items[i])
                i += 1

    def _run_window(self, items, i: int, start: float) -> list:
        """
        Return the samples from items[i] that may go in one run, in segments of one layout.

        See :func:`~.packing.layout_segments`; empty: the sample at i needs _write_sample.
        """
        file = self._file
        if (file is None or file.packer is None or self._rotation.file_start_t is None
                or self._flush_policy.wall_due(start)
                or self._rotation.size_reached(file.size())):
            return []
        return layout_segments(items, i, file.sample_plans,
                               file.packer.chunk_size - file.packer.chunk_used())

    def _pack_run(self, items, i: int, start: float) -> int:
        """
        Write the run of samples from items[i]; return how many.

        See _write_sample_run; 0: the sample at i needs _write_sample.
        """
        segments = self._run_window(items, i, start)
        if not segments:
            return 0
        given = [int(item[0]) for segment in segments for item in segment[2]]
        times = list(itertools.accumulate(given, max, initial=self._last_t))[1:]  # clamped
        # (the file splits before the first one past its span; a flush is due after the first
        # one past the sim-time period)
        end = self._flush_policy.run_end(times, self._rotation.run_end(times, len(times)))
        written = 0
        for (names, channel_ids), sizes, samples in segments:
            take = min(len(samples), end - written)
            if take <= 0:
                break
            count = self._pack_segment(names, channel_ids, sizes, samples[:take],
                                       given[written:written + take],
                                       times[written:written + take])
            written += count
            if count < take:   # (a sample of other payload sizes: the next run starts there)
                break
        if not written:
            return 0
        self._last_t = times[written - 1]
        if self._flush_policy.due(start, self._last_t):
            self._flush(start)
        return written

    def _pack_segment(self, names, channel_ids, sizes, samples, given, times) -> int:
        """Pack samples of one layout at (clamped) ``times``; return how many were written."""
        sequence = self._sequence
        firsts = [sequence.get(name, 0) for name in names]
        count = self._file.packer.pack_run(channel_ids, firsts, times,
                                           [item[2] for item in samples], sizes)
        for name, first in zip(names, firsts):
            sequence[name] = first + count
        self.clamped += len(sizes) * sum(a != b for a, b in zip(given[:count], times))
        self.bytes += sum(sizes) * count
        self.messages += len(names) * count
        return count

    # -- faults, state, closing --------------------------------------------------------------
    def _set_fault(self, exc: BaseException) -> None:
        if self.fault:
            return
        where = f' ({self.paths[-1]})' if self.paths else ''
        self.fault = f'logging stopped{where}: {type(exc).__name__}: {exc}'
        if self.on_fault is None:   # (else the owner reports it, once, in its own words)
            _logger.error(self.fault)
        file, self._file = self._file, None
        if file is not None:
            file.abandon()
        if self.on_fault is not None:
            try:
                self.on_fault(self.fault)
            except Exception:  # noqa: BLE001
                _logger.exception('on_fault callback failed')

    @property
    def active(self) -> bool:
        """Return True while messages are being written."""
        return self._file is not None

    @property
    def path(self) -> str:
        """Return the file being written (the last one after a split)."""
        return self.paths[-1] if self.paths else ''

    def counters(self, strings: bool = False) -> dict:
        """Messages, bytes, clamped and dropped counts, flushes, files, fault."""
        values = {'messages': self.messages, 'bytes': self.bytes, 'clamped': self.clamped,
                  'dropped': self.dropped, 'flushes': self.flushes, 'files': len(self.paths),
                  'fault': self.fault}
        return {k: str(v) for k, v in values.items()} if strings else values

    def close(self) -> None:
        """Write what is queued, finish and index the file (idempotent; never raises)."""
        _open_recorders.discard(self)
        self._mode.stop()
        if self._file is None:
            return
        try:
            self._close_file()
        except Exception as exc:  # noqa: BLE001
            self._set_fault(exc)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


_open_recorders: 'weakref.WeakSet[Recorder]' = weakref.WeakSet()


@atexit.register
def _close_open_recorders() -> None:  # pragma: no cover - runs at interpreter exit
    for recorder in list(_open_recorders):
        recorder.close()
