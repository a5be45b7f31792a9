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
"""

from __future__ import annotations

import os
import time
from typing import Callable, NamedTuple

from .waiting import Wait
from ..io.contract import MODES
from ..scenes.scene import SceneError

__all__ = ['BehindLog', 'FreeRunPacing', 'LockstepPacing', 'make_pacing', 'Pacing',
           'PacingReport', 'RealTimePacing', 'set_thread_scheduling']

BEHIND_WARN_INTERVAL_S = 30.0   # wall s: at most one 'behind real time' WARN this often


class PacingReport(NamedTuple):
    """A pacing's part of one /diagnostics message."""

    lag_steps: int        # periods behind the wall clock now
    max_lag_steps: int    # most periods behind since the previous report
    warning: str          # a WARN message, '' if none
    values: dict          # its own diagnostics keys (key -> text)


class Pacing:
    """
    The interface of every pacing, with what most modes share.

    The base class holds the common interface and what most modes share: one timer that runs
    while the node runs, no wall-clock reference, nothing to add to diagnostics.

    What a pacing uses of its node: ``dt``, ``simulator``, ``running``, ``paused``,
    ``wall_clock``, ``steady_clock``, ``run_period``, ``send``, ``subscriptions_matched``,
    ``command_subscriptions``, ``run_due_reports``, ``create_timer``, ``destroy_timer`` and
    ``get_logger``.

    :param get: a parameter's current value by name (``PARAMETERS`` are read).
    """

    mode = ''
    PARAMETERS: tuple = ()      # the runtime-changeable parameters this mode reads
    publishes_clock = True      # sim time on /clock (a use_sim_time node follows it)
    late_ticks = 0              # ticks that found more than one period due (real time)
    slipped_s = 0.0             # wall time dropped because the lag exceeded max_lag

    def __init__(self, get: Callable):
        self.node = None
        self._timer = None
        self.parameters_changed(get, self.PARAMETERS)

    def label(self) -> str:
        """Return the mode as the start-up INFO line names it."""
        return self.mode.replace('_', '-')

    def start(self, node) -> None:
        """Create the timers on ``node`` (stopped while the node is paused)."""
        self.node = node
        self.make_timer()

    def parameters_changed(self, get: Callable, names) -> None:
        """Read the parameters (``names``: those that changed)."""

    def make_timer(self) -> None:
        """(Re)create the pacing timer, from now."""
        node = self.node
        if self._timer is not None:
            node.destroy_timer(self._timer)
        self.resync()
        period, callback, idle = self._timer_spec()
        self._timer = node.create_timer(period, callback, clock=node.steady_clock,
                                        autostart=node.running and not idle)

    def _timer_spec(self) -> tuple:
        """(period in wall s, callback, idle: the timer stays stopped even when running)."""
        raise NotImplementedError

    def resync(self) -> None:
        """Restart the wall-clock reference (real time): no catch-up for time not running."""

    def run(self, running: bool) -> None:
        """Follow the node as it starts (resumes, is reset) or stops running."""
        if running:
            self.resync()
            self._timer.reset()
        else:
            self._timer.cancel()

    def stop(self) -> None:
        """Stop the timer (a fault, or the context shutting down)."""
        self._timer.cancel()

    def sample_ready(self, k: int, samples) -> None:
        """Prepare for sample k (its CDR bytes per output topic), about to be published."""

    def command_received(self, command) -> None:
        """Count a command that has arrived (decoded, applied or refused)."""

    def reset(self) -> None:
        """Follow the simulation back to t = 0."""

    def waiting(self) -> Wait | None:
        """Return what the node waits for before its next period (None: nothing)."""
        return None

    def report(self, rate_hz: float, slipped_s: float, wall_s: float) -> PacingReport:
        """
        Return this mode's diagnostics for a window of ``wall_s``.

        In the window ``rate_hz`` periods per second ran and ``slipped_s`` of wall time was
        dropped.
        """
        return PacingReport(0, 0, '', {})

    def apply_priority(self, priority: int, logger) -> bool:
        """SCHED_FIFO at ``priority`` for the process's threads; True if in force."""
        logger.warning(f'realtime_priority: only in real_time mode (mode is {self.mode}); '
                       'scheduling unchanged')
        return False


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
        # (the log opened, sample 0, the first spin) took 0.1-0.2 s beside a busy core, which
        # the first tick would otherwise find due and slip. It moves by whole periods: the
        # periods stay due just before the timer's ticks (a schedule set at the first tick's
        # own, late, time put every period a tick late: ~1 ms of lag)
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

    def _timer_spec(self) -> tuple:
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


