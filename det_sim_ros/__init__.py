"""det_sim_ros: dielectric elastomer transducers coupled with buckled beams, simulated for ROS 2."""

__version__ = '0.1.0'


def _quiet_stop_while_the_node_imports() -> None:
    """
    Run as the node (``sim_node``, ``python -m det_sim_ros.sim_node``): SIGINT and SIGTERM while
    its modules are still importing (rclpy, numpy, the kernels; before ``sim_node.main`` takes
    the signals over) exit quietly with code 0 instead of a KeyboardInterrupt traceback or a
    kill by the signal. Nothing has been started then, so there is nothing to finish.
    """
    import os
    import signal
    import sys
    argv = list(getattr(sys, 'orig_argv', []))
    as_module = any(a == 'det_sim_ros.sim_node' for a in argv[:4])
    if not (as_module or os.path.basename(sys.argv[0] if sys.argv else '') == 'sim_node'):
        return

    def stop(signum, frame):
        # not an exception: raised inside a C extension's initialisation (rclpy's pybind11
        # module) it would come out as an ImportError traceback
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # noqa: BLE001
                pass
        os._exit(0)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, stop)


_quiet_stop_while_the_node_imports()
