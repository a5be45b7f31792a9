"""
Work-precision map against the continuum: level x Ritz terms x tolerance, error against CPU.

Workloads, each at every point of GRID (level, n_r, tolerances):

'Periods repeated': the fraction of control periods the step-count controller ran again with
more steps (the embedded estimate over the tolerance). Each point's integration error is its
error against the same level's own converged run (at tolerance OWN), on the same scale.

- the three 'step' cases of bench/continuum_reference.py (fixed eps_b 0.15 / 0.20, simply
  supported 0.20; released, 3 kV from 1.5 to 3 s, 4.5 s) through ``simulate()``
  (bench/fidelity_choice.run_level): error = max |dy - dy_ref| over the 3 kV phase / stroke
  against the stored converged reference (exact n_r 11, LSODA rtol 1e-10), whether the beam
  switches as the reference does, CPU s per simulated s (one run, time.process_time), internal
  steps per period;
- a controller's input (CONTROLLER_END s of the default scene from rest: a new command every
  period, a 0 / 2.5 kV square wave at 2 Hz, so the beam switches twice a second, plus a uniform
  +-DITHER V dither per sample): error = max |dy - dy_ref| over the run / the travel of y_ref,
  dy = y - y(0) the displacement from the rest state,
  y_ref the simulator at exact n_r 11, tolerance 1e-8 (which agrees with the continuum
  reference to 1.5e-7 of the stroke on the step cases), switching right = the sign of q at the
  end of every half period as the reference's;
- with ``--array``: the shipped array (100 copies, two threads) under the controller's input
  (each copy its own dither), ARRAY_END s, wall clock: x real time and steps per period per
  copy, at ARRAY_POINTS only (an array run costs up to 100x a single cell's);
- with ``--lsoda``: scipy's LSODA on the same compiled right-hand side (``Model.f``, one solve
  per constant voltage, bench/continuum_reference.solve_case) on the step cases at LSODA_POINTS.

Writes bench/data/work_precision_map.csv (one row per point and workload) and, with ``--plot``,
docs/figures/work_precision_map.png (error against CPU, one curve per level and n_r, the front
marked). ``--plot-only`` redraws from the CSV. Run it under the bench lock:

    flock bench/.lock env PYTHONPATH=. python bench/work_precision_map.py [--quick]
        [--array] [--lsoda] [--plot]
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import time

from continuum_reference import (case_name, CASES, load_reference, solve_case, stroke,
                                 stroke_error, switched)
from det_sim_ros.analysis.scenarios import delta_y, STEP_END
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate, Simulator
from fidelity_choice import DOC, MACHINE, run_level, write_doc
import numpy as np

TOLERANCES = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-8)
GRID = {   # (fidelity, n_r): tolerances (the paper's and the consistent level's error is %)
    ('paper', 1): (1e-2, 1e-4, 1e-6),
    ('consistent', 3): (1e-2, 1e-3, 1e-4, 1e-6),
    ('consistent', 5): (1e-2, 1e-3, 1e-4, 1e-6),
    ('exact', 3): TOLERANCES,
    ('exact', 4): (1e-2, 1e-3, 1e-4, 1e-6),
    ('exact', 5): (1e-2, 3e-3, 1e-3, 1e-4, 1e-5, 1e-6, 1e-8),
    ('exact', 6): (1e-2, 1e-3, 1e-4, 1e-5, 1e-6),
    ('exact', 7): (1e-2, 1e-3, 3e-4, 1e-4, 1e-5, 1e-6, 1e-8),
    ('exact', 8): (1e-3, 1e-4, 1e-5),
    ('exact', 9): (1e-3, 1e-4, 1e-5, 1e-6, 1e-8),
}
QUICK_GRID = {('paper', 1): (1e-6,), ('exact', 3): (1e-3,), ('exact', 5): (1e-3, 1e-6),
              ('exact', 7): (1e-4,)}
ARRAY_POINTS = (('paper', 1, 1e-6), ('exact', 3, 1e-2), ('exact', 3, 1e-3), ('exact', 4, 1e-2),
                ('exact', 5, 1e-2), ('exact', 5, 1e-3))
LSODA_POINTS = (('exact', 5, 1e-4), ('exact', 5, 1e-6), ('exact', 7, 1e-4), ('exact', 7, 1e-6))
CONTROLLER_END = 3.0    # s
CONTROLLER_HIGH = 2500.0   # V
CONTROLLER_HZ = 2.0     # square wave frequency: one switch per high half period
DITHER = 25.0           # V, uniform +- per sample
ARRAY_END = 1.0         # s
ARRAY_THREADS = 2
REFERENCE = ('exact', 11, 1e-8)
BEGIN, END = '<!-- work_precision_map: begin -->', '<!-- work_precision_map: end -->'
HERE = os.path.dirname(os.path.abspath(__file__))
CSV = os.path.join(HERE, 'data', 'work_precision_map.csv')
FIGURE = os.path.join(HERE, os.pardir, 'docs', 'figures', 'work_precision_map.png')
FIELDS = ('workload', 'fidelity', 'n_r', 'tolerance', 'error', 'integration_error',
          'switch_ok', 'cpu_per_s', 'x_real_time', 'steps_per_period', 'repeated')
OWN = 1e-8   # each level's own converged run: its tolerance


def level_overrides(fidelity, n_r, tolerance) -> dict:
    """Return the scene overrides of one map point."""
    return {'scene.fidelity': fidelity, 'scene.n_ritz': n_r, 'integrator.tolerance': tolerance}


def controller_volts(periods: int, dt: float, copies: int = 1, seed: int = 0) -> np.ndarray:
    """Return (periods x copies) commands: the 2 Hz 0 / 2.5 kV square wave plus the dither."""
    t = np.arange(periods) * dt
    square = CONTROLLER_HIGH * (((t * CONTROLLER_HZ) % 1.0) < 0.5)
    dither = np.random.default_rng(seed).uniform(-DITHER, DITHER, (periods, copies))
    return np.clip(square[:, None] + dither, 0.0, None)


def half_period_signs(t, q) -> np.ndarray:
    """Return the sign of q at the end of every half period of the square wave."""
    ends = np.arange(1, int(t[-1] * 2 * CONTROLLER_HZ) + 1) / (2 * CONTROLLER_HZ)
    return np.sign(q[np.searchsorted(t, ends - 1e-9) - 1])


def run_controller(fidelity, n_r, tolerance):
    """Return (result, CPU s, steps per period) of the controller's input on the default scene."""
    scene = load_scene('default', level_overrides(fidelity, n_r, tolerance))
    periods = round(CONTROLLER_END / scene.dt)
    volts = controller_volts(periods, scene.dt)
    sim = Simulator(scene)
    start = time.process_time()
    result = simulate(sim, volts, CONTROLLER_END)
    result.periods_repeated = sim.stepper.periods_repeated / periods
    return result, time.process_time() - start, sim.steps_taken / periods


