"""
Test the node's reliability as a process: signals, bad start-up input, SIGKILL, no NaN.

Reliability of the node as a process: stops by SIGTERM/SIGINT at any moment, every bad
start-up input, SIGKILL and the log, no NaN published.

The process tests start real ``sim_node`` processes (about 2 s each on a shared 2-core host),
two at a time. The default run samples the stop moments: 6 SIGTERM + 6 SIGINT stops, 4 SIGKILLs
and 6 of the bad start-up inputs as processes (all of them in-process). Set
``DET_SIM_RELIABILITY=full`` for the full counts (20 + 20 stops, 10 SIGKILLs, every bad
input as a process too). The moments are drawn from a seeded generator: reproducible.
"""

import concurrent.futures
import dataclasses
import glob
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
import warnings

from conftest import child_env
from det_sim_ros.io.log import is_torn, LogReader
from det_sim_ros.ros.node import main
from det_sim_ros.ros.params import NODE_PARAMS
from det_sim_ros.scenes.scene import (INTEGRATOR_SPEC, load_scene, PHYSICS_SPEC, SCENE_SPEC,
                                      scene_to_dict, STRUCTURE_SPEC)
import pytest

pytestmark = pytest.mark.ros

FULL = os.environ.get('DET_SIM_RELIABILITY', '') == 'full'
READY = 'voltage command order'     # the node's last start-up line
WALL_LIMIT = 120.0                  # s, a safety net only
EXIT_LIMIT = 30.0                   # s from a stop signal to the exit: 6x the node's own bound
REFUSAL_LIMIT = 30.0                # s for a refused start to exit (a safety net: it takes ~1 s)


def _interactive():
    """In the child: SIGINT as in a terminal (a shell's background job inherits it ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _env():
    # a process that hangs prints every thread's stack on SIGABRT (see _wait_exit)
    return child_env(PYTHONUNBUFFERED='1', PYTHONFAULTHANDLER='1')


def _wait_exit(proc):
    """Return the exit code, or 'hung' after the stacks a SIGABRT made the process print."""
    try:
        return proc.wait(timeout=EXIT_LIMIT)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        try:
            proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
        return 'hung'


def _exit_and_output(proc, limit):
    """
    Return (exit code, output) of a child whose output is a pipe; ('hung', output and stacks).

    A child still running after ``limit`` s is sent SIGABRT: its faulthandler prints every
    thread's Python stack, and gdb (where it may attach) the native ones, into the failure.
    """
    try:
        output, _ = proc.communicate(timeout=limit)
        return proc.returncode, output
    except subprocess.TimeoutExpired:
        pass   # (a later communicate() still returns all the output)
    native = ''
    if shutil.which('gdb'):
        native = subprocess.run(['gdb', '-p', str(proc.pid), '-batch', '-ex',
                                 'thread apply all bt'], capture_output=True, text=True,
                                timeout=60.0).stdout
    proc.send_signal(signal.SIGABRT)
    try:
        output, _ = proc.communicate(timeout=10.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        output, _ = proc.communicate()
    return 'hung', f'{output}\nnative stacks:\n{native or "(no gdb)"}'


@dataclasses.dataclass
class Run:
    proc: subprocess.Popen
    out: str
    log_dir: str
    started: float

    def text(self):
        with open(self.out, encoding='utf-8', errors='replace') as stream:
            return stream.read()

    def wait_handling(self):
        """
        Wait until the process handles SIGTERM itself (/proc/<pid>/status SigCgt).

        From then on the package's code runs. Before, while the interpreter starts (and the
        PyPI ROS wheels re-execute it once), the signals' default actions apply: nothing has
        started yet.
        """
        deadline = time.monotonic() + WALL_LIMIT
        while True:
            with open(f'/proc/{self.proc.pid}/status') as stream:
                caught = [line for line in stream if line.startswith('SigCgt:')]
            if caught and int(caught[0].split()[1], 16) >> (signal.SIGTERM - 1) & 1:
                return
            assert self.proc.poll() is None and time.monotonic() < deadline, self.text()
            time.sleep(0.002)

    def wait_ready(self):
        deadline = time.monotonic() + WALL_LIMIT
        while READY not in self.text():
            assert self.proc.poll() is None, f'the node exited early:\n{self.text()}'
            assert time.monotonic() < deadline, 'the node did not start'
            time.sleep(0.02)
        return time.time()


def start_node(tmp, name, *params):
    log_dir = os.path.join(tmp, name)
    out = os.path.join(tmp, name + '.txt')
    args = [sys.executable, '-m', 'det_sim_ros.cli.sim_node', '--ros-args',
            '-r', f'__ns:=/{name}', '-p', f'log.path:={log_dir}', '-p', 'info_period:=0.0',
            '-p', 'scene.fidelity:=paper']   # the stop, not the fidelity, is the subject
    for p in params:
        args += ['-p', p]
    with open(out, 'w') as stream:
        proc = subprocess.Popen(args, stdout=stream, stderr=subprocess.STDOUT, env=_env(),
                                preexec_fn=_interactive)
    return Run(proc, out, log_dir, time.time())


FLOOD = textwrap.dedent("""
    import math, sys, time
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    rclpy.init()
    node = rclpy.create_node('flood', namespace=sys.argv[1])
    pub = node.create_publisher(Float64MultiArray, 'voltage_command', 10)
    joint = node.create_publisher(JointState, 'voltage_command_joint', 10)
    bad = [[math.nan], [math.inf], [1e9], [-5.0], [1.0, 2.0], []]
    k = 0
    period = 1e-4                        # 10 kHz
    next_t = time.monotonic()
    try:
        while True:
            k += 1
            if k % 7 == 0:
                pub.publish(Float64MultiArray(data=bad[k % len(bad)]))
            elif k % 11 == 0:
                joint.publish(JointState(name=['det0', 'det0'], position=[1.0, 2.0]))
            else:
                pub.publish(Float64MultiArray(data=[float(k % 3000)]))
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    except KeyboardInterrupt:
        pass
