"""
Test sim_node's start-up as a process: --help, stray arguments, the log path, a duplicate name.

Also ~/reset's answer naming the log file the run continues in. The process tests run the real
entry point (``python -m det_sim_ros.cli.sim_node``) on the test domain.
"""

import concurrent.futures
import contextlib
import os
import re
import signal
import subprocess
import sys
import time

from conftest import child_env, ChildProcess
from det_sim_ros.ros.name_check import Claim, ESTABLISHED_S, yields
from det_sim_ros.ros.params import NODE_PARAMS
import pytest

pytestmark = pytest.mark.ros

ENTRY = [sys.executable, '-m', 'det_sim_ros.cli.sim_node']
READY = 'voltage command order'     # the node's last start-up line
TIMEOUT = 60.0                      # s, a safety net only


def run_entry(args, cwd, timeout=TIMEOUT):
    """Run sim_node with ``args`` to its end; return the CompletedProcess (text)."""
    try:
        return subprocess.run(ENTRY + list(args), cwd=cwd, env=child_env(), text=True,
                              capture_output=True, timeout=timeout)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f'sim_node {" ".join(args)} still running after {timeout} s: '
                    f'{(exc.stderr or b"")[-2000:]}')


class Node(ChildProcess):
    """A sim_node process whose output is read line by line."""

    def __init__(self, cwd, *args, environ=None):
        super().__init__(ENTRY + list(args), cwd, environ)


@pytest.mark.parametrize('flag', ['--help', '-h'])
def test_help_prints_usage_modes_and_parameters(tmp_path, flag):
    """Check that --help/-h lists usage, modes and every parameter; nothing starts."""
    result = run_entry([flag], cwd=tmp_path, timeout=30.0)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith('usage: sim_node')
    for mode in ('real_time', 'free_run', 'lockstep'):
        assert f'  {mode}  ' in result.stdout
    for name, param in NODE_PARAMS.items():
        assert f'  {name}  (default ' in result.stdout
        assert param.description.split()[0] in result.stdout
    assert '(default 256.0; 0 to 1e+06; fixed at start)' in result.stdout   # log.split_mb
    intro = ' '.join(result.stdout.split('modes (')[0].split())
    for topic in ('voltage_command', 'voltage_command_joint', 'displacement', 'structure'):
        assert topic in re.findall(r'\w+', intro), topic   # the topics' own names
    assert result.stderr == ''                 # no ROS log line: rclpy was not initialised
    assert os.listdir(tmp_path) == []          # no log directory, no file


@pytest.mark.parametrize('args', [['-p', 'real_time:=false'], ['free_run'],
                                  ['--ros-args', '-p', 'real_time:=false', '--', 'extra']])
def test_arguments_outside_ros_args_are_refused(tmp_path, args):
    """Check that an argument outside --ros-args gets one line naming --ros-args, exit 1."""
    result = run_entry(args, cwd=tmp_path, timeout=30.0)
    assert result.returncode == 1
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and '--ros-args' in lines[0], result.stderr
    assert repr(args[-1] if args[-1] == 'extra' else args[0]) in lines[0]
    assert os.listdir(tmp_path) == []


def _unwritable_paths(tmp_path):
    plain = tmp_path / 'plain_file'
    plain.write_text('')
    yield '/proc/det_sim_logs'
    yield str(plain / 'logs')
    yield str(plain / 'run.mcap')
    (tmp_path / 'folder.mcap').mkdir()
    yield str(tmp_path / 'folder.mcap')
    if os.path.isdir('/sys'):      # not writable, for root neither (sysfs)
        yield '/sys/det.mcap'
    if os.geteuid() != 0:          # root writes into a directory without write permission
        locked = tmp_path / 'locked'
        locked.mkdir(mode=0o555)
        yield str(locked)


