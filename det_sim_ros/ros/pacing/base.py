"""The interface every pacing has (:class:`Pacing`) and its part of the diagnostics."""

from __future__ import annotations

from typing import Callable, NamedTuple

from ..waiting import Wait

__all__ = ['Pacing', 'PacingReport']


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
        period, callback, idle = self.timer_spec()
        self._timer = node.create_timer(period, callback, clock=node.steady_clock,
                                        autostart=node.running and not idle)

    def timer_spec(self) -> tuple:
        """Return (period in wall s, callback, idle: the timer stays stopped even when running)."""
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
