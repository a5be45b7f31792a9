"""sim_node with sensors: measured and truth topics, the log, lockstep repeatability, resim."""

import os
import subprocess
import sys

from det_sim_ros.io.log.reader import LogReader
from det_sim_ros.io.messages import decode_joint_state
from det_sim_ros.io.replay import resimulate
from det_sim_ros.ros.testing import det_sim  # noqa: F401
import pytest
from test_lockstep import make_pi

pytestmark = pytest.mark.ros

NOISY = {'sensors.seed': 3, 'sensors.displacement.noise_std': 5e-6,
         'sensors.displacement.correlation_time': 2e-3, 'sensors.displacement.dropout': 0.1,
         'sensors.displacement.delay_samples': 1, 'sensors.displacement.quantization': 1e-6,
         'sensors.charge.bias': 1e-9, 'sensors.charge.dropout': 0.3}


def _records(path):
    return [(m.topic, m.log_time, m.sequence, bytes(m.data)) for m in LogReader(path).messages()]


def _listener(context, topics):
    import rclpy
    from sensor_msgs.msg import JointState
    node = rclpy.create_node('listener', context=context)
    node.heard = {topic: {} for topic in topics}
    for topic in topics:
        node.create_subscription(JointState, topic, lambda data, topic=topic: node.heard[
            topic].__setitem__(decode_joint_state(data).stamp_ns, data), 100, raw=True)
    return node


def test_measured_and_truth_arrive_and_are_logged(det_sim, tmp_path):  # noqa: F811
    sim = det_sim('default', overrides=NOISY, params={'log.path': str(tmp_path / 'a.mcap')})
    topics = ('displacement', '/sim_node/truth/displacement', 'charge',
              '/sim_node/truth/charge', 'current')
    listener = _listener(sim.context, topics)
    sim.run(until=0.3, nodes=[make_pi(sim.context, joint=True, target=1e-3), listener])
    assert set(sim.node.truth_publishers) == {'displacement', 'charge'}
    path = sim.node.recorder.path
    sim.close()
    logged = {}
    for topic, t, _, data in _records(path):
        logged.setdefault(topic, {})[t] = data
    assert len(logged['/sim_node/truth/displacement']) == len(logged['/current']) == 301
    assert 240 < len(logged['/displacement']) < 301 and len(logged['/charge']) < 260
    for topic in topics:   # what arrived is what was logged; the truth from its first match
        name = topic if topic.startswith('/') else '/' + topic
        heard = listener.heard[topic]
        assert heard and all(logged[name][t] == data for t, data in heard.items())
        assert len(heard) >= len(logged[name]) - 20
    truth = decode_joint_state(logged['/sim_node/truth/displacement'][200_000_000]).position
    measured = decode_joint_state(logged['/displacement'].get(201_000_000) or
                                  logged['/displacement'][202_000_000]).position
    assert truth != measured and abs(truth[0] - measured[0]) < 5e-5
    result = resimulate(path)
    assert result.ok(0.0), result.table()
    assert result.compared['truth/charge.position (q_p)'] == 301


def test_noisy_lockstep_runs_give_identical_logs_idle_and_with_a_busy_core(
        det_sim, tmp_path):  # noqa: F811
    paths = []
    for n_busy in (0, 1):
        busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
                for _ in range(n_busy)]
        try:
            sim = det_sim('default', overrides=NOISY,
                          params={'log.path': str(tmp_path / f'run{n_busy}.mcap')})
            sim.run(until=0.4, nodes=[make_pi(sim.context, joint=True, target=1e-3)])
            paths.append(sim.node.recorder.path)
            sim.close()
        finally:
            for proc in busy:
                proc.kill()
                proc.wait()
    first, second = (_records(p) for p in paths)
    assert len(first) > 400 * 6 and first == second
    assert os.path.getsize(paths[0]) > 0 and resimulate(paths[1]).ok(0.0)


def test_lockstep_loop_through_the_sensors_equals_the_offline_loop(det_sim):  # noqa: F811
    import numpy as np
    from det_sim_ros.io.sensing import MeasuredOutputs
    from det_sim_ros.scenes.scene import load_scene
    from det_sim_ros.sim.simulator import Simulator
    from test_lockstep import pi_volts
    overrides = {'sensors.displacement.dropout': 0.05}
    sim = det_sim('sensor_laser', overrides=overrides)
    run = sim.run(until=0.8, nodes=[make_pi(sim.context, joint=True)])
    # offline: a sample the sensor dropped reaches no controller: the voltage is held
    offline = Simulator(load_scene('sensor_laser', overrides))
    outputs = MeasuredOutputs(offline)
    out, state, volts, dropped = np.array(list(offline.outputs().values())), {'i': 0.0}, [0.0], 0
    for k in range(800):
        reading = outputs.read(k, out)['displacement']
        if reading is None:
            dropped += 1
        else:
            volts_k = pi_volts(state, reading[0], k * offline.dt, offline.dt)
            offline.set_input([volts_k])
        volts.append(float(offline.u[0]))
        out = offline.step().copy()
    assert 20 < dropped < 70
    assert run.signal('voltage').tobytes() == np.array(volts).tobytes()
    assert sim.node.pacing.missed_deadlines == 0