def _displacement(result) -> np.ndarray:
    """Return y - y(0): the travel from the rest state (whose y differs a little by level)."""
    return result['y'] - result['y'][0]


def controller_rows(point, reference, own=None):
    """
    Return ([the controller run's row], its result) at one point.

    Error against ``reference`` (the continuum) and, with ``own``, against the level's own
    converged run: max |y - y_ref| over the run / the travel of the continuum's y.
    """
    result, cpu, steps = run_controller(*point)
    travel = reference['y'].max() - reference['y'].min()
    error = float(np.max(np.abs(_displacement(result) - _displacement(reference))) / travel)
    own = own if own is not None else result
    own_error = float(np.max(np.abs(_displacement(result) - _displacement(own))) / travel)
    ok = np.array_equal(half_period_signs(result.t, result['q']),
                        half_period_signs(reference.t, reference['q']))
    row = _row('controller', point, error, own_error, ok, cpu / CONTROLLER_END, steps)
    row['repeated'] = result.periods_repeated
    return [row], result


def step_rows(point, reference, own=None):
    """
    Return (the map rows of the three step cases at one point, their dy by case).

    Error against the continuum ``reference`` and, with ``own`` (dy by case of the level's own
    converged run), against its own model: the integration error.
    """
    rows, dys = [], {}
    for beam, eps_b in CASES:
        name = case_name(beam, eps_b)
        ref = reference[name]
        run, cpu, steps = run_level(beam, eps_b, point[0], point[1], repeats=1,
                                    **{'integrator.tolerance': point[2]})
        dy, _ = delta_y(run.t, run['y'], run.scene.beam_length)
        dys[name] = dy
        scale = stroke(ref['y'])
        error = stroke_error(run.t, dy, ref['dy'], scale)
        own_error = stroke_error(run.t, dy, (own or dys)[name], scale)
        ok = switched(run.t, run['q']) == switched(ref['t'], ref['q'])
        rows.append(_row(name, point, error, own_error, ok, cpu / STEP_END, steps))
        rows[-1]['repeated'] = run.periods_repeated / round(STEP_END / run.scene.dt)
    return rows, dys


