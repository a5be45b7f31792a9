"""
What a running node is waiting for, said in its log, its INFO line and /diagnostics.

A node can wait for two things: a lockstep node for its controllers' answers to the latest
sample (:class:`~det_sim_ros.ros.pacing.LockstepPacing`), and a node started with
``wait_for_subscribers`` for that many subscriptions of its ``displacement`` output before
sample 0 (:class:`SubscriberGate`). Each describes its wait as a :class:`Wait`; once a wait has
lasted ``REPORT_AFTER_S`` it is shown: one INFO line when it passes that age and one when it
ends (:class:`WaitLog`), the periodic INFO line and the /diagnostics message name it while it
lasts. ``det_sim fleet`` relays the two log lines per node (``WAIT_STARTED``, ``WAIT_OVER``).
Wall times in s. No ROS here: the node passes in what its endpoints report.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

__all__ = ['REPORT_AFTER_S', 'SubscriberGate', 'Wait', 'WAIT_OVER', 'WAIT_STARTED', 'WaitLog']

REPORT_AFTER_S = 1.0      # shorter waits are a controller's normal reply time
WAIT_STARTED = 'waiting '   # how the log line of a wait that has passed REPORT_AFTER_S starts
WAIT_OVER = 'wait over after '   # how the log line of its end starts


class Wait(NamedTuple):
    """One wait of the node: for ``missing`` more ``noun``s on ``topics`` (``got`` of ``need``)."""

    seconds: float            # wall time waited so far
    missing: int              # answers (subscriptions) still to come
    noun: str                 # 'answer' or 'subscriber'
    topics: Sequence[str]     # the topics they come on (any one of them)
    got: int
    need: int
    detail: str = ''          # e.g. which sample; '' for none
    note: str = ''            # added after the counts, e.g. that no publisher has matched

    def text(self) -> str:
        """Return the wait as the log and /diagnostics say it (see the module docstring)."""
        plural = '' if self.missing == 1 else 's'
        detail = f' {self.detail}' if self.detail else ''
        return (f'{WAIT_STARTED}{self.seconds:.1f} s for {self.missing} {self.noun}{plural}'
                f'{detail} on {" or ".join(self.topics)} ({self.got} of {self.need}'
                + (f'; {self.note})' if self.note else ')'))

    def shown(self) -> bool:
        """Return True once the wait is long enough to be reported."""
        return self.seconds >= REPORT_AFTER_S


class WaitLog:
    """
    Log a node's waits: one line when a wait passes ``REPORT_AFTER_S``, one when it ends.

    :param info: the logger's ``info`` (called with the line).
    """

    def __init__(self, info: Callable[[str], None]):
        self._info = info
        self._reported: Wait | None = None    # the wait that has been logged, still lasting

    def check(self, wait: Wait | None) -> None:
        """Log what changed since the last call; ``wait`` is the node's wait now, or None."""
        if wait is not None and wait.shown():
            if self._reported is None:
                self._info(wait.text())
            self._reported = wait
        elif self._reported is not None:
            self._info(f'{WAIT_OVER}{self._reported.seconds:.1f} s; running')
            self._reported = None


class SubscriberGate:
    """
    Hold sample 0 and the stepping until ``need`` subscriptions of the output have matched.

    While closed, the node publishes nothing and does not step (the pacing is not running).
    It opens once ``matched()`` reaches ``need`` and sample 0, then published, has been
    acknowledged by every matched reliable subscription (``acked()``): so the subscriber has
    sample 0 before sample 1 exists, even at depth 1. A best-effort output acknowledges at once.

    :param need: subscriptions to wait for (0: open from the start).
    :param topic: the output topic they are counted on (resolved name).
    :param matched: the number of subscriptions matched now.
    :param acked: True once every matched subscription has acknowledged what was published.
    :param clock: wall clock, s.
    """

    def __init__(self, need: int, topic: str, matched: Callable[[], int],
                 acked: Callable[[], bool], clock: Callable[[], float]):
        self.need, self.topic = need, topic
        self._matched, self._acked, self._clock = matched, acked, clock
        self._since = clock()
        self.sample_zero_sent = need == 0
        self.open = need == 0

    def poll(self, publish_sample_zero: Callable[[], None]) -> bool:
        """Publish sample 0 when the subscriptions have matched; return True once open."""
        if self.open:
            return True
        if not self.sample_zero_sent:
            if self._matched() < self.need:
                return False
            publish_sample_zero()
            self.sample_zero_sent = True
        self.open = self._acked()
        return self.open

    def restart(self) -> None:
        """Hold sample 0 again (a reset before the gate opened): it is re-published on opening."""
        if not self.open:
            self.sample_zero_sent = False

    def waiting(self) -> Wait | None:
        """Return the wait while closed, else None."""
        if self.open:
            return None
        got = min(self._matched(), self.need)
        return Wait(self._clock() - self._since, max(self.need - got, 0) or 1, 'subscriber',
                    (self.topic,), got, self.need,
                    'to acknowledge sample 0' if self.sample_zero_sent else '')