def test_unwritable_log_path_refuses_to_start(tmp_path):
    """
    Check that a log.path that cannot be written gives one FATAL line and exit 1.

    The line names the node as it was named (``-r __node:=``) and the reason; nothing else
    but INFO lines (no line of the recorder's own).
    """
    for path in _unwritable_paths(tmp_path):
        result = run_entry(['--ros-args', '-r', '__node:=sim_node_b',
                            '-p', f'log.path:={path}', '-p', 'real_time:=false',
                            '-p', 'allow_duplicate_name:=true', '-p', 'scene.fidelity:=paper'],
                           cwd=tmp_path)
        assert result.returncode == 1, (path, result.stderr)
        problems = [line for line in result.stderr.splitlines() if '[INFO]' not in line]
        assert len(problems) == 1, (path, result.stderr)
        assert '[FATAL]' in problems[0] and 'cannot start: parameter log.path' in problems[0]
        assert '[sim_node_b]: ' in problems[0] and repr(path) in problems[0]
        assert 'cannot write a log there (' in problems[0]


def _params_file(tmp_path):
    """Write a ROS params file with a misspelled key under a known section (lockstep)."""
    path = tmp_path / 'params.yaml'
    path.write_text('/**:\n  ros__parameters:\n    lockstep:\n      timout: 2.0\n'
                    '    log:\n      enabled: false\n')
    return str(path)


def test_a_misspelled_parameter_is_named_with_the_closest_known_one(tmp_path):
    """
    Check a misspelled -p name and params-file key: a WARN naming the closest known parameter.

    The node still starts (the misspelled values are ignored, as the warning says).
    """
    node = Node(tmp_path, '--ros-args', '-r', '__ns:=/startup_typo', '-p', 'modee:=free_run',
                '--params-file', _params_file(tmp_path), '-p', 'info_period:=0.0')
    try:
        warning = node.wait_for("unknown parameter 'lockstep.timout'")
        assert '[WARN]' in warning and "did you mean 'lockstep.timeout'?" in warning
        warning = node.wait_for("unknown parameter 'modee'")
        assert '[WARN]' in warning and "did you mean 'mode'?" in warning
        node.wait_for(READY)
    finally:
        node_stopped = node.stop()
    assert node_stopped == 0, ''.join(node.lines)


def test_strict_parameters_makes_a_misspelled_name_fatal(tmp_path):
    """Check that with strict_parameters an unknown name stops the start: one FATAL line."""
    result = run_entry(['--ros-args', '-r', '__ns:=/startup_strict', '-p', 'modee:=free_run',
                        '--params-file', _params_file(tmp_path),
                        '-p', 'strict_parameters:=true'], cwd=tmp_path)
    assert result.returncode == 1, result.stderr
    problems = [line for line in result.stderr.splitlines() if '[INFO]' not in line]
    assert len(problems) == 1 and '[FATAL]' in problems[0], result.stderr
    assert "did you mean 'mode'?" in problems[0]
    assert "did you mean 'lockstep.timeout'?" in problems[0]
    assert READY not in result.stderr


def test_a_stop_says_how_far_the_run_went_and_where_its_log_is(tmp_path):
    """Check the INFO line a stopped node leaves: its sim time, periods and log file."""
    node = Node(tmp_path, '--ros-args', '-r', '__ns:=/startup_stop', '-p', 'mode:=free_run',
                '-p', f'log.path:={tmp_path / "logs"}', '-p', 'info_period:=0.0',
                '-p', 'scene.fidelity:=paper')
    try:
        node.wait_for(READY)
        time.sleep(1.0)   # past the start-up, which a stop unwinds without this line
    finally:
        node_stopped = node.stop()
    assert node_stopped == 0, ''.join(node.lines)
    stopped = [line for line in node.lines if 'stopped at t = ' in line]
    assert len(stopped) == 1 and '[INFO]' in stopped[0], ''.join(node.lines)
    logs = sorted((tmp_path / 'logs').glob('*.mcap'))
    assert len(logs) == 1 and f'log: {logs[0]}' in stopped[0]
    periods = int(re.search(r'after (\d+) period', stopped[0]).group(1))
    t = float(re.search(r'stopped at t = ([\d.e+-]+) s', stopped[0]).group(1))
    assert periods > 0 and t == pytest.approx(periods * 1e-3, rel=1e-6)   # free run, 1 kHz


