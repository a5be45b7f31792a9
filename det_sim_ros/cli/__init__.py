"""
Command-line entry points: ``det_sim``, ``det_sim_replay`` and ``sim_node``.

``det_sim`` (:func:`main`) is one command with its verbs, one module each in :mod:`.verbs`;
``det_sim_replay`` (:func:`main_replay`) is the ``replay`` verb on its own; ``sim_node`` is
:mod:`.sim_node`. Nothing heavy is imported until a command runs.

SIGINT and SIGTERM while the command's modules import and its arguments are read end it with
'interrupted' and exit code 130 (an exception there could come out of a C extension's
initialisation as an ImportError), ``det_sim watch`` quietly with 0 (its usual end is Ctrl-C);
the verbs then take the signals over (an offline verb as KeyboardInterrupt, the node verbs at
their next wait, det_sim_ros.ros.shell).
"""

import contextlib
import os
import signal
import sys
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM)


def exit_at_once(code: int, line: bytes = b'') -> None:
    """
    Flush stdout and stderr, write ``line`` to stderr and end the process with ``code``.

    For signal handlers that run while C extensions initialise: an exception raised there could
    come out as an ImportError traceback, so the process ends without one.
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - exiting anyway
            pass
    if line:
        os.write(2, line)
    os._exit(code)


def _interrupted(signum, frame):
    exit_at_once(130, b'det_sim: interrupted\n')


def _stopped_watching(signum, frame):
    exit_at_once(0)   # watch's usual end is Ctrl-C, also before it has started (docs/shell.md)


@contextlib.contextmanager
def _quiet_start(handler=_interrupted):
    """Within the block (in the main thread), a stop signal ends the process at once, quietly."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in SIGNALS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def main(argv=None) -> int:
    """``det_sim``: parse ``argv`` (default: the command line) and run its verb."""
    verb = (sys.argv[1:] if argv is None else list(argv))[:1]
    with _quiet_start(_stopped_watching if verb == ['watch'] else _interrupted):
        from .det_sim import main as run
        return run(argv)


def main_replay(argv=None) -> int:
    """``det_sim_replay``: parse ``argv`` (default: the command line) and run it."""
    with _quiet_start():
        from .det_sim import main_replay as run
        return run(argv)
