"""
What a controller's command rate costs the physics: CPU and internal steps per control period.

The node holds each command for a whole control period, so a controller that sends a new voltage
every period makes every period start with an input jump; on RC scenes the exponential steppers
then resolve the charge transient with graded fine steps (_csrc/stepping/period.c), even when
the jump is 1 V.

For the default scene and the 100-copy array as shipped (their level and their integrator: 'auto'
at the level's own tolerance), after the start has settled: the voltage held (the benchmarks' usual
case), a new voltage every 10 periods, and a new voltage every period (a 1 V/ms ramp, and a 5 Hz
sine of 500 V); CPU us per period and internal steps per period and DET (Simulator.step(), as the
node runs it). The error column (default scene only) is the largest |q - reference| over the run
(q: the deflection), relative to the largest |q|, against the same drive at tolerance 1e-10; the
row with the transient resolution switched off shows its share of the cost and of the accuracy.

Run: python bench/command_rate.py [--periods 1000]; ``--quick``: 20 periods after 20, the
default scene only (a smoke run).
"""

import argparse
import math
import time

from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.integrators import TransientSettings
import det_sim_ros.sim.simulator as simulator_module
from det_sim_ros.sim.simulator import Simulator
import numpy as np

DRIVES = {
    'held': lambda k: 1500.0,
    'new every 10 periods': lambda k: 1500.0 + (k // 10) * 10.0 % 500.0,
    'new every period (1 V/ms ramp)': lambda k: 1500.0 + k % 500,
    'new every period (5 Hz sine)': lambda k: 1500.0 + 500.0 * math.sin(2 * math.pi * 5e-3 * k),
}


def run(scene_name, overrides, drive, periods, transient=True, settle=300):
    """Return (CPU us per period, steps per period and DET, deflection q of the first DET)."""
    original = simulator_module.transient_settings
    if not transient:
        simulator_module.transient_settings = lambda method, scene: TransientSettings()
    try:
        sim = Simulator(load_scene(scene_name, overrides))
    finally:
        simulator_module.transient_settings = original
    n = sim.model.n_inputs
    column = [name.split('[')[0] for name in sim.output_names].index('q')   # the first DET's
    sim.set_input([1500.0] * n)
    for _ in range(settle):        # past the start's transient
        sim.step()
    steps0, out = sim.steps_taken, np.empty(periods)
    start = time.process_time()
    for k in range(periods):
        sim.set_input([drive(k)] * n)
        out[k] = sim.step()[column]
    cpu = time.process_time() - start
    return cpu / periods * 1e6, (sim.steps_taken - steps0) / periods / n, out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--periods', type=int, default=1000)
    parser.add_argument('--quick', action='store_true', help='20 periods, the default scene')
    args = parser.parse_args(argv)
    scenes, settle = (('default', {}), ('array', {})), 300
    if args.quick:
        scenes, settle, args.periods = scenes[:1], 20, 20
    print('| scene | drive | transient resolution | CPU us / period | steps / period / DET '
          '| error (rel.) |')
    print('|---|---|---|---|---|---|')
    for scene_name, overrides in scenes:
        for label, drive in DRIVES.items():
            reference = None
            if scene_name == 'default':
                reference = run(scene_name, {'integrator.tolerance': 1e-10}, drive,
                                args.periods, settle=settle)[2]
            for transient in ((True, False) if label != 'held' else (True,)):
                cost, steps, out = run(scene_name, overrides, drive, args.periods, transient,
                                       settle)
                error = ('' if reference is None else
                         f'{np.max(np.abs(out - reference)) / np.max(np.abs(reference)):.1e}')
                print(f'| {scene_name} | {label} | {"on" if transient else "off"} | '
                      f'{cost:.1f} | {steps:.2f} | {error} |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