STUCK_START = """
import ctypes, sys
import rclpy, rclpy.node
from det_sim_ros.ros import node, spinning
from det_sim_ros.scenes.scene import SceneError
spinning.MIDDLEWARE_START_LIMIT_S = 1.0


def stuck_in_the_middleware(*args, **kwargs):
    ctypes.PyDLL(None).sleep(20)   # a C call that holds the GIL: no Python thread runs


def slow_scene(*args, **kwargs):
    ctypes.PyDLL(None).sleep(3)
    raise SceneError('scene key x: planted')


where = sys.argv[1]
if where == 'rclpy.init':
    rclpy.init = stuck_in_the_middleware
elif where == 'scene':
    node.load_node_scene = slow_scene
else:
    setattr(rclpy.node.Node, where, stuck_in_the_middleware)
sys.exit(node.main(['sim_node', '--ros-args', '-p', 'log.enabled:=false']))
"""


@pytest.mark.parametrize('where', ['rclpy.init', '__init__', 'create_subscription'])
def test_a_start_stuck_in_the_middleware_ends_with_its_stacks(tmp_path, where):
    """
    Check that a start stuck in the middleware ends with exit 1 and every thread's stack.

    rclpy's context, the node's DDS participant, the name claim's subscription: each made to
    hang in a C call that holds the GIL (where neither a Python thread nor a signal handler
    runs). The start's watchdog (set to 1 s here) writes the stacks, the stuck call among them,
    and exits 1 instead of leaving a silent process.
    """
    result = subprocess.run([sys.executable, '-c', STUCK_START, where], cwd=tmp_path,
                            env=child_env(), text=True, capture_output=True, timeout=TIMEOUT)
    assert result.returncode == 1, result.stderr[-2000:]
    assert 'Timeout (0:00:01)' in result.stderr
    assert 'stuck_in_the_middleware' in result.stderr


def test_the_start_bound_leaves_a_slow_scene_preparation_alone(tmp_path):
    """
    Check that the middleware's start bound does not cut a scene preparation that takes long.

    A scene that takes 3 s to load (3x the bound set here) still ends in its own one-line
    refusal: the bound covers the middleware's calls only.
    """
    result = subprocess.run([sys.executable, '-c', STUCK_START, 'scene'], cwd=tmp_path,
                            env=child_env(), text=True, capture_output=True, timeout=TIMEOUT)
    assert result.returncode == 1 and 'Timeout' not in result.stderr, result.stderr[-2000:]
    lines = (result.stdout + result.stderr).strip().splitlines()
    assert len(lines) == 1 and 'cannot start' in lines[0] and 'planted' in lines[0]


EMBEDDED = """
import faulthandler, time
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from det_sim_ros.ros.node import SimNode
faulthandler.dump_traceback_later(5.0, exit=True)   # the embedding program's own watchdog
context = Context()
rclpy.init(context=context)
node = SimNode(context=context, parameter_overrides=[
    Parameter('log.enabled', value=False), Parameter('info_period', value=0.0)])
node.destroy_node()
rclpy.try_shutdown(context=context)
time.sleep(10.0)   # the watchdog ends the program here
print('the watchdog was cancelled')
"""


def test_an_embedded_node_leaves_the_programs_watchdog_alone(tmp_path):
    """
    Check that a node made in another program neither arms nor cancels faulthandler's watchdog.

    The program arms its own 5 s watchdog, makes a SimNode (the det_sim fixture's way; well
    under a second), and sleeps past it: its watchdog must still end it, in the sleep (exit 1,
    'Timeout', the sleep's line on the stack; a host so slow that making the node took the 5 s
    fails on that line instead of passing). The start bound is sim_node's process's alone.
    """
    result = subprocess.run([sys.executable, '-c', EMBEDDED], cwd=tmp_path, env=child_env(),
                            text=True, capture_output=True, timeout=TIMEOUT)
    sleep = 'time.sleep(10.0)   # the watchdog ends the program here'
    sleep_line = 1 + EMBEDDED.splitlines().index(sleep)   # (-c counts from its first line)
    assert result.returncode == 1 and 'Timeout (0:00:05)' in result.stderr, (
        result.stdout + result.stderr[-2000:])
    assert f'line {sleep_line} in <module>' in result.stderr, result.stderr[-2000:]
    assert 'was cancelled' not in result.stdout


