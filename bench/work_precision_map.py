"""
Work-precision map against the continuum: level x Ritz family x terms x tolerance, error vs CPU.

A level is (fidelity, Ritz family, n_r); each point adds the integrator tolerance. Workloads at
every point of GRID, each case run through ``simulate()`` (CPU: time.process_time, one run):

- 'step': the three step cases of bench/continuum_reference.py (fixed eps_b 0.15 / 0.20,
  simply supported 0.20; released, 3 kV from 1.5 to 3 s, 4.5 s): error = max |dy - dy_ref| over
  the 3 kV phase / stroke; whether the beam switches as the reference does;
- 'switching' (shared scenarios): both beams at eps_b 0.15 and 0.20, released, a 3 kV square
  wave from 0.5 s to 2.5 s at 2 Hz: error = max |y - y_ref| from 0.5 s / the travel there; the
  snaps (sign changes of q) as the reference's: as many, each within 2 ms; and at 10 Hz
  (error and snaps reported, not scored: there the converged model's own refinements differ by
  27-85 % of the travel, bench/continuum_reference.py's table: the path depends on rounding);
- 'controller': both beams at 0.20 from rest, a new command every period (a 0 / 2.5 kV square
  wave at 2 Hz plus a +-25 V dither), 2.5 s: error as for switching;
- with ``--pwm`` (instead of the cases above; its own CSV and doc section): the 'pwm'
  scenario (released; from 0.5 s to 2.5 s a 10 Hz PWM at 3 kV, duty 30 %, 50 %, 70 %, 50 %)
  on both beams at eps_b 0.15 and 0.20, at PWM_POINTS. Judged for robustness first:
  ``analysis.predictability.predictability()`` of the point's run, and the same twin of the
  converged reference (interface mass x (1 + 1e-6), rtol x 0.9, LSODA). Where both paths are
  robust the case is scored as switching (error, every snap within 2 ms); where either is not,
  its error and snaps are reported, not scored (bench/pwm_statistics.py scores those on
  statistics over ensembles);
- with ``--array``: the shipped array (100 copies, two threads) under the controller's input
  (each copy its own dither), ARRAY_END s: x real time from both threads' CPU and the wall clock;
- with ``--lsoda``: scipy's LSODA on the same compiled right-hand side (``Model.f``, one solve
  per constant voltage, bench/continuum_reference.solve_case) at LSODA_POINTS, on the step and
  2 Hz switching cases, against this stepper at the default level.

Each beam is judged on its own cases (a Ritz family is per beam): a point's score for a beam is
its worst scored error there, whether it makes every snap, and its slowest case's x real time.
"integration": its error against the same level at the tightest tolerance of the grid (the
level's own converged run), over that run's error against the continuum.

Writes bench/data/work_precision_map.csv (one row per point and case; ``--pwm``:
bench/data/work_precision_pwm.csv, ``--docs`` its own section) and, with ``--plot``,
docs/figures/work_precision_map.png (per beam: worst error against the slowest case's CPU, one
curve per level, the front marked); ``--docs`` rewrites the map's section of docs/fidelity.md;
``--plot-only`` redraws from the CSV. Run it under the bench lock:

    flock bench/.lock env PYTHONPATH=. python bench/work_precision_map.py [--quick]
        [--array] [--lsoda] [--plot] [--docs]
    flock bench/.lock env PYTHONPATH=. python bench/work_precision_map.py --pwm [--quick]
        [--docs]

``--quick``: QUICK_GRID's points on two cases (with ``--pwm``: QUICK_PWM_POINTS against a
coarse reference), the CSV into a temporary file unless --out names one (a smoke run).
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile
import time

from continuum_reference import (case_name, CASES, controller_volts, load_reference,
                                 REFERENCE_N_R, REFERENCE_RTOL, solve_case, stroke,
                                 stroke_error, switched, switching_case_name, SWITCHING_CASES,
                                 switching_inputs)
from det_sim_ros.analysis.predictability import Perturbation, predictability, Stroke
from det_sim_ros.analysis.scenarios import (delta_y, snap_times, STEP_END, step_scene,
                                            step_voltage, SWITCHING_END, switching_error)
from det_sim_ros.physics.model import ModelDomainError
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.integrators import integration_tolerance
from det_sim_ros.sim.simulator import simulate, Simulator
from fidelity_choice import _commit, DOC, MACHINE, write_doc
import numpy as np

POLY, MODES = 'polynomial', 'buckling_modes'
GRID = {   # (fidelity, family, n_r): tolerances; the last of each is its own converged run
    ('paper', POLY, 1): (1e-2, 1e-6),
    ('consistent', POLY, 3): (1e-2, 1e-4, 1e-6),
    ('exact', POLY, 3): (1e-2, 1e-3, 1e-6),
    ('exact', POLY, 5): (1e-2, 1e-3, 1e-4, 1e-6),
    ('exact', POLY, 6): (1e-2, 1e-3, 1e-6),
    ('exact', POLY, 7): (1e-2, 3e-3, 1e-3, 1e-4, 1e-6),
    ('exact', POLY, 8): (1e-2, 1e-3, 1e-4, 1e-6),
    ('exact', POLY, 9): (1e-3, 1e-4, 1e-6),
    ('exact', MODES, 2): (1e-2, 1e-3, 1e-6),
    ('exact', MODES, 3): (1e-2, 3e-3, 1e-3, 1e-4, 1e-6),
    ('exact', MODES, 4): (1e-2, 1e-3, 1e-4, 1e-6),
    ('exact', MODES, 5): (1e-2, 1e-3, 1e-6),
}
QUICK_GRID = {('exact', MODES, 3): (1e-2, 1e-4)}   # on the first step and switching case only
ARRAY_POINTS = (('paper', POLY, 1, 1e-6), ('exact', POLY, 3, 1e-2), ('exact', MODES, 3, 1e-2),
                ('exact', MODES, 3, 1e-3))
LSODA_POINTS = (('exact', MODES, 3, 1e-4), ('exact', MODES, 3, 1e-6), ('exact', POLY, 7, 1e-4),
                ('exact', POLY, 7, 1e-6))
# the 'pwm' cases' points: each beam's default, the levels on the map's fronts, tight ones
PWM_POINTS = (('exact', MODES, 3, 1e-2), ('exact', MODES, 3, 1e-4), ('exact', MODES, 4, 1e-3),
              ('exact', MODES, 5, 1e-3), ('exact', POLY, 7, 3e-3), ('exact', POLY, 7, 1e-4),
              ('exact', POLY, 9, 1e-3), ('exact', POLY, 9, 1e-4))
QUICK_PWM_POINTS = (('exact', MODES, 3, 1e-2), ('exact', POLY, 7, 3e-3))
PWM_CASES = (('fixed', 0.15), ('fixed', 0.20), ('simply_supported', 0.15),
             ('simply_supported', 0.20))
PWM_CSV_FIELDS = ('point_robust_until', 'reference_robust_until')
ARRAY_END = 1.0         # s
ARRAY_THREADS = 2
BEAMS = ('fixed', 'simply_supported')
BEGIN, END = '<!-- work_precision_map: begin -->', '<!-- work_precision_map: end -->'
PWM_BEGIN, PWM_END = '<!-- work_precision_pwm: begin -->', '<!-- work_precision_pwm: end -->'
HERE = os.path.dirname(os.path.abspath(__file__))
CSV = os.path.join(HERE, 'data', 'work_precision_map.csv')
PWM_CSV = os.path.join(HERE, 'data', 'work_precision_pwm.csv')
FIGURE = os.path.join(HERE, os.pardir, 'docs', 'figures', 'work_precision_map.png')
FIELDS = ('workload', 'case', 'beam', 'fidelity', 'shapes', 'n_r', 'tolerance', 'error',
          'integration_error', 'snaps', 'snaps_ref', 'right', 'scored', 'cpu_per_s',
          'x_real_time', 'steps_per_period', 'repeated')


def level_overrides(fidelity, shapes, n_r, tolerance) -> dict:
    """Return the scene overrides of one map point."""
    return {'scene.fidelity': fidelity, 'scene.shapes': shapes, 'scene.n_ritz': n_r,
            'integrator.tolerance': tolerance}


def workloads():
    """Return (workload, case name, beam, eps_b, drive) of every case the map runs."""
    out = [('step', case_name(b, e), b, e, None) for b, e in CASES]
    for beam, eps_b, drive in SWITCHING_CASES:
        kind = 'controller' if drive == 'controller' else f'switching {drive:g} Hz'
        out.append((kind, switching_case_name(beam, eps_b, drive), beam, eps_b, drive))
    return out


def run_case(point, beam, eps_b, drive):
    """Return (t, y, q, CPU s, steps per period, periods repeated) of one case at one point."""
    overrides = level_overrides(*point)
    if drive is None:
        scene = step_scene(beam, eps_b, **overrides)
        end = STEP_END
        volts = np.array([step_voltage(scene.physics.v_max)(k * scene.dt)
                          for k in range(round(end / scene.dt))])
    else:
        extra, volts = switching_inputs(beam, eps_b, drive, 1e-3)
        scene = step_scene(beam, eps_b, **overrides, **extra)
        end = SWITCHING_END
    sim = Simulator(scene)
    start = time.process_time()
    run = simulate(sim, volts, end)
    cpu = time.process_time() - start
    periods = len(volts)
    return (run.t, run['y'], run['q'], cpu / end, sim.steps_taken / periods,
            sim.stepper.periods_repeated / periods, scene)


def score(workload, t, y, q, ref, own_y=None):
    """Return (error, integration error, snaps, reference snaps, right, scored) of one run."""
    if workload == 'step':
        dy = delta_y(t, y, 0.0)[0]
        error = stroke_error(t, dy, ref['dy'], stroke(ref['y']))
        own = (stroke_error(t, dy, delta_y(t, own_y, 0.0)[0], stroke(ref['y']))
               if own_y is not None else 0.0)
        right = switched(t, q) == switched(ref['t'], ref['q'])
        return error, own, int(switched(t, q)), int(switched(ref['t'], ref['q'])), right, True
    error = switching_error(t, y, ref['y'])
    travel = ref['y'][t >= 0.5 - 1e-9]
    own = (float(np.max(np.abs((y - own_y)[t >= 0.5 - 1e-9])) / np.ptp(travel))
           if own_y is not None else 0.0)
    made, expected = snap_times(t, q), snap_times(ref['t'], ref['q'])
    right = len(made) == len(expected) and (
        not len(made) or float(np.max(np.abs(made - expected))) <= 2.0e-3)
    scored = not workload.startswith('switching 10')
    return error, own, len(made), len(expected), right, scored


def point_rows(point, reference, own=None, cases=None):
    """Return (the rows of every case (or of ``cases``) at one point, its y by case)."""
    rows, ys = [], {}
    for workload, name, beam, eps_b, drive in cases or workloads():
        try:
            t, y, q, cpu, steps, repeated, _ = run_case(point, beam, eps_b, drive)
        except ModelDomainError as exc:   # e.g. |w'| reached 1: the level cannot run the case
            print(f'  {name:>40} {_level(*point[:3]):>24} {point[3]:.0e}: {exc}', flush=True)
            ys[name] = None
            rows.append(dict(zip(FIELDS, (workload, name, beam, *point, float('inf'),
                                          float('inf'), -1, -1, False,
                                          not workload.startswith('switching 10'),
                                          float('inf'), 0.0, float('nan'), float('nan')))))
            continue
        ys[name] = y
        mine = None if own is None or own.get(name) is None else own[name]
        error, own_error, snaps, snaps_ref, right, scored = score(
            workload, t, y, q, reference[name], mine)
        rows.append(dict(zip(FIELDS, (workload, name, beam, *point, error, own_error, snaps,
                                      snaps_ref, right, scored, cpu, 1.0 / cpu, steps,
                                      repeated))))
        print(f'  {name:>40} {_level(*point[:3]):>24} {point[3]:.0e}: error {error:.2e} '
              f'(own {own_error:.1e}) snaps {snaps}/{snaps_ref}{"" if right else " WRONG"} '
              f'{1 / cpu:.0f}x {steps:.1f} steps/period', flush=True)
    return rows, ys


def lsoda_rows(point, reference):
    """Return LSODA's rows (same compiled rhs) on the step and 2 Hz switching cases."""
    rows = []
    for workload, name, beam, eps_b, drive in workloads():
        if workload not in ('step', 'switching 2 Hz'):
            continue
        start = time.process_time()
        run = solve_case(beam, eps_b, point[2], point[3], drive, shapes=point[1])
        cpu = (time.process_time() - start) / run['t'][-1]
        error, _, snaps, snaps_ref, right, _ = score(workload, run['t'], run['y'], run['q'],
                                                     reference[name])
        rows.append(dict(zip(FIELDS, (f'lsoda {workload}', name, beam, *point, error,
                                      float('nan'), snaps, snaps_ref, right, True, cpu,
                                      1.0 / cpu, float('nan'), float('nan')))))
        print(f'  lsoda {name:>34} {_level(*point[:3])} rtol {point[3]:.0e}: error '
              f'{error:.2e} {1 / cpu:.1f}x', flush=True)
    return rows