class FifoRequest:
    """
    ``realtime_priority``: SCHED_FIFO for every thread of the node's process, all or nothing.

    Not the stepping thread alone, measured: it shares locks with DDS's threads (a publisher's
    history, a subscription's queue) and the GIL with the log writer, and one of those holding
    one while a busy process has its core holds the stepping thread up (the likely cause; not
    traced to the lock). Beside a busy core, a
    controller at SCHED_FIFO 40, 20-30 s runs: arrival lag p99 5.7-42 ms with the stepping
    thread alone, 1.1-7.7 ms with every thread but the log writer (the stepping thread writing
    the log), 0.6-1.0 ms with every thread (bench/realtime_switching.py). Threads started
    later inherit the policy from the thread that starts them. ``state`` says what is in
    force: 'off', 'SCHED_FIFO N' or why it was refused.
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


class FreeRunPacing(Pacing):
    """
    As fast as possible: each tick runs steps_per_tick periods, then publishes them.

    The samples go out back to back: DDS spends about half the CPU per message on a burst that
    it spends on the same messages ~0.1 ms apart (it wakes its own and the subscribers'
    threads per message then; measured on the 2-core test host), and free run has no
    wall-clock deadline to keep. Commands are still taken before every period.

    The always-due 1 us timer starves the node's other timers in rclpy's EventsExecutor (a 1 s
    timer next to it fired at 1, 2, 2, 4, 4, 4, 7 s...), so each tick also runs the node's
    periodic reports that are due by the wall clock (``run_due_reports``).
    """

    mode = 'free_run'
    PARAMETERS = ('steps_per_tick',)

    def parameters_changed(self, get: Callable, names) -> None:
        self.steps_per_tick = get('steps_per_tick')

    def _timer_spec(self) -> tuple:
        return 1.0e-6, self._tick, False

    def _tick(self) -> None:
        node = self.node
        if not node.running:
            return
        batch = []
        try:
            for _ in range(self.steps_per_tick):
                if not node.run_period(batch):
                    return
        finally:
            if node.send(batch):
                node.run_due_reports()


class LockstepPacing(Pacing):
    """
    The next period runs once every expected source has answered the latest sample.

    The expected sources are lockstep.sources. A JointState command answers the sample its
    header stamp names (an unset stamp, 0, the latest); a Float64MultiArray the latest sample.
    A refused command answers too (the voltages are held). Answers to older samples are
    applied but do not count. A sample whose displacement a sensor dropped needs no answer
    (nobody received it).
    """

    mode = 'lockstep'
    PARAMETERS = ('lockstep.sources', 'lockstep.timeout')
    RESEND_PERIOD_S = 0.05

    def __init__(self, get: Callable):
        self.answers = 0            # answers to the latest sample
        self.stale_answers = 0      # JointState commands stamped with an older sample
        self.missed_deadlines = 0
        self.wait_s = 0.0           # wall time spent waiting for answers
        self._missed_seen = 0       # missed deadlines at the last report
        self._published_wall = time.perf_counter()
        self._stepping = False
        self._last_sample = ()      # the bytes of sample 0 (re-sent until answered)
        self._heard_by = 0          # subscriptions matched when sample 0 was published
        super().__init__(get)

    def start(self, node) -> None:
        super().start(node)
        node.create_timer(self.RESEND_PERIOD_S, self._resend, clock=node.steady_clock)
        # a sample whose displacement a sensor dropped has no answer to wait for: the next
        # period runs from the executor (not nested in this one's publication)
        self._unheard = node.create_timer(1.0e-6, self._run_unheard, clock=node.steady_clock)
        self._unheard.cancel()

    def _run_unheard(self) -> None:
        self._unheard.cancel()
        self._advance()

    def parameters_changed(self, get: Callable, names) -> None:
        self.sources = get('lockstep.sources')
        if 'lockstep.timeout' in names:
            self.timeout = get('lockstep.timeout')
            if self._timer is not None:
                self.make_timer()
        self._advance()   # fewer sources may already have answered

    def _timer_spec(self) -> tuple:
        return self.timeout or 3600.0, self._deadline, not self.timeout

    def run(self, running: bool) -> None:
        if running:
            if self.timeout:
                self._timer.reset()
            self._advance()   # the answers may have come while paused
        else:
            self._timer.cancel()

    def sample_ready(self, k: int, samples) -> None:
        """Wait for the answers to a new sample (until the deadline)."""
        self.answers = 0
        self._published_wall = time.perf_counter()
        if self.timeout and not self.node.paused:
            self._timer.reset()
        if k == 0:
            self._last_sample = samples
            self._heard_by = self.node.subscriptions_matched()
        if not self.node.outputs.heard(samples):
            self.answers = self.sources
            self._unheard.reset()

    def command_received(self, command) -> None:
        node = self.node
        if command.stamp_ns:
            answered = int(round(command.stamp_ns * 1e-9 / node.dt))
            if answered < node.simulator.k:
                self.stale_answers += 1
                return
        self.answers += 1
        self._advance()

    def reset(self) -> None:
        self.answers = 0   # answers to the old run's last sample do not start the new one

    def waiting(self) -> Wait | None:
        """Return the wait for the answers to the latest sample (None while not waiting)."""
        node = self.node
        if (node is None or self._stepping or not node.running
                or self.answers >= self.sources):
            return None
        subscriptions = node.command_subscriptions.values()
        heard = [sub.topic_name for sub in subscriptions if sub.get_publisher_count()]
        return Wait(time.perf_counter() - self._published_wall, self.sources - self.answers,
                    'answer', heard or [sub.topic_name for sub in subscriptions], self.answers,
                    self.sources, f'to t = {node.simulator.t:.6g} s',
                    '' if heard else 'no publisher matched')

    def _advance(self) -> None:
        """Run the next period once every expected source has answered."""
        node = self.node
        if (node is None or self._stepping or not node.running
                or self.answers < self.sources):
            return
        self.wait_s += time.perf_counter() - self._published_wall
        self._run_period()

    def _deadline(self) -> None:
        """Hold the voltages and go on: the answers did not come in time."""
        node = self.node
        if not node.running:
            return
        self.missed_deadlines += 1
        node.get_logger().warning(
            f'lockstep: {self.answers} of {self.sources} answer(s) to t = '
            f'{node.simulator.t:.6g} s within {self.timeout:g} s; holding the voltages '
            f'({self.missed_deadlines} missed)', throttle_duration_sec=1.0)
        self.wait_s += time.perf_counter() - self._published_wall
        self._run_period()

    def _run_period(self) -> None:
        # answers taken during the period count for the next sample, not as a nested period
        self._stepping = True
        try:
            self.node.run_period()
        finally:
            self._stepping = False

    def _resend(self) -> None:
        """
        Re-send sample 0 (not logged) to subscriptions matched since, until it is answered.

        At t = 0 (also after ~/reset) a controller discovered after sample 0 was published
        never saw it, and both would wait forever: sample 0 is re-sent when new subscriptions
        have matched since, until it is answered.
        """
        node = self.node
        if node.simulator.k != 0 or self.answers >= self.sources or not self._last_sample:
            return
        matched = node.subscriptions_matched()
        if matched > self._heard_by:
            self._heard_by = matched
            node.send(((0, self._last_sample, None),))

    def report(self, rate_hz: float, slipped_s: float, wall_s: float) -> PacingReport:
        missed = self.missed_deadlines - self._missed_seen
        self._missed_seen = self.missed_deadlines
        warning = (f'lockstep: {missed} missed deadline(s) in the last {wall_s:.1f} s (the '
                   f'controller did not answer within {self.timeout:g} s)' if missed > 0
                   else '')
        return PacingReport(0, 0, warning, {
            'lockstep_answers': f'{self.answers} of {self.sources}',
            'lockstep_missed_deadlines': str(self.missed_deadlines),
            'lockstep_stale_answers': str(self.stale_answers),
            'lockstep_wait_s': f'{self.wait_s:.3f}'})


PACINGS = {pacing.mode: pacing for pacing in (RealTimePacing, FreeRunPacing, LockstepPacing)}
assert set(PACINGS) == set(MODES)


def make_pacing(get: Callable) -> Pacing:
    """Return the pacing the parameters ``mode`` and ``real_time`` (its alias) ask for."""
    mode = get('mode') or ('real_time' if get('real_time') else 'free_run')
    if mode not in PACINGS:
        raise SceneError(f"parameter 'mode': one of {', '.join(MODES)} (got {mode!r})")
    return PACINGS[mode](get)


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