def test_claims_are_ordered_the_same_way_by_every_node():
    """Check the claims' order: established first, then the smaller id; no clock in it."""
    running, new, other = Claim(True, 9), Claim(False, 1), Claim(False, 7)
    assert yields(new, running) and not yields(running, new)      # whatever the ids
    assert yields(other, new) and not yields(new, other)          # alike: the smaller id
    assert yields(Claim(True, 9), Claim(True, 7))
    assert not yields(new, Claim(True, 1))          # its own claim, heard back established
    for claim in (running, new):
        assert Claim.parse(claim.text()) == claim
    assert Claim.parse('not a claim') is None and Claim.parse('1796570663 00ff') is None


def test_duplicate_name_refused_unless_allowed(tmp_path):
    """
    Check a second node of one name: one FATAL line and exit 1, or a WARN when allowed.

    The duplicates find the name locked on this host before they claim or publish anything
    (det_sim_ros.ros.name_check) and stop; the running node goes on. An allowed duplicate says
    so at once, before its start-up line.
    """
    args = ['--ros-args', '-r', '__ns:=/startup_dup', '-p', 'log.enabled:=false',
            '-p', 'info_period:=0.0']
    first = Node(tmp_path, *args)
    try:
        # the start line names the level: the shipped default is the exact kinematics in 3
        # buckling modes on its fixed beam; and the tolerance in effect, its level's
        from det_sim_ros.scenes.scene import load_scene
        from det_sim_ros.sim.integrators import integration_tolerance
        line = first.wait_for(READY)
        assert 'fidelity exact buckling modes n_r=3' in line
        tolerance = integration_tolerance(load_scene('default'))
        assert f', tolerance {tolerance:g} (auto: its level); ' in line, line
        with concurrent.futures.ThreadPoolExecutor(3) as pool:
            seconds = list(pool.map(lambda _: run_entry(args, cwd=tmp_path), range(3)))
        for second in seconds:
            assert second.returncode == 1, second.stderr
            fatal = [line for line in second.stderr.splitlines() if '[FATAL]' in line]
            assert len(fatal) == 1 and 'another node named /startup_dup/sim_node' in fatal[0]
            assert 'Traceback' not in second.stderr
        assert first.proc.poll() is None           # the running node was not the one refused
        # a scene of its own tolerance (an allowed duplicate): the start line says it
        scene = tmp_path / 'tolerance.yaml'
        scene.write_text('base: default\nintegrator:\n  tolerance: 2.5e-05\n')
        allowed = Node(tmp_path, *args, '-p', 'allow_duplicate_name:=true',
                       '-p', f'scene_file:={scene}')
        try:
            warning = allowed.wait_for('another node named /startup_dup/sim_node')
            assert '[WARN]' in warning
            assert ', tolerance 2.5e-05; ' in allowed.wait_for(READY)
        finally:
            allowed_stopped = allowed.stop()
        assert allowed_stopped == 0
    finally:
        first_stopped = first.stop()
    assert first_stopped == 0, ''.join(first.lines)


