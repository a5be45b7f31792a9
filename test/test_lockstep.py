"""
Test lockstep mode and the det_sim pytest plugin.

In lockstep every period waits for the controller, so a closed loop through ROS equals the same
loop offline bit for bit, and two runs give the same log whatever the host load.
"""

import os
import subprocess
import sys
import textwrap
import time

from conftest import child_env
from det_sim_ros.io.contract import OutputContract
from det_sim_ros.io.log import LogReader
from det_sim_ros.io.replay import resimulate
# The fixture, as the plugin gives it. pyflakes reads each test's det_sim argument as a
# redefinition of this import, hence the F811 noqa on those tests.
from det_sim_ros.ros.testing import det_sim  # noqa: F401
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

pytestmark = pytest.mark.ros

KP, KI, T_STEP, TARGET = 2.0e4, 6.0e6, 0.6, 2.0e-3   # V/m, V/(m s), s, m


def pi_volts(state, dy, t, dt, target=TARGET):
    """Return the PI law's voltage, V: 0 V until T_STEP, then PI on the displacement error."""
    if t < T_STEP - 1e-12:
        return 0.0
    error = target - dy
    state['i'] += error * dt
    return min(3000.0, max(0.0, KP * error + KI * state['i']))


def make_pi(context, name='pi', joint=False, stamp=True, namespace='', target=TARGET,
            until=None, after_match=False):
    """
    Create a PI controller node that answers every displacement sample.

    ``until``: none after that sim time, s; ``node.done`` is then set, so a lockstep run ends
    at exactly that sample.

    ``after_match``: a controller in another process answers only once its command publisher
    has matched the node's subscription (an answer sent before would be lost and the lockstep
    would wait for it forever); the sample that came before is answered on the match event.
    """
    import rclpy
    from rclpy.event_handler import PublisherEventCallbacks
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    node = rclpy.create_node(name, context=context, namespace=namespace)
    node.done = False
    state = {'i': 0.0}
    waiting = []          # the sample that arrived before the publisher matched
    topic, kind = (('voltage_command_joint', JointState) if joint
                   else ('voltage_command', Float64MultiArray))

    def on_match(status):
        if status.current_count > 0 and waiting:
            on_dy(waiting.pop())
    pub = node.create_publisher(kind, topic, 10, event_callbacks=PublisherEventCallbacks(
        matched=on_match) if after_match else None)

    def on_dy(msg):
        if after_match and pub.get_subscription_count() == 0:
            waiting[:] = [msg]
            return
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if until is not None and t >= until - 1e-9:
            node.done = True
            return
        volts = pi_volts(state, msg.position[0], t, 1e-3, target)
        if joint:
            cmd = JointState(name=['det0'], position=[volts])
            if stamp:
                cmd.header.stamp = msg.header.stamp   # answers this sample
            pub.publish(cmd)
        else:
            pub.publish(Float64MultiArray(data=[volts]))
    node.create_subscription(JointState, 'displacement', on_dy, 10)
    return node


def offline_loop(t_end):
    """Run the same closed loop without ROS: sample k -> command -> period k+1."""
    scene = load_scene('default')
    sim = Simulator(scene)
    contract = OutputContract(sim.model)
    out = np.array(list(sim.outputs().values()))
    state = {'i': 0.0}
    dys, volts = [], [0.0]
    for k in range(int(round(t_end / sim.dt)) + 1):
        dy = contract.values(out, 'displacement', 'position')[0]
        dys.append(dy)
        if k == int(round(t_end / sim.dt)):
            break
        v = pi_volts(state, dy, k * sim.dt, sim.dt)
        sim.set_input([v])
        volts.append(v)
        out = sim.step().copy()
    return np.array(dys), np.array(volts)


@pytest.mark.parametrize('joint', [False, True])
def test_lockstep_loop_equals_the_offline_loop_and_the_pi_settles(det_sim, joint):  # noqa: F811
    """
    Check that the lockstep PI loop equals the offline loop and settles.

    Through ROS in lockstep the PI loop is the offline loop bit for bit (Float64MultiArray
    or stamped JointState answers), and it brings Δy to 2 mm within 5 % by 0.5 s.
    """
    sim = det_sim('default')
    run = sim.run(until=1.2, nodes=[make_pi(sim.context, joint=joint)])
    dys, volts = offline_loop(1.2)
    assert run.t.size == dys.size and run.t[-1] == pytest.approx(1.2)
    assert run.signal('dy').tobytes() == dys.tobytes()
    assert run.signal('voltage').tobytes() == volts.tobytes()
    metrics = run.step_metrics('dy', target=TARGET, t_step=T_STEP)
    assert metrics.settling_time <= 0.5
    assert abs(metrics.steady_state_error) <= 0.05 * TARGET
    assert metrics.overshoot < 0.05 and 0.0 < metrics.rise_time < metrics.settling_time
    assert sim.node.pacing.missed_deadlines == 0 and sim.node.commands.refused == 0


def _busy(n):
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(n)]


def _log_records(path):
    return [(m.topic, m.log_time, m.sequence, m.data) for m in LogReader(path).messages()]


