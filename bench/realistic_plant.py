#!/usr/bin/env python3
"""
The same PI controller against the ideal plant and a realistic one, offline; a plot of both.

The ideal plant is the default scene: every sample is the exact state, on time. The realistic
plant is config/bench_rig.yaml, the default scene read by the laser sensor preset and driven
through the lab amplifier preset: the controller sees what sim_node would publish (noise,
quantization, delay, dropped samples) and commands through a DAC, a period's delay, the
amplifier's bandwidth, slew rate and current limit; the plot shows both the true Δy and what
the controller measured. One closed loop per plant,
sample k -> command -> period k + 1, as in sim_node's lockstep mode: a controller that answers
each sample it receives (a dropped one is not answered and the voltage holds), the same run
bit for bit as through sim_node (test/test_sensors_node.py).

Usage: python bench/realistic_plant.py [--png docs/figures/realistic_plant.png]; ``--quick``:
0.2 s, the figure into a temporary folder (a smoke run).
"""

import argparse
import os
import tempfile

from det_sim_ros.io.sensing import MeasuredOutputs
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np

REALISTIC = 'bench_rig'
KP, KI = 2.0e4, 6.0e6            # V/m, V/(m s): stable against the ideal plant
TARGET, T_STEP, T_END = 2.0e-3, 0.1, 1.0   # m, s, s


def closed_loop(scene, end=T_END):
    """Run the PI loop; return t, the true Δy, the measured Δy (NaN: dropped), the voltage."""
    sim = Simulator(scene)
    outputs = MeasuredOutputs(sim)
    n = int(round(end / sim.dt))
    t = np.arange(n + 1) * sim.dt
    true_dy, seen_dy, volts = np.empty(n + 1), np.full(n + 1, np.nan), np.zeros(n + 1)
    out = np.array(list(sim.outputs().values()))
    integral, v = 0.0, 0.0
    for k in range(n + 1):
        true_dy[k] = outputs.contract.values(out, 'displacement', 'position')[0]
        reading = outputs.read(k, out)['displacement']
        if reading is not None:   # (a dropped sample reaches no controller: the voltage holds)
            seen_dy[k] = reading[0]
            if k * sim.dt >= T_STEP - 1e-12:
                error = TARGET - reading[0]
                integral += error * sim.dt
                v = min(3000.0, max(0.0, KP * error + KI * integral))
        volts[k] = v
        if k < n:
            sim.set_input([v])
            out = sim.step()
    return t, true_dy, seen_dy, volts


def plot(runs, path):
    """Save the responses of both plants (Δy and voltage) to ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for label, (t, true_dy, seen_dy, volts), colour in zip(
            ('ideal plant', 'realistic plant'), runs, ('tab:blue', 'tab:red')):
        if label == 'realistic plant':
            top.plot(t, seen_dy * 1e3, '.', ms=2, color='0.6', label='realistic: measured')
        top.plot(t, true_dy * 1e3, color=colour, label=f'{label}: true Δy')
        bottom.plot(t, volts, color=colour, label=label)
    top.axhline(TARGET * 1e3, color='k', lw=0.5, ls='--')
    top.set_ylabel('Δy (mm)')
    top.legend(loc='lower right', fontsize=8)
    bottom.set_ylabel('command (V)')
    bottom.set_xlabel('t (s)')
    bottom.legend(loc='lower right', fontsize=8)
    top.set_title(f'PI (Kp = {KP:g} V/m, Ki = {KI:g} V/(m s)) to Δy = {TARGET * 1e3:g} mm; '
                  f'realistic: {REALISTIC}', fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--png', default='docs/figures/realistic_plant.png')
    parser.add_argument('--quick', action='store_true', help='0.2 s, the figure to a temp dir')
    args = parser.parse_args()
    end = T_END
    if args.quick:
        end = 0.2
        args.png = os.path.join(tempfile.mkdtemp(prefix='realistic_plant_'), 'quick.png')
    runs = [closed_loop(load_scene('default'), end), closed_loop(load_scene(REALISTIC), end)]
    for name, (t, true_dy, seen_dy, volts) in zip(('ideal', 'realistic'), runs):
        late = t >= end - 0.1
        print(f'{name:9s}: true Δy over the last 0.1 s {true_dy[late].mean() * 1e3:.4f} mm '
              f'(std {true_dy[late].std() * 1e6:.2f} um), command std {volts[late].std():.1f} V,'
              f' max Δy {true_dy.max() * 1e3:.3f} mm, {int(np.isnan(seen_dy).sum())} samples'
              ' dropped')
    plot(runs, args.png)
    print(f'wrote {args.png}')


if __name__ == '__main__':
    main()