""")


def start_flood(tmp, name):
    return subprocess.Popen([sys.executable, '-c', FLOOD, f'/{name}'], env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def finished_logs(log_dir):
    """Every log file of the run: finished (footer, summary) and readable; all outputs finite."""
    files = sorted(glob.glob(os.path.join(log_dir, '*.mcap')))
    counts = []
    for path in files:
        assert not is_torn(path), path
        reader = LogReader(path)
        n = 0
        for message in reader.messages():
            if message.topic.endswith(('deflection', 'displacement', 'charge', 'current')):
                msg = message.decode()
                assert all(math.isfinite(v) for v in list(msg.position) + list(msg.velocity))
                n += 1
        assert reader.complete, (path, reader.errors)
        assert 'det_sim_ros.end' in reader.metadata
        counts.append(n)
    return counts


def _stop_case(tmp, case):
    sig, moment, delay, index = case
    name = f"{sig.name.lower()}_{moment.replace('-', '_')}_{index}"   # a valid ROS name
    flood = start_flood(tmp, name) if moment == 'flood' else None
    run = start_node(tmp, name, 'real_time:=true')
    try:
        if moment == 'start-up':
            run.wait_handling()
            time.sleep(delay)                      # inside imports / preparation
        else:
            run.wait_ready()
            time.sleep(delay)
        run.proc.send_signal(sig)
        code = _wait_exit(run.proc)
    finally:
        if run.proc.poll() is None:
            run.proc.kill()
        if flood is not None:
            flood.send_signal(signal.SIGINT)
            flood.wait(timeout=WALL_LIMIT)
    text = run.text()
    return name, code, text, run.log_dir


def _cases(n_per_signal):
    rng = random.Random(17)
    cases = []
    moments = ['start-up', 'running', 'flood']
    for sig in (signal.SIGTERM, signal.SIGINT):
        for i in range(n_per_signal):
            moment = moments[i % 3]
            # start-up: 0-1.2 s after the package's code took the signals (imports, scene,
            # model, compile; the whole start-up takes 1.5-2 s here)
            delay = rng.uniform(0.0, 1.2) if moment == 'start-up' else rng.uniform(0.0, 1.0)
            cases.append((sig, moment, delay, i))
    return cases


def test_sigterm_and_sigint_at_any_moment_exit_0_with_a_finished_log(tmp_path):
    """
    Check that SIGTERM and SIGINT at any moment exit 0 with a finished log.

    (Or, should the middleware's teardown hang, exit 1 within its bound with the stacks: the
    log is finished before that teardown.)

    SIGTERM / SIGINT during start-up, while running and under a 10 kHz command flood (with
    NaN, out-of-range, wrong-length and repeated-name commands): exit 0, no traceback, every
    log file finished and indexed, no non-finite output.
    """
    cases = _cases(20 if FULL else 6)
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        results = list(pool.map(lambda c: _stop_case(str(tmp_path), c), cases))
    problems = []
    logged = 0
    for name, code, text, log_dir in results:
        # the documented bound (docs/topics.md, Stopping): a middleware teardown that hangs is
        # ended after TEARDOWN_LIMIT_S with exit code 1 and every thread's stack, log finished
        bounded = code == 1 and 'Timeout (' in text and 'most recent call first' in text
        if (code != 0 and not bounded) or 'Traceback' in text or 'Error' in text:
            problems.append(f'{name}: exit {code}\n{text}')
            continue
        if bounded:   # (a warning: the run's summary shows it)
            warnings.warn(f'{name}: the teardown hung and was ended by its bound:\n{text}')
        counts = finished_logs(log_dir)
        logged += bool(counts and counts[0])
    assert not problems, '\n'.join(problems)
    assert logged >= len(cases) // 2          # the running / flood cases logged samples


def test_sigkill_leaves_a_log_standard_readers_open(tmp_path, ros_context):
    """
    Check that SIGKILL leaves a log that standard readers open.

    SIGKILL at a random moment (real time): mcap's reader and rosbags read the file as it
    is, and it holds the samples up to at most 100 ms of sim time before the kill. The sim time
    at the kill is the newest sample received here just before it (so the loss measured is a
    lower bound by the transport latency, ~1 ms).
    """
    from pathlib import Path

    import rclpy
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader
    from sensor_msgs.msg import JointState
    rng = random.Random(19)
    targets = [rng.uniform(0.3, 2.0) for _ in range(10 if FULL else 4)]
    from rclpy.executors import SingleThreadedExecutor
    watcher = rclpy.create_node('kill_watcher', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(watcher)
    lost = []
    try:
        for index, target in enumerate(targets):
            name = f'sigkill_{index}'
            newest = [-1]
            sub = watcher.create_subscription(
                JointState, f'/{name}/displacement',
                lambda msg: newest.__setitem__(0, max(newest[0], msg.header.stamp.sec * 10**9
                                                      + msg.header.stamp.nanosec)), 100)
            run = start_node(str(tmp_path), name, 'real_time:=true')
            deadline = time.monotonic() + WALL_LIMIT
            try:
                while newest[0] < target * 1e9:
                    assert run.proc.poll() is None and time.monotonic() < deadline, run.text()
                    executor.spin_once(timeout_sec=0.01)
                run.proc.kill()
                run.proc.wait(timeout=WALL_LIMIT)
            finally:
                if run.proc.poll() is None:
                    run.proc.kill()
                watcher.destroy_subscription(sub)
            (path,) = glob.glob(os.path.join(run.log_dir, '*.mcap'))
            reader = LogReader(path)
            last = max(m.log_time for m in reader.messages())
            lost.append((newest[0] - last) * 1e-9)
            with open(path, 'rb') as stream:
                standard = sum(1 for _ in make_reader(stream).iter_messages())
            with AnyReader([Path(path)]) as bag:
                assert sum(1 for _ in bag.messages()) == standard > 0
    finally:
        executor.shutdown()
        watcher.destroy_node()
    print(f'SIGKILL: sim time lost per kill (s): {[round(x, 4) for x in lost]}, '
          f'worst {max(lost):.4f} s')
    assert max(lost) <= 0.100


# -- every start-up key with a wrong type and an out-of-range value ---------------------------

def _bad_values(spec):
    """(wrong type, out of range) for a scene spec entry; None where a kind has no range."""
    kind = spec[0]
    if kind == 'bool':
        return 'maybe', None
    if kind == 'choice':
        return 7, 'bogus'
    if kind == 'names':
        return 7, ['a', 'a']
    if kind == 'str':
        return 7, 'bogus'
    lower, upper = spec[1], spec[3]
    wrong = 'abc' if kind == 'float' else 2.5
    if math.isfinite(upper):
        out = upper * 2 + 1 if kind == 'float' else int(upper) + 1
    else:
        out = lower - 1 if kind == 'float' else int(lower) - 1
    return wrong, out


def startup_keys():
    """(key, value, what) for every scene and node key; plus the scene file parameter."""
    rows = []
    sections = {'scene': SCENE_SPEC, 'physics': PHYSICS_SPEC, 'integrator': INTEGRATOR_SPEC,
                'structure': STRUCTURE_SPEC}
    for section, spec in sections.items():
        for key, entry in spec.items():
            wrong, out = _bad_values(entry)
            rows.append((f'{section}.{key}', wrong, 'type'))
            if out is not None:
                rows.append((f'{section}.{key}', out, 'range'))
    rows += [('rate_hz', 'abc', 'type'), ('rate_hz', 0.0, 'range'),
             ('dets.det0.Rs', 'abc', 'type'), ('dets.det0.Rs', -1.0, 'range'),
             ('dets.nobody.Rs', 1.0, 'range'), ('scene_file', 7, 'type'),
             ('scene_file', 'no_such_scene', 'range')]
    for name, (default, _, _, bounds) in NODE_PARAMS.items():
        wrong = {bool: 'maybe', int: 2.5, float: 'abc', str: 7}[type(default)]
        rows.append((f'node:{name}', wrong, 'type'))
        if isinstance(default, str) and bounds is not None:   # choices
            rows.append((f'node:{name}', 'not_' + bounds[0], 'range'))
        elif bounds is not None:
            rows.append((f'node:{name}', bounds[1] * 2 + 1, 'range'))
    return rows


def _yaml_text(value):
    import yaml
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()


def _as_parameter(key, value):
    name = key.split(':', 1)[1] if key.startswith('node:') else key
    return f'{name}:={_yaml_text(value)}'


def _as_file(tmp_path, key, value):
    import yaml
    data = scene_to_dict(load_scene('default'), wrap=True)
    inner = data['sim_node']['ros__parameters']
    if key.startswith('node:'):
        target, path = inner.setdefault('node', {}), key.split(':', 1)[1].split('.')
    else:
        target, path = inner, key.split('.')
    for part in path[:-1]:
        target = target.setdefault(part, {})
    target[path[-1]] = value
    file = tmp_path / f'bad_{abs(hash((key, repr(value))))}.yaml'
    file.write_text(yaml.safe_dump(data))
    return f'scene_file:={file}'


KEYS = startup_keys()


def _quiet(key):
    """No log files from the checks (unless log.enabled itself is the key under test)."""
    return [] if key == 'node:log.enabled' else ['-p', 'log.enabled:=false']


@pytest.mark.parametrize('route', ['parameter', 'file'])
def test_every_bad_startup_input_is_one_line_in_process(capfd, tmp_path, route):
    """
    Check that every bad start-up input gives one line naming its key, in process.

    Every scene and node key x {wrong type, out of range}, given with -p and in a scene
    file: main() returns 1 and prints one line naming the key (in-process: fast).
    """
    failures = []
    for key, value, what in KEYS:
        if route == 'file' and key == 'scene_file':
            continue
        arg = (_as_parameter(key, value) if route == 'parameter'
               else _as_file(tmp_path, key, value))
        # a value the node wrongly accepts would start it: stop it after 10 s (then exit 0)
        guard = threading.Timer(10.0, os.kill, (os.getpid(), signal.SIGTERM))
        guard.start()
        try:
            code = main(['sim_node', '--ros-args', *_quiet(key), '-p', arg])
        finally:
            guard.cancel()
        out, err = capfd.readouterr()
        lines = [line for line in (out + err).splitlines() if line.strip()]
        parts = key.split(':')[-1].split('.')
        named = bool(lines) and (any(part in lines[0] for part in parts[1:] or parts)
                                 or key == 'scene_file' and 'scene file' in lines[0])
        if code != 1 or len(lines) != 1 or 'cannot start' not in lines[0] or not named:
            failures.append(f'{key} = {value!r} ({what}, {route}): exit {code}: {lines}')
    assert not failures, '\n'.join(failures)


def test_bad_startup_inputs_as_processes(tmp_path):
    """
    Check that bad start-up inputs give one line and exit 1 in real processes too.

    The same through real processes (a sample by default): one line, exit 1, no traceback.
    """
    rng = random.Random(23)
    rows = KEYS if FULL else rng.sample(KEYS, 6) + [
        ('integrator.method', 'bogus', 'range'), ('physics.Rs', 'abc', 'type')]

    def run(row):
        key, value, _ = row
        arg = _as_parameter(key, value)
        proc = subprocess.Popen([sys.executable, '-m', 'det_sim_ros.cli.sim_node', '--ros-args',
                                 *_quiet(key), '-p', arg], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, env=_env())
        code, text = _exit_and_output(proc, REFUSAL_LIMIT)
        return row, code, text.strip()
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        results = list(pool.map(run, rows))
    failures = [f'{row}: exit {code}: {text}' for row, code, text in results
                if code != 1 or 'Traceback' in text or len(text.splitlines()) != 1]
    assert not failures, '\n'.join(failures)


def test_integer_for_a_double_parameter_is_accepted(capfd):
    """
    Check that an integer given for a double parameter is accepted as a double.

    `-p physics.Rs:=1` (an integer where a double is declared) starts; the node reads 1.0.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from det_sim_ros.ros.node import SimNode
    context = Context()
    rclpy.init(context=context)
    try:
        node = SimNode(context=context, parameter_overrides=[
            Parameter('physics.Rs', value=1), Parameter('real_time_factor', value=2),
            Parameter('log.enabled', value=False), Parameter('info_period', value=0.0)])
        assert node.scene.physics.Rs == 1.0 and node.get_parameter('physics.Rs').value == 1.0
        assert node.get_parameter('real_time_factor').value == 2.0
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_node_repairs_a_torn_log_in_its_directory_at_start(tmp_path, harness):
    """
    Check that the node repairs a torn log in its directory when it starts.

    A log cut inside a write (power loss): the next start in that directory repairs it.
    """
    from std_msgs.msg import Float64MultiArray

    from det_sim_ros.io.log import Recorder
    folder = tmp_path / 'logs'
    torn = folder / 'det_sim_20260101-000000_1.mcap'
    recorder = Recorder(tmp_path / 'live.mcap', None, flush_sim_s=0.01)
    for k in range(100):
        recorder.record('voltage_command', Float64MultiArray(data=[float(k)]), k * 1_000_000)
    folder.mkdir()
    shutil.copyfile(recorder.path, torn)   # the crash: what is on disk before the file's end
    recorder.close()
    with open(torn, 'r+b') as stream:
        stream.truncate(os.path.getsize(torn) - 10)
    assert is_torn(str(torn))
    h = harness(**{'log.path': str(folder)})
    assert not is_torn(str(torn))
    assert len(list(LogReader(str(torn)).messages())) >= 90
    assert h.node.recorder.path != str(torn)
