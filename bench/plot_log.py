"""
Time ``det_sim plot`` on a long log (target: a 10-minute 1 kHz log in <= 10 s).

Writes a log as sim_node would (a square wave 0 / 3 kV every 0.5 s, commands at 100 Hz, every
output topic at 1 kHz, encoded by the node's own sample encoder) from the simulator's offline
run, then times read + summary + PNG.

    python bench/plot_log.py [--minutes 10] [--scene default] [--out bench/out]

``--quick``: a 0.6 s log in a temporary folder (a smoke run).
"""

import argparse
import os
import tempfile
import time

from det_sim_ros.io import logplot
from det_sim_ros.io.contract import encode_float64_multi_array, OutputContract, TOPIC_TYPES
from det_sim_ros.io.log import Recorder
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np


def write_log(path, scene_name, minutes):
    """Write the log of the square wave as sim_node would; return its number of samples."""
    scene = load_scene(scene_name)
    t_end = 60.0 * minutes
    n = int(round(t_end * scene.rate_hz))
    period = int(round(0.01 * scene.rate_hz))          # commands every 10 ms
    k = np.arange(n)
    volts = np.where((k * scene.dt) % 1.0 < 0.5, 0.0, 3000.0)[:, None] * np.ones(scene.n_dets)
    sim = Simulator(scene)
    run = simulate(sim, volts, t_end)
    encoder = OutputContract(sim.model).encoder()   # sim_node's encoder: the same bytes
    out = np.column_stack([run[name] for name in sim.output_names])
    with Recorder(path, scene, flush_period_s=1.0) as rec:
        for i in range(n + 1):
            t_ns = int(round(i * scene.dt * 1e9))
            if i < n and i % period == 0:
                rec.record('voltage_command', encode_float64_multi_array(volts[i].tolist()),
                           t_ns, TOPIC_TYPES['voltage_command'])
            rec.record_sample(t_ns, encoder.topics, encoder.encode(out[i], t_ns), TOPIC_TYPES)
    return n


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('--minutes', type=float, default=10.0)
    parser.add_argument('--scene', default='default')
    parser.add_argument('--out', default='bench/out')
    parser.add_argument('--quick', action='store_true', help='a 0.6 s log, in a temp dir')
    args = parser.parse_args()
    if args.quick:
        args.minutes, args.out = 0.01, tempfile.mkdtemp(prefix='plot_log_')
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