def pwm_references(quick: bool = False) -> dict:
    """
    Return {case name: reference} of the 'pwm' cases, each with its robustness.

    The converged beam (as the stored reference: exact, polynomial n_r 11, LSODA at 1e-10)
    with 'robust_until', where its twin
    (interface mass x (1 + 1e-6), rtol x 0.9, as predictability()'s) first leaves 5 % of the
    stroke, None if never. ``quick``: n_r 7 at 1e-6 (a smoke run).
    """
    n_r, rtol = (7, 1e-6) if quick else (REFERENCE_N_R, REFERENCE_RTOL)
    twin = Perturbation()
    out = {}
    for beam, eps_b in PWM_CASES:
        scene = step_scene(beam, eps_b, **{'scene.initial_state': 'released'})
        run = solve_case(beam, eps_b, n_r, rtol, 'pwm')
        other = solve_case(beam, eps_b, n_r, rtol * twin.tolerance_factor, 'pwm',
                           overrides={'physics.m': scene.physics.m * (1.0 + twin.relative)})
        level = {'scene.fidelity': 'exact', 'scene.shapes': POLY, 'scene.n_ritz': n_r}
        stroke_of = Stroke(Simulator(scene.replace(**level)).model)
        distance = np.maximum(np.abs(run['y'] - other['y']) / stroke_of.y0[0],
                              np.abs(run['q'] - other['q']) / stroke_of.q_gap[0])
        beyond = np.nonzero(distance > 0.05)[0]
        run['robust_until'] = float(run['t'][beyond[0]]) if beyond.size else None
        run['peak'] = float(np.max(distance))
        out[switching_case_name(beam, eps_b, 'pwm')] = run
        print(f'  reference pwm/{case_name(beam, eps_b)} (n_r {n_r}, rtol {rtol:g}): '
              f'{len(snap_times(run["t"], run["q"]))} snaps, its twin '
              + ('robust' if beyond.size == 0 else f'beyond 5 % from {run["robust_until"]:.3f} s')
              + f' (peak {run["peak"]:.1%})', flush=True)
    return out


