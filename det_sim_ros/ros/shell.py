"""
A short-lived client of one running sim_node, for the ``det_sim`` node verbs.

:class:`NodeShell` is a small rclpy node in a context of its own: it publishes voltage
commands, calls the node's services (pause, step, reset), gets and sets its parameters and
subscribes to its outputs. It stands in for the few ``ros2 topic / service / param`` commands
a sim_node user needs, for installs without the ros2 command line (docs/shell.md).

Every wait is bounded by ``timeout`` (wall seconds); a node that does not answer in time, a
refused request or an unknown DET name raise :class:`ShellError` with one line. SIGINT and
SIGTERM are taken note of while the shell is open and raised as KeyboardInterrupt at its next
wait (within 0.05 s), never inside the executor's callbacks, where rclpy turns it into a
RuntimeError; the shell's teardown runs to its end.
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from typing import Callable

from ..io.contract import COMMAND_TOPIC, JOINT_COMMAND_TOPIC
from ..scenes.outputs import output_topics

__all__ = ['NodeShell', 'ShellError', 'OUTPUT_TOPICS', 'target_name']

OUTPUT_TOPICS = output_topics()   # the per-DET output topics, in publishing order


class ShellError(RuntimeError):
    """The node did not answer, or refused (one line)."""


def target_name(namespace: str, node: str) -> str:
    """Return the node's fully qualified name: ('arm1', 'sim_node') -> '/arm1/sim_node'."""
    namespace = namespace.strip('/')
    return f"/{namespace + '/' if namespace else ''}{node.strip('/')}"


