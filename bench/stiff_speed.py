"""
Stiff beam modes: speed and accuracy of the exact kinematics, side by side in one run.

The three 'step' cases (fixed eps_b 0.15 and 0.20, simply supported 0.20; 0 V, 3 kV from 1.5 to
3.0 s, to 4.5 s, released start, tolerance 1e-6) at fidelity exact with n_r 3, 5, 7 and at the
paper's level. Per row: steps per 1 ms period, CPU us per step and per period, x real time and
the integration error (max |Delta-y - Delta-y_ref| over the run relative to the stroke, against
the same model solved with 'etdrk4' at tolerance 1e-10; cached in --ref-dir). Each exact level
runs with 'auto' ('etdrk4_linearized') and with 'etdrk4' (the beams' stiff modes in the explicit
stages) for a measured ratio; scipy's Radau on the kernel's rhs at rtol 1e-6 (restarted every
sample, as the project's reference solutions) gives the scipy column (--scipy: all rows, the
worst case only, or none). --baseline DIR times the paper level through another checkout's
kernel in a subprocess (bench/checkouts.py), interleaved with this one, for a same-host ratio.
``--quick``: the fixed beam at 0.20 at the paper's level only, no scipy (a smoke run; with
--baseline, one run each). One case takes ~2 min on a shared 2-core host:

    flock bench/.lock python bench/stiff_speed.py --cases simply_supported0.20 \
        [--scipy worst] [--baseline ../other-checkout] [--ref-dir DIR]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

from checkouts import run_in_tree, THIS_TREE

from det_sim_ros.analysis.scenarios import reference_solution, STEP_END, step_error, \
    step_scene, step_voltage
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np

CASES = (('fixed', 0.15), ('fixed', 0.20), ('simply_supported', 0.20))
LEVELS = (('exact', 3), ('exact', 5), ('exact', 7), ('paper', 1))
TOLERANCE = 1e-6
N_PERIODS = int(round(STEP_END * 1000))

_PAPER_SNIPPET = """
import sys, time
from det_sim_ros.analysis.scenarios import step_scene, step_voltage
from det_sim_ros.sim.simulator import simulate, Simulator
beam, eps, runs = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
scene = step_scene(beam, eps, **{'integrator.tolerance': 1e-6})
best = []
for _ in range(runs):
    sim = Simulator(scene)
    t0 = time.process_time()
    simulate(sim, step_voltage(scene.physics.v_max), 4.5)
    best.append(time.process_time() - t0)
print(min(best) / 4500 * 1e6)
"""


def _scene(beam, eps_b, fidelity, n_ritz, method, tolerance=TOLERANCE):
    return step_scene(beam, eps_b, **{'scene.fidelity': fidelity, 'scene.n_ritz': n_ritz,
                                      'integrator.tolerance': tolerance,
                                      'integrator.method': method})


def reference(beam, eps_b, fidelity, n_ritz, ref_dir):
    """Return the states of the run solved with 'etdrk4' at tolerance 1e-10 (cached)."""
    name = f'refx_{beam}_{eps_b}_{n_ritz}.npy' if fidelity == 'exact' else \
        f'refx_{beam}_{eps_b}_{fidelity}.npy'
    path = os.path.join(ref_dir, name)
    if os.path.exists(path):
        return np.load(path)
    scene = _scene(beam, eps_b, fidelity, n_ritz, 'etdrk4', 1e-10)
    X = simulate(scene, step_voltage(scene.physics.v_max), STEP_END).x
    os.makedirs(ref_dir, exist_ok=True)
    np.save(path, X)
    return X


def kernel_row(beam, eps_b, fidelity, n_ritz, method, X_ref):
    """Return the measured row of one run through simulate()."""
    sim = Simulator(_scene(beam, eps_b, fidelity, n_ritz, method))
    t0 = time.process_time()
    run = simulate(sim, step_voltage(sim.scene.physics.v_max), STEP_END)
    cpu = time.process_time() - t0
    steps = sim.steps_taken
    return {'method': sim.method.name, 'steps': steps / N_PERIODS, 'us_step': cpu / steps * 1e6,
            'us_period': cpu / N_PERIODS * 1e6, 'realtime': STEP_END / cpu,
            'error': step_error(sim.model, run.t, run.x, X_ref)[0]}


def scipy_row(beam, eps_b, fidelity, n_ritz, X_ref):
    """Return (CPU s, error) of solve_ivp Radau at rtol 1e-6 on the kernel's rhs."""
    scene = _scene(beam, eps_b, fidelity, n_ritz, 'etdrk4')
    t0 = time.process_time()
    # restarted at every 1 ms sample (one solve per phase failed: its first steps overshoot)
    t, X = reference_solution(scene, STEP_END, method='Radau', rtol=TOLERANCE)
    cpu = time.process_time() - t0
    return cpu, step_error(Simulator(scene).model, t, X, X_ref)[0]


