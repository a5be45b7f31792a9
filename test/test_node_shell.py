"""
Test the ``det_sim`` verbs that talk to a running sim_node, against a real node.

sim_node (plate scene, namespace /arm1, started paused) runs in this process, spun in a
thread of its own context on the test domain; the verbs reach it over DDS like any other
process would: send, watch, pause, resume, advance, reset, param get and set.
"""

import random
import signal
import subprocess
import sys
import threading
import time

from conftest import child_env, ChildProcess
from det_sim_ros.cli import main
import pytest

pytestmark = pytest.mark.ros

NS = ['--ns', 'arm1']
RATE = 0.1   # real_time_factor: 100 samples per wall second


@pytest.fixture(scope='module')
def spun_node():
    """Start the plate's sim_node, spun by an executor in a thread; yield (node, executor)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from det_sim_ros.ros.node import SimNode
    from conftest import DOMAIN_ID
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    params = {'scene_file': 'plate', 'start_paused': True, 'log.enabled': False,
              'info_period': 0.0, 'real_time_factor': RATE}
    sim = SimNode(context=context, namespace='/arm1',
                  parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(sim)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    yield sim, executor
    executor.shutdown()
    sim.destroy_node()
    rclpy.try_shutdown(context=context)
    thread.join(timeout=10.0)


@pytest.fixture
def node(spun_node):
    """Return the module's running sim_node."""
    return spun_node[0]


@pytest.fixture
def set_paused(spun_node):
    """
    Pause (True) or resume (False) the node with the function its ~/pause service calls.

    For a test's setup and cleanup: run in the node's executor thread, as the service runs it,
    with no shell of its own (test_send_by_name_and_in_det_order_then_advance and
    test_watch_csv_and_live_lines check the pause and resume verbs).
    """
    sim, executor = spun_node

    def set_paused(paused):
        task = executor.create_task(sim.set_paused, paused)
        deadline = time.monotonic() + 30.0
        while not task.done():
            assert time.monotonic() < deadline, 'the executor did not run the pause'
            time.sleep(0.005)
        assert sim.paused == paused
    return set_paused


def _charge(node):
    return dict(zip(node.det_names,
                    node.contract.values(node.current_outputs(), 'charge', 'position')))


def _ok(capsys, argv):
    assert main(argv + NS) == 0, capsys.readouterr().err
    return capsys.readouterr().out


def _error(capsys, argv, code):
    assert main(argv) == code
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('det_sim: error: '), err
    return err


def test_send_by_name_and_in_det_order_then_advance(node, capsys):
    assert 'paused' in _ok(capsys, ['pause'])
    assert node.paused
    assert 'right=1500 V on /arm1/voltage_command_joint' in _ok(capsys, ['send', 'right=1500'])
    assert 'advanced 3 period(s): t = 0.003 s' in _ok(capsys, ['advance', '3'])
    charge = _charge(node)
    assert charge['left'] == 0.0 and charge['right'] > 0.0
    assert 'left=2000, right=0 V on /arm1/voltage_command' in _ok(capsys, ['send', '2000', '0'])
    _ok(capsys, ['advance'])
    assert _charge(node)['left'] > 0.0
    assert 'reset to t = 0' in _ok(capsys, ['reset'])
    assert _charge(node) == {'left': 0.0, 'right': 0.0}


def test_send_out_of_range_says_the_node_clamps_it(node, capsys):
    assert main(['send', 'left=-500', 'right=1000'] + NS) == 0
    captured = capsys.readouterr()
    assert 'sent left=-500, right=1000 V' in captured.out
    assert captured.err == ('det_sim: note: the node applies left: -500 V clamped to [0, 3000] V '
                            '(/arm1/voltage_command_joint)\n')
    assert main(['send', '0', '0'] + NS) == 0 and capsys.readouterr().err == ''


@pytest.mark.parametrize('argv, code, message', [
    (['send', '1000'] + NS, 2, '1 voltage(s) for 2 DET(s)'),
    (['send', 'middle=5'] + NS, 2, "unknown or repeated DET 'middle'; the DETs: left, right"),
    (['send', 'left=1', '2'] + NS, 2, 'not both'),
    (['send', 'left=1', 'left=2'] + NS, 2, "unknown or repeated DET 'left'"),
    (['send', 'left=nan'] + NS, 2, 'finite'),
    (['param', 'set', 'real_time_factor', '-1'] + NS, 1, 'real_time_factor not set'),
    (['param', 'get', 'no_such_thing'] + NS, 1, "no parameter 'no_such_thing'"),
    (['pause', '--ns', 'nowhere', '--timeout', '0.5'], 1, 'no service /nowhere/sim_node/pause'),
    (['send', '5', '--ns', 'nowhere', '--timeout', '0.5'], 1, 'no service'),
    # --duration: a safety net for a watch that ignores --timeout
    (['watch', '--ns', 'nowhere', '--timeout', '0.5', '--duration', '30'], 1,
     'no sample on /nowhere/displacement within 0.5 s: /nowhere/sim_node does not publish it'),
])
def test_bad_values_and_no_node_are_one_line(node, capsys, argv, code, message):
    assert message in _error(capsys, argv, code)


def test_parameters_get_and_set(node, capsys):
    assert _ok(capsys, ['param', 'get', 'real_time_factor']).strip() == str(RATE)
    assert _ok(capsys, ['param', 'get', 'structure.dets']).strip() == "['left', 'right']"
    assert _ok(capsys, ['param', 'get', 'mode']).strip() == "''"
    assert _ok(capsys, ['param', 'set', 'max_lag', '1']).strip() == 'max_lag = 1.0'
    assert node.get_parameter('max_lag').value == 1.0