def test_two_lockstep_runs_give_identical_logs_even_with_every_core_busy(
        det_sim, tmp_path):  # noqa: F811
    """
    Check that two lockstep runs give identical logs, even with every core busy.

    The same scene, controller and initial state: the same log records (every sample and
    every command at the period it applied to), also when every core is busy; resim agrees.
    """
    paths = []
    for n_busy in (0, os.cpu_count() or 2):
        busy = _busy(n_busy)
        try:
            sim = det_sim('default', {'scene.fidelity': 'paper'},
                          params={'log.path': str(tmp_path / f'run{n_busy}.mcap')})
            sim.run(until=0.8, nodes=[make_pi(sim.context, joint=True)])
            recorder = sim.node.recorder
            sim.close()
        finally:
            for proc in busy:
                proc.kill()
                proc.wait()
        assert recorder.fault == ''
        paths.append(recorder.path)
    first, second = (_log_records(p) for p in paths)
    assert len(first) > 800 * 5 and first == second
    commands = [r for r in first if r[0] == '/voltage_command_joint']
    assert len(commands) == 800   # one answer per sample, at that sample's time
    assert [r[1] for r in commands] == [k * 1_000_000 for k in range(800)]
    result = resimulate(paths[1])
    assert result.ok(0.0) and result.commands == 800, result.table()


def test_two_sources_and_stale_answers(det_sim):  # noqa: F811
    """
    Check that the node waits for two sources and applies stale answers without counting them.

    lockstep.sources = 2: the node waits for both; a JointState stamped with an older
    sample is applied but does not count; an unstamped one answers the latest sample.
    """
    import rclpy
    from sensor_msgs.msg import JointState
    sim = det_sim('plate', params={'lockstep.sources': 2})
    stale = []

    def controller(name, det, volts, stamped):
        node = rclpy.create_node(name, context=sim.context)
        pub = node.create_publisher(JointState, 'voltage_command_joint', 10)

        def on_sample(msg):
            cmd = JointState(name=[det], position=[volts])
            if stamped:
                cmd.header.stamp = msg.header.stamp
                if msg.header.stamp.nanosec == 5_000_000 and not stale:
                    stale.append(1)
                    old = JointState(name=[det], position=[volts])
                    old.header.stamp.nanosec = 1_000_000    # answers sample 1: stale
                    pub.publish(old)
            pub.publish(cmd)
        node.create_subscription(JointState, 'displacement', on_sample, 10)
        return node
    run = sim.run(until=0.05, nodes=[controller('a', 'left', 1000.0, True),
                                     controller('b', 'right', 2000.0, False)])
    assert sim.node.pacing.stale_answers == 1 and sim.node.pacing.missed_deadlines == 0
    assert run.voltage[1:].tolist() == [[1000.0, 2000.0]] * 50
    assert sim.node.commands.received >= 2 * 50 + 1   # the answers to samples 0..49 + stale