def paper_baseline(baseline, beam, eps_b, rounds=3, runs=5):
    """Return (us per period here, us per period through ``baseline``), interleaved."""
    here, there = [], []
    for _ in range(rounds):
        for root, out in ((THIS_TREE, here), (baseline, there)):
            text = run_in_tree(root, [sys.executable, '-c', _PAPER_SNIPPET, beam, str(eps_b),
                                      str(runs)])
            out.append(float(text.split()[-1]))
    return statistics.median(here), statistics.median(there)


def _line(cells):
    return '| ' + ' | '.join(cells) + ' |'


def main(argv=None) -> int:
    """Run the benchmark and print its table (markdown)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--scipy', choices=('all', 'worst', 'none'), default='worst')
    p.add_argument('--ref-dir', default='bench/out/stiff_refs')
    p.add_argument('--baseline', default='', help='another checkout for the paper ratio')
    p.add_argument('--levels', default='exact3,exact5,exact7,paper1')
    p.add_argument('--cases', default='fixed0.15,fixed0.20,simply_supported0.20',
                   help='a run of all three takes ~5 min on a shared 2-core host')
    p.add_argument('--quick', action='store_true', help='fixed 0.20, paper, no scipy')
    args = p.parse_args(argv)
    if args.quick:
        args.levels, args.cases, args.scipy = 'paper1', 'fixed0.20', 'none'
        args.ref_dir = tempfile.mkdtemp(prefix='stiff_refs_')   # not the full run's cache
    levels = [lv for lv in LEVELS if f'{lv[0]}{lv[1]}' in args.levels.split(',')]
    print(_line(['case', 'level', 'method', 'steps/period', 'us/step', 'us/period',
                 'x real time', 'error/stroke', 'old/new CPU', 'scipy/kernel CPU',
                 'scipy error']))
    print(_line(['---'] * 11))
    for beam, eps_b in CASES:
        if f'{beam}{eps_b:.2f}' not in args.cases.split(','):
            continue
        case = f'{beam} {eps_b:.2f}'
        worst = (beam, eps_b) == CASES[-1]
        for fidelity, n_ritz in levels:
            X_ref = reference(beam, eps_b, fidelity, n_ritz, args.ref_dir)
            new = kernel_row(beam, eps_b, fidelity, n_ritz, 'auto', X_ref)
            rows = [new]
            if fidelity == 'exact':
                rows.append(kernel_row(beam, eps_b, fidelity, n_ritz, 'etdrk4', X_ref))
            sp = ('', '')
            if args.scipy == 'all' or (args.scipy == 'worst' and worst):
                cpu, err = scipy_row(beam, eps_b, fidelity, n_ritz, X_ref)
                sp = (f'{cpu * 1e6 / N_PERIODS / new["us_period"]:.1f}', f'{err:.1e}')
            for i, r in enumerate(rows):
                ratio = f'{rows[1]["us_period"] / new["us_period"]:.1f}' if len(rows) > 1 \
                    and i == 0 else ''
                print(_line([case, f'{fidelity} {n_ritz}', r['method'], f'{r["steps"]:.1f}',
                             f'{r["us_step"]:.2f}', f'{r["us_period"]:.1f}',
                             f'{r["realtime"]:.1f}', f'{r["error"]:.1e}', ratio,
                             sp[0] if i == 0 else '', sp[1] if i == 0 else '']), flush=True)
        if args.baseline:
            here, there = paper_baseline(args.baseline, beam, eps_b,
                                         *((1, 1) if args.quick else ()))
            print(_line([case, 'paper 1', f'this tree / {args.baseline}', '', '',
                         f'{here:.2f} / {there:.2f}', '', '', '', '', '']), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
