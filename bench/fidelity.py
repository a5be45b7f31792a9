"""
Model fidelity benchmark: what each fidelity level gets right and what it costs.

(a) Ritz critical load of one beam vs n_r against the Euler load (both beams).
(b) Model error vs CPU: for 'paper' (n_r = 1), 'consistent' (n_r = 1..7) and 'exact' (n_r = 3,
    5, 7, 9), the max relative error of the static load P l^2/EI, the reference-point deflection
    (the published q) and the max deflection against the exact elastica for y/l in
    [0.01, 0.15], next to the simulator's CPU seconds per simulated second on the 'step'
    scenario (eps_b = 0.20, median of 3 runs, time.process_time; the automatic internal step
    count, listed, follows the fastest beam mode).
(c) The 'step' scenario, both beams, eps_b in {0.15, 0.20, 0.25}: paper vs consistent and exact
    n_r = 5, eps_y at the end of the 3 kV phase and whether the beam switched (sign of q at the
    end of the 3 kV phase differs from the sign at its start, as in `det_sim step`).

Writes fidelity_*.csv, fidelity.md and (with matplotlib) fidelity.png to --out.

    PYTHONPATH=. python bench/fidelity.py [--quick] [--out bench/out]

``--quick``: three levels (paper, consistent and exact n_r 3), 0.2 s timing runs, 2 path points
(y/l 0.01, 0.02), eps_b 0.20 only; without --out, into a temporary folder (a smoke run).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import math
import os
import statistics
import sys
import tempfile
import time

from det_sim_ros.analysis import elastica as E
from det_sim_ros.analysis import fidelity as F
from det_sim_ros.analysis.scenarios import delta_y, step_scene, STEP_SWITCH_TIMES, step_voltage
from det_sim_ros.physics.model import ModelDomainError
from det_sim_ros.sim.simulator import simulate, Simulator
from fidelity_choice import _commit, MACHINE
import numpy as np

BEAMS = ('simply_supported', 'fixed')
LEVELS = ([('paper', 1)] + [('consistent', n) for n in range(1, 8)]
          + [('exact', n) for n in (3, 5, 7, 9)])


def _write_csv(path, header, rows):
    with open(path, 'w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def critical_loads(n_max):
    rows = []
    for beam in BEAMS:
        p_cr = E.euler_load(beam)
        for n in range(1, n_max + 1):
            p = F.beam_ritz(beam, 'consistent', n)[0].critical_load()[0]
            rows.append((beam, n, p, p_cr, p / p_cr - 1.0))
    return rows


def _sim(beam, fidelity, n, eps_b, t_end):
    scene = step_scene(beam, eps_b, **{'scene.fidelity': fidelity, 'scene.n_ritz': n})
    sim = Simulator(scene)
    sub = F.stable_substeps(sim.model, scene.dt, sim.substeps)
    if sub != sim.substeps:
        sim = Simulator(scene, substeps=sub)
    return scene, sim


def cpu_per_second(beam, fidelity, n, t_end, reps):
    times = []
    for _ in range(reps):
        scene, sim = _sim(beam, fidelity, n, 0.20, t_end)
        t0 = time.process_time()
        simulate(sim, step_voltage(scene.physics.v_max), t_end)
        times.append((time.process_time() - t0) / t_end)
    return statistics.median(times), sim.substeps


def error_vs_cpu(ys, t_end, reps, levels=LEVELS):
    rows = []
    for beam in BEAMS:
        el = E.elastica(beam, ys)
        simulate(_sim(beam, 'paper', 1, 0.2, 0.01)[1], step_voltage(0.0), 0.01)   # compile
        for fidelity, n in levels:
            path = F.beam_ritz(beam, fidelity, n)[0].path(ys)
            e_p = np.max(np.abs(path.load / el.load - 1.0))
            e_q = np.max(np.abs(path.q_ref / el.q_ref - 1.0))
            e_m = np.max(np.abs(path.q_max / el.q_max - 1.0))
            cpu, sub = cpu_per_second(beam, fidelity, n, t_end, reps)
            rows.append((beam, fidelity, n, e_p, e_q, e_m, cpu, sub))
            print(f'  {beam} {fidelity} n_r={n}: load {e_p:.2%} q_ref {e_q:.2%} '
                  f'q_max {e_m:.2%} cpu {cpu:.3f} s/s ({sub} substeps)', flush=True)
    return rows


def step_comparison(eps_list, n_cons):
    rows, runs = [], {}
    t_on, t_off = STEP_SWITCH_TIMES
    for beam in BEAMS:
        for eps in eps_list:
            for fidelity, n in (('paper', 1), ('consistent', n_cons), ('exact', n_cons)):
                scene, sim = _sim(beam, fidelity, n, eps, 4.5)
                try:
                    run = simulate(sim, step_voltage(scene.physics.v_max), 4.5)
                except ModelDomainError as exc:   # exact kinematics: |w'| reached 1
                    rows.append((beam, eps, fidelity, n, math.nan, None, math.nan, math.nan,
                                 math.nan))
                    print(f'  step {beam} eps_b={eps} {fidelity} n_r={n}: {exc}', flush=True)
                    continue
                t, q = run.t, run['q']
                _, eps_y = delta_y(t, run['y'], scene.beam_length)
                i_on = int(np.searchsorted(t, t_on - 1e-9))
                i_end = int(np.searchsorted(t, t_off - 1e-9)) - 1
                switched = bool(np.sign(q[i_end]) != np.sign(q[i_on]))
                rows.append((beam, eps, fidelity, n, float(eps_y[i_end]), switched,
                             float(q[i_on]), float(q[i_end]), float(q[-1])))
                runs[(beam, eps, fidelity)] = (t, eps_y)
                print(f'  step {beam} eps_b={eps} {fidelity} n_r={n}: eps_y {eps_y[i_end]:.2%} '
                      f'switched {switched}', flush=True)
    return rows, runs


def markdown(crit, err, step, args):
    lines = ['# Model fidelity', '',
             f'Measured {datetime.date.today().isoformat()}, commit {_commit()}, {MACHINE}, by '
             f'`python bench/fidelity.py{" --quick" if args.quick else ""}` (CPU times: ±30 %). '
             'Loads P l²/EI of one beam; y/l end shortening; deflections at the reference point '
             '(x = 2l/3 simply supported, l/2 fixed: the q the simulator publishes) and max |w|.',
             '', '## Critical load vs Ritz terms (error against Euler)', '',
             '| n_r | simply supported P_cr l²/EI | rel. error | fixed P_cr l²/EI | rel. error |',
             '|---|---|---|---|---|']
    by = {(b, n): (p, e) for b, n, p, _, e in crit}
    for n in sorted({n for _, n, *_ in crit}):
        ps, es = by[('simply_supported', n)]
        pf, ef = by[('fixed', n)]
        lines.append(f'| {n} | {ps:.9f} | {es:.2e} | {pf:.9f} | {ef:.2e} |')
    lines += ['', f'Euler: {E.euler_load("simply_supported"):.9f} (clamped-pinned, tan μ = μ), '
              f'{E.euler_load("fixed"):.9f} (clamped-clamped, 4π²).', '',
              '## Model error vs CPU', '',
              'Max relative error against the exact elastica for y/l in '
              f'[{args.ys[0]:.2f}, {args.ys[-1]:.2f}]; CPU seconds per simulated second on the '
              f'step scenario (eps_b = 0.20, median of {args.reps}, {args.t_end:g} s simulated).',
              '', '| beam | fidelity | n_r | load error | q_ref error | q_max error | '
              'CPU s / sim s | substeps |', '|---|---|---|---|---|---|---|---|']
    for b, f, n, ep, eq, em, cpu, sub in err:
        lines.append(f'| {b} | {f} | {n} | {ep:.2%} | {eq:.2%} | {em:.2%} | {cpu:.3f} | {sub} |')
    lines += ['', '## Step scenario: paper vs consistent vs exact', '',
              'eps_y at the end of the 3 kV phase; switched = sign of q at the end of the 3 kV '
              "phase differs from its sign at the start; 'slope limit': the exact kinematics' "
              "w' = sin(theta) reached 1 in the run (a domain error, see docs/model.md).", '',
              '| beam | eps_b | eps_y paper | eps_y consistent | eps_y exact | switched paper | '
              'switched consistent | switched exact |', '|---|---|---|---|---|---|---|---|']
    tab = {(b, e, f): (ey, sw) for b, e, f, _, ey, sw, *_ in step}

    def cell(value, switched):
        if switched is None:
            return 'slope limit', 'slope limit'
        return f'{value:.2%}', 'yes' if switched else 'no'
    for b in BEAMS:
        for e in args.eps:
            cols = [cell(*tab[(b, e, f)]) for f in ('paper', 'consistent', 'exact')]
            lines.append(f'| {b} | {e:.2f} | ' + ' | '.join(c[0] for c in cols) + ' | '
                         + ' | '.join(c[1] for c in cols) + ' |')
    return '\n'.join(lines) + '\n'


def plot(err, runs, args, path):
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print('matplotlib not installed: no PNG')
        return
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    ax = axes[0]
    for b, mk in zip(BEAMS, 'os'):
        pts = [(cpu, ep, f, n) for bb, f, n, ep, eq, em, cpu, sub in err if bb == b]
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], mk + '-', label=f'{b}: load')
        for cpu, ep, f, n in pts:
            ax.annotate('paper' if f == 'paper' else f'{f[0]}{n}', (cpu, ep), fontsize=8)
    ax.set_xlabel('CPU s per simulated s (step scenario)')
    ax.set_ylabel('max rel. load error vs elastica (y/l <= 0.15)')
    ax.set_title('model error vs CPU (labels: c/e = consistent/exact, n_r)')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend()
    ax = axes[1]
    for (b, e, f), (t, ey) in runs.items():
        ax.plot(t, 100 * ey, {'paper': '-', 'consistent': '--'}.get(f, ':'),
                label=f'{b} {e:.2f} {f}')
    ax.set_xlabel('t (s)')
    ax.set_ylabel('eps_y (%)')
    ax.set_title('step scenario: paper (solid), consistent (dashed), exact (dotted)')
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', default=None, help='default: bench/out (--quick: a temp folder)')
    ap.add_argument('--quick', action='store_true',
                    help='3 levels, one 0.2 s timing run, 2 path points, eps_b 0.20')
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = (tempfile.mkdtemp(prefix='fidelity_') if args.quick
                    else os.path.join('bench', 'out'))
    os.makedirs(args.out, exist_ok=True)
    args.ys = np.array([0.01, 0.02]) if args.quick else np.linspace(0.01, 0.15, 15)
    args.reps, args.t_end = (1, 0.2) if args.quick else (3, 4.5)
    args.eps = [0.20] if args.quick else [0.15, 0.20, 0.25]
    levels = [('paper', 1), ('consistent', 3), ('exact', 3)] if args.quick else LEVELS
    n_cons = 3 if args.quick else 5
    print('critical loads ...', flush=True)
    crit = critical_loads(3 if args.quick else 9)
    _write_csv(os.path.join(args.out, 'fidelity_critical_load.csv'),
               ['beam', 'n_ritz', 'P_cr_l2_EI', 'euler', 'rel_error'], crit)
    print('error vs CPU ...', flush=True)
    err = error_vs_cpu(args.ys, args.t_end, args.reps, levels)
    _write_csv(os.path.join(args.out, 'fidelity_error_cpu.csv'),
               ['beam', 'fidelity', 'n_ritz', 'load_error', 'q_ref_error', 'q_max_error',
                'cpu_s_per_sim_s', 'substeps'], err)
    print('step scenario ...', flush=True)
    step, runs = step_comparison(args.eps, n_cons)
    _write_csv(os.path.join(args.out, 'fidelity_step.csv'),
               ['beam', 'eps_b', 'fidelity', 'n_ritz', 'eps_y_on_end', 'switched', 'q_on_start',
                'q_on_end', 'q_final'], step)
    md = markdown(crit, err, step, args)
    with open(os.path.join(args.out, 'fidelity.md'), 'w') as fh:
        fh.write(md)
    plot(err, runs, args, os.path.join(args.out, 'fidelity.png'))
    print(md)
    return 0


if __name__ == '__main__':
    sys.exit(main())
