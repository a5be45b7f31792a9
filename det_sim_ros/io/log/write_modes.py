"""
How the recorder's records reach the file.

:class:`WriteNow` writes them in the recording thread; :class:`WriteBehind`
(``background=True``) queues their bytes for the
:class:`~det_sim_ros.io.log.writer_thread.WriterThread`.

A mode is given the :class:`~det_sim_ros.io.log.recorder.Recorder` it serves (its public state:
``active``, ``fault``, ``dropped``, ``type_of``) and the recorder's writing steps as a
:class:`WriteSteps`: the seam between the two is these callables, not the recorder's insides.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

from .writer_thread import NEW_FILE, WriterThread
from ..cdr import serialize
from ..schemas import type_name_of

__all__ = ['WriteNow', 'WriteBehind', 'WriteSteps']


@dataclasses.dataclass(frozen=True)
class WriteSteps:
    """
    The recorder's steps that put records in the file, in the calling thread.

    Given to a mode by the :class:`~det_sim_ros.io.log.recorder.Recorder`; a mode calls them
    from the recording thread (:class:`WriteNow`) or hands them to the writer thread
    (:class:`WriteBehind`), never both.
    """

    message: Callable       # (topic, msg, log_time_ns, type_name) -> bool
    sample: Callable        # (log_time_ns, topics, data, types) -> bool
    sample_run: Callable    # (queued samples) -> None: consecutive samples, packed in runs
    new_file: Callable      # () -> None: finish the file and open the next one now
    maybe_flush: Callable   # () -> None: flush if the wall-time period has passed
    fault: Callable         # (exception) -> None: stop recording on an error


class WriteNow:
    """Records are written in the recording thread, as they come."""

    caught_up = 0
    queued = 0

    def __init__(self, recorder, steps: WriteSteps):
        self._recorder = recorder
        self._steps = steps

    def message(self, topic: str, msg, log_time_ns: int, type_name: str | None) -> bool:
        """Write a message: Recorder.record."""
        recorder = self._recorder
        if not recorder.active:
            recorder.dropped += 1
            return False
        return self._steps.message(topic, msg, log_time_ns, type_name)

    def sample(self, log_time_ns: int, topics, data, types) -> bool:
        """Write a sample: Recorder.record_sample."""
        recorder = self._recorder
        if not recorder.active:
            recorder.dropped += len(data)
            return False
        return self._steps.sample(log_time_ns, topics, data, types)

    def new_file(self) -> None:
        """Continue in a new file now."""
        self._steps.new_file()

    def stop(self) -> None:
        """Nothing is pending."""


class WriteBehind:
    """
    Records queued as bytes, written by the writer thread.

    The bytes are serialized here; the writer thread writes, compresses and flushes them in
    order. The thread owns the file (None for a moment between two files), so queueing depends
    only on whether recording has stopped.
    """

    def __init__(self, recorder, steps: WriteSteps, period_s: float, max_queue: int):
        self._recorder = recorder
        self._steps = steps
        self._thread = WriterThread(steps.message, steps.sample_run, steps.new_file,
                                    steps.maybe_flush, steps.fault, period_s=period_s,
                                    max_queue=max_queue)

    @property
    def caught_up(self) -> int:
        """Return how many times the recording thread wrote the queue itself."""
        return self._thread.caught_up

    @property
    def queued(self) -> int:
        """Items waiting for the writer thread."""
        return len(self._thread)

    def _stopped(self, count: int) -> bool:
        recorder = self._recorder
        if recorder.fault or not self._thread.running:
            recorder.dropped += count
            return True
        return False

    def message(self, topic: str, msg, log_time_ns: int, type_name: str | None) -> bool:
        """Queue a message: Recorder.record."""
        if self._stopped(1):
            return False
        if isinstance(msg, (bytearray, memoryview)):
            msg = bytes(msg)
        elif not isinstance(msg, bytes):   # serialized here: the queue holds bytes only
            type_name = type_name or self._recorder.type_of(topic) or type_name_of(msg)
            msg = serialize(msg)
        self._thread.put((topic, msg, log_time_ns, type_name))
        return True

    def sample(self, log_time_ns: int, topics, data, types) -> bool:
        """Queue a sample: Recorder.record_sample."""
        if self._stopped(len(data)):
            return False
        self._thread.put((log_time_ns, topics, data, types))
        return True

    def new_file(self) -> None:
        """Continue in a new file after what is queued; it is open on return."""
        if self._recorder.active:
            self._thread.put(NEW_FILE)
            self._thread.write_queued()   # the caller may report the new file's name
        else:
            self._steps.new_file()

    def stop(self) -> None:
        """Stop the thread after writing what is queued."""
        self._thread.stop()
