"""
What a looser error control would buy on an array: error per copy against steps and CPU.

An array scene's copies (config/array.yaml with --copies, at --fidelity) under bench/batch.py's
workloads ('step': one v_max step of 0.3 s per copy, switch-on times spread; 'square': a 0 /
v_max square wave of period 0.2 s per copy, phases spread), 1 s at tolerance 1e-6, with the
local tolerance of the step-count controller multiplied by 1, 3, 10, 30 (a study only: the
scenes keep their calibrated value). Per row: the median and the worst copy's error (max
|y - y_ref| over the run / the copy's stroke, against the same run at tolerance 1e-10), steps
per period and copy, CPU us per period and copy (one thread). Run:

    python bench/array_tolerance.py [--fidelity paper] [--copies 20] [--workload step]

``--quick``: 2 copies, 0.1 s, factors 1 and 3 (a smoke run).
"""

import argparse
import time

from batch import _commands
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim import integrators
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np

FACTORS = (1, 3, 10, 30)
T_END = 1.0


def run(args, tolerance, factor):
    """Return y per copy (periods x copies), CPU s and steps per period and copy."""
    saved = dict(integrators.LOCAL_TOLERANCE), integrators.LINEARIZED_LOCAL_TOLERANCE
    integrators.LOCAL_TOLERANCE.update({k: v * factor for k, v in saved[0].items()})
    integrators.LINEARIZED_LOCAL_TOLERANCE = saved[1] * factor
    try:
        scene = load_scene('array', {'structure.copies': args.copies,
                                     'scene.fidelity': args.fidelity,
                                     'integrator.tolerance': tolerance})
        sim = Simulator(scene)
    finally:
        integrators.LOCAL_TOLERANCE.update(saved[0])
        integrators.LINEARIZED_LOCAL_TOLERANCE = saved[1]
    periods = int(round(args.t_end / scene.dt))
    volts = _commands(args.copies, periods, scene.dt, scene.physics.v_max, kind=args.workload)
    start = time.process_time()
    result = simulate(sim, volts, args.t_end)
    cpu = time.process_time() - start
    y = np.stack([result[f'y[det{i}]'] for i in range(args.copies)], axis=1)
    return y, cpu, sim.stepper.steps_taken / periods / args.copies


def main():
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--fidelity', default='paper')
    parser.add_argument('--copies', type=int, default=20)
    parser.add_argument('--workload', default='step', choices=('step', 'square'))
    parser.add_argument('--quick', action='store_true', help='2 copies, 0.1 s, two factors')
    args = parser.parse_args()
    args.t_end, factors = T_END, FACTORS
    if args.quick:
        args.copies, args.t_end, factors = 2, 0.1, FACTORS[:2]
    y_ref, _, _ = run(args, 1e-10, 1)
    stroke = y_ref.max(axis=0) - y_ref.min(axis=0)
    print(f'{args.copies} copies at {args.fidelity}, {args.workload}, tolerance 1e-6\n')
    print('| local tolerance | median copy error | worst copy error | steps/period/copy | '
          'CPU µs/period/copy |')
    print('|---|---|---|---|---|')
    for factor in factors:
        y, cpu, steps = run(args, 1e-6, factor)
        error = np.max(np.abs(y - y_ref), axis=0) / stroke
        print(f'| ×{factor} | {np.median(error):.1e} | {error.max():.1e} (det{error.argmax()}) '
              f'| {steps:.2f} | {cpu / (args.t_end * 1000) / args.copies * 1e6:.2f} |')


if __name__ == '__main__':
    main()