def pwm_rows(point, references) -> list:
    """Return the rows of the 'pwm' cases at one point, scored where both paths are robust."""
    rows = []
    for beam, eps_b in PWM_CASES:
        name = switching_case_name(beam, eps_b, 'pwm')
        ref = references[name]
        try:
            t, y, q, cpu, steps, repeated, scene = run_case(point, beam, eps_b, 'pwm')
            # the twin's tolerance x 0.9 must not cross 'auto''s BDF threshold (1e-3): the
            # stepper named as the run resolved it
            scene = scene.replace(**{'integrator.method': Simulator(scene).method.name})
            measured = predictability(scene, switching_inputs(beam, eps_b, 'pwm', 1e-3)[1],
                                      SWITCHING_END)
        except ModelDomainError as exc:
            print(f'  {name:>40} {_level(*point[:3]):>24} {point[3]:.0e}: {exc}', flush=True)
            continue
        robust = measured.robust and ref['robust_until'] is None
        error, _, snaps, snaps_ref, right, _ = score('pwm', t, y, q, ref)
        rows.append(dict(zip(FIELDS + PWM_CSV_FIELDS, (
            'pwm', name, beam, *point, error, float('nan'), snaps, snaps_ref, right, robust,
            cpu, 1.0 / cpu, steps, repeated,
            '' if measured.robust else measured.robust_until,
            '' if ref['robust_until'] is None else ref['robust_until']))))
        print(f'  {name:>40} {_level(*point[:3]):>24} {point[3]:.0e}: '
              + ('robust' if measured.robust else f'not robust from {measured.robust_until:.3f} s')
              + f', error {error:.2e} snaps {snaps}/{snaps_ref}'
              + ('' if robust else ' (not scored)') + f' {1 / cpu:.0f}x', flush=True)
    return rows


