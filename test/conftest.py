"""
Fixtures for launch-free, in-process ROS 2 tests, and the check of the ``ros`` mark.

A test that starts rclpy (a context, a node) or a process carries ``@pytest.mark.ros`` (a
module of such tests ``pytestmark = pytest.mark.ros``), so ``pytest -m "not ros"`` runs the rest
as a fast inner loop. A test that uses a ROS fixture without the mark is refused at collection;
one that starts rclpy or a process without it fails when it does.

rclpy runs in an isolated domain with localhost-only discovery, set before rclpy.init: the
ROS_DOMAIN_ID the user has set (respected), else one picked from the pid. Each test gets its
own context; a :class:`Harness` holds the node under test and a test node spun together in one
executor: the EventsExecutor that sim_node's main() uses, or (``executor='single'``) rclpy's
SingleThreadedExecutor.
"""

import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# Test the installed package (with its compiled kernel), never the source tree beside it: child
# processes (`python -m det_sim_ros.cli.sim_node`) inherit the working directory, and without this
# their sys.path would start there (Python 3.11+: PYTHONSAFEPATH).
os.environ.setdefault('PYTHONSAFEPATH', '1')
# A run started in the background of a non-interactive shell (a CI job, nohup) inherits SIGINT
# ignored, and so would every child process: a test that stops a child with SIGINT would wait
# for ever. A handler, unlike an ignored signal, is reset to the default in a child.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def child_env(**extra):
    """
    Return the environment for a Python child process of a test.

    The child imports what this process imports (its sys.path: the installed package, or
    whatever PYTHONPATH a developer gave).
    """
    return dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), **extra)


