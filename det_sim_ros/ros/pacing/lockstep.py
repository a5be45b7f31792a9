"""Lockstep pacing: the next period runs when the controllers have answered the latest sample."""

from __future__ import annotations

import time
from typing import Callable

from .base import Pacing, PacingReport
from ..waiting import Wait

__all__ = ['LockstepPacing']


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

    def timer_spec(self) -> tuple:
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
