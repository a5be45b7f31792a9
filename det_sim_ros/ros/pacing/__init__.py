"""
When the node runs its control periods: one pacing object per mode.

``real_time``  a timer at dt / real_time_factor runs the periods that the wall clock says are
               due (catching up at most max_catchup_steps per tick; a lag beyond max_lag slips)
``free_run``   a 1 us timer runs steps_per_tick periods per tick and publishes them as a burst
``lockstep``   the controller's answers to the latest sample run the next period; the timer is
               only the deadline (lockstep.timeout), after which the voltages are held

In every mode sim time stays on the grid t = k dt: a pacing only decides when the node runs
its next period (:meth:`SimNode.run_period <det_sim_ros.ros.node.SimNode.run_period>`). The
node chooses its pacing once (:func:`make_pacing`) and calls the same few methods whatever the
mode. Wall times are in s.

Modules, by job: :mod:`.base` (the interface), one per mode (:mod:`.real_time`,
:mod:`.free_run`, :mod:`.lockstep`), and :mod:`.realtime_priority` (SCHED_FIFO).
"""

from __future__ import annotations

from typing import Callable

from .base import Pacing, PacingReport
from .free_run import FreeRunPacing
from .lockstep import LockstepPacing
from .real_time import BEHIND_WARN_INTERVAL_S, BehindLog, RealTimePacing
from .realtime_priority import set_thread_scheduling
from ...io.contract import MODES
from ...scenes.scene import SceneError

__all__ = ['BehindLog', 'BEHIND_WARN_INTERVAL_S', 'FreeRunPacing', 'LockstepPacing',
           'make_pacing', 'Pacing', 'PacingReport', 'RealTimePacing', 'set_thread_scheduling']


PACINGS = {pacing.mode: pacing for pacing in (RealTimePacing, FreeRunPacing, LockstepPacing)}
assert set(PACINGS) == set(MODES)


def make_pacing(get: Callable) -> Pacing:
    """Return the pacing the parameters ``mode`` and ``real_time`` (its alias) ask for."""
    mode = get('mode') or ('real_time' if get('real_time') else 'free_run')
    if mode not in PACINGS:
        raise SceneError(f"parameter 'mode': one of {', '.join(MODES)} (got {mode!r})")
    return PACINGS[mode](get)