def pwm_section(rows, references) -> str:
    """Return the markdown of the 'pwm' cases: robustness, and the score where robust."""
    import datetime
    out = [f'Measured {datetime.date.today().isoformat()}, commit {_commit()}, {MACHINE}, by '
           '`flock bench/.lock env PYTHONPATH=. python bench/work_precision_map.py --pwm '
           "--docs`. The 'pwm' scenario (released; from 0.5 s a 10 Hz PWM at 3 kV, duty 30, "
           "50, 70, 50 % for 0.5 s each, to 2.5 s). First robustness: the point's own run by "
           '`predictability()` (its twin: interface mass × (1 + 1e-6), tolerance × 0.9, beyond '
           '5 % of the stroke from the time given), and the same twin of the converged '
           'reference (exact, polynomial n_r 11, LSODA at 1e-10, rtol × 0.9). Where both are '
           'robust the case is scored as switching (max |y − y_ref| from 0.5 s / travel; '
           "snaps made / the reference's, ✓ each within 2 ms); elsewhere the same numbers are "
           'reported in italics, not scored: the path is not a result of either model.', '']
    names = [switching_case_name(b, e, 'pwm') for b, e in PWM_CASES]
    ref_cells = []
    for name in names:
        ref = references[name]
        until = ('robust' if ref['robust_until'] is None
                 else f'not robust from {ref["robust_until"]:.2f} s')
        ref_cells.append(f'{until}, {len(snap_times(ref["t"], ref["q"]))} snaps')
    out += ['| level | tolerance | ' + ' | '.join(
                n.split('/')[1].replace('simply_supported', 'simply supported')
                .replace('_', ' ε_b ') for n in names) + ' |',
            '|---|---|' + '---|' * len(names),
            '| converged reference | 1e-10 | ' + ' | '.join(ref_cells) + ' |']
    by = {}
    for r in map(_num_pwm, rows):
        by.setdefault((r['fidelity'], r['shapes'], int(r['n_r']), r['tolerance']), {})[
            r['case']] = r
    for key in sorted(by, key=lambda k: (k[1] != MODES, k[2], -k[3])):
        cells = []
        for name in names:
            r = by[key].get(name)
            if r is None:
                cells.append('–')
                continue
            until = ('robust' if r['point_robust_until'] == '' else
                     f'not robust from {float(r["point_robust_until"]):.2f} s')
            numbers = (f'{r["error"]:.1%}, {int(r["snaps"])}/{int(r["snaps_ref"])}'
                       f'{" ✓" if r["right"] else " ✗"}, {r["x_real_time"]:.0f}×')
            cells.append(f'{until}: ' + (numbers if r['scored'] else f'*{numbers}*'))
        out.append(f'| {_level(*key[:3])} | {key[3]:g} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(out)


def _num_pwm(row):
    out = _num({k: v for k, v in row.items() if k in FIELDS})
    for key in PWM_CSV_FIELDS:
        out[key] = '' if row[key] in ('', None) else float(row[key])
    return out


def array_rows(point):
    """Return the shipped array's rows (wall clock and CPU, ARRAY_THREADS threads)."""
    scene = load_scene('array', level_overrides(*point))
    periods = round(ARRAY_END / scene.dt)
    volts = controller_volts(periods, scene.dt, scene.n_dets)
    sim = Simulator(scene, threads=ARRAY_THREADS)
    start, cpu = time.perf_counter(), time.process_time()
    simulate(sim, volts, ARRAY_END)
    wall = (time.perf_counter() - start) / ARRAY_END
    cpu = (time.process_time() - cpu) / ARRAY_END / ARRAY_THREADS
    steps = sim.steps_taken / periods / sim.model.arrays.n_groups
    print(f'  array {_level(*point[:3])} {point[3]:.0e}: {1 / cpu:.2f}x real time on '
          f'{ARRAY_THREADS} cores (CPU), {1 / wall:.2f}x by the wall clock', flush=True)
    nan = float('nan')
    return [dict(zip(FIELDS, (kind, 'array', 'fixed', *point, nan, nan, 0, 0, True, False,
                              cost, 1.0 / cost, steps, nan)))
            for kind, cost in (('array', wall), ('array cpu', cpu))]


def _level(fidelity, shapes, n_r) -> str:
    if fidelity == 'paper':
        return 'paper'
    return f'{fidelity} {"modes" if shapes == MODES else "poly"} n_r {n_r}'


def _num(row):
    out = {}
    for k, v in row.items():
        if k in ('workload', 'case', 'beam', 'fidelity', 'shapes'):
            out[k] = v
        elif k in ('right', 'scored'):
            out[k] = v in (True, 'True')
        else:
            out[k] = float(v)
    return out


def by_point(rows):
    """Return {(fidelity, shapes, n_r, tolerance): [rows]} of the simulator's own rows."""
    out = {}
    for r in map(_num, rows):
        if r['workload'].startswith(('lsoda', 'array')):
            continue
        out.setdefault((r['fidelity'], r['shapes'], int(r['n_r']), r['tolerance']), []).append(r)
    return out


def beam_score(rows, beam):
    """Return (worst scored error, all snaps right, slowest x real time, worst integration)."""
    mine = [r for r in rows if r['beam'] == beam and r['scored']]
    return (max(r['error'] for r in mine), all(r['right'] for r in mine),
            min(r['x_real_time'] for r in mine), max(r['integration_error'] for r in mine))


def front(points):
    """Return the indices of the Pareto front of (cost, error) pairs (lower both)."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    best, keep = float('inf'), []
    for i in order:
        if points[i][1] < best:
            best = points[i][1]
            keep.append(i)
    return keep


def beam_front(points, beam):
    """Return the keys on one beam's front among the points that make every snap."""
    keys = [k for k, rows in points.items() if beam_score(rows, beam)[1]]
    scores = [beam_score(points[k], beam) for k in keys]
    return {keys[i] for i in front([(1.0 / s[2], s[0]) for s in scores])}


def plot(rows, path=FIGURE):
    """Per beam: worst scored error against the slowest case's CPU, one curve per level."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    points = by_point(rows)
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.2), sharey=True)
    levels = sorted({k[:3] for k in points}, key=lambda k: (k[0] != 'paper', k))
    cycle = plt.get_cmap('tab20').colors
    colors = {level: cycle[i % len(cycle)] for i, level in enumerate(levels)}
    for ax, beam in zip(axes, BEAMS):
        for level in levels:
            pts = sorted((k[3], *beam_score(points[k], beam)) for k in points if k[:3] == level)
            pts = [p for p in pts if p[3] > 0.0]   # a level that cannot run the case: none
            if not pts:
                continue
            style = {'paper': ':', 'consistent': '--'}.get(level[0], '-')
            line, = ax.loglog([1.0 / p[3] for p in pts], [p[1] for p in pts], style,
                              marker='o' if level[1] == MODES else 's', ms=4,
                              color=colors[level], label=_level(*level))
            for tol, err, right, x, _ in pts:
                ax.annotate(f'{tol:.0e}' + ('' if right else ' ✗'), (1.0 / x, err), fontsize=6,
                            color=line.get_color(), xytext=(3, 2), textcoords='offset points')
        keys = sorted(beam_front(points, beam), key=lambda k: -beam_score(points[k], beam)[2])
        ax.loglog([1.0 / beam_score(points[k], beam)[2] for k in keys],
                  [beam_score(points[k], beam)[0] for k in keys], color='k', lw=3, alpha=0.25,
                  label='front (every snap made)')
        ax.axhline(0.01, color='r', lw=0.8, ls='--')
        ax.axvline(1 / 50, color='g', lw=0.8, ls='--')
        ax.set_xlabel('CPU s per simulated s, slowest case')
        ax.set_title(f'{beam.replace("_", " ")} beam: step and 2 Hz switching cases', fontsize=9)
        ax.grid(True, which='both', lw=0.3)
    axes[0].set_ylabel('worst error against the continuum (stroke / travel)')
    handles = {h.get_label(): h for ax in axes for h in ax.get_lines()}
    axes[1].legend([handles[k] for k in handles if not k.startswith('_')],
                   [k for k in handles if not k.startswith('_')], fontsize=6, ncol=2)
    fig.suptitle('Work-precision map (labels: integrator.tolerance; ✗: a snap missed or '
                 'mistimed; red: 1 %, green: 50x real time)', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f'wrote {os.path.normpath(path)}')


def doc_section(rows) -> str:
    """Return the markdown of the map: per beam, error, snaps and cost of every point."""
    import datetime
    points = by_point(rows)
    fronts = {beam: beam_front(points, beam) for beam in BEAMS}
    out = [f'Measured {datetime.date.today().isoformat()}, commit {_commit()}, {MACHINE}, by '
           '`flock bench/.lock env PYTHONPATH=. python bench/work_precision_map.py --lsoda '
           '--array --plot --docs` (one run per point, CPU time of one core: ±30 % with the '
           'load; ratios side by side in one run). Per beam: the worst error over its step '
           'cases (max |Δy − Δy_ref| over the 3 kV phase / stroke), its 2 Hz switching cases '
           'and its controller case (max |y − y_ref| from 0.5 s / travel); "snaps": every '
           'snap of the converged beam made, each within 2 ms (the step cases: switching as '
           'it does); × real time: its slowest case; "integration": the error against the '
           "same level at the tightest tolerance listed for it, over that run's own error. "
           'Front: no point that makes every snap is both cheaper and more accurate.', '',
           '![work-precision map](figures/work_precision_map.png)', '',
           '| level | tolerance | fixed: worst error | snaps | × real time | '
           'simply supported: worst error | snaps | × real time | integration / model | '
           '10 Hz error (fixed / simply supp.) | front |',
           '|---|---|---|---|---|---|---|---|---|---|---|']
    for key in sorted(points, key=lambda k: (k[0] != 'paper', k[0], k[1] != MODES, k[2], -k[3])):
        rows_k = points[key]
        cells = []
        integration = []
        for beam in BEAMS:
            err, right, x, own = beam_score(rows_k, beam)
            cells += [f'{err:.2%}', 'all' if right else '**missed**', f'{x:.0f}']
            integration.append(own / max(err, 1e-12))
        fast = [max(r['error'] for r in rows_k if r['workload'] == 'switching 10 Hz'
                    and r['beam'] == beam) for beam in BEAMS]
        tightest = key[3] == min(k[3] for k in points if k[:3] == key[:3])
        marks = [beam.split('_')[0] for beam in BEAMS if key in fronts[beam]]
        out.append(f'| {_level(*key[:3])} | {key[3]:g} | ' + ' | '.join(cells) + ' | '
                   + ('–' if tightest else f'{max(integration):.0%}') + ' | '
                   + f'{fast[0]:.0%} / {fast[1]:.0%} | ' + ', '.join(marks) + ' |')
    arrays = {}
    lsoda = {}
    for r in map(_num, rows):
        key = (r['fidelity'], r['shapes'], int(r['n_r']), r['tolerance'])
        if r['workload'].startswith('array'):
            arrays.setdefault(key, {})[r['workload']] = r
        elif r['workload'].startswith('lsoda'):
            lsoda.setdefault(key, []).append(r)
    if arrays:
        out += ['', f'The shipped array (100 copies of the fixed ε_b 0.20 cell, {ARRAY_THREADS} '
                f"threads, {ARRAY_END:g} s of the controller's input, each copy its own "
                'dither): × real time from the CPU time of both threads, and by the wall clock:',
                '', '| level | tolerance | × real time (CPU, 2 cores) | × real time (wall) | '
                'steps per period per copy | fixed: worst error |', '|---|---|---|---|---|---|']
        for key, v in arrays.items():
            cell = points.get(key)
            out.append(f'| {_level(*key[:3])} | {key[3]:g} | '
                       f'{v["array cpu"]["x_real_time"]:.2f} | {v["array"]["x_real_time"]:.2f} '
                       f'| {v["array"]["steps_per_period"]:.1f} | '
                       + (f'{beam_score(cell, "fixed")[0]:.2%}' if cell else '–') + ' |')
    if lsoda:
        out += ['', "scipy's LSODA on the same compiled right-hand side (`Model.f`, one solve "
                'per constant voltage) against this stepper at the default level (auto '
                'tolerance), per beam on the step and 2 Hz switching cases: worst error and '
                "slowest × real time; 'cost ratio': LSODA's CPU over the stepper's at the "
                'default, slowest cases:', '',
                '| level | LSODA rtol | beam | LSODA worst error | LSODA × real time | '
                'cost ratio |', '|---|---|---|---|---|---|']
        for key, rs in lsoda.items():
            for beam in BEAMS:
                mine = [r for r in rs if r['beam'] == beam]
                default = load_scene('default', {'scene.beam': beam})
                own_key = ('exact', *default.ritz_level, integration_tolerance(default))
                if not mine or own_key not in points or own_key[1:3] != key[1:3]:
                    continue
                x = min(r['x_real_time'] for r in mine)
                ratio = beam_score(points[own_key], beam)[2] / x
                out.append(f'| {_level(*key[:3])} | {key[3]:g} | {beam.replace("_", " ")} | '
                           f'{max(r["error"] for r in mine):.2%} | {x:.1f} | {ratio:.1f} |')
    return '\n'.join(out)


def read_csv(path=CSV):
    """Return the rows of a written map."""
    with open(path, encoding='utf-8') as fh:
        return list(csv.DictReader(fh))


def main(argv=None) -> int:
    """Run the sweep, write the CSV (and the figure, and the doc section)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='a handful of points only')
    ap.add_argument('--array', action='store_true', help='also the 100-copy array')
    ap.add_argument('--lsoda', action='store_true', help='also scipy LSODA')
    ap.add_argument('--plot', action='store_true', help='draw the figure')
    ap.add_argument('--plot-only', action='store_true', help='redraw from the CSV only')
    ap.add_argument('--docs', action='store_true',
                    help='write the map section of docs/fidelity.md')
    ap.add_argument('--pwm', action='store_true',
                    help="only the 'pwm' cases (their own CSV and doc section)")
    ap.add_argument('--out', default=None,
                    help='the CSV (default: the stored map; --quick: a temporary file)')
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = (os.path.join(tempfile.mkdtemp(prefix='work_precision_map_'), 'quick.csv')
                    if args.quick else PWM_CSV if args.pwm else CSV)
    if args.pwm:
        return pwm_main(args)
    if args.plot_only:
        plot(read_csv(args.out))
        if args.docs:
            write_doc(doc_section(read_csv(args.out)), begin=BEGIN, end=END)
        return 0
    reference = load_reference()
    simulate(Simulator(load_scene('default')), np.zeros(10), 0.01)   # warm up
    rows = []
    os.makedirs(os.path.dirname(args.out), exist_ok=True)

    def save():   # after every level: a long sweep keeps what it measured
        with open(args.out, 'w', encoding='utf-8', newline='') as fh:
            writer = csv.DictWriter(fh, FIELDS)
            writer.writeheader()
            writer.writerows(rows)
    cases = [workloads()[0], workloads()[len(CASES)]] if args.quick else None
    for level, tolerances in (QUICK_GRID if args.quick else GRID).items():
        own_rows, own = point_rows((*level, tolerances[-1]), reference, cases=cases)
        rows += own_rows
        for tol in tolerances[:-1]:
            rows += point_rows((*level, tol), reference, own, cases)[0]
        save()
    if args.lsoda:
        for point in LSODA_POINTS:
            rows += lsoda_rows(point, reference)
    if args.array:
        for point in ARRAY_POINTS:
            rows += array_rows(point)
    save()
    print(f'wrote {os.path.normpath(args.out)}')
    if args.plot:
        plot(rows)
    if args.docs:
        write_doc(doc_section(rows), begin=BEGIN, end=END)
        print(f'wrote the map into {os.path.normpath(DOC)}')
    return 0


def pwm_main(args) -> int:
    """Run the 'pwm' cases at PWM_POINTS; write their CSV (and their doc section)."""
    out = args.out
    references = pwm_references(args.quick)
    rows = []
    for point in QUICK_PWM_POINTS if args.quick else PWM_POINTS:
        rows += pwm_rows(point, references)
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with open(out, 'w', encoding='utf-8', newline='') as fh:
        writer = csv.DictWriter(fh, FIELDS + PWM_CSV_FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    print(f'wrote {os.path.normpath(out)}')
    text = pwm_section([{k: str(v) for k, v in r.items()} for r in rows], references)
    print(text)
    if args.docs and not args.quick:
        write_doc(text, begin=PWM_BEGIN, end=PWM_END)
        print(f'wrote the pwm cases into {os.path.normpath(DOC)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