class _Interrupts:
    """SIGINT and SIGTERM noted by the handler and raised by :meth:`check` (main thread only)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.signum = 0
        self._previous = {}

    def install(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._note)

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def check(self) -> None:
        """Raise KeyboardInterrupt once for a signal that came since the last check."""
        if self.signum:
            self.signum = 0
            raise KeyboardInterrupt

    def _note(self, signum, frame):
        self.signum = signum


class NodeShell:
    """
    A client node that talks to the sim_node ``namespace``/``node``.

    Use it as a context manager: the rclpy context is created on entry, shut down on exit.
    """

    def __init__(self, namespace: str = '', node: str = 'sim_node', timeout: float = 5.0):
        self.namespace = '/' + namespace.strip('/') if namespace.strip('/') else ''
        self.target = target_name(namespace, node)
        self.timeout = timeout
        self._context = self._node = self._executor = None
        self._interrupts = _Interrupts()

    def __enter__(self) -> 'NodeShell':
        self._interrupts.install()      # before rclpy's import: a Ctrl-C there waits too
        try:
            import rclpy
            from rclpy.context import Context
            from rclpy.signals import SignalHandlerOptions
            self._context = Context()
            # rclpy's handlers would shut the context down under a running callback
            rclpy.init(args=[], context=self._context,
                       signal_handler_options=SignalHandlerOptions.NO)
            self._node = rclpy.create_node(f'det_sim_shell_{os.getpid()}',
                                           context=self._context,
                                           start_parameter_services=False)
            self._executor = _executor(self._context)
            self._executor.add_node(self._node)
            self._interrupts.check()
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        try:
            if self._executor is not None:
                self._executor.shutdown()
            if self._node is not None:
                self._node.destroy_node()
            if self._context is not None:
                import rclpy
                rclpy.try_shutdown(context=self._context)
        finally:
            self._interrupts.restore()

    def topic(self, name: str) -> str:
        """Return a sim_node topic's name in the shell's namespace."""
        return f'{self.namespace}/{name}'

    def spin(self, seconds: float) -> None:
        """Serve the shell's callbacks for ``seconds`` of wall time."""
        end = time.monotonic() + seconds
        while self._context.ok() and time.monotonic() < end:
            self._spin_once(min(0.05, max(end - time.monotonic(), 0.0)))

    def _spin_once(self, seconds: float) -> None:
        self._executor.spin_once(timeout_sec=seconds)
        self._interrupts.check()

    def _until(self, condition: Callable[[], bool], seconds: float, step=None) -> bool:
        """Spin (or call ``step(seconds)``) until ``condition()``; return it at the end."""
        end = time.monotonic() + seconds
        while not condition():
            left = end - time.monotonic()
            if left <= 0.0:
                return False
            if step is None:
                self._spin_once(min(0.05, left))
            else:
                step(min(0.05, left))
                self._interrupts.check()
        return True

    # -- services -----------------------------------------------------------------------------
    def call(self, service: str, srv_type, request):
        """Call the node's service ``~/service`` (or a full name); return the response."""
        name = service if service.startswith('/') else f'{self.target}/{service}'
        client = self._node.create_client(srv_type, name)
        try:
            if not self._until(client.service_is_ready, self.timeout):
                raise ShellError(f'no service {name} within {self.timeout:g} s (is sim_node '
                                 'running, with this --ns and --node?)')
            future = client.call_async(request)
            if not self._until(future.done, self.timeout):
                raise ShellError(f'{name} did not answer within {self.timeout:g} s')
            return future.result()
        finally:
            self._node.destroy_client(client)

    def pause(self, paused: bool) -> str:
        """Pause (True) or resume (False); return the node's answer."""
        from std_srvs.srv import SetBool
        return self.call('pause', SetBool, SetBool.Request(data=paused)).message

    def trigger(self, service: str) -> str:
        """Call a std_srvs/Trigger service (step, reset); return its answer or raise."""
        from std_srvs.srv import Trigger
        response = self.call(service, Trigger, Trigger.Request())
        if not response.success:
            raise ShellError(f'{self.target}/{service}: {response.message}')
        return response.message

    # -- parameters ---------------------------------------------------------------------------
    def get_parameter(self, name: str):
        """Return a parameter's value (bool, int, float, str or list)."""
        return self.get_parameters([name])[0]

    def get_parameters(self, names: list[str]) -> list:
        """Return several parameters' values in one call of the node's service."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        from rcl_interfaces.msg import ParameterType
        response = self.call('get_parameters', GetParameters, GetParameters.Request(
            names=list(names)))
        values = list(response.values)
        for i, name in enumerate(names):
            if i >= len(values) or values[i].type == ParameterType.PARAMETER_NOT_SET:
                raise ShellError(f'{self.target} has no parameter {name!r}')
        return [parameter_value_to_python(value) for value in values[:len(names)]]

    def set_parameter(self, name: str, value) -> None:
        """Set a parameter (an int for a double parameter is taken as a float), or raise."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        current = self.get_parameter(name)
        if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        message = Parameter(name, value=value).to_parameter_msg()
        request = SetParameters.Request(parameters=[message])
        (result,) = self.call('set_parameters', SetParameters, request).results
        if not result.successful:
            raise ShellError(f'{self.target}: {name} not set: {result.reason or "refused"}')

    def det_names(self) -> list[str]:
        """Return the node's DETs in command order (its ``structure.dets`` parameter)."""
        return list(self.get_parameter('structure.dets'))

    # -- topics -------------------------------------------------------------------------------
    def send(self, volts: list[float], names: list[str] | None = None) -> str:
        """
        Publish one voltage command and wait until the node has it; return the topic.

        ``names`` None: ``volts`` is one value per DET in command order (voltage_command);
        else the voltages of the DETs ``names`` (voltage_command_joint, the others hold).
        """
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        if not all(math.isfinite(v) for v in volts):
            raise ShellError('voltages must be finite numbers')
        if names is None:
            topic, msg = COMMAND_TOPIC, Float64MultiArray(data=list(volts))
        else:
            topic, msg = JOINT_COMMAND_TOPIC, JointState(name=list(names), position=list(volts))
        publisher = self._node.create_publisher(type(msg), self.topic(topic), 10)
        try:
            self._wait_for(lambda: publisher.get_subscription_count() > 0,
                           f'no subscriber on {self.topic(topic)}')
            publisher.publish(msg)
            acked = [False]

            def wait_acked(seconds):
                acked[0] = publisher.wait_for_all_acked(_duration(seconds))
            if not self._until(lambda: acked[0], self.timeout, wait_acked):
                raise ShellError(f'{self.target} did not acknowledge the command on '
                                 f'{self.topic(topic)} within {self.timeout:g} s')
        finally:
            self._node.destroy_publisher(publisher)
        return self.topic(topic)

    def subscribe(self, topic: str, callback: Callable, depth: int = 100) -> None:
        """Call ``callback(topic, JointState)`` for every message on an output topic."""
        from sensor_msgs.msg import JointState
        self._node.create_subscription(JointState, self.topic(topic),
                                       lambda msg: callback(topic, msg), depth)

    def node_publishes(self, topic: str) -> bool:
        """Return whether the node publishes on its topic ``topic`` (as the graph knows now)."""
        return any(target_name(info.node_namespace, info.node_name) == self.target
                   for info in self._node.get_publishers_info_by_topic(self.topic(topic)))

    def _wait_for(self, condition: Callable[[], bool], what: str) -> None:
        if not self._until(condition, self.timeout):
            raise ShellError(f'{what} within {self.timeout:g} s (is sim_node running, '
                             'with this --ns?)')


def _executor(context):
    """
    Return rclpy's EventsExecutor, which keeps up with a 1 kHz node's outputs.

    It enables faulthandler on sys.stderr, so where that is no file (a captured stream) the
    SingleThreadedExecutor is used instead.
    """
    import sys
    from rclpy.executors import SingleThreadedExecutor
    from .spinning import make_executor
    try:
        sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        return SingleThreadedExecutor(context=context)
    return make_executor(context)


def _duration(seconds: float):
    from rclpy.duration import Duration
    return Duration(nanoseconds=int(seconds * 1e9))
