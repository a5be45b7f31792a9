"""Real-time pacing: sim time follows the wall clock, and says why when it falls behind."""

from __future__ import annotations

import time
from typing import Callable

from .base import Pacing, PacingReport
from .realtime_priority import FifoRequest

__all__ = ['RealTimePacing', 'PeriodCost', 'behind_reason', 'BehindLog',
           'BEHIND_WARN_INTERVAL_S']

BEHIND_WARN_INTERVAL_S = 30.0   # wall s: at most one 'behind real time' WARN this often


class RealTimePacing(Pacing):
    """
    Sim time follows the wall clock times real_time_factor.

    Each tick runs the periods due; a lag beyond max_lag is dropped from the wall clock (a
    slip: sim time then runs below real time), never from the sim steps.
    """

    mode = 'real_time'
    PARAMETERS = ('real_time_factor', 'max_catchup_steps', 'max_lag')
    publishes_clock = False

    def __init__(self, get: Callable):
        self.late_ticks = 0
        self.slipped_s = 0.0
        self.max_lag_seen = 0     # most periods behind since the last report
        self._wall0 = 0.0         # the wall-clock reference and the period k at it
        self._k0 = 0
        self._cost = PeriodCost()
        self._fifo = FifoRequest(get('realtime_priority'))
        self._behind_log = None
        self._first_tick = True
        super().__init__(get)

    def start(self, node) -> None:
        super().start(node)
        logger = node.get_logger()
        self._behind_log = BehindLog(logger.warning, logger.info, lambda: node.wall_clock())
        self._cost.take(node.simulator)   # the first window starts here
        # the schedule starts at the first tick: the node's start-up after its timer was made
        # (the log opened, sample 0, the first spin) is what the first tick would otherwise
        # find due and slip. It moves by whole periods: the periods stay due just before the
        # timer's ticks (a schedule set at the first tick's own, late, time puts every period a
        # tick late). How long and how late: docs/real_time.md (Real-time pacing)
        self._first_tick = True

    def label(self) -> str:
        return 'real-time x%g' % self.real_time_factor

    def parameters_changed(self, get: Callable, names) -> None:
        self.max_catchup = get('max_catchup_steps')
        self.max_lag = get('max_lag')
        if 'real_time_factor' in names:
            self.real_time_factor = get('real_time_factor')
            if self._timer is not None:
                self.make_timer()     # the period changes

    def timer_spec(self) -> tuple:
        return self.node.dt / self.real_time_factor, self._tick, False

    def resync(self) -> None:
        self._wall0 = self.node.wall_clock()
        self._k0 = self.node.simulator.k

    def run(self, running: bool) -> None:
        self._first_tick = False   # a resume (or the gate opening) restarts the schedule now
        super().run(running)

    def steps_due(self, now: float) -> int:
        """Return the control periods the wall clock (at ``now``) is ahead of sim time."""
        # + 1e-6: a period is due at its boundary despite round-off (0.003 / 0.001 < 3)
        return (self._k0 + int((now - self._wall0) * self.real_time_factor / self.node.dt
                               + 1e-6) - self.node.simulator.k)

    def _tick(self) -> None:
        """Run the periods that are due; more than one due is a late tick."""
        node = self.node
        if not node.running:
            return
        due = self.steps_due(node.wall_clock())
        if self._first_tick:
            self._first_tick = False
            if due > 1:   # the rest of the start-up, whole periods: neither slipped nor run
                self._k0 -= due - 1
                due = 1
        if due <= 0:
            return
        if due > 1:
            self.late_ticks += 1
        dt = node.dt
        allowed = 1 + int(self.max_lag / dt + 1e-9)   # periods due at the largest lag
        if due > allowed:
            excess = due - allowed
            self._k0 -= excess            # the wall-clock reference moves: sim time slips
            self.slipped_s += excess * dt / self.real_time_factor
            due = allowed
        self.max_lag_seen = max(self.max_lag_seen, due - 1)
        for _ in range(min(due, self.max_catchup)):
            if not node.run_period():
                return

    def report(self, rate_hz: float, slipped_s: float, wall_s: float) -> PacingReport:
        node = self.node
        running = node.running
        lag = max(0, self.steps_due(node.wall_clock()) - 1) if running else 0
        max_lag = max(lag, self.max_lag_seen)
        self.max_lag_seen = 0
        dt, warning = node.dt, ''
        if running and wall_s > 0 and slipped_s > 0.01 * wall_s:
            # a user-visible slowdown: more than 1 % of the window's wall time dropped
            warning = (f'below real time: RTF {rate_hz * dt:.3f} of {self.real_time_factor:g} '
                       f'(slipped {slipped_s * 1e3:.0f} ms in the last {wall_s:.1f} s)')
        elif running and max_lag * dt > 0.5 * self.max_lag > 0.0:
            warning = (f'lagging: up to {max_lag * dt * 1e3:.0f} ms behind the wall clock '
                       f'(slips beyond {self.max_lag * 1e3:g} ms)')
        cpu_s, steps = self._cost.take(node.simulator)
        budget_s = dt / self.real_time_factor
        if self._behind_log is not None:
            self._behind_log.check(warning, behind_reason(cpu_s, steps, budget_s))
        values = {'cpu_per_period_ms': f'{cpu_s * 1e3:.3f}' if cpu_s is not None else '',
                  'steps_per_period': f'{steps:.1f}' if steps is not None else '',
                  'realtime_priority': self._fifo.state}
        return PacingReport(lag, max_lag, warning, values)

    def apply_priority(self, priority: int, logger) -> bool:
        """SCHED_FIFO at ``priority`` for every thread of the process; True if in force."""
        return self._fifo.apply(logger)


