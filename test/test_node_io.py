"""
Test sim_node's I/O: published bytes, commands in catch-up bursts, bounded lag, executors.

The published bytes are the simulator's values, commands that arrive during a catch-up burst
apply from the next period, the lag behind the wall clock is bounded (the node slips instead),
both executors work.

Real-time pacing is driven by a fake wall clock (``node.wall_clock``): no wall-clock thresholds;
one test runs a node on the real clock with periods far dearer than real time gives them.
"""

import re

from conftest import WALL_TIMEOUT
from det_sim_ros.io.contract import decode_joint_state, OUTPUT_FIELDS
from det_sim_ros.io.log import LogReader
from det_sim_ros.io.replay import resimulate
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

pytestmark = pytest.mark.ros
# s of wall time a wait for a log line that follows at once may take (the fake wall clock
# moved, a diagnostics window reported): a broken behaviour fails in seconds, not at the
# safety net WALL_TIMEOUT
PROMPT = 5.0
# ... on the real clock, a node slipping from its first periods: a few 0.5 s diagnostics
# windows, with room for a loaded 2-core machine
PROMPT_REAL_CLOCK = 20.0


class FakeWall:
    """A wall clock that moves only when the test says so."""

    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


def _wait_readable(node, topic='voltage_command'):
    """Block until a command sits in the node's subscription (delivered, not yet taken)."""
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    sub = node.command_subscriptions[topic]
    with sub.handle, node.context.handle:
        wait_set = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, node.context.handle)
        wait_set.clear_entities()
        wait_set.add_subscription(sub.handle)
        wait_set.wait(int(WALL_TIMEOUT * 1e9))
        assert wait_set.get_ready_entities('subscription'), 'the command never arrived'


def _real_time_node(harness, tmp_path, **params):
    h = harness(real_time=True, start_paused=True, **{'log.path': str(tmp_path / 'logs')},
                **params)
    wall = FakeWall()
    h.node.wall_clock = wall
    assert h.call('pause', data=False).success   # the pacing reference: now, k = 0
    for _ in range(5):
        h.executor.spin_once(timeout_sec=0.005)
    assert h.node.simulator.k == 0                     # the fake clock has not moved
    return h, wall


def test_published_bytes_are_the_simulator_values(harness):
    """
    Check that the published bytes are the offline simulator's values.

    What subscribers receive (raw CDR) decodes to the offline simulator's outputs bit for
    bit; the same bytes are what the log holds.
    """
    from sensor_msgs.msg import JointState
    h = harness(start_paused=True)
    raw = {topic: {} for topic in OUTPUT_FIELDS}
    subs = [h.test.create_subscription(JointState, topic,
                                       lambda data, topic=topic: raw[topic].__setitem__(
                                           decode_joint_state(data).stamp_ns, data), 100,
                                       raw=True)
            for topic in OUTPUT_FIELDS]
    h.spin_until(lambda: all(s.get_publisher_count() for s in subs), 'discovery')
    h.command([2200.0])
    for k in range(1, 31):
        assert h.call('step').success
    h.spin_until(lambda: all(30_000_000 in raw[t] for t in raw), 'the 30th sample')
    sim = Simulator(h.node.scene)
    sim.set_input([2200.0])
    y0 = np.array(h.node.y0)
    names = sim.output_names
    for k in range(1, 31):
        out = sim.step()
        t_ns = k * 1_000_000
        for topic, fields in OUTPUT_FIELDS.items():
            msg = decode_joint_state(raw[topic][t_ns])
            assert msg.name == ['det0']
            for field, output in fields.items():
                want = out[names.index(output)]
                if topic == 'displacement':
                    want = y0[0] - want
                assert np.array(getattr(msg, field)).tobytes() == np.array([want]).tobytes()


@pytest.mark.parametrize('executor', ['events', 'single'])
def test_command_during_catch_up_applies_from_the_next_period(harness, tmp_path, executor):
    """
    Check that a command arriving during a catch-up burst applies from the next period.

    40 periods fall due at once (a burst); a command that arrives after the burst's 5th
    sample is applied to the 6th period, not after the burst. The log says so, and it
    re-simulates bit for bit.
    """
    from std_msgs.msg import Float64MultiArray
    h, wall = _real_time_node(harness, tmp_path, executor=executor)
    node = h.node
    arrivals = []

    def on_sample(k, out):
        if k == 5:
            h.cmd.publish(Float64MultiArray(data=[2500.0]))
            _wait_readable(node)
        arrivals.append((k, node.simulator.u.tolist()))
    node.on_sample = on_sample
    wall.now += 40 * node.dt   # 40 periods due: one tick runs them all
    h.spin_until(lambda: node.simulator.k >= 40, '40 periods')
    assert node.simulator.k == 40 and node.pacing.late_ticks >= 1
    assert dict(arrivals)[5] == [0.0] and dict(arrivals)[6] == [2500.0]
    recorder = node.recorder
    h.close()
    commands = [m.log_time for m in LogReader(recorder.path).messages(['voltage_command'])]
    assert commands == [5_000_000]      # applied before the step from t_5 to t_6
    result = resimulate(recorder.path)
    assert result.ok(0.0) and result.commands == 1, result.table()


