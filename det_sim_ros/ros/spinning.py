"""
How sim_node spins and stops.

Its executor, and SIGINT/SIGTERM turned into a clean stop between two callbacks (see
:class:`StopSignals`).
"""

from __future__ import annotations

import signal

import rclpy

__all__ = ['make_executor', 'spin', 'spin_until_stopped', 'StopRequested', 'StopSignals']


def make_executor(context=None):
    """
    Return the executor sim_node spins in: rclpy's EventsExecutor.

    It takes about 6 µs per timer callback here against ~100 µs for the
    SingleThreadedExecutor (bench/node_rate.py measures both). Spin it with :func:`spin`.
    """
    from rclpy.experimental import EventsExecutor
    return EventsExecutor(context=context)


def spin(executor, context=None):
    """
    Spin ``executor`` until the context shuts down.

    EventsExecutor.spin() (rclpy 7.1) does not return on Ctrl-C while no event comes in (e.g.
    paused); spin_once with a timeout does (it raises ExternalShutdownException).
    """
    context = context or rclpy.get_default_context()
    while context.ok():
        executor.spin_once(timeout_sec=0.1)


class StopRequested(BaseException):
    """SIGINT/SIGTERM during start-up: unwinds the preparation (nothing to finish yet)."""


class StopSignals:
    """
    SIGINT and SIGTERM end the node cleanly at any moment, exit code 0 and a finished log.

    rclpy's own handlers shut the context down from inside the signal handler, while a
    stepping-timer callback may be publishing: that callback then fails (``RCLError:
    publisher's context is invalid``, ``failed to initialize wait set``) and the node exits with
    a traceback. Here the handlers only take note: during start-up (scene, model, first compile)
    they unwind it at once; once running, the spin loop stops between two callbacks (so no
    callback and no log write is ever cut in half), then the log is finished and the context
    shut down, in that order.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.requested = 0            # the signal number once a stop was asked for
        self.preparing = True
        self._previous = {}

    def __enter__(self):
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum, frame):
        self.requested = signum
        if self.preparing:
            self.preparing = False
            raise StopRequested()


def spin_until_stopped(node, stop) -> None:
    """Run the node's callbacks until a stop signal (checked at least every 0.1 s)."""
    executor = make_executor(node.context)
    executor.add_node(node)
    try:
        while not stop.requested and node.context.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.remove_node(node)
        executor.shutdown(timeout_sec=0.0)
