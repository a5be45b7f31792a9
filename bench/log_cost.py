"""
Cost of MCAP logging per simulation step, measured offline (no ROS graph).

The node's per-step work: encode the output bytes (det_sim_ros.io.contract), record them (and a
command every 10 steps), synchronously or with the writer thread. Prints CPU microseconds per
step (all threads); run on a shared host, compare the rows of one run.

Run: PYTHONPATH=. python bench/log_cost.py [n_steps]; ``--quick``: 500 steps (a smoke run).
"""

import os
import sys
import tempfile
import time

from det_sim_ros.io.contract import encode_float64_multi_array, OutputContract, TOPIC_TYPES
from det_sim_ros.io.log import Recorder
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator


def main(n_steps=20000):
    scene = load_scene('default', {'scene.initial_state': 'released'})
    sim = Simulator(scene)
    encoder = OutputContract(sim.model).encoder()
    topics = encoder.topics
    with tempfile.TemporaryDirectory() as folder:
        results = {}
        for label in ('no log', 'log', 'log thread', 'no log ', 'log ', 'log thread '):
            recorder = None
            if label.startswith('log'):
                recorder = Recorder(os.path.join(folder, f'{len(results)}.mcap'), scene,
                                    background='thread' in label)
            sim.reset()
            start = time.process_time()
            for k in range(n_steps):
                t_ns = round(k * sim.dt * 1e9)
                if k % 10 == 0:
                    volts = [1000.0 + k % 500]
                    if recorder is not None:
                        recorder.record('voltage_command', encode_float64_multi_array(volts),
                                        t_ns, TOPIC_TYPES['voltage_command'])
                    sim.set_input(volts)
                out = sim.step()
                data = encoder.encode(out, t_ns)
                if recorder is not None:
                    recorder.record_sample(t_ns, topics, data, TOPIC_TYPES)
            if recorder is not None:
                recorder.close()
            elapsed = time.process_time() - start
            extra = ''
            if recorder is not None:
                size = os.path.getsize(recorder.path)
                extra = f'  {recorder.messages} msgs, {size / n_steps:.0f} B/step'
            results[label] = elapsed / n_steps * 1e6
            print(f'{label.strip():10s}: {results[label]:7.1f} us/step{extra}')
        base = min(results['no log'], results['no log '])
        for kind in ('log', 'log thread'):
            cost = min(results[kind], results[kind + ' ']) - base
            print(f'{kind} cost: {cost:.1f} us/step ({cost / (sim.dt * 1e6) * 100:.1f} % of the '
                  f'{sim.dt * 1e6:.0f} us control period)')


if __name__ == '__main__':
    main(500 if sys.argv[1:] == ['--quick'] else int(sys.argv[1]) if len(sys.argv) > 1
         else 20000)
