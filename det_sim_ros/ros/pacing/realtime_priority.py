"""``realtime_priority``: SCHED_FIFO for the node's threads (Linux), all or nothing."""

from __future__ import annotations

import os

__all__ = ['FifoRequest', 'set_thread_scheduling']


class FifoRequest:
    """
    ``realtime_priority``: SCHED_FIFO for every thread of the node's process, all or nothing.

    Not the stepping thread alone, which measured worse: it shares locks with DDS's threads (a
    publisher's history, a subscription's queue) and the GIL with the log writer, and one of
    those holding one while a busy process has its core holds the stepping thread up (the
    likely cause; not traced to the lock). The arrival lags of each choice:
    docs/performance.md (Real time through switching; bench/realtime_switching.py), from
    docs/real_time.md (Scheduling priority). Threads started later inherit the policy from the
    thread that starts them. ``state`` says what is in force: 'off', 'SCHED_FIFO N' or why it
    was refused.
    """

    def __init__(self, priority: int):
        self.priority = priority
        self.state = 'off'

    def apply(self, logger) -> bool:
        """Put every thread of the process at SCHED_FIFO; True if in force."""
        tids = sorted(int(t) for t in os.listdir('/proc/self/task'))
        changed, refused = 0, ''
        for tid in tids:
            refused = set_thread_scheduling(tid, self.priority)
            if refused:
                break
            changed += 1
        if refused:
            for tid in tids:
                set_thread_scheduling(tid, 0)
            self.state = f'refused ({refused})'
            logger.warning(f'realtime_priority {self.priority}: SCHED_FIFO refused ({refused}); '
                           'running with normal scheduling (grant CAP_SYS_NICE, or an rtprio '
                           'limit in /etc/security/limits.conf)')
            return False
        self.state = f'SCHED_FIFO {self.priority}'
        logger.info(f'SCHED_FIFO priority {self.priority} for {changed} thread(s) (stepping, '
                    'DDS, rclpy, log writer)')
        return True


def set_thread_scheduling(tid: int, priority: int) -> str:
    """
    Put thread ``tid`` (a native id) at SCHED_FIFO ``priority``, or back to SCHED_OTHER if 0.

    Return '' or why the system refused (e.g. 'Operation not permitted' without CAP_SYS_NICE).
    """
    policy = os.SCHED_FIFO if priority else os.SCHED_OTHER
    try:
        os.sched_setscheduler(tid, policy, os.sched_param(priority))
    except ProcessLookupError:   # a thread that has ended
        return ''
    except (PermissionError, OSError, AttributeError) as exc:   # (no sched_* outside Linux)
        return getattr(exc, 'strerror', None) or str(exc)
    return ''