def lsoda_rows(point, reference):
    """Return LSODA's rows (same compiled rhs) on the step cases at one point."""
    rows = []
    for beam, eps_b in CASES:
        ref = reference[case_name(beam, eps_b)]
        start = time.process_time()
        run = solve_case(beam, eps_b, point[1], point[2])
        cpu = time.process_time() - start
        error = stroke_error(run['t'], run['dy'], ref['dy'], stroke(ref['y']))
        ok = switched(run['t'], run['q']) == switched(ref['t'], ref['q'])
        rows.append(_row(f'lsoda {case_name(beam, eps_b)}', point, error, float('nan'), ok,
                         cpu / run['t'][-1], float('nan')))
    return rows


def array_row(point):
    """Return the shipped array's row (wall clock, ARRAY_THREADS threads) at one point."""
    scene = load_scene('array', level_overrides(*point))
    periods = round(ARRAY_END / scene.dt)
    volts = controller_volts(periods, scene.dt, scene.n_dets)
    sim = Simulator(scene, threads=ARRAY_THREADS)
    start, cpu = time.perf_counter(), time.process_time()
    simulate(sim, volts, ARRAY_END)
    wall = (time.perf_counter() - start) / ARRAY_END
    cpu = (time.process_time() - cpu) / ARRAY_END
    steps = sim.steps_taken / periods / sim.model.arrays.n_groups
    print(f'    array CPU (both threads) {cpu:.3f} s/s: {ARRAY_THREADS / cpu:.2f}x real time '
          f'on {ARRAY_THREADS} idle cores')
    return [_row('array', point, float('nan'), float('nan'), True, wall, steps),
            _row('array cpu', point, float('nan'), float('nan'), True, cpu / ARRAY_THREADS,
                 steps)]


def _row(workload, point, error, own_error, ok, cpu_per_s, steps) -> dict:
    row = dict(zip(FIELDS, (workload, point[0], point[1], point[2], error, own_error, ok,
                            cpu_per_s, 1.0 / cpu_per_s, steps, float('nan'))))
    print(f'  {workload:>22} {point[0]:>10} {point[1]} {point[2]:.0e}: error {error:.2e} '
          f'(own {own_error:.1e}) {"" if ok else "SWITCHING WRONG "}{cpu_per_s:.4f} CPU s/s '
          f'({1 / cpu_per_s:.1f}x) {steps:.1f} steps/period', flush=True)
    return row


def front(points):
    """Return the indices of the Pareto front of (cost, error) pairs (lower both)."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    best, keep = float('inf'), []
    for i in order:
        if points[i][1] < best:
            best = points[i][1]
            keep.append(i)
    return keep


def summary(rows):
    """Return {(fidelity, n_r, tolerance): (worst step error, slowest step CPU/s, ...)}."""
    out = {}
    for r in rows:
        if r['workload'] in [case_name(b, e) for b, e in CASES]:
            key = (r['fidelity'], int(r['n_r']), float(r['tolerance']))
            err, cpu, ok = out.get(key, (0.0, 0.0, True))
            out[key] = (max(err, float(r['error'])), max(cpu, float(r['cpu_per_s'])),
                        ok and r['switch_ok'] in (True, 'True'))
    return out


def plot(rows, path=FIGURE):
    """Draw worst step-case error against the slowest case's CPU, a curve per level and n_r."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    best = summary(rows)
    fig, ax = plt.subplots(figsize=(8, 5.5))
    levels = sorted({(f, n) for f, n, _ in best}, key=lambda k: (k[0] != 'paper', k))
    for fidelity, n_r in levels:
        pts = sorted((t, *best[(f, n, t)]) for f, n, t in best if (f, n) == (fidelity, n_r))
        label = 'paper' if fidelity == 'paper' else f'{fidelity} n_r {n_r}'
        style = {'paper': ':', 'consistent': '--'}.get(fidelity, '-')
        line, = ax.loglog([p[2] for p in pts], [p[1] for p in pts], style, marker='o', ms=4,
                          label=label)
        for tol, err, cpu, _ in pts:
            ax.annotate(f'{tol:.0e}', (cpu, err), fontsize=6, color=line.get_color(),
                        xytext=(3, 2), textcoords='offset points')
    lsoda = {}
    for r in rows:
        if r['workload'].startswith('lsoda'):
            key = (int(r['n_r']), float(r['tolerance']))
            e, c = lsoda.get(key, (0.0, 0.0))
            lsoda[key] = (max(e, float(r['error'])), max(c, float(r['cpu_per_s'])))
    if lsoda:
        ax.loglog([v[1] for v in lsoda.values()], [v[0] for v in lsoda.values()], 'kx', ms=7,
                  label='scipy LSODA, exact (same rhs)')
    keys = list(best)
    idx = front([(best[k][1], best[k][0]) for k in keys])
    ax.loglog([best[keys[i]][1] for i in idx], [best[keys[i]][0] for i in idx], color='k',
              lw=3, alpha=0.25, label='front')
    ax.axhline(0.01, color='r', lw=0.8, ls='--')
    ax.axvline(1 / 25, color='g', lw=0.8, ls='--')
    ax.text(1 / 25, ax.get_ylim()[0] * 1.5, ' 25x real time', color='g', fontsize=7)
    ax.text(ax.get_xlim()[0] * 1.1, 0.011, '1 % of the stroke', color='r', fontsize=7)
    ax.set_xlabel('CPU s per simulated s, slowest of the three step cases')
    ax.set_ylabel('worst error against the continuum / stroke')
    ax.set_title('Work-precision map (labels: integrator.tolerance)')
    ax.grid(True, which='both', lw=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f'wrote {os.path.normpath(path)}')


