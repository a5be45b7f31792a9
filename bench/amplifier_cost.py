"""
The amplifier's cost: CPU time per control period through simulate(), each knob against off.

The default scene as shipped (1 kHz, its level and its integrator: 'auto' at the level's own
tolerance; a preset row is that preset as shipped) runs 1 s under two drives: 'steps'
(0 V, 3 kV at 0.1 s, 1.5 kV at 0.55 s) and 'new voltage every period' (1.5 kV + 1 kV sin(2 pi
5 Hz t), a controller's command). Every configuration is timed in every round, in turn, and the
table gives the least process CPU time per period over the rounds, its ratio to the amplifier
off, and the internal steps per period. A shared host only adds time; compare the ratios.
Run: python bench/amplifier_cost.py [--rounds 7] (~1 min); ``--quick``: 0.1 s, one round,
the amplifier off and every knob on (a smoke run).
"""

import argparse
import subprocess
import time

from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np

CONFIGS = {
    'off': {},
    'dac_bits 12': {'amplifier.dac_bits': 12},
    'delay 1 ms': {'amplifier.delay': 1.0e-3},
    'offset 2 V': {'amplifier.offset': 2.0},
    'bandwidth 2 kHz': {'amplifier.bandwidth': 2.0e3},
    'slew_rate 1 V/us': {'amplifier.slew_rate': 1.0e6},
    'current_limit 2 mA': {'amplifier.current_limit': 2.0e-3},
    'every knob': {'amplifier.dac_bits': 12, 'amplifier.delay': 1.0e-3, 'amplifier.offset': 2.0,
                   'amplifier.bandwidth': 2.0e3, 'amplifier.slew_rate': 1.0e6,
                   'amplifier.current_limit': 2.0e-3},
    'preset amplifier_lab': 'amplifier_lab',
    'preset amplifier_dcdc': 'amplifier_dcdc',
}
N = 1000   # periods (1 s)


def drives() -> dict:
    """Return the two command profiles (V per period)."""
    t = np.arange(N) * 1e-3
    return {'steps': np.where(t < 0.1, 0.0, np.where(t < 0.55, 3000.0, 1500.0)),
            'new voltage every period': 1500.0 + 1000.0 * np.sin(2.0 * np.pi * 5.0 * t)}


def scene_of(config):
    """Return the scene of a configuration (overrides of the default, or a preset's name)."""
    return load_scene(config) if isinstance(config, str) else load_scene('default', config)


def time_one(scene, profile) -> tuple:
    """Return (CPU seconds per period, steps per period) of one run."""
    sim = Simulator(scene)
    start = time.process_time()
    simulate(sim, profile, len(profile) * 1e-3)
    return (time.process_time() - start) / len(profile), sim.steps_taken / len(profile)


def main(argv=None) -> None:
    """Time every configuration under both drives and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--rounds', type=int, default=7)
    parser.add_argument('--quick', action='store_true', help='0.1 s, one round, two rows')
    args = parser.parse_args(argv)
    configs, periods = CONFIGS, N
    if args.quick:
        configs, periods, args.rounds = {k: CONFIGS[k] for k in ('off', 'every knob')}, 100, 1
    scenes = {name: scene_of(config) for name, config in configs.items()}
    best = {}
    steps = {}
    for drive, profile in drives().items():
        profile = profile[:periods]
        for name, scene in scenes.items():   # warm: statics solved and cached
            steps[(drive, name)] = time_one(scene, profile)[1]
        for _ in range(args.rounds):
            for name, scene in scenes.items():
                cost = time_one(scene, profile)[0]
                best[(drive, name)] = min(best.get((drive, name), cost), cost)
    head = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True,
                          text=True).stdout.strip()
    print(f'{time.strftime("%Y-%m-%d")}, commit {head}, 2-core shared host; '
          f'least of {args.rounds} rounds, CPU per period')
    for drive in drives():
        off = best[(drive, 'off')]
        print(f'\n{drive}\n| amplifier | us per period | ratio to off | steps per period |')
        print('| --- | --- | --- | --- |')
        for name in configs:
            cost = best[(drive, name)]
            print(f'| {name} | {cost * 1e6:.1f} | {cost / off:.2f} | '
                  f'{steps[(drive, name)]:.1f} |')


if __name__ == '__main__':
    main()
