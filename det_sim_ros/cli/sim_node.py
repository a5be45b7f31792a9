"""
The ``sim_node`` entry point.

It runs as the console script, as ``ros2 run det_sim_ros sim_node`` and as ``python -m
det_sim_ros.cli.sim_node``.

SIGINT and SIGTERM while the node's modules are still importing (rclpy, numpy, the kernel;
before :func:`det_sim_ros.ros.node.main` takes the signals over) exit quietly with code 0
instead of a KeyboardInterrupt traceback or a kill by the signal: nothing has been started
then, so there is nothing to finish. This module imports nothing heavy before that.
"""

import os
import signal
import sys


def _quiet_stop(signum, frame):
    # not an exception: raised inside a C extension's initialisation (rclpy's pybind11 module)
    # it would come out as an ImportError traceback
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - exiting anyway
            pass
    os._exit(0)


def main(args=None) -> int:
    """Run the simulator node (see :func:`det_sim_ros.ros.node.main`)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _quiet_stop)
    from ..ros.node import main as run_node
    return run_node(args)


if __name__ == '__main__':
    sys.exit(main())