def _level(fidelity, n_r) -> str:
    return 'paper' if fidelity == 'paper' else f'{fidelity} n_r {n_r}'


def _by_point(rows):
    """Return {(fidelity, n_r, tolerance): {workload: row}} with numbers as numbers."""
    out = {}
    for r in rows:
        key = (r['fidelity'], int(r['n_r']), float(r['tolerance']))
        out.setdefault(key, {})[r['workload']] = {
            k: (v if k in ('workload', 'fidelity') else
                (v in (True, 'True')) if k == 'switch_ok' else float(v)) for k, v in r.items()}
    return out


def doc_section(rows) -> str:
    """Return the markdown of the map: the front, the auto tolerances' evidence, array, LSODA."""
    import datetime
    import subprocess
    cases = [case_name(b, e) for b, e in CASES]
    points = _by_point(rows)
    steps = {k: v for k, v in points.items() if all(c in v for c in cases)}
    best = summary(rows)
    keys = list(best)
    on_front = {keys[i] for i in front([(best[k][1], best[k][0]) for k in keys])}
    try:
        commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True,
                                text=True, check=True, cwd=HERE).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = 'unknown'
    out = [f'Measured {datetime.date.today().isoformat()}, commit {commit}, {MACHINE} (one run '
           'per point, CPU time of one core: ±30 % with the load; ratios side by side in one '
           'run). Error: max |Δy − Δy_ref| of a step case over its 3 kV phase / stroke, the '
           'worst of the three; CPU: the slowest of the three; "integration": the error against '
           f'the same level at tolerance {OWN:g}, as a fraction of the own error of the level '
           'against the continuum (worst case); controller: '
           f'{CONTROLLER_END:g} s of the default scene under a new command every period (a '
           f'{CONTROLLER_HZ:g} Hz 0 / {CONTROLLER_HIGH / 1e3:g} kV square wave, ±{DITHER:g} V '
           f'dither), max |Δy − Δy_ref| / travel against exact n_r {REFERENCE[1]} at '
           f'{REFERENCE[2]:g}. Front: no other point both cheaper and more accurate on the step '
           'cases. `bench/work_precision_map.py --docs` rewrites this section.', '',
           '![work-precision map](figures/work_precision_map.png)', '',
           '| level | tolerance | worst error | integration / model | slowest × real time | '
           'steps per period (slowest) | periods repeated (slowest) | controller error | '
           'controller × real time | front |',
           '|---|---|---|---|---|---|---|---|---|---|']
    own_error = {(f, n): max(steps[(f, n, OWN)][c]['error'] for c in cases)
                 for f, n, _ in steps if (f, n, OWN) in steps}
    for key in sorted(steps, key=lambda k: (k[0] != 'paper', k[0], k[1], -k[2])):
        fidelity, n_r, tol = key
        if tol == OWN and tol not in GRID.get((fidelity, n_r), ()):
            continue
        v = steps[key]
        slow = max(cases, key=lambda c: v[c]['cpu_per_s'])
        ratio = max(v[c]['integration_error'] / steps[(fidelity, n_r, OWN)][c]['error']
                    for c in cases) if (fidelity, n_r) in own_error else float('nan')
        ctl = v.get('controller')
        wrong = '' if all(v[c]['switch_ok'] for c in cases) else ' (switches wrongly)'
        out.append(f'| {_level(fidelity, n_r)} | {tol:g} | {best[key][0]:.2%}{wrong} | '
                   f'{ratio:.1%} | {1 / best[key][1]:.0f} | {v[slow]["steps_per_period"]:.1f} | '
                   f'{v[slow]["repeated"]:.1%} | '
                   + (f'{ctl["error"]:.2%} | {ctl["x_real_time"]:.0f} | ' if ctl
                      else '– | – | ')
                   + ('**yes**' if key in on_front else '') + ' |')
    arrays = {k: v for k, v in points.items() if 'array' in v}
    if arrays:
        out += ['', f'The shipped array (100 copies, {ARRAY_THREADS} threads, {ARRAY_END:g} s of '
                'the input of the controller, each copy its own dither): × real time from the '
                f'CPU time of both threads ({ARRAY_THREADS} idle cores) and from the wall clock '
                'on this shared host (other sessions running beside it):', '',
                '| level | tolerance | × real time (CPU, 2 cores) | × real time (wall, shared) '
                '| steps per period per copy | error, fixed ε_b 0.20 (the cell of the array) |',
                '|---|---|---|---|---|---|']
        for (fidelity, n_r, tol), v in arrays.items():
            cell = steps.get((fidelity, n_r, tol), {}).get('fixed_0.20')
            out.append(f'| {_level(fidelity, n_r)} | {tol:g} | '
                       f'{v["array cpu"]["x_real_time"]:.2f} | {v["array"]["x_real_time"]:.2f} | '
                       f'{v["array"]["steps_per_period"]:.1f} | '
                       + (f'{cell["error"]:.2%}' if cell else '–') + ' |')
    lsoda = {k: v for k, v in points.items() if any(w.startswith('lsoda') for w in v)}
    if lsoda:
        out += ['', 'LSODA (scipy) on the same compiled right-hand side (`Model.f`, one solve '
                'per constant voltage), the step cases, against this stepper at the same level:',
                '', '| level | LSODA rtol | worst error | slowest × real time |',
                '|---|---|---|---|']
        for (fidelity, n_r, tol), v in lsoda.items():
            err = max(v[f'lsoda {c}']['error'] for c in cases)
            x = min(v[f'lsoda {c}']['x_real_time'] for c in cases)
            out.append(f'| {_level(fidelity, n_r)} | {tol:g} | {err:.2%} | {x:.0f} |')
    return '\n'.join(out)