class ChildProcess:
    """
    A child process whose output lines (stdout and stderr) are read by a thread.

    A line that never comes fails the test at the deadline instead of blocking readline() for
    ever.
    """

    TIMEOUT = 60.0   # s, a safety net only

    def __init__(self, args, cwd, environ=None):
        """``environ``: variables that differ from :func:`child_env`'s (e.g. ROS_DOMAIN_ID)."""
        self.proc = subprocess.Popen(list(args), cwd=cwd, text=True, bufsize=1,
                                     env=child_env(PYTHONUNBUFFERED='1', **(environ or {})),
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        self.lines = []
        self._queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self._queue.put(line)
        self._queue.put(None)

    def wait_for(self, text) -> str:
        """Read lines until one holds ``text``; fail if the process ends first."""
        deadline = time.monotonic() + self.TIMEOUT
        while (left := deadline - time.monotonic()) > 0.0:
            try:
                line = self._queue.get(timeout=left)
            except queue.Empty:
                break
            if line is None:
                break
            self.lines.append(line)
            if text in line:
                return line
        pytest.fail(f'no {text!r} from {self.proc.args[2:4]}: {"".join(self.lines)}')

    def stop(self) -> int:
        """SIGINT, then wait (kill at the deadline); return the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=self.TIMEOUT)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        while (line := self._queue.get(timeout=self.TIMEOUT)) is not None:
            self.lines.append(line)
        return self.proc.returncode


def pick_domain_id(environ, pid) -> int:
    """
    Return the ROS domain id for the tests, the one the det_sim fixture picks.

    The user's ROS_DOMAIN_ID when set (a number in 0..232), else 1 + pid % 101 (avoids the
    default domain 0, so a running ROS system is not disturbed).
    """
    from det_sim_ros.ros.testing import pick_domain_id as pick
    try:
        return pick(environ, pid)
    except ValueError as exc:
        raise pytest.UsageError(str(exc)) from None


DOMAIN_ID = pick_domain_id(os.environ, os.getpid())
os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)

WALL_TIMEOUT = 120.0  # s; a safety net only: a wait that hits it fails the test

ROS_FIXTURES = ('ros_context', 'det_sim')   # harness uses ros_context
ROS_MARK_HINT = ('mark it @pytest.mark.ros (or its module pytestmark = pytest.mark.ros): '
                 'pytest -m "not ros" must stay free of rclpy and processes')


def pytest_sessionstart(session):
    """
    Build matplotlib's font cache (when matplotlib is installed) before any test runs.

    matplotlib lists the system fonts with an ``fc-list`` process the first time it draws text
    and caches the list in MPLCONFIGDIR. On a fresh machine (an empty cache) the first test that
    draws would start that process under the ``ros`` mark's guard and fail for it, or pass when an
    earlier test happened to draw first.
    """
    try:
        from matplotlib import font_manager  # noqa: F401
    except ImportError:   # no plots extra: the tests that draw skip or check the hint
        pass


def pytest_collection_modifyitems(config, items):
    """Refuse the run when a test uses a ROS fixture without the ``ros`` mark."""
    unmarked = [item.nodeid for item in items
                if set(ROS_FIXTURES) & set(getattr(item, 'fixturenames', ()))
                and item.get_closest_marker('ros') is None]
    if unmarked:
        raise pytest.UsageError(f'{len(unmarked)} test(s) use {" or ".join(ROS_FIXTURES)} '
                                f'without the ros mark ({", ".join(unmarked[:5])}): '
                                + ROS_MARK_HINT)


@pytest.fixture(autouse=True)
def ros_mark_checked(request, monkeypatch):
    """Fail a test without the ``ros`` mark when it starts rclpy or a process."""
    if request.node.get_closest_marker('ros') is not None:
        return

    def refuse(what):
        def refused(*args, **kwargs):
            pytest.fail(f'{request.node.nodeid} {what}: {ROS_MARK_HINT}', pytrace=False)
        return refused

    monkeypatch.setattr(subprocess.Popen, '__init__', refuse('starts a process'))
    try:
        from rclpy.context import Context
    except ImportError:   # no rclpy: nothing to start
        return
    monkeypatch.setattr(Context, 'init', refuse('initialises rclpy'))


@pytest.fixture
def ros_context():
    """Initialise rclpy in a fresh context on the test domain."""
    import rclpy
    from rclpy.context import Context
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    yield context
    rclpy.try_shutdown(context=context)


def stamp_ns(stamp):
    """Nanoseconds of a builtin_interfaces/Time."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class Harness:
    """
    The node under test plus a test node that commands it and records what it publishes.

    ``samples[topic]`` maps the sample's sim time (ns) to its ``position`` values
    (``deflection`` also stores ``velocity`` in ``velocities``); ``names[topic]`` holds the
    channel names of the latest sample. The ``structure`` topic is recorded when the node's
    scene has structure outputs (the plate).
    """

    TOPICS = ('deflection', 'displacement', 'charge', 'current')
    STRUCTURE = 'structure'

    def __init__(self, context, namespace='', executor='events', **params):
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        from std_srvs.srv import SetBool, Trigger
        from diagnostic_msgs.msg import DiagnosticArray
        import rclpy
        self.closed = False

        from det_sim_ros.ros.node import make_executor, SimNode

        # node I/O, pacing, lockstep, recording: the fidelity is not their subject, and the
        # paper's one-term model keeps them fast; scene.fidelity=None keeps the scene's own
        if params.setdefault('scene.fidelity', 'paper') is None:
            del params['scene.fidelity']
        params.setdefault('real_time', False)
        params.setdefault('info_period', 0.0)
        params.setdefault('log.enabled', 'log.path' in params)  # no MCAP files unless asked
        params.setdefault('allow_duplicate_name', True)   # no discovery wait in-process
        overrides = [Parameter(name, value=value) for name, value in params.items()]
        self.context = context
        self.node = SimNode(context=context, namespace=namespace, parameter_overrides=overrides)
        self.test = rclpy.create_node('tester', context=context, namespace=namespace)
        self.executor = (make_executor(context) if executor == 'events'
                         else SingleThreadedExecutor(context=context))
        self.executor.add_node(self.node)
        self.executor.add_node(self.test)
        self.samples = {topic: {} for topic in self.TOPICS + (self.STRUCTURE,)}
        self.names = {}
        self.velocities = {}
        self.clock = []
        self.diagnostics = []
        self.non_finite = []
        self.subs = [self.test.create_subscription(
            JointState, topic, lambda msg, topic=topic: self._on_sample(topic, msg), 100)
            for topic in self.TOPICS]
        structure_subs = []
        if self.node.structure_names:
            structure_subs.append(self.test.create_subscription(
                JointState, self.STRUCTURE,
                lambda msg: self._on_sample(self.STRUCTURE, msg), 100))
        self.subs.append(self.test.create_subscription(
            Clock, '/clock', lambda msg: self.clock.append(stamp_ns(msg.clock)), 100))
        self.subs.append(self.test.create_subscription(
            DiagnosticArray, '/diagnostics', self.diagnostics.append, 10))
        self.cmd = self.test.create_publisher(Float64MultiArray, 'voltage_command', 10)
        self.joint_cmd = self.test.create_publisher(JointState, 'voltage_command_joint', 10)
        self.subs += structure_subs
        self.clients = {
            'pause': self.test.create_client(SetBool, 'sim_node/pause'),
            'step': self.test.create_client(Trigger, 'sim_node/step'),
            'reset': self.test.create_client(Trigger, 'sim_node/reset'),
        }
        self.executor.spin_once(timeout_sec=0)
        self.spin_until(lambda: all(s.get_publisher_count() > 0
                                    for s in self.subs[:4] + structure_subs)
                        and self.cmd.get_subscription_count() > 0
                        and self.joint_cmd.get_subscription_count() > 0
                        and all(c.service_is_ready() for c in self.clients.values()),
                        'discovery')

    def _on_sample(self, topic, msg):
        values = list(msg.position) + list(msg.velocity)
        if not all(math.isfinite(v) for v in values):
            self.non_finite.append((topic, values))
        t = stamp_ns(msg.header.stamp)
        self.samples[topic][t] = list(msg.position)
        self.names[topic] = list(msg.name)
        if topic == 'deflection':
            self.velocities[t] = list(msg.velocity)

    def spin_until(self, condition, what='condition', timeout=WALL_TIMEOUT):
        """
        Spin both nodes until condition() holds; fail after ``timeout`` s of wall time.

        The default is the safety net; a wait for what follows at once (a log line, a refusal)
        passes a few seconds, so a test whose behaviour broke fails in seconds, not minutes.
        """
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                pytest.fail(f'timed out waiting for {what}')
            self.executor.spin_once(timeout_sec=0.01)

    def latest(self, topic):
        """Sim time (ns) of the newest sample received on topic, -1 if none."""
        return max(self.samples[topic], default=-1)

    def spin_until_sim_time(self, t, topic='displacement'):
        """Spin until a sample stamped at or after sim time t (s) has arrived on topic."""
        target = int(round(t * 1e9))
        self.spin_until(lambda: self.latest(topic) >= target, f'{topic} at t = {t} s')

    def call(self, name, **fields):
        """Call ~/pause, ~/step or ~/reset and return the response."""
        client = self.clients[name]
        request = client.srv_type.Request(**fields)
        future = client.call_async(request)
        self.spin_until(future.done, f'~/{name} response')
        return future.result()

    def command(self, volts):
        """Publish a Float64MultiArray command and spin until the node has received it."""
        from std_msgs.msg import Float64MultiArray
        self._send(self.cmd, Float64MultiArray(data=[float(v) for v in volts]))

    def joint_command(self, names, volts):
        """Publish a JointState command (position = volts) and wait for its arrival."""
        from sensor_msgs.msg import JointState
        self._send(self.joint_cmd, JointState(name=list(names),
                                              position=[float(v) for v in volts]))

    def _send(self, publisher, msg):
        before = self.node.commands.received
        publisher.publish(msg)
        self.spin_until(lambda: self.node.commands.received > before, 'command delivery')

    def close(self):
        """Destroy the nodes and the executor (once: tests may close early to flush a log)."""
        if self.closed:
            return
        self.closed = True
        self.executor.shutdown()
        self.test.destroy_node()
        self.node.destroy_node()


@pytest.fixture
def harness(ros_context):
    """Make Harness objects (call with node parameters); cleaned up after the test."""
    made = []

    def make(**params):
        h = Harness(ros_context, **params)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()