def test_a_refused_duplicate_reaches_nothing_of_the_running_nodes(tmp_path, ros_context):
    """
    Check that a second node of one name publishes nothing on the running node's topics.

    A subscriber watches the running node's displacement (reliable, 10 s deep) while a duplicate
    starts and is refused: the stamps it receives only go forward, 1 ms apart (a duplicate's
    samples would start from t = 0 again), and displacement never has a second publisher. The
    duplicate exits 1 with one FATAL line, under the name it was given (``-r __node:=``), and
    it stepped no period (no stop line): a duplicate's first ~0.1 s of samples can go out before
    a subscriber has matched it, so its own account is checked too. Refused by the host's lock,
    it never claimed the name either: the claim topic never has a second writer.
    """
    import threading
    import rclpy
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState
    args = ['--ros-args', '-r', '__ns:=/startup_quiet', '-r', '__node:=sim_node_b',
            '-p', 'log.enabled:=false', '-p', 'info_period:=0.0']
    topic, claim_topic = '/startup_quiet/displacement', '/startup_quiet/sim_node_b/_name_claim'
    watcher = rclpy.create_node('duplicate_watcher', context=ros_context)
    stamps, publishers, claimers, done = [], [], [], threading.Event()
    watcher.create_subscription(JointState, topic, lambda msg: stamps.append(
        msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec), QoSProfile(depth=10000))
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(watcher)

    def watch():
        while not done.is_set():
            executor.spin_once(timeout_sec=0.01)
            publishers.append(watcher.count_publishers(topic))
            claimers.append(watcher.count_publishers(claim_topic))
    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    first = Node(tmp_path, *args)
    try:
        first.wait_for(READY)
        deadline = time.monotonic() + TIMEOUT
        while not stamps or stamps[-1] < 500_000_000:   # the running node's stamps advanced
            assert time.monotonic() < deadline, 'no samples of the running node'
            time.sleep(0.05)
        duplicate = run_entry(args, cwd=tmp_path)
        before = len(stamps)
        while len(stamps) < before + 200:               # 0.2 s more of the running node
            assert time.monotonic() < deadline, 'the running node stopped publishing'
            time.sleep(0.05)
    finally:
        done.set()
        thread.join(timeout=10.0)
        executor.shutdown()
        watcher.destroy_node()
        stopped = first.stop()
    assert stopped == 0, ''.join(first.lines)
    steps = {b - a for a, b in zip(stamps, stamps[1:])}
    assert steps == {1_000_000}, sorted(steps)[:5]    # forward only, none from a second node
    assert max(publishers) == 1, max(publishers)
    assert max(claimers) == 1, max(claimers)
    assert duplicate.returncode == 1, duplicate.stderr
    lines = duplicate.stderr.splitlines()
    fatal = [n for n, line in enumerate(lines) if '[FATAL]' in line]
    assert len(fatal) == 1, duplicate.stderr
    # it stepped no period (a stop line says how many) and its FATAL line names it as named
    assert not any('stopped at' in line for line in lines), duplicate.stderr
    assert '[startup_quiet.sim_node_b]: ' in lines[fatal[0]]
    assert 'another node named /startup_quiet/sim_node_b' in lines[fatal[0]]


def test_of_nodes_started_together_exactly_one_keeps_its_name(tmp_path):
    """
    Check three nodes of one name started at the same moment: one runs, two are refused.

    Each orders the claims the same way (none established yet: the instance id), so exactly
    one goes on, whichever claim each hears first.
    """
    args = ['--ros-args', '-r', '__ns:=/startup_together', '-p', 'log.enabled:=false',
            '-p', 'info_period:=0.0']
    nodes = [Node(tmp_path, *args) for _ in range(3)]
    try:
        deadline = time.monotonic() + TIMEOUT   # a refused node exits, before publishing
        while (len(refused := [node for node in nodes if node.proc.poll() is not None]) < 2
               and time.monotonic() < deadline):
            time.sleep(0.05)
        time.sleep(1.0)                          # (a third refusal would come by now)
        refused = [node for node in nodes if node.proc.poll() is not None]
        assert len(refused) == 2, [node.proc.returncode for node in nodes]
        [running] = [node for node in nodes if node not in refused]
        running.wait_for(READY)
    finally:
        codes = [node.stop() for node in nodes]
    assert sorted(codes) == [0, 1, 1], codes
    for node in refused:
        fatal = [line for line in node.lines if '[FATAL]' in line]
        assert len(fatal) == 1 and 'another node named /startup_together/sim_node' in fatal[0]


def test_the_host_lock_is_one_per_domain_and_name():
    """Check the host's lock: held once per (domain, name), free again once released."""
    from det_sim_ros.ros.host_lock import HostNameLock, LockState, lock_address
    name = f'/host_lock_{os.getpid()}/sim_node'
    first = HostNameLock(7, name)
    try:
        assert first.state is LockState.HELD
        assert HostNameLock(7, name).state is LockState.HELD_ELSEWHERE   # any other holder
        others = [HostNameLock(8, name), HostNameLock(7, name + '_b'),
                  HostNameLock(7, f'/host_lock_{os.getpid()}')]
        assert [lock.state for lock in others] == [LockState.HELD] * 3
        for lock in others:
            lock.release()
    finally:
        first.release()
    again = HostNameLock(7, name)
    assert again.state is LockState.HELD
    again.release()
    # any name gives an address of one length, of hex digits after a fixed prefix
    addresses = {lock_address(7, n) for n in ('/a', '/ä/' + 'x' * 500, '/a b/\\0')}
    assert len(addresses) == 3 and len({len(a) for a in addresses}) == 1


