"""
When the recorder flushes: after a wall-time period or a log (sim) time period.

Every ``period_s`` of wall time and every ``sim_ns`` of log (sim) time, whichever comes
first. A flush bounds what a SIGKILL loses; the sim-time bound holds whatever the speed of the
run, where a wall-clock period alone loses more sim time the faster a free run goes
(docs/logging.md, Why the writer is built this way).
"""

from __future__ import annotations

import bisect
from typing import Callable

__all__ = ['FlushPolicy']


class FlushPolicy:
    """
    Decide when the recorder flushes (see the module docstring).

    :param period_s: wall time between flushes (s; 0: after every message).
    :param sim_s: log time between flushes (s; 0: wall time only).
    :param clock: the wall clock (s).
    """

    def __init__(self, period_s: float, sim_s: float, clock: Callable[[], float]):
        self.period_s = float(period_s)
        self.sim_ns = int(float(sim_s) * 1e9)
        self.clock = clock
        self._last_wall = 0.0   # (restart() when a file is opened)
        self._last_t = 0

    def restart(self, t: int) -> None:
        """Start a new file at log time ``t``: both periods count from now."""
        self.done(self.clock(), t)

    def done(self, now: float, t: int) -> None:
        """Note a flush at wall time ``now``, after log time ``t``."""
        self._last_wall = now
        self._last_t = t

    def wall_due(self, now: float) -> bool:
        """Return whether the wall-time period has passed."""
        return now - self._last_wall >= self.period_s

    def due(self, now: float, t: int) -> bool:
        """Return whether a flush is due after the message at log time ``t``."""
        return self.wall_due(now) or bool(self.sim_ns and t - self._last_t >= self.sim_ns)

    def run_end(self, times, end: int) -> int:
        """
        Return how many log ``times`` may be written before a flush is due.

        ``times`` are non-decreasing; the flush is due after the last one written; at most
        ``end``.
        """
        if not self.sim_ns:
            return end
        return min(end, bisect.bisect_left(times, self._last_t + self.sim_ns) + 1)
