"""
Test sim_node's start-up as a process: --help, stray arguments, the log path, a duplicate name.

Also ~/reset's answer naming the log file the run continues in. The process tests run the real
entry point (``python -m det_sim_ros.cli.sim_node``) on the test domain.
"""

import concurrent.futures
import os
import queue
import signal
import subprocess
import sys
import threading
import time

from conftest import child_env
from det_sim_ros.ros.discovery import ANNOUNCE_S
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


class Node:
    """A sim_node process whose output is read line by line."""

    def __init__(self, cwd, *args):
        self.proc = subprocess.Popen(ENTRY + list(args), cwd=cwd, text=True, bufsize=1,
                                     env=child_env(PYTHONUNBUFFERED='1'),
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        self.lines = []
        # a reader thread, so that a line that never comes fails at the deadline instead of
        # blocking readline() for ever
        self._queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self._queue.put(line)
        self._queue.put(None)

    def wait_for(self, text):
        """Read lines until one holds ``text``; fail if the process ends first."""
        deadline = time.monotonic() + TIMEOUT
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
        pytest.fail(f'no {text!r} from sim_node: {"".join(self.lines)}')

    def stop(self):
        """SIGINT, then wait; return the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        while (line := self._queue.get(timeout=TIMEOUT)) is not None:
            self.lines.append(line)
        return self.proc.returncode


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
    if os.geteuid() != 0:          # root writes into a directory without write permission
        locked = tmp_path / 'locked'
        locked.mkdir(mode=0o555)
        yield str(locked)


def test_unwritable_log_path_refuses_to_start(tmp_path):
    """Check that a log.path that cannot be written gives one FATAL line and exit 1."""
    for path in _unwritable_paths(tmp_path):
        result = run_entry(['--ros-args', '-p', f'log.path:={path}', '-p', 'real_time:=false',
                            '-p', 'allow_duplicate_name:=true', '-p', 'scene.fidelity:=paper'],
                           cwd=tmp_path)
        assert result.returncode == 1, (path, result.stderr)
        problems = [line for line in result.stderr.splitlines() if '[INFO]' not in line]
        assert len(problems) == 1, (path, result.stderr)
        assert '[FATAL]' in problems[0] and 'cannot start: parameter log.path' in problems[0]
        assert repr(path) in problems[0]


def test_duplicate_name_refused_unless_allowed(tmp_path):
    """
    Check a second node of one name: one FATAL line and exit 1, or a WARN when allowed.

    The duplicates start once the first node is past its first announcements (ANNOUNCE_S), when
    they depend on its periodic ones: at Fast DDS's 3 s period a fifth of them would not see it
    within the check's window and start anyway.
    """
    args = ['--ros-args', '-r', '__ns:=/startup_dup', '-p', 'log.enabled:=false',
            '-p', 'info_period:=0.0']
    first = Node(tmp_path, *args)
    try:
        # the start line names the level: the shipped default is the exact kinematics, 5 terms
        assert 'fidelity exact n_r=5' in first.wait_for(READY)
        time.sleep(ANNOUNCE_S)
        with concurrent.futures.ThreadPoolExecutor(3) as pool:
            seconds = list(pool.map(lambda _: run_entry(args, cwd=tmp_path), range(3)))
        for second in seconds:
            assert second.returncode == 1, second.stderr
            fatal = [line for line in second.stderr.splitlines() if '[FATAL]' in line]
            assert len(fatal) == 1 and 'another node named /startup_dup/sim_node' in fatal[0]
            assert READY not in second.stderr
        allowed = Node(tmp_path, *args, '-p', 'allow_duplicate_name:=true')
        try:
            allowed.wait_for(READY)
            warning = allowed.wait_for('another node named /startup_dup/sim_node')
            assert '[WARN]' in warning
        finally:
            assert allowed.stop() == 0
    finally:
        assert first.stop() == 0, ''.join(first.lines)


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
