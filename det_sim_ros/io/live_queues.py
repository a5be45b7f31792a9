"""
The live view's hand-overs between threads, each bounded and counted.

A Foxglove WebSocket server runs its callbacks on threads of its own; sim_node's state belongs
to its executor thread, and its samples leave through a sender thread. :class:`CallQueue`
carries client requests to the thread that owns the state (bounded: a full queue refuses;
a call that timed out before it started is cancelled, never run late; one that started and
has not finished is :class:`Pending`, and its outcome is handed over when it comes);
:class:`SampleQueue` carries samples to
the sender (bounded: the oldest go, counted). Neither imports ROS.
"""

from __future__ import annotations

from collections import deque
import threading
from typing import Callable

__all__ = ['Busy', 'CallQueue', 'Pending', 'SampleQueue']


class Busy(RuntimeError):
    """The call queue is full: the request is refused (the reason is the text)."""


class Pending(TimeoutError):
    """A call started on the worker thread and not finished in time: it goes on."""


_WAITING, _RUNNING, _CANCELLED = 'waiting', 'running', 'cancelled'


class _Work:
    __slots__ = ('work', 'state', 'done', 'outcome', 'late')

    def __init__(self, work):
        self.work, self.state, self.done, self.outcome = work, _WAITING, None, None
        self.late = None   # called with the outcome when the caller stopped waiting for it


class CallQueue:
    """
    Work handed from other threads to one worker thread, which runs it with :meth:`run_pending`.

    At most ``limit`` pieces of work wait; beyond that :meth:`post` and :meth:`call` raise
    :class:`Busy`. A :meth:`call` not run within ``timeout_s`` is cancelled and raises
    TimeoutError: it never runs afterwards; one that started and has not finished within
    another ``timeout_s`` raises :class:`Pending` (it goes on; its outcome goes to the call's
    ``late``). Posted work that raises is counted and its exception handed to ``on_error``
    (on the worker thread); the worker never sees it.

    Counters: ``refused`` (queue full), ``timed_out``, ``pending`` (answered Pending),
    ``failed`` (posted work that raised), ``most`` (the longest the queue has been).
    """

    def __init__(self, limit: int, timeout_s: float,
                 on_error: Callable[[Exception], None] = lambda exc: None):
        self.limit, self.timeout_s = int(limit), float(timeout_s)
        self._on_error = on_error
        self._pending: deque[_Work] = deque()
        self._lock = threading.Lock()
        self.refused = self.timed_out = self.pending = self.failed = self.most = 0

    def __len__(self) -> int:
        return len(self._pending)

    def _put(self, item: _Work) -> None:
        with self._lock:
            if len(self._pending) >= self.limit:
                self.refused += 1
                raise Busy(f'the node is busy: {self.limit} client requests are waiting')
            self._pending.append(item)
            self.most = max(self.most, len(self._pending))

    def post(self, work: Callable[[], object]) -> None:
        """Run ``work()`` on the worker thread soon; do not wait. :class:`Busy` if full."""
        self._put(_Work(work))

    def call(self, work: Callable[[], object],
             late: Callable[[bool, object], None] | None = None):
        """
        Run ``work()`` on the worker thread; return its result (its exception raised).

        :param late: called on the worker thread with (True, result) or (False, exception)
            when the work finishes after :class:`Pending` was raised.
        :raises Busy: the queue is full (nothing runs).
        :raises TimeoutError: not started within ``timeout_s`` (cancelled: nothing runs).
        :raises Pending: started, not finished within another ``timeout_s``: it goes on.
        """
        item = _Work(work)
        item.done = threading.Event()
        self._put(item)
        if not item.done.wait(self.timeout_s):
            with self._lock:
                if item.state == _WAITING:   # not started: it never will
                    item.state = _CANCELLED
                    self._pending.remove(item)
                    self.timed_out += 1
                    raise TimeoutError(f'the node did not answer within {self.timeout_s:g} s; '
                                       'nothing was done')
            # started just now: its outcome is the answer (the work is short)
            if not item.done.wait(self.timeout_s):
                with self._lock:
                    if item.outcome is None:   # still running: say so, hand its outcome on
                        item.late = late
                        self.pending += 1
                        raise Pending(f'the node started it and has not finished within '
                                      f'{2 * self.timeout_s:g} s; it goes on, its outcome '
                                      'follows')
        ok, value = item.outcome
        if not ok:
            raise value
        return value

    def run_pending(self) -> None:
        """
        Run the work waiting now (on the worker thread).

        Work posted while it runs waits for the next call, so a flood of requests cannot keep
        the worker here.
        """
        for _ in range(len(self._pending)):
            with self._lock:
                if not self._pending:
                    return
                item = self._pending.popleft()
                item.state = _RUNNING
            try:
                outcome = (True, item.work())
            except Exception as exc:  # noqa: BLE001 - a caller's answer, or counted
                outcome = (False, exc)
                if item.done is None:
                    self.failed += 1
                    self._on_error(exc)
            with self._lock:
                item.outcome, late = outcome, item.late
            if item.done is not None:
                item.done.set()
            if late is not None:
                try:
                    late(*outcome)
                except Exception as exc:  # noqa: BLE001 - counted, handed over
                    self.failed += 1
                    self._on_error(exc)


class SampleQueue:
    """
    Batches of samples from a producer to one consumer, at most ``limit`` waiting.

    When a batch does not fit the oldest waiting samples are dropped and counted
    (``dropped``); ``most`` is the longest the queue has been.
    """

    def __init__(self, limit: int):
        self.limit = int(limit)
        self._queue: deque = deque(maxlen=self.limit)
        self._lock = threading.Lock()
        self.dropped = self.most = 0

    def __len__(self) -> int:
        return len(self._queue)

    def put(self, batch) -> None:
        """Append a batch (a sequence of samples); drop (and count) the oldest beyond the limit."""
        with self._lock:
            queue = self._queue
            self.dropped += max(0, len(queue) + len(batch) - self.limit)
            queue.extend(batch)
            self.most = max(self.most, len(queue))

    def take(self) -> deque:
        """Return what waits (oldest first) and empty the queue."""
        with self._lock:
            taken, self._queue = self._queue, deque(maxlen=self.limit)
        return taken