def test_timeout_holds_the_voltages_and_counts_missed_deadlines(det_sim):  # noqa: F811
    """
    Check that a lockstep timeout holds the voltages and counts missed deadlines.

    No controller and lockstep.timeout: each period waits that long, then runs with the
    held voltages and counts a missed deadline.
    """
    sim = det_sim('default', params={'lockstep.timeout': 0.005})
    sim.start(wait=False)
    sim.spin_until(lambda: sim.node.simulator.k >= 20, '20 periods')
    simulator = sim.node.simulator
    assert sim.node.pacing.missed_deadlines == simulator.k and simulator.u.tolist() == [0.0]
    assert sim.result().t.size == simulator.k + 1   # every period ran and was recorded
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    import rclpy
    listener = rclpy.create_node('diag_listener', context=sim.context)
    seen = []
    listener.create_subscription(DiagnosticArray, '/diagnostics', seen.append, 10)
    sim.start([listener], wait=False)
    sim.spin_until(lambda: listener.count_publishers('/diagnostics') > 0, 'discovery')
    sim.node.publish_diagnostics()
    sim.spin_until(lambda: seen, '/diagnostics')
    status = seen[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.WARN and 'missed deadline' in status.message
    assert int(values['lockstep_missed_deadlines']) >= 20 and values['mode'] == 'lockstep'


def test_the_lockstep_deadline_lasts_the_timeout_by_the_clock(det_sim):  # noqa: F811
    """
    Check that each missed deadline takes lockstep.timeout of wall time, by a clock.

    A contract of the mode, not a speed target: with no controller, n periods take n timeouts
    (a controller that answers late is cut off after the timeout it set, not earlier or ten
    times later). The bounds are generous for a loaded host: no less than 0.9 n timeout (a
    timer does not fire early; 0.9 allows the clocks' granularity) and no more than
    3 n timeout + 1 s (each period's own step is ~0.1 ms; the slack is for a busy CPU), so a
    deadline twice too short or ten times too long fails and scheduling noise does not.
    """
    timeout, periods = 0.05, 20
    sim = det_sim('default', params={'lockstep.timeout': timeout})
    sim.start(wait=False)
    sim.spin_until(lambda: sim.node.simulator.k >= 2, 'the first deadlines')
    k0, t0 = sim.node.simulator.k, time.monotonic()
    sim.spin_until(lambda: sim.node.simulator.k >= k0 + periods, f'{periods} more periods')
    elapsed = time.monotonic() - t0
    done = sim.node.simulator.k - k0
    assert sim.node.pacing.missed_deadlines == sim.node.simulator.k
    assert 0.9 * done * timeout <= elapsed <= 3.0 * done * timeout + 1.0, (elapsed, done)


def test_lockstep_pause_step_reset_and_clock(harness, ros_context):
    """
    Check that pause, step, reset and /clock work in lockstep.

    ~/pause, ~/step and ~/reset keep working in lockstep; /clock follows the samples and a
    use_sim_time node follows it.
    """
    import rclpy
    from rclpy.parameter import Parameter
    h = harness(mode='lockstep', start_paused=True)
    follower = rclpy.create_node('follower', context=ros_context, parameter_overrides=[
        Parameter('use_sim_time', value=True)])
    h.executor.add_node(follower)
    for k in (1, 2, 3):   # paused: ~/step advances without an answer
        assert h.call('step').success
        h.spin_until(lambda k=k: h.latest('displacement') == k * 1_000_000, f'sample {k}')
    assert h.call('pause', data=False).success
    for _ in range(20):   # running, but nobody answers: the node waits at k = 3
        h.executor.spin_once(timeout_sec=0.005)
    assert h.node.simulator.k == 3
    h.command([1500.0])   # the test node answers once: one period
    h.spin_until(lambda: h.latest('displacement') == 4 * 1_000_000, 'sample 4')
    h.spin_until(lambda: max(h.clock, default=0) == 4 * 1_000_000, '/clock at t_4')
    h.spin_until(lambda: follower.get_clock().now().nanoseconds == 4 * 1_000_000,
                 'the follower clock')
    assert h.node.simulator.k == 4
    assert h.call('reset').success and h.node.simulator.k == 0
    h.command([800.0])
    h.spin_until(lambda: h.node.simulator.k == 1, 'the first period after the reset')
    h.executor.remove_node(follower)
    follower.destroy_node()


def test_bad_mode_is_refused(ros_context):
    from det_sim_ros.ros.node import SimNode
    from det_sim_ros.scenes.scene import SceneError
    from rclpy.parameter import Parameter
    with pytest.raises(SceneError, match='mode.*lockstep'):
        SimNode(context=ros_context, parameter_overrides=[Parameter('mode', value='fast')])


README_EXAMPLE = textwrap.dedent("""
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    def make_pi(sim):                                  # a PI node: Δy to 2 mm from 0.6 s
        node = rclpy.create_node('pi', context=sim.context)
        cmd = node.create_publisher(Float64MultiArray, 'voltage_command', 10)
        integral = [0.0]
        def on_dy(msg):                                # answers every sample
            t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            error = 2e-3 - msg.position[0] if t >= 0.6 else 0.0
            integral[0] += error * 1e-3
            volts = min(3000.0, max(0.0, 2e4 * error + 6e6 * integral[0]))
            cmd.publish(Float64MultiArray(data=[volts]))
        node.create_subscription(JointState, 'displacement', on_dy, 10)
        return node

    def test_pi_brings_dy_to_2_mm(det_sim):
        sim = det_sim('default')                       # sim_node in lockstep, own ROS domain
        run = sim.run(until=1.2, nodes=[make_pi(sim)])
        step = run.step_metrics('dy', target=2e-3, t_step=0.6)
        assert step.settling_time <= 0.5 and abs(step.steady_state_error) <= 0.05 * 2e-3

    def test_pi_settles_on_every_perturbed_plant(det_sim):   # what 8 perturbed copies share
        runs = det_sim.ensemble(lambda sim: [make_pi(sim)], until=1.2, copies=8)
        assert runs.shared(start=0.6, target=2e-3, t_step=0.6).settling[1] <= 0.5
""")


def test_readme_example_runs_as_a_plugin(tmp_path):
    """
    Check that the README's examples run as pytest plugin tests (one run, an ensemble).

    The README's example, in a file of its own, with the plugin loaded as pytest loads an
    installed one (the pytest11 entry point, or -p before the package is reinstalled). A
    DeprecationWarning is an error there, as in a user's strict run: the plugin's own imports
    (rclpy's type support parser, through lark-parser) must not raise one.
    """
    from importlib.metadata import entry_points
    readme = open(os.path.join(os.path.dirname(__file__), '..', 'README.md')).read()
    assert README_EXAMPLE.strip() in readme   # the tested code is the documented code
    (tmp_path / 'test_example.py').write_text(README_EXAMPLE)
    installed = any(e.value == 'det_sim_ros.ros.testing' for e in entry_points(group='pytest11'))
    env = child_env()
    proc = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                           '-W', 'error::DeprecationWarning']
                          + ([] if installed else ['-p', 'det_sim_ros.ros.testing'])
                          + [str(tmp_path / 'test_example.py')],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert '2 passed' in proc.stdout and 'warning' not in proc.stdout, proc.stdout
