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

__all__ = ['FreeRunPacing', 'LockstepPacing', 'make_pacing', 'Pacing', 'PacingReport',
           'RealTimePacing', 'set_fifo_priority']


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
        super().__init__(get)

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
        return PacingReport(lag, max_lag, warning, {})

    def apply_priority(self, priority: int, logger) -> bool:
        changed, refused = set_fifo_priority(priority)
        if refused:
            logger.warning(f'realtime_priority {priority}: SCHED_FIFO refused ({refused}); '
                           'running with normal scheduling (grant CAP_SYS_NICE, or an rtprio '
                           'limit in /etc/security/limits.conf)')
        else:
            logger.info(f'SCHED_FIFO priority {priority} for {changed} thread(s)')
        return not refused


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


def set_fifo_priority(priority: int) -> tuple[int, str]:
    """
    Set SCHED_FIFO at ``priority`` for every thread of this process, all or nothing.

    The threads are the executor's, DDS's and the log writer's; threads started later inherit
    the priority. Return (threads changed, the reason it was refused or '').
    """
    changed, refused = 0, ''
    for tid in sorted(int(t) for t in os.listdir('/proc/self/task')):
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            changed += 1
        except ProcessLookupError:   # a thread that has just ended
            continue
        except (PermissionError, OSError) as exc:
            refused = exc.strerror or str(exc)
            break
    if refused:
        for tid in (int(t) for t in os.listdir('/proc/self/task')):
            try:
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
            except OSError:
                pass
    return changed, refused