def test_watch_csv_and_live_lines(node, capfd, set_paused):
    """Watch with a real stderr (capfd): rclpy's EventsExecutor, as on a terminal."""
    def ok(argv):
        assert main(argv + NS) == 0
        return capfd.readouterr().out

    ok(['send', 'left=3000'])
    assert 'running' in ok(['resume'])
    try:
        lines = ok(['watch', '--csv', '--count', '3']).splitlines()
        assert lines[0].startswith('t,deflection.position.left,deflection.position.right,'
                                   'deflection.velocity.left')
        assert len(lines) == 4 and len(lines[1].split(',')) == 1 + 5 * 2
        steps = [round(float(line.split(',')[0]) * 1000) for line in lines[1:]]
        assert steps == list(range(steps[0], steps[0] + 3))   # consecutive samples
        live = ok(['watch', '--count', '2']).splitlines()
        assert len(live) == 2 and all(line.startswith('t = ') for line in live)
        assert 'left: dy' in live[-1] and 'right: dy' in live[-1]
        assert main(['advance'] + NS) == 1
        assert 'not paused' in capfd.readouterr().err
    finally:
        set_paused(True)


def test_watch_waits_for_a_paused_node_says_so_and_shows_it_once_resumed(set_paused, tmp_path):
    """Check a paused node's watch: a note after --timeout (5 s), lines after resume, exit 0."""
    set_paused(True)
    watch = ChildProcess([sys.executable, '-m', 'det_sim_ros.cli', 'watch', *NS], tmp_path)
    try:
        note = watch.wait_for('waiting')
        assert note == ('det_sim: /arm1/sim_node has published no sample on /arm1/displacement '
                        'yet (paused?); waiting\n')
        assert main(['resume'] + NS) == 0
        assert 'left: dy' in watch.wait_for('t = ')
    finally:
        code = watch.stop()
        set_paused(True)
    assert code == 0 and 'error' not in ''.join(watch.lines), watch.lines


INTERRUPTED = [['send', 'left=100'], ['watch'], ['watch', '--csv'], ['pause'], ['resume'],
               ['advance', '20'], ['reset'], ['param', 'get', 'real_time_factor'],
               ['param', 'set', 'max_lag', '0.5']]


def _handles_sigterm(pid) -> bool:
    """Return whether the process catches SIGTERM (det_sim's handler: /proc SigCgt)."""
    with open(f'/proc/{pid}/status') as stream:
        caught = [line for line in stream if line.startswith('SigCgt:')]
    return bool(caught) and bool(int(caught[0].split()[1], 16) >> (signal.SIGTERM - 1) & 1)


def _interrupt(argv, delay):
    """Run ``det_sim ARGV``; SIGINT it ``delay`` s after it took the signals."""
    from conftest import DOMAIN_ID
    proc = subprocess.Popen([sys.executable, '-m', 'det_sim_ros.cli', *argv, *NS], text=True,
                            env=child_env(ROS_DOMAIN_ID=str(DOMAIN_ID), PYTHONUNBUFFERED='1'),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60.0
        while proc.poll() is None and not _handles_sigterm(proc.pid):
            assert time.monotonic() < deadline, 'the verb never took the signals'
            time.sleep(0.002)
        try:   # a verb done before the moment ends is not signalled (no wait for the moment)
            proc.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, out, err


def test_every_verb_stops_cleanly_on_ctrl_c_at_any_moment(set_paused):
    """
    Check SIGINT at random moments of each verb: exit 0 or 130 with one line, no traceback.

    From the moment det_sim takes the signals (its first line) to its end: its imports, the
    shell's start, discovery, a wait for the node's answer, the watch loop and the teardown. A
    verb that was done exits 0 (watch too: its usual end is Ctrl-C); one cut short says
    'det_sim: interrupted' and exits 130. rclpy turned a KeyboardInterrupt inside its
    executor into 'RuntimeError: Unable to convert call argument'; one inside a C extension's
    import came out as an ImportError.
    """
    rng = random.Random(5)
    # one random moment in each third of the first 1.5 s per verb (its start, its wait, its
    # end): every phase is hit in every run, at fewer cases than uniform draws need
    cases = [(argv, rng.uniform(lo, lo + 0.5)) for argv in INTERRUPTED for lo in (0.0, 0.5, 1.0)]
    problems, interrupted, previous = [], 0, None
    try:
        for argv, delay in cases:
            # a paused node to advance, samples to watch: set before a verb's first case (its
            # cases leave the node as they found it; the verbs before may not)
            if argv[0] in ('advance', 'watch') and argv != previous:
                set_paused(argv[0] == 'advance')
            previous = argv
            code, out, err = _interrupt(argv, delay)
            # -2: the signal came while the interpreter exited, after the shell had given the
            # signals back (a shell reports it as 130 too); nothing more was to be written
            clean = (code in (0, -2) and not err.strip()) or (
                code == 130 and err == 'det_sim: interrupted\n')
            if not clean:
                problems.append(f'{argv} after {delay:.2f} s: exit {code}\n{err}')
            interrupted += code == 130 or argv[0] == 'watch'
    finally:
        set_paused(True)
    assert not problems, '\n'.join(problems)
    assert interrupted >= len(cases) // 3      # most stops came before the verb was done


def test_ctrl_c_as_watch_starts_exits_0(set_paused):
    """
    Check Ctrl-C at once after det_sim took the signals: watch exits 0, quietly (docs/shell.md).

    The moment falls in det_sim's start (its imports, the arguments), before the shell opens.
    """
    set_paused(False)
    try:
        for argv in (['watch'], ['watch', '--csv']):
            code, out, err = _interrupt(argv, 0.0)
            assert (code, err) == (0, ''), (argv, code, err)
    finally:
        set_paused(True)
