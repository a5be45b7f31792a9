"""
What a controller's moving command costs: × real time, steps and the method's upkeep.

Per case and level: φ chains of the linearized stages; Jacobians and LU factorizations of BDF.

A controller sends a new command every period, and each move starts a charge transient
(docs/numerics.md, 'Charge transients in dyadic steps'). Cases, fixed or simply supported beam
at ε_b 0.20, from the map's levels:

- 'dither': from rest, 1.5 kV + a uniform ±25 V per period (seed 1), 2 s;
- 'controller': the map's controller input (a 2 Hz 0 / 2.5 kV square wave plus the dither);
- '2 Hz': the map's 2 Hz switching case (few moves: the transient is not its cost).

CPU time (time.process_time) of ``simulate()``, best of two, one process per (tree, case), the
trees taking turns case by case so that two kernels are compared side by side in one run:

    python bench/controller_cost.py --tree . --tree ../other_checkout   # each built in place

Without --tree, this checkout alone (trees run through bench/checkouts.py). ``--quick``: one
dither case of 0.2 s (a smoke run). Run under ``flock bench/.lock`` (one CPU benchmark at a time).
"""

import argparse
import json
import os
import sys
import time

from checkouts import run_in_tree, THIS_TREE

HERE = os.path.dirname(os.path.abspath(__file__))
# (beam, Ritz family, n_r, tolerance, drive)
CASES = (
    ('fixed', 'buckling_modes', 3, 1e-2, 'dither'),
    ('fixed', 'buckling_modes', 3, 1e-3, 'dither'),
    ('fixed', 'polynomial', 5, 3e-3, 'dither'),
    ('fixed', 'polynomial', 7, 3e-3, 'dither'),
    ('simply_supported', 'polynomial', 7, 3e-3, 'dither'),
    ('simply_supported', 'polynomial', 9, 1e-4, 'dither'),
    ('fixed', 'buckling_modes', 3, 1e-2, 'controller'),
    ('simply_supported', 'buckling_modes', 3, 1e-2, 'controller'),
    ('fixed', 'polynomial', 7, 3e-3, 'controller'),
    ('simply_supported', 'polynomial', 7, 3e-3, 'controller'),
    ('simply_supported', 'polynomial', 7, 3e-3, 2.0),
    ('fixed', 'buckling_modes', 3, 1e-2, 2.0),
)
QUICK_CASES = (('fixed', 'buckling_modes', 3, 1e-2, 'dither', 200),)   # + periods of dither


def run_case(case) -> list:
    """Return [× real time, steps, (Jacobians, weight sets, chains)] of one case, here."""
    import numpy as np
    from continuum_reference import switching_inputs
    from det_sim_ros.analysis.scenarios import step_scene
    from det_sim_ros.sim.simulator import simulate, Simulator
    from work_precision_map import level_overrides
    beam, shapes, n_r, tolerance, drive, *periods = case
    if drive == 'dither':
        extra = {'scene.initial_state': 'rest'}
        volts = 1500.0 + np.random.default_rng(1).uniform(-25.0, 25.0, (periods or [2000])[0])
    else:
        extra, volts = switching_inputs(beam, 0.20, drive, 1e-3)
    scene = step_scene(beam, 0.20, **level_overrides('exact', shapes, n_r, tolerance), **extra)
    seconds = len(volts) * scene.dt
    best = float('inf')
    for _ in range(2):
        sim = Simulator(scene)
        start = time.process_time()
        simulate(sim, volts, seconds)
        best = min(best, time.process_time() - start)
    if getattr(sim.stepper, 'kind', None) == 'bdf' or getattr(sim.method, 'multistep', False):
        return [seconds / best, sim.steps_taken, list(sim.stepper.bdf_counts()), 'bdf']
    return [seconds / best, sim.steps_taken, list(sim.stepper.linear_counts()), sim.method.name]


def main(argv=None) -> int:
    """Run every case in every tree, trees taking turns; print one line per case."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--tree', action='append', default=[],
                    help='a source tree (kernel built in place) to run; repeatable')
    ap.add_argument('--case', help=argparse.SUPPRESS)   # one case, in this process
    ap.add_argument('--quick', action='store_true', help='one dither case of 0.2 s')
    args = ap.parse_args(argv)
    if args.case:
        print(json.dumps(run_case(json.loads(args.case))))
        return 0
    trees = args.tree or [THIS_TREE]
    for case in QUICK_CASES if args.quick else CASES:
        cells = []
        for tree in trees:
            out = run_in_tree(tree, [sys.executable, os.path.join(HERE, 'controller_cost.py'),
                                     '--case', json.dumps(case)])
            speed, steps, counts, method = json.loads(out.strip().splitlines()[-1])
            if method == 'bdf':
                upkeep = f'{counts[0]:5d} Jacobians {counts[1]:5d} LUs'
            else:
                upkeep = f'{counts[2]:5d} chains'
            cells.append(f'{speed:5.0f}x {steps:6d} steps {method:>17} {upkeep}')
        beam, shapes, n_r, tolerance, drive = case[:5]
        print(f'{beam:>16} {shapes:>14} {n_r} {tolerance:.0e} {drive!s:>10}: '
              + ' | '.join(cells), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