def read_csv(path=CSV):
    """Return the rows of a written map."""
    with open(path, encoding='utf-8') as fh:
        return list(csv.DictReader(fh))


def main(argv=None) -> int:
    """Run the sweep, write the CSV (and the figure)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='a handful of points only')
    ap.add_argument('--array', action='store_true', help='also the 100-copy array')
    ap.add_argument('--lsoda', action='store_true', help='also scipy LSODA')
    ap.add_argument('--no-controller', action='store_true', help='skip the controller run')
    ap.add_argument('--plot', action='store_true', help='draw the figure')
    ap.add_argument('--plot-only', action='store_true', help='redraw from the CSV only')
    ap.add_argument('--docs', action='store_true',
                    help='write the map section of docs/fidelity.md')
    ap.add_argument('--out', default=CSV)
    args = ap.parse_args(argv)
    if args.plot_only:
        plot(read_csv(args.out))
        if args.docs:
            write_doc(doc_section(read_csv(args.out)), begin=BEGIN, end=END)
        return 0
    reference = load_reference()
    simulate(Simulator(load_scene('default')), np.zeros(10), 0.01)   # warm up
    rows = []
    controller_ref = None
    if not args.no_controller:
        controller_ref, _, _ = run_controller(*REFERENCE)
    for (fidelity, n_r), tolerances in (QUICK_GRID if args.quick else GRID).items():
        own_rows, own = step_rows((fidelity, n_r, OWN), reference)
        if controller_ref is not None:
            own_ctl_rows, own_ctl = controller_rows((fidelity, n_r, OWN), controller_ref)
            own_rows += own_ctl_rows
        rows += own_rows
        for tol in tolerances:
            if tol == OWN:
                continue
            rows += step_rows((fidelity, n_r, tol), reference, own)[0]
            if controller_ref is not None:
                rows += controller_rows((fidelity, n_r, tol), controller_ref, own_ctl)[0]
    if args.lsoda:
        for point in LSODA_POINTS:
            rows += lsoda_rows(point, reference)
    if args.array:
        for point in ARRAY_POINTS:
            rows += array_row(point)
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, 'w', encoding='utf-8', newline='') as fh:
        writer = csv.DictWriter(fh, FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    print(f'wrote {os.path.normpath(args.out)}')
    if args.plot:
        plot(rows)
    if args.docs:
        write_doc(doc_section(rows), begin=BEGIN, end=END)
        print(f'wrote the map into {os.path.normpath(DOC)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