class PeriodCost:
    """
    What a window's periods cost: the node thread's CPU and the internal steps per period.

    The CPU is the calling thread's (``time.thread_time``) between two :meth:`take` calls,
    which the node's reports make from its executor's thread: the thread that takes the
    commands, steps, encodes, publishes, queues the log and runs the timers (not the log
    writer's thread, nor DDS's).
    """

    def __init__(self):
        self._mark = None     # (thread CPU s, internal steps, period k) at the last take

    def take(self, simulator) -> tuple:
        """Return (CPU s, internal steps) per period since the last take, or (None, None)."""
        now = (time.thread_time(), simulator.steps_taken, simulator.k)
        last, self._mark = self._mark, now
        if last is None or now[2] <= last[2] or now[1] < last[1]:   # none ran, or a reset
            return None, None
        periods = now[2] - last[2]
        return (now[0] - last[0]) / periods, (now[1] - last[1]) / periods


def behind_reason(cpu_s: float | None, steps: float | None, budget_s: float) -> str:
    """
    Say why a real-time node may be behind: a period's CPU against the wall time it is given.

    ``cpu_s`` is the CPU per period (s) of the node's thread, ``steps`` the integrator's
    internal steps per period, ``budget_s`` the wall time per period.
    """
    if cpu_s is None:
        return 'no period ran in the window (or it was reset)'
    text = (f'a period cost {cpu_s * 1e3:.3f} ms of CPU ({steps:.1f} internal steps) for '
            f'{budget_s * 1e3:.3f} ms of wall time')
    if cpu_s > 0.8 * budget_s:   # DDS's threads and the log writer need some of it too
        return (text + ': the periods take about all the CPU real time gives them (a looser '
                'integrator.tolerance, a lower fidelity or real_time_factor < 1 would fit)')
    return text + ': the node did not get the CPU in time (a busy host; see realtime_priority)'


class BehindLog:
    """
    Log when a real-time node falls behind (WARN, with why) and when it has caught up (INFO).

    :meth:`check` is called once per diagnostics window with that window's pacing warning
    ('' when on time). A WARN is logged at most once per ``interval_s`` of ``clock``; an
    episode that starts sooner is counted and named in the next WARN, and its end is not
    logged (its start was not).
    """

    def __init__(self, warn: Callable[[str], None], info: Callable[[str], None],
                 clock: Callable[[], float], interval_s: float = BEHIND_WARN_INTERVAL_S):
        self._warn, self._info, self._clock = warn, info, clock
        self.interval_s = interval_s
        self._since = None          # wall time the current episode started (None: on time)
        self._warned = False        # the current episode's start was logged
        self._last_warn = None
        self._unlogged = 0          # episodes not logged since the last WARN

    def check(self, warning: str, reason: str) -> None:
        """Follow one window: ``warning`` ('' = on time) and ``reason`` (its cost)."""
        now = self._clock()
        if warning and self._since is None:
            self._since = now
            self._warned = self._last_warn is None or now - self._last_warn >= self.interval_s
            if self._warned:
                more = (f' ({self._unlogged} more time(s) since the last warning)'
                        if self._unlogged else '')
                self._warn(f'behind real time{more}: {warning}; {reason}')
                self._last_warn, self._unlogged = now, 0
            else:
                self._unlogged += 1
        elif not warning and self._since is not None:
            if self._warned:
                self._info(f'caught up with real time after {now - self._since:.1f} s behind')
            self._since = None