# Holds the lock of (7, argv[1]) in a process that forks a child (multiprocessing's fork, as a
# ProcessPoolExecutor on Linux does), prints the child's pid and waits to be killed.
FORKING_HOLDER = """
import multiprocessing, sys, time
from det_sim_ros.ros.host_lock import HostNameLock, LockState
lock = HostNameLock(7, sys.argv[1])
assert lock.state is LockState.HELD
child = multiprocessing.get_context('fork').Process(target=time.sleep, args=(120,))
child.start()
print(child.pid, flush=True)
time.sleep(120)
"""


def test_a_forked_child_keeps_no_lock():
    """
    Check that the lock dies with the process that took it, not with its last forked child.

    A process takes the lock and forks a child (which shares its descriptors); the parent is
    SIGKILLed while the child lives on: the name is free at once, and to the child it is held
    by another process.
    """
    from det_sim_ros.ros.host_lock import HostNameLock, LockState
    name = f'/host_lock_fork_{os.getpid()}/sim_node'
    parent = subprocess.Popen([sys.executable, '-c', FORKING_HOLDER, name], env=child_env(),
                              stdout=subprocess.PIPE, text=True)
    child_pid = int(parent.stdout.readline())
    try:
        assert HostNameLock(7, name).state is LockState.HELD_ELSEWHERE
        parent.kill()
        parent.wait()
        os.kill(child_pid, 0)                      # the child still runs
        successor = HostNameLock(7, name)
        assert successor.state is LockState.HELD
        successor.release()
    finally:
        parent.kill()
        parent.wait()
        with contextlib.suppress(ProcessLookupError):
            os.kill(child_pid, signal.SIGKILL)


