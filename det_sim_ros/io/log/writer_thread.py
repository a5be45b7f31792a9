"""
The recorder's background writer and the bound on its queue.

The writer is a thread that writes what the recording thread queued, in order, every
``period_s``.

The writer thread gets the GIL only now and then while the node's thread runs flat out, so in a
free run an unbounded queue grows without bound, and memory and the crash guarantee with it
(docs/logging.md, Why the writer is built this way). Past ``max_queue`` items the recording
thread writes the queue itself (:meth:`WriterThread.put`), under the same lock.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Callable

__all__ = ['WriterThread', 'NEW_FILE']

NEW_FILE = object()   # a queue item: continue in a new file here
_RUN = 16             # samples written between two releases of the GIL


class WriterThread:
    """
    The queue and its writer thread (named ``mcap-writer``, a daemon).

    :param write_message: ``(topic, data, log time, type name)`` -> write one message.
    :param write_samples: a list of ``(log time, topics, payloads, types)`` -> write them.
    :param new_file: continue in a new file.
    :param maybe_flush: flush if the wall-time period has passed.
    :param on_error: an exception raised by any of them (the writer stops writing nothing
        else: the callbacks handle their own faults).
    """

    def __init__(self, write_message: Callable, write_samples: Callable, new_file: Callable,
                 maybe_flush: Callable, on_error: Callable[[BaseException], None], *,
                 period_s: float = 0.01, max_queue: int = 64):
        self._queue = collections.deque()   # append/popleft are atomic
        self._lock = threading.RLock()       # one writer at a time: the thread or the recorder
        self._write_message, self._write_samples = write_message, write_samples
        self._new_file, self._maybe_flush, self._on_error = new_file, maybe_flush, on_error
        self.max_queue = max(1, int(max_queue))
        self.period_s = float(period_s)
        self.caught_up = 0    # times the recording thread wrote the queue itself
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name='mcap-writer', daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        """Return whether the thread takes items (until :meth:`stop`)."""
        return self._thread is not None

    def __len__(self) -> int:
        return len(self._queue)

    def put(self, item) -> None:
        """Queue ``item``; write the queue here when it holds more than ``max_queue``."""
        self._queue.append(item)
        if len(self._queue) > self.max_queue:
            self.caught_up += 1
            self._guarded(yield_gil=False)

    def write_queued(self) -> None:
        """Write everything queued now, in the calling thread."""
        self._guarded(yield_gil=False)

    def _guarded(self, yield_gil: bool) -> None:
        try:
            with self._lock:
                self._drain(yield_gil)
        except Exception as exc:  # noqa: BLE001 - a logging fault stops logging, nothing else
            self._on_error(exc)

    def _loop(self) -> None:
        try:
            while not self._stop.wait(self.period_s):
                with self._lock:
                    self._drain()
                    self._maybe_flush()
        except Exception as exc:  # noqa: BLE001 - a logging fault stops logging, nothing else
            self._on_error(exc)

    def _drain(self, yield_gil: bool = True) -> None:
        """
        Write everything queued, in order.

        ``yield_gil``: release the GIL every 16 samples (the writer thread, so the node's thread is
        not held up; the node's own catch-up must not: each release makes it wait for the GIL
        back; docs/logging.md).
        """
        queue = self._queue
        written = 0
        while queue:
            item = queue.popleft()
            if item is NEW_FILE:
                self._new_file()
            elif isinstance(item[0], str):      # (topic, data, time, type): one message
                self._write_message(*item)
            else:                               # samples: the ones queued after it too
                run = [item]
                while (queue and (len(run) < _RUN or not yield_gil) and queue[0] is not NEW_FILE
                       and not isinstance(queue[0][0], str)):
                    run.append(queue.popleft())
                self._write_samples(run)
                written += len(run) - 1
            written += 1
            if written >= _RUN and yield_gil:
                # hand the GIL to the node's thread now and then: a waiting publisher is held
                # up by at most 16 samples' writes, not by the whole queue; a release per
                # sample costs more CPU than the writes
                written = 0
                time.sleep(0)

    def stop(self) -> None:
        """Stop the thread and write what is queued (idempotent)."""
        if self._thread is None:
            return
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join()
        self._thread = None
        with self._lock:
            self._drain()
