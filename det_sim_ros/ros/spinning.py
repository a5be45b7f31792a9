"""
How sim_node spins and stops.

Its executor, and SIGINT/SIGTERM turned into a clean stop between two callbacks (see
:class:`StopSignals`): the log is finished first, then the middleware is taken down within
:data:`TEARDOWN_LIMIT_S`.
"""

from __future__ import annotations

import contextlib
import faulthandler
import gc
import signal

import rclpy

__all__ = ['limit_middleware_start', 'limit_teardown', 'make_executor',
           'MIDDLEWARE_START_LIMIT_S', 'spin', 'spin_until_stopped', 'StopRequested',
           'StopSignals', 'TEARDOWN_LIMIT_S']

# s: the executor's, the node's and the context's teardown at the end of a run (a few ms
# here), and the interpreter's exit after it; ros2 launch, too, escalates a SIGINT that did not
# end a process after 5 s
TEARDOWN_LIMIT_S = 5.0
# s: the middleware's part of a start (rclpy's context, the node and its DDS participant, the
# name claim's endpoints; milliseconds here): far above a loaded host's, far below a user's
# patience with a silent process
MIDDLEWARE_START_LIMIT_S = 20.0


def make_executor(context=None):
    """
    Return the executor sim_node spins in: rclpy's EventsExecutor.

    Its timer callbacks cost a fraction of the SingleThreadedExecutor's (docs/performance.md,
    'Node I/O and real time'; ``bench/node_rate.py`` measures both). Spin it with :func:`spin`.
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
        faulthandler.cancel_dump_traceback_later()   # torn down: an in-process caller goes on

    def end(self) -> None:
        """
        End the run, whatever ended it: bound the teardown from here on.

        No signal unwinds it any more, and :func:`limit_teardown` ends a teardown (or a last
        log line on /rosout) that hangs in the middleware; leaving cancels the bound.
        """
        self.preparing = False
        limit_teardown()

    def _on_signal(self, signum, frame):
        self.requested = signum
        if self.preparing:
            self.preparing = False
            raise StopRequested()


def limit_teardown(seconds: float = TEARDOWN_LIMIT_S) -> None:
    """
    Bound what follows the end of a run: a teardown still running after ``seconds`` ends it.

    The middleware's teardown (executor, node, context; the DDS participant at the
    interpreter's exit) runs in C++, mostly holding the GIL, where no Python thread can step in;
    faulthandler's watchdog is a C thread that needs no GIL. It writes every thread's stack to
    stderr and exits with code 1: a teardown that hangs says where. After a stop it is armed
    once the log is finished (:meth:`StopSignals.end`); leaving StopSignals cancels it.
    """
    faulthandler.dump_traceback_later(seconds, exit=True)


@contextlib.contextmanager
def limit_middleware_start():
    """
    Within the block, a start stuck in the middleware ends the process.

    The same watchdog as :func:`limit_teardown`, after :data:`MIDDLEWARE_START_LIMIT_S`:
    a DDS participant that never comes up would leave a silent process that publishes nothing
    and ignores Ctrl-C (rclpy's C++ calls hold the GIL, so neither a Python thread nor a signal
    handler runs); instead every thread's stack goes to stderr and the process exits with
    code 1. Leaving the block cancels the watchdog (faulthandler has one, so
    any other ``dump_traceback_later`` too): for sim_node's own process, not for a program that
    embeds a node (:class:`~det_sim_ros.ros.node.SimNode`'s ``middleware_bound``).
    """
    faulthandler.dump_traceback_later(MIDDLEWARE_START_LIMIT_S, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def spin_until_stopped(node, stop) -> int:
    """
    Run the node's callbacks until a stop signal (checked at least every 0.1 s); return the code.

    Then finish the node's log before anything of the middleware is taken down. What the
    start-up made (modules, the model, rclpy's and DDS's objects) lives as long as the process:
    it is frozen (:func:`gc.freeze`), so the garbage collector's full collections no longer walk
    it. Unfrozen, one such collection a fraction of a second into a run held the node for
    250 ms beside a busy core: 250 periods late, a slip in real time. A node that hears an
    older one of its name only after its start-up (of another host: ``node.name_claim.refusal``)
    stops the same way, with its FATAL line before the stop line, and returns 1; else 0.
    """
    executor = make_executor(node.context)
    executor.add_node(node)
    gc.freeze()
    refused = False
    try:
        while not stop.requested and node.context.ok() and not node.name_claim.refusal:
            executor.spin_once(timeout_sec=0.1)
    finally:
        if node.recorder is not None:
            node.recorder.close()
        refused = bool(not stop.requested and node.name_claim.refusal)
        if refused:
            node.get_logger().fatal(f'cannot run: {node.name_claim.refusal}')
        _say_stopped(node)
        stop.end()
        executor.remove_node(node)
        executor.shutdown(timeout_sec=0.0)
    return 1 if refused else 0


def _say_stopped(node) -> None:
    """Log one INFO line: how far the run went and where its (finished) log is."""
    recorder = node.recorder
    if recorder is None or not recorder.paths:
        where = 'no log (log.enabled is false)'
    else:
        earlier = len(recorder.paths) - 1
        where = f'log: {recorder.paths[-1]}'
        if earlier:
            where += f' (and {earlier} earlier file(s))'

    node.get_logger().info(f'stopped at t = {node.simulator.t:.6g} s after '
                           f'{node.steps_total} period(s); {where}')
