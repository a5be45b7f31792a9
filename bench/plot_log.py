"""
Time ``det_sim plot`` on a long log (target: a 10-minute 1 kHz log in <= 10 s).

Writes a log as sim_node would (a square wave 0 / 3 kV every 0.5 s, commands at 100 Hz, all
four output topics at 1 kHz) with the simulator's offline run and pre-serialized messages,
then times read + summary + PNG.

    python bench/plot_log.py [--minutes 10] [--scene default] [--out bench/out]
"""

import argparse
import os
import struct
import time

from det_sim_ros.io import logplot
from det_sim_ros.io.log import Recorder, serialize
from det_sim_ros.io.replay import OutputContract
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate
import numpy as np


def write_log(path, scene_name, minutes):
    from std_msgs.msg import Float64MultiArray
    scene = load_scene(scene_name)
    t_end = 60.0 * minutes
    n = int(round(t_end * scene.rate_hz))
    n_det = scene.n_dets
    period = int(round(0.01 * scene.rate_hz))          # commands every 10 ms
    k = np.arange(n)
    volts = np.where((k * scene.dt) % 1.0 < 0.5, 0.0, 3000.0)[:, None] * np.ones(n_det)
    run = simulate(scene, volts, t_end)
    contract = OutputContract(run_model(scene))
    names = run_model(scene).output_names
    out = np.column_stack([run[name] for name in names])
    templates = contract.messages(out[0], 0)
    raw = {topic: bytearray(serialize(msg)) for topic, msg in templates.items()}
    # every value of these messages sits at a fixed offset: patch them per sample
    layout = {topic: logplot._joint_state_layout(bytes(data)) for topic, data in raw.items()}
    with Recorder(path, scene, flush_period_s=1.0) as rec:
        for i in range(n + 1):
            t_ns = int(round(i * scene.dt * 1e9))
            if i < n and i % period == 0:
                rec.record('voltage_command', Float64MultiArray(data=volts[i].tolist()), t_ns)
            sec, nsec = divmod(t_ns, 1_000_000_000)
            for topic, data in raw.items():
                lay = layout[topic]
                struct.pack_into('<iI', data, lay['stamp'], sec, nsec)
                for field, (at, count) in lay['arrays'].items():
                    if count:
                        values = contract.values(out[i], topic, field) if topic != \
                            contract.structure_topic else contract.structure(out[i])
                        data[at:at + 8 * count] = np.asarray(values, '<f8').tobytes()
                rec.record(topic, bytes(data), t_ns, type_name='sensor_msgs/msg/JointState')
    return n


_MODELS = {}


def run_model(scene):
    from det_sim_ros.physics.model import build_model
    key = id(scene)
    if key not in _MODELS:
        _MODELS[key] = build_model(scene)
    return _MODELS[key]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('--minutes', type=float, default=10.0)
    parser.add_argument('--scene', default='default')
    parser.add_argument('--out', default='bench/out')
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, f'plot_bench_{args.scene}_{args.minutes:g}min.mcap')
    if not os.path.exists(path):
        start = time.perf_counter()
        n = write_log(path, args.scene, args.minutes)
        print(f'wrote {path}: {n} samples, {os.path.getsize(path) / 2**20:.1f} MiB in '
              f'{time.perf_counter() - start:.1f} s')
    start = time.perf_counter()
    cpu = time.process_time()
    data = logplot.read_log(path)
    t_read = time.perf_counter() - start
    text = logplot.summary(data)
    png = logplot.plot_log(data, os.path.join(args.out, 'plot_bench.png'))
    print(text)
    print(f'det_sim plot: read {t_read:.2f} s, total {time.perf_counter() - start:.2f} s wall, '
          f'{time.process_time() - cpu:.2f} s CPU -> {png}')


if __name__ == '__main__':
    main()
