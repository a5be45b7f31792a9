"""
Cost of MCAP logging per simulation step (issue 5): the node's per-step work with and without
the recorder, measured offline (no ROS graph): build the 4 output JointStates, record them (and a
command every 10 steps). Prints microseconds per step.

Run: PYTHONPATH=. python bench/log_cost.py [n_steps]
"""

import os
import sys
import tempfile
import time

from det_sim_ros.mcap_log import Recorder, serialize
from det_sim_ros.replay import output_messages, rest_shortening
from det_sim_ros.scene import load_scene
from det_sim_ros.simulator import Simulator


def main(n_steps=20000):
    scene = load_scene('default', {'scene.initial_state': 'released'})
    sim = Simulator(scene)
    y0 = rest_shortening(scene)
    names = sim.output_names
    from std_msgs.msg import Float64MultiArray
    command = Float64MultiArray(data=[1000.0])
    msgs = output_messages(dict(zip(names, sim.step())), 0, y0)
    for msg in msgs.values():  # warm up
        serialize(msg)
    with tempfile.TemporaryDirectory() as folder:
        results = {}
        for label in ('no log', 'log', 'no log ', 'log '):
            recorder = Recorder(os.path.join(folder, f'{len(results)}.mcap'), scene) \
                if label.startswith('log') else None
            sim.reset()
            start = time.perf_counter()
            for k in range(n_steps):
                t_ns = round(k * sim.dt * 1e9)
                if k % 10 == 0:
                    if recorder is not None:
                        recorder.record('voltage_command', command, t_ns)
                    sim.set_input([1000.0 + k % 500])
                out = sim.step()
                messages = output_messages(dict(zip(names, out)), t_ns, y0)
                if recorder is not None:
                    for topic, msg in messages.items():
                        recorder.record(topic, msg, t_ns)
            elapsed = time.perf_counter() - start
            if recorder is not None:
                recorder.close()
                size = os.path.getsize(recorder.path)
                extra = (f'  in record(): {recorder.record_time_s / n_steps * 1e6:.1f} us/step, '
                         f'{recorder.messages} msgs, {size / n_steps:.0f} B/step, '
                         f'{recorder.flushes} flushes')
            else:
                extra = ''
            results[label] = elapsed / n_steps * 1e6
            print(f'{label.strip():7s}: {results[label]:7.1f} us/step{extra}')
        cost = min(results['log'], results['log ']) - min(results['no log'], results['no log '])
        print(f'logging cost: {cost:.1f} us/step ({cost / (sim.dt * 1e6) * 100:.1f} % of the '
              f'{sim.dt * 1e6:.0f} us control period)')


if __name__ == '__main__':
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20000)
