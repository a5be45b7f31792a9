"""
The exact kinematics' cost, this tree against another checkout, side by side in one run.

On the three 'step' cases (fixed eps_b 0.15 and 0.20, simply supported 0.20; tolerance 1e-6,
method 'auto') at fidelity exact with n_r 3, 5, 7:

- the right-hand side's CPU time per call, both kernels loaded in this process (the
  baseline's compiled module under another package name) on the same model arrays, over 500
  states of the step run (they reach its largest slopes), timed in alternating rounds (best of
  --rounds each); the binding's call overhead (the paper model's call, timed the same way) is
  subtracted;
- the step run through simulate() in each checkout (a subprocess with its PYTHONPATH, the two
  interleaved, best of --repeats): CPU time per 1 ms period, steps per period, and
  max |Delta-y - Delta-y_baseline| over the run relative to the stroke.

The checkouts run through bench/checkouts.py. ~3 min on a shared 2-core host:

    flock bench/.lock python bench/exact_rhs_cost.py --baseline DIR [--levels 5,7]

``--quick``: the fixed beam at 0.15, n_r 3, one run and two rounds each, against this checkout
itself unless --baseline names another (a smoke run).
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import json
import os
import sys
import tempfile
import time

from checkouts import run_in_tree, THIS_TREE

from det_sim_ros.analysis.scenarios import step_scene
from det_sim_ros.core import kernel
from det_sim_ros.sim.simulator import Simulator
import numpy as np

CASES = (('fixed', 0.15), ('fixed', 0.20), ('simply_supported', 0.20))

_SNIPPET = """
import json, sys, time
import numpy as np
from det_sim_ros.analysis.scenarios import delta_y, step_scene, step_voltage
from det_sim_ros.sim.simulator import simulate, Simulator
beam, eps_b, n_ritz, out = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
scene = step_scene(beam, eps_b, **{'scene.fidelity': 'exact', 'scene.n_ritz': n_ritz,
                                  'integrator.tolerance': 1e-6, 'integrator.method': 'auto'})
sim = Simulator(scene)
t0 = time.process_time()
run = simulate(sim, step_voltage(scene.physics.v_max), 4.5)
cpu = time.process_time() - t0
model = sim.model
u = np.zeros(model.n_inputs)
y = np.array([model.outputs(s, u)['y'] for s in run.x])
np.save(out, delta_y(run.t, y, scene.beam_length)[0])

np.save(out.replace('.npy', '_x.npy'), run.x[::max(1, len(run.x) // 500)])
print(json.dumps({'us_period': cpu / 4500 * 1e6, 'steps': sim.steps_taken / 4500}))
"""


def measure(root, beam, eps_b, n_ritz, out):
    """Return one checkout's numbers (its Delta-y saved to ``out``)."""
    text = run_in_tree(root, [sys.executable, '-c', _SNIPPET, beam, str(eps_b), str(n_ritz),
                              out])
    return json.loads(text.splitlines()[-1])


def load_kernel(root):
    """Return the compiled kernel module of the checkout ``root`` (imported under its path)."""
    path, = glob.glob(os.path.join(root, 'det_sim_ros', 'core', '_ckernel*.so'))
    spec = importlib.util.spec_from_file_location('baseline_kernel._ckernel', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _per_call(model, states, u, dx):
    t0 = time.process_time()
    for x in states:
        model.rhs(x, u, dx)
    return (time.process_time() - t0) / len(states)


def rhs_costs(arrays, states, floor_arrays, baseline, rounds):
    """Return the rhs CPU us per call (this kernel, the baseline's), less the call overhead."""
    u = np.zeros(1)
    dx = np.zeros(states.shape[1])
    floor_states = np.zeros((len(states), floor_arrays.n_state))
    best = [float('inf')] * 4
    for _ in range(rounds):
        for i, (module, a, xs) in enumerate(((kernel, arrays, states),
                                             (baseline, arrays, states),
                                             (kernel, floor_arrays, floor_states))):
            model = module.Model(a)
            out = dx if xs is states else np.zeros(a.n_state)
            best[i] = min(best[i], _per_call(model, xs, u, out))
    return (best[0] - best[2]) * 1e6, (best[1] - best[2]) * 1e6


def _line(cells):
    return '| ' + ' | '.join(cells) + ' |'


def main(argv=None) -> int:
    """Run the comparison and print its table (markdown)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--baseline', help='the other checkout (built in place)')
    p.add_argument('--levels', default='3,5,7')
    p.add_argument('--repeats', type=int, default=2, help='runs of each checkout')
    p.add_argument('--rounds', type=int, default=40, help='rhs timing rounds')
    p.add_argument('--quick', action='store_true', help='fixed 0.15, n_r 3, one run')
    args = p.parse_args(argv)
    cases = CASES
    if args.quick:
        cases, args.levels, args.repeats, args.rounds = CASES[:1], '3', 1, 2
        args.baseline = args.baseline or THIS_TREE
    if not args.baseline:
        p.error('--baseline DIR is required (the other checkout)')
    roots = (THIS_TREE, os.path.abspath(args.baseline))
    baseline = load_kernel(roots[1])
    print(_line(['case', 'n_r', 'rhs us/call (this / baseline)', 'ratio',
                 'us/period (this / baseline)', 'ratio', 'steps/period (this / baseline)',
                 'max |dDelta-y| / stroke']))
    print(_line(['---'] * 8))
    with tempfile.TemporaryDirectory() as tmp:
        for beam, eps_b in cases:
            for n_ritz in (int(v) for v in args.levels.split(',')):
                best = [None, None]
                for _ in range(args.repeats):
                    for i, root in enumerate(roots):
                        got = measure(root, beam, eps_b, n_ritz, os.path.join(tmp, f'{i}.npy'))
                        best[i] = got if best[i] is None else {
                            k: min(best[i][k], got[k]) for k in got}
                new, old = best
                dy_new, dy_old = (np.load(os.path.join(tmp, f'{i}.npy')) for i in (0, 1))
                arrays = Simulator(step_scene(beam, eps_b, **{
                    'scene.fidelity': 'exact', 'scene.n_ritz': n_ritz})).model.arrays
                floor = Simulator(step_scene(beam, eps_b)).model.arrays
                states = np.ascontiguousarray(np.load(os.path.join(tmp, '0_x.npy')))
                new['rhs_us'], old['rhs_us'] = rhs_costs(arrays, states, floor, baseline,
                                                         args.rounds)
                deviation = np.max(np.abs(dy_new - dy_old)) / np.max(np.abs(dy_old))
                print(_line([f'{beam} {eps_b:.2f}', str(n_ritz),
                             f'{new["rhs_us"]:.2f} / {old["rhs_us"]:.2f}',
                             f'{old["rhs_us"] / new["rhs_us"]:.2f}',
                             f'{new["us_period"]:.0f} / {old["us_period"]:.0f}',
                             f'{old["us_period"] / new["us_period"]:.2f}',
                             f'{new["steps"]:.2f} / {old["steps"]:.2f}',
                             f'{deviation:.1e}']), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