def test_lag_is_bounded_by_slipping(harness, tmp_path):
    """
    Check that the lag behind the wall clock is bounded by slipping.

    10 s of wall time at once: the node runs only max_lag worth of periods, drops the rest
    of the wall time (counted as slipped), then keeps pace; /diagnostics says so.
    """
    from diagnostic_msgs.msg import DiagnosticStatus
    h, wall = _real_time_node(harness, tmp_path, max_lag=0.02)
    node = h.node
    dt = node.dt
    wall.now += 10.0
    h.spin_until(lambda: node.simulator.k > 0, 'the late tick')
    for _ in range(5):
        h.executor.spin_once(timeout_sec=0.005)
    assert node.simulator.k == 21          # the period due now plus 20 ms of lag, no more
    assert node.pacing.slipped_s == pytest.approx(10.0 - 21 * dt, abs=1e-9)
    assert node.pacing.steps_due(wall()) == 0
    # after the slip the node keeps pace with the clock again: one period per period
    for n in range(1, 4):
        wall.now += dt
        h.spin_until(lambda n=n: node.simulator.k == 21 + n, 'the next period')
    assert node.pacing.slipped_s == pytest.approx(10.0 - 21 * dt, abs=1e-9)
    node.publish_diagnostics()
    h.spin_until(lambda: h.diagnostics, '/diagnostics')
    status = h.diagnostics[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.WARN and 'below real time' in status.message
    assert values['slipped_s'] == f'{10.0 - 21 * dt:.3f}' and values['lag_ms'] == '0.0'
    assert float(values['max_lag_ms']) == pytest.approx(20.0)
    # a quiet window afterwards: OK again
    h.diagnostics.clear()
    node.publish_diagnostics()
    h.spin_until(lambda: h.diagnostics, '/diagnostics')
    assert h.diagnostics[-1].status[0].level == DiagnosticStatus.OK
    # every period was run (no sim step dropped) and published in order
    recorder = node.recorder
    h.close()
    stamps = [decode_joint_state(m.data).stamp_ns
              for m in LogReader(recorder.path).messages(['displacement'])]
    assert stamps == [k * 1_000_000 for k in range(25)]


def test_small_lag_catches_up_without_slipping(harness, tmp_path):
    """Check that a late tick within max_lag runs every due period and slips nothing."""
    h, wall = _real_time_node(harness, tmp_path)   # default max_lag 50 ms
    node = h.node
    wall.now += 30 * node.dt
    h.spin_until(lambda: node.simulator.k == 30, '30 periods')
    assert node.pacing.slipped_s == 0.0 and node.pacing.late_ticks == 1


@pytest.mark.parametrize('executor', ['events', 'single'])
def test_services_and_parameters_with_either_executor(harness, executor):
    """Check that ~/pause, ~/step, ~/reset and parameter changes work in both executors."""
    from rclpy.parameter import Parameter
    h = harness(start_paused=True, executor=executor)
    h.command([1000.0])
    for k in (1, 2):
        assert h.call('step').success
        h.spin_until(lambda k=k: h.latest('deflection') == k * 1_000_000, f'sample {k}')
    assert h.node.set_parameters([Parameter('max_lag', value=0.2)])[0].successful
    assert not h.node.set_parameters([Parameter('max_lag', value=-1.0)])[0].successful
    assert h.node.get_parameter('max_lag').value == 0.2
    assert h.call('reset').success and h.node.simulator.k == 0
    assert h.call('pause', data=False).success
    h.spin_until_sim_time(0.05)
    assert not h.non_finite


@pytest.mark.parametrize('outcome', ['granted', 'refused'])
def test_realtime_priority_is_applied_to_every_thread_or_degrades(harness, monkeypatch, tmp_path,
                                                                  outcome):
    """
    Check that realtime_priority applies SCHED_FIFO to every thread, or degrades to a warning.

    Every thread of the process goes to SCHED_FIFO (real-time mode): the stepping thread (this
    one: the harness spins in it), rclpy's, DDS's and the log writer's. Without permission
    every thread is put back to normal scheduling, the node says why on /diagnostics and runs.
    (os.sched_setscheduler is recorded, not called: the test process stays as it is.)
    """
    import os
    import threading
    calls = []

    def fake(tid, policy, param):
        calls.append((tid, policy, param.sched_priority))
        if outcome == 'refused' and policy == os.SCHED_FIFO:
            raise PermissionError(1, 'Operation not permitted')
    monkeypatch.setattr(os, 'sched_setscheduler', fake)
    h = harness(real_time=True, realtime_priority=20, **{'log.path': str(tmp_path)})
    h.spin_until(lambda: h.node.simulator.k > 3, 'periods')   # running either way
    fifo = {tid for tid, policy, prio in calls if policy == os.SCHED_FIFO and prio == 20}
    assert h.node.realtime_scheduling == (outcome == 'granted')
    values = {kv.key: kv.value for kv in h.node.publish_diagnostics().status[0].values}
    threads = {int(t) for t in os.listdir('/proc/self/task')}
    if outcome == 'granted':
        # the main thread and the threads rclpy, DDS and the log started (one call per thread)
        assert threading.get_native_id() in fifo and len(fifo) == len(calls) > 2
        assert values['realtime_priority'] == 'SCHED_FIFO 20'
    else:
        back = {tid for tid, policy, _ in calls if policy == os.SCHED_OTHER}
        assert back >= fifo and back & threads   # all or nothing
        assert values['realtime_priority'] == 'refused (Operation not permitted)'


def test_realtime_priority_is_ignored_outside_real_time(harness, monkeypatch):
    import os
    calls = []
    monkeypatch.setattr(os, 'sched_setscheduler', lambda *a: calls.append(a))
    h = harness(real_time=False, realtime_priority=20)
    assert not h.node.realtime_scheduling and not calls


def test_falling_behind_real_time_warns_once_and_says_when_caught_up(harness, tmp_path):
    """
    Check that falling behind real time is logged: one WARN with how far and why, then caught up.

    Driven by the fake wall clock and node.publish_diagnostics() (one diagnostics window per
    call): 10 s of wall time at once slips the node; the window's report logs one WARN naming
    the slip and the cost of a period (CPU, internal steps, wall time per period); a quiet
    window logs the catch-up (INFO). A second slip within the rate limit is not warned again;
    one after it is, and names the episode it did not warn of.
    """
    from det_sim_ros.ros.pacing import BEHIND_WARN_INTERVAL_S
    from test_lockstep_waiting import listen_to_rosout
    # (no diagnostics timer in the test's time: each window is one publish_diagnostics call)
    h, wall = _real_time_node(harness, tmp_path, max_lag=0.02, diagnostics_period=3600.0)
    lines = listen_to_rosout(h)
    node = h.node

    def slip(seconds):
        k = node.simulator.k
        wall.now += seconds
        h.spin_until(lambda: node.simulator.k > k, 'the late tick')
        node.publish_diagnostics()

    def quiet_window():
        node.publish_diagnostics()

    def logged(start):
        for _ in range(20):   # /rosout is asynchronous: give it a few spins
            h.executor.spin_once(timeout_sec=0.01)
        return [line for line in lines if line.startswith(start)]

    slip(10.0)
    h.spin_until(lambda: logged('behind real time'), 'the WARN', timeout=PROMPT)
    (warned,) = logged('behind real time')
    assert 'below real time' in warned and 'slipped' in warned
    assert 'ms of CPU' in warned and 'internal steps' in warned
    assert '1.000 ms of wall time' in warned   # dt 1 ms at real_time_factor 1
    assert not logged('caught up')
    quiet_window()
    h.spin_until(lambda: logged('caught up with real time'), 'the caught-up line',
                 timeout=PROMPT)
    slip(1.0)                                  # within the rate limit: not warned again
    quiet_window()
    assert len(logged('behind real time')) == 1 and len(logged('caught up')) == 1
    slip(BEHIND_WARN_INTERVAL_S)               # after it: warned, naming the silent episode
    h.spin_until(lambda: len(logged('behind real time')) == 2, 'the second WARN',
                 timeout=PROMPT)
    assert '(1 more time(s) since the last warning)' in logged('behind real time')[1]


def test_a_node_whose_periods_cost_more_than_real_time_gives_says_so(harness):
    """
    Check a real-time node that cannot keep up, on the real clock: a WARN and /diagnostics.

    integrator.substeps 100000 makes every 1 ms period cost far more than 1 ms of CPU (about
    20 ms here: 0.2 us per internal step of the one-term model), so the node slips behind the
    wall clock from its first periods. Within a few diagnostics windows (0.5 s each) it must log
    one 'behind real time' WARN naming the slip and the period's cost (which the WARN measures
    itself: more than the 1 ms it is given), and /diagnostics must say WARN.
    """
    from diagnostic_msgs.msg import DiagnosticStatus
    from test_lockstep_waiting import listen_to_rosout
    h = harness(real_time=True, diagnostics_period=0.5, **{'integrator.substeps': 100000})
    lines = listen_to_rosout(h)
    h.spin_until(lambda: any(line.startswith('behind real time') for line in lines),
                 "the 'behind real time' WARN", timeout=PROMPT_REAL_CLOCK)
    (warned,) = [line for line in lines if line.startswith('behind real time')]
    assert 'below real time' in warned or 'lagging' in warned, warned
    cpu_ms, budget_ms = (float(x) for x in re.search(
        r'a period cost ([0-9.]+) ms of CPU \(100000\.0 internal steps\) for ([0-9.]+) ms of '
        r'wall time', warned).groups())
    assert budget_ms == 1.0 and cpu_ms > budget_ms, warned      # dt 1 ms, real_time_factor 1
    assert 'take about all the CPU' in warned
    h.spin_until(lambda: any(m.status[0].level == DiagnosticStatus.WARN for m in h.diagnostics),
                 '/diagnostics at WARN', timeout=PROMPT_REAL_CLOCK)
    (status, *_) = [m.status[0] for m in h.diagnostics
                    if m.status[0].level == DiagnosticStatus.WARN]
    assert 'below real time' in status.message or 'lagging' in status.message, status.message
