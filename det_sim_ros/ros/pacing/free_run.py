"""Free-run pacing: periods as fast as the node runs them, published in bursts."""

from __future__ import annotations

from typing import Callable

from .base import Pacing

__all__ = ['FreeRunPacing']


class FreeRunPacing(Pacing):
    """
    As fast as possible: each tick runs steps_per_tick periods, then publishes them.

    The samples go out back to back: DDS spends less CPU per message on a burst than on the
    same messages spread out (it wakes its own and the subscribers' threads per message then),
    and free run has no wall-clock deadline to keep. Commands are still taken before every
    period.

    The always-due 1 us timer starves the node's other timers in rclpy's EventsExecutor, so each
    tick also runs the node's periodic reports that are due by the wall clock
    (``run_due_reports``). The measurements: docs/real_time.md (Free run).
    """

    mode = 'free_run'
    PARAMETERS = ('steps_per_tick',)

    def parameters_changed(self, get: Callable, names) -> None:
        self.steps_per_tick = get('steps_per_tick')

    def timer_spec(self) -> tuple:
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