def test_a_refusal_names_the_holder(tmp_path):
    """Check that a process refused the lock reads the holder's pid and command line."""
    from det_sim_ros.ros.host_lock import HostNameLock, LockState
    name = f'/host_lock_holder_{os.getpid()}/sim_node'
    marker = f'holder-marker-{os.getpid()}'
    script = tmp_path / 'holder.py'
    script.write_text('import sys, time\nfrom det_sim_ros.ros.host_lock import HostNameLock\n'
                      'lock = HostNameLock(7, sys.argv[1])\nprint(lock.state.name, flush=True)\n'
                      'time.sleep(120)\n')
    holder = subprocess.Popen([sys.executable, str(script), name, marker], env=child_env(),
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == 'HELD'
        refused = HostNameLock(7, name)
        assert refused.state is LockState.HELD_ELSEWHERE
        said = refused.holder()
        assert said == f'pid {holder.pid}: {sys.executable} {script} {name} {marker}', said
    finally:
        holder.kill()
        holder.wait()


def test_the_host_lock_alone_refuses_a_node(tmp_path):
    """
    Check that a name held on this host refuses a node at once, with no claim on DDS at all.

    This process holds the lock of /startup_locked/sim_node and runs no node: only the lock can
    refuse the one started. With ROS_AUTOMATIC_DISCOVERY_RANGE=OFF (a node that can meet no
    other) no lock is taken and it starts.
    """
    from det_sim_ros.ros.host_lock import HostNameLock, LockState
    held = HostNameLock(int(os.environ.get('ROS_DOMAIN_ID', '0')), '/startup_locked/sim_node')
    assert held.state is LockState.HELD
    args = ['--ros-args', '-r', '__ns:=/startup_locked', '-p', 'log.enabled:=false']
    try:
        refused = run_entry(args, cwd=tmp_path)
        assert refused.returncode == 1, refused.stderr
        fatal = [line for line in refused.stderr.splitlines() if '[FATAL]' in line]
        assert len(fatal) == 1 and 'another node named /startup_locked/sim_node' in fatal[0]
        assert f'(on this host, pid {os.getpid()}: ' in fatal[0]   # the holder: this process
        alone = Node(tmp_path, *args, environ={'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF'})
        try:
            alone.wait_for(READY)
        finally:
            stopped = alone.stop()
        assert stopped == 0, ''.join(alone.lines)
    finally:
        held.release()


def test_a_discovery_range_off_takes_no_lock():
    """Check that only ROS_AUTOMATIC_DISCOVERY_RANGE=OFF means that no other node is found."""
    from det_sim_ros.ros.name_check import discovers_no_other_node
    assert discovers_no_other_node({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'off'})
    for value in ('LOCALHOST', 'SUBNET', 'SYSTEM_DEFAULT', ''):
        assert not discovers_no_other_node({'ROS_AUTOMATIC_DISCOVERY_RANGE': value})
    assert not discovers_no_other_node({})


def test_a_killed_node_leaves_its_name_free(tmp_path):
    """Check that a node killed by SIGKILL holds no lock: a new node of its name starts."""
    args = ['--ros-args', '-r', '__ns:=/startup_killed', '-p', 'log.enabled:=false',
            '-p', 'info_period:=0.0']
    killed = Node(tmp_path, *args)
    try:
        killed.wait_for(READY)
    finally:
        killed.proc.kill()
        killed.proc.wait()
    successor = Node(tmp_path, *args)
    try:
        successor.wait_for(READY)
        time.sleep(0.5)
        assert successor.proc.poll() is None
    finally:
        stopped = successor.stop()
    assert stopped == 0, ''.join(successor.lines)
    assert not any('another node named' in line for line in successor.lines)


def test_other_domains_and_other_names_run_together(tmp_path):
    """
    Check that nodes of one name in two ROS domains, and of two names in one, all run.

    The host's lock is per (domain, fully qualified name); the names are as remapped.
    """
    from conftest import DOMAIN_ID
    other_domain = {'ROS_DOMAIN_ID': str(DOMAIN_ID % 232 + 1)}
    base = ['--ros-args', '-p', 'log.enabled:=false', '-p', 'info_period:=0.0']
    starts = [(['-r', '__ns:=/startup_apart'], None),
              (['-r', '__ns:=/startup_apart'], other_domain),
              (['-r', '__ns:=/startup_apart', '-r', '__node:=sim_node_b'], None),
              (['-r', '__ns:=/startup_apart/sim_node'], None)]
    nodes = [Node(tmp_path, *base, *remap, environ=environ) for remap, environ in starts]
    try:
        for node in nodes:
            node.wait_for(READY)
        time.sleep(0.5)
        assert [node.proc.poll() for node in nodes] == [None] * len(nodes)
    finally:
        codes = [node.stop() for node in nodes]
    assert codes == [0] * len(nodes), [''.join(node.lines) for node in nodes]
    assert not any('another node named' in line for node in nodes for line in node.lines)


def _wait_for_line(path, text, proc, timeout=TIMEOUT):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if text in path.read_text():
            return
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    pytest.fail(f'no {text!r} in {path}: {path.read_text()}')


def test_a_duplicate_on_another_host_stops_once_it_hears_the_established_claim(tmp_path):
    """
    Check two nodes of one name on two hosts (network namespaces): the newcomer stops.

    Each holds its own host's lock (a network namespace is a host to the lock as to DDS), so
    the newcomer does not wait for the claims of other hosts and stops when DDS brings the
    established node's claim: one FATAL line, exit code 1; the established node goes on.
    """
    from netns_hosts import can_make_namespaces, NetnsHosts
    why = can_make_namespaces()
    if why:
        pytest.skip(f'{why}: the hosts of this test are network namespaces')
    args = ENTRY + ['--ros-args', '-r', '__ns:=/startup_hosts', '-p', 'log.enabled:=false',
                    '-p', 'info_period:=0.0']
    with NetnsHosts(2) as net:
        env = net.ros_env(child_env(PYTHONUNBUFFERED='1'))
        outputs = [tmp_path / f'h{host}.out' for host in range(2)]
        procs = []
        for host, path in enumerate(outputs):
            with open(path, 'w') as out:
                procs.append(net.popen(host, args, stdout=out, stderr=subprocess.STDOUT,
                                       env=env, cwd=tmp_path))
            if host == 0:   # running, established: its claim wins over a newcomer's
                _wait_for_line(path, READY, procs[-1])
                time.sleep(ESTABLISHED_S + 0.5)
        established, newcomer = procs
        try:
            code = newcomer.wait(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            code = 'still running'
        running = established.poll() is None
        established.send_signal(signal.SIGINT)
        established_code = established.wait(timeout=TIMEOUT)
    text = outputs[1].read_text()
    assert code == 1, text
    fatal = [line for line in text.splitlines() if '[FATAL]' in line]
    assert len(fatal) == 1 and 'another node named /startup_hosts/sim_node' in fatal[0], text
    assert running and established_code == 0, outputs[0].read_text()


def test_reset_answer_names_the_new_log_file(harness, tmp_path):
    """Check that ~/reset's answer names the file the log continues in, not the old one."""
    h = harness(**{'log.path': str(tmp_path / 'logs'), 'start_paused': True})
    recorder = h.node.recorder
    old = recorder.path
    answer = h.call('reset')
    assert answer.success
    assert recorder.path != old and len(recorder.paths) == 2
    assert answer.message.endswith(f'the log continues in {recorder.path}')
    assert old not in answer.message


# sim_node with this process's wall clock an hour behind (Python's time.time_ns and time.time):
# a node whose start time were compared would look an hour older than any other
SKEWED_ENTRY = [sys.executable, '-c', (
    'import runpy, sys, time\n'
    'real_ns, real_s = time.time_ns, time.time\n'
    'time.time_ns = lambda: real_ns() - 3600 * 10**9\n'
    'time.time = lambda: real_s() - 3600.0\n'
    'sys.argv[0] = "sim_node"\n'
    'runpy.run_module("det_sim_ros.cli.sim_node", run_name="__main__")\n')]


def test_across_hosts_a_newcomer_with_a_skewed_clock_publishes_nothing(tmp_path):
    """
    Check the path across hosts on one host: DET_SIM_HOST_LOCK=off, DDS alone settles the name.

    A node runs until established; a newcomer of its name whose wall clock is an hour behind
    starts: it waits for the claims of DDS, hears the established one and stops before it
    publishes (one FATAL line, exit 1). A watch of the name's samples from before the newcomer
    to after its end sees one run only: the running node's samples, one period apart, none
    from t = 0 again.
    """
    environ = {'DET_SIM_HOST_LOCK': 'off'}
    args = ['--ros-args', '-r', '__ns:=/startup_skew', '-p', 'log.enabled:=false',
            '-p', 'info_period:=0.0']
    running = Node(tmp_path, *args, environ=environ)
    try:
        running.wait_for(READY)
        time.sleep(ESTABLISHED_S + 0.5)
        watch = subprocess.Popen([sys.executable, '-m', 'det_sim_ros.cli', 'watch', '--csv',
                                  '--ns', 'startup_skew', '--duration', '8'], cwd=tmp_path,
                                 env=child_env(), text=True, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE)
        try:
            header = b''   # (byte by byte: communicate() would miss what a readline buffered)
            while not header.endswith(b'\n') and (byte := os.read(watch.stdout.fileno(), 1)):
                header += byte
            assert header.startswith(b't,'), header                 # it has samples
            newcomer = subprocess.Popen(SKEWED_ENTRY + args, cwd=tmp_path, text=True,
                                        env=child_env(**environ), stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE)
            try:   # (it ends within its claim's settling, SETTLE_MAX_S after its start-up)
                _, newcomer_err = newcomer.communicate(timeout=20.0)
            except subprocess.TimeoutExpired:
                newcomer.kill()
                _, newcomer_err = newcomer.communicate()
            rows, _ = watch.communicate(timeout=TIMEOUT)
        finally:
            watch.kill()
            watch.wait()
        still_running = running.proc.poll() is None
    finally:
        stopped = running.stop()
    assert newcomer.returncode == 1, newcomer_err
    fatal = [line for line in newcomer_err.splitlines() if '[FATAL]' in line]
    assert len(fatal) == 1 and 'another node named /startup_skew/sim_node' in fatal[0]
    assert still_running and stopped == 0, ''.join(running.lines)
    steps = [round(float(row.split(',')[0]) * 1000) for row in rows.splitlines()]
    assert len(steps) > 1000 and steps[0] > 1000    # (the running node's: seconds in)
    jumps = [(a, b) for a, b in zip(steps, steps[1:]) if b != a + 1]
    assert not jumps, jumps   # none from the newcomer, none lost
