"""
Whether the default level is right in the statistical sense where the 'pwm' path is not robust.

The 'pwm' scenario (released at 0 V; from 0.5 s to 2.5 s a 10 Hz PWM at 3 kV, duty 30 %, 50 %,
70 %, 50 % for 0.5 s each) on both beams at eps_b 0.15 and 0.20. Each case is first judged by
``analysis.predictability.predictability()`` at the default level; where its path is not robust
no level can be held to one run of it, and the level is scored on statistics instead.

Per case and level, an ensemble of COPIES perturbed runs (``analysis.ensemble.ensemble()``:
copy 0 the scene, copy i the interface mass x (1 + 1e-6 z_i) and the tolerance x (1 - 0.1 u_i),
the measure's perturbation sizes, so the copies differ in what rounding decides). Until the
default run stops being robust its stretch is scored as switching (copy 0 against the converged
level's copy 0: max |y - y_ref| over the travel, the snaps each within 2 ms, and the time the two
paths are first 5 % of the travel apart); from then to 2.5 s (the whole 0.5-2.5 s where it is
robust) per copy:

- the snap rate (sign changes of q per s);
- the fraction of the time on q > 0 (the released start's branch) and the branch at the end;
- Δy over the rest shortening y0: its time mean and its range (max - min).

A level is within the converged level's spread on a statistic when its ensemble mean lies within
two standard errors of the difference of the means (sqrt(s1²/n1 + s2²/n2)) plus ALLOWANCE (the
map's 1 % target on fractions and on Δy / y0; none on the snap rate: every snap); Mann-Whitney's
U test (scipy, two-sided) gives a p-value beside it. Per sample: the fraction of samples where
the two ensembles' mean Δy agree within the same bound. The converged level with another seed
(its copy 0 shared) is the test's own false-alarm baseline.

Levels (LEVELS): the default; candidates (exact kinematics at more Ritz terms); the converged
level (exact kinematics, polynomial n_r 11 at tolerance 1e-6: the continuum reference's terms,
bench/continuum_reference.py, at the tightest tolerance of the work-precision map). Each
ensemble's CPU is measured (process time, one core). Prints the markdown tables; ``--docs``
rewrites their section of docs/fidelity.md. Under the bench lock:

    flock bench/.lock env PYTHONPATH=. python bench/pwm_statistics.py [--quick] [--docs]

--quick: the simply supported eps_b 0.20 case, 3 copies, the default against polynomial n_r 9
at 1e-3 as a stand-in for the converged level (seconds; a smoke run of the code path).
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import sys
import time

from det_sim_ros.analysis.ensemble import Ensemble, ensemble
from det_sim_ros.analysis.predictability import predictability, Stroke
from det_sim_ros.analysis.response import SimRun
from det_sim_ros.analysis.scenarios import (pwm_voltage, snap_times, SWITCHING_END,
                                            switching_scene, SWITCHING_START)
from det_sim_ros.physics.statics import rest_shortenings
from det_sim_ros.sim.simulator import Simulator
from fidelity_choice import _commit, MACHINE, write_doc
import numpy as np
from scipy.stats import mannwhitneyu

CASES = (('fixed', 0.15), ('fixed', 0.20), ('simply_supported', 0.15),
         ('simply_supported', 0.20))
V_HIGH = 3000.0    # V
COPIES = 20
SEED = 0


def _level(shapes, n_r, tolerance):
    return {'scene.fidelity': 'exact', 'scene.shapes': shapes, 'scene.n_ritz': n_r,
            'integrator.tolerance': tolerance}


CONVERGED = ('converged: poly n_r 11, 1e-6', _level('polynomial', 11, 1e-6))
# per beam: the default, candidates from the work-precision map's fronts, the converged level
LEVELS = {
    'fixed': (('default', {}), ('modes n_r 4, 1e-3', _level('buckling_modes', 4, 1e-3)),
              ('modes n_r 5, 1e-3', _level('buckling_modes', 5, 1e-3)),
              ('poly n_r 9, 1e-3', _level('polynomial', 9, 1e-3)),
              ('poly n_r 9, 1e-4', _level('polynomial', 9, 1e-4)), CONVERGED),
    'simply_supported': (('default', {}), ('poly n_r 9, 1e-3', _level('polynomial', 9, 1e-3)),
                         ('poly n_r 9, 1e-4', _level('polynomial', 9, 1e-4)), CONVERGED),
}
QUICK = {'case': ('simply_supported', 0.20), 'copies': 3,
         'levels': (('default', {}), ('stand-in: poly n_r 9, 1e-3',
                                      _level('polynomial', 9, 1e-3)))}
STATISTICS = ('snap rate', 'time on q > 0', 'q > 0 at the end', 'mean Δy / y0',
              'Δy range / y0')
# per statistic: the difference allowed beyond two standard errors (the map's 1 % target on
# fractions and on Δy / y0; every snap: none on the snap rate)
ALLOWANCE = (0.0, 0.01, 0.01, 0.01, 0.01)
NULL = 'converged, seed 1 (baseline)'
BEGIN, END = '<!-- pwm_statistics: begin -->', '<!-- pwm_statistics: end -->'


def run_ensemble(scene, volts, t_end: float, copies: int, seed: int = SEED, cache: str = '',
                 key: str = '') -> tuple:
    """
    Return (the :class:`Ensemble` of ``analysis.ensemble.ensemble()``, its CPU s).

    ``cache``: a folder where the runs are kept under ``key`` (a rerun of the tables reads them
    back, with the CPU they took).
    """
    path = os.path.join(cache, f'{key}-{copies}-{seed}.npz') if cache else ''
    if path and os.path.exists(path):
        with np.load(path) as data:
            t, nan = data['t'], np.full((len(data['t']), 1), np.nan)
            return (Ensemble([SimRun(['det'], t, nan, q[:, None], dy[:, None], nan, nan)
                              for q, dy in zip(data['q'], data['dy'])]), float(data['cpu']))
    start = time.process_time()
    runs = ensemble(scene, t_end, volts=volts, copies=copies, seed=seed)
    cpu = time.process_time() - start
    if path:
        os.makedirs(cache, exist_ok=True)
        np.savez_compressed(path, t=runs.runs[0].t, q=np.array([r.q[:, 0] for r in runs.runs]),
                            dy=np.array([r.dy[:, 0] for r in runs.runs]), cpu=cpu)
    return runs, cpu


def copy_statistics(runs: Ensemble, y0: float, start: float) -> np.ndarray:
    """Return (copies x STATISTICS): each copy's statistics from ``start`` s to the end."""
    span = runs.runs[0].t[-1] - start
    dy = [run.dy[run.t >= start - 1e-9, 0] / y0 for run in runs.runs]
    return np.column_stack([runs.snap_counts(start) / span, runs.time_on_plus(start),
                            [b == 'buckled+' for b in runs.final_branches()],
                            [np.mean(d) for d in dy], [np.ptp(d) for d in dy]]).astype(float)


def compare(level: np.ndarray, converged: np.ndarray) -> list:
    """
    Per statistic: (level mean, sd, converged mean, sd, within, Mann-Whitney p).

    Within: |difference of the means| <= 2 standard errors of it + ALLOWANCE (where both
    ensembles agree copy for copy, a robust stretch, the allowance alone decides).
    """
    out = []
    for j in range(level.shape[1]):
        a, b = level[:, j], converged[:, j]
        se = math.sqrt(np.var(a, ddof=1) / len(a) + np.var(b, ddof=1) / len(b))
        diff = abs(float(np.mean(a) - np.mean(b)))
        within = diff <= 2.0 * se + ALLOWANCE[j] + 1e-12
        p = (1.0 if np.all(a == a[0]) and np.all(b == a[0])
             else float(mannwhitneyu(a, b, alternative='two-sided').pvalue))
        out.append((float(np.mean(a)), float(np.std(a, ddof=1)), float(np.mean(b)),
                    float(np.std(b, ddof=1)), within, p))
    return out


def envelope(runs: Ensemble, converged: Ensemble, y0: float, start: float) -> float:
    """
    Return the fraction of samples from ``start`` where the two ensembles' mean Δy agree.

    Agree: within 2 standard errors of the difference plus ALLOWANCE of y0.
    """
    window = runs.runs[0].t >= start - 1e-9
    mine = np.array([run.dy[window, 0] for run in runs.runs]) / y0
    ref = np.array([run.dy[window, 0] for run in converged.runs]) / y0
    se = np.sqrt(mine.var(axis=0, ddof=1) / len(mine) + ref.var(axis=0, ddof=1) / len(ref))
    gap = np.abs(mine.mean(axis=0) - ref.mean(axis=0))
    return float(np.mean(gap <= 2.0 * se + ALLOWANCE[3] + 1e-12))


def robust_stretch(run, converged_run, end: float | None) -> tuple:
    """
    Return (error, snaps right, parted) of one run (t, q, y) against the converged one.

    Over [0.5 s, ``end``), scored as switching: max |y - y_ref| over the converged run's travel
    from 0.5 s to the end of the run; the snaps as many, each within 2 ms. ``parted``: the
    first time from 0.5 s where |y - y_ref| exceeds 5 % of that travel (None if never).
    """
    t, q, y = run
    _, q_ref, y_ref = converged_run
    after = t >= SWITCHING_START - 1e-9
    travel = float(np.ptp(y_ref[after]))
    stretch = after & (t < (t[-1] + 1.0 if end is None else end) - 1e-9)
    error = float(np.max(np.abs(y - y_ref)[stretch]) / travel)
    made, expected = snap_times(t[stretch], q[stretch]), snap_times(t[stretch], q_ref[stretch])
    right = len(made) == len(expected) and (
        not len(made) or float(np.max(np.abs(made - expected))) <= 2.0e-3)
    beyond = np.nonzero(after & (np.abs(y - y_ref) > 0.05 * travel))[0]
    return error, right, float(t[beyond[0]]) if beyond.size else None


def pinned(scene):
    """
    Return ``scene`` with its stepper named, as 'auto' resolves it at its own tolerance.

    'auto' picks BDF from a tolerance of 1e-3 up (integrators.BDF_MIN_TOLERANCE): a copy whose
    tolerance is drawn below a level's 1e-3 would otherwise run another method.
    """
    return scene.replace(**{'integrator.method': Simulator(scene).method.name})


def _path(runs: Ensemble, scene) -> tuple:
    """Return copy 0 (the scene itself) as (t, q, y): y from Δy and the level's rest y0."""
    run = runs.runs[0]
    return run.t, run.q[:, 0], rest_shortenings(scene)[0] - run.dy[:, 0]


def study(cases, levels_of, copies: int, seed: int = SEED, cache: str = '') -> list:
    """Return one result per case: its robustness and each level's ensemble and comparison."""
    results = []
    for beam, eps_b in cases:
        scene = switching_scene(beam, eps_b)
        volts = pwm_voltage(V_HIGH)
        measured = predictability(scene, volts, SWITCHING_END)
        split = SWITCHING_START if measured.robust else measured.robust_until
        y0 = float(Stroke(Simulator(scene).model).y0[0])
        print(f'{beam} {eps_b:.2f}: {measured.summary()}', flush=True)
        levels = levels_of(beam)
        reference = levels[-1][0]
        ensembles = {}
        for name, overrides in levels + ((NULL, levels[-1][1]),):
            level_scene = pinned(scene.replace(**overrides))
            runs, cpu = run_ensemble(level_scene, volts, SWITCHING_END, copies,
                                     seed + (name == NULL), cache,
                                     f'{beam}_{eps_b:.2f}-{name.split(":")[-1].strip()}')
            ensembles[name] = (runs, cpu, copy_statistics(runs, y0, split),
                               _path(runs, level_scene))
            print(f'  {name}: {copies} copies, {cpu:.1f} s CPU', flush=True)
        ref_runs, _, ref_stats, ref_path = ensembles[reference]
        rows = []
        for name in [n for n, _ in levels[:-1]] + [NULL]:
            runs, cpu, stats, path = ensembles[name]
            rows.append({'level': name, 'cpu_per_run': cpu / copies,
                         'compare': compare(stats, ref_stats),
                         'envelope': envelope(runs, ref_runs, y0, split),
                         'path': (robust_stretch(path, ref_path, measured.robust_until)
                                  if name != NULL else None)})
        results.append({'beam': beam, 'eps_b': eps_b, 'robust_until': measured.robust_until,
                        'split': split, 'reference': reference, 'rows': rows,
                        'reference_cpu': ensembles[reference][1] / copies})
    return results


def _sd(mean: float, sd: float) -> str:
    """Return a standard deviation for a cell: 0 where it is rounding of a constant."""
    return '0' if sd <= 1e-12 * max(1.0, abs(mean)) else f'{sd:.2g}'


def tables(results, copies: int, command: str) -> str:
    """Return the markdown: per case, each level's statistics against the converged level's."""
    reference = results[0]['reference'] if results else ''
    out = [f'Measured {datetime.date.today().isoformat()}, commit {_commit()}, {MACHINE}, by '
           f"`{command}`. The 'pwm' scenario at 3 kV. Per level an ensemble of {copies} "
           f'copies (`analysis.ensemble.ensemble()`, seed {SEED}: copy 0 the scene, copy i the '
           'interface mass × (1 + 1e-6 z_i) and the tolerance × (1 − 0.1 u_i)). Until the '
           'default run stops being robust (`predictability()`) the copies agree and the '
           "stretch is scored as switching (copy 0 against the converged level's copy 0: "
           'max |y − y_ref| over the travel, ✓ every snap within 2 ms; and the time the two '
           'paths are first 5 % of the travel apart, over the whole run); from then to 2.5 s '
           "each copy's statistics: its snap rate (1/s), time on q > 0, q > 0 at the end, and "
           'Δy over y0 (mean, range). A cell: the ensemble mean ± standard deviation, ✓ where '
           'its mean lies within two standard errors of the difference from the mean of the '
           f'converged level ({reference}) plus an allowance (1 % on fractions and on Δy / y0, '
           '0 on the snap rate: the 1 % target and every snap of the map), ✗ where not, and '
           "Mann-Whitney's two-sided p beside it; 'Δy mean': the fraction of samples where the "
           'ensemble mean Δy is within the same bound of the converged mean. The last row, the '
           'converged level again with another seed (its copy 0 shared), is the '
           "test's own false-alarm baseline. CPU: per run, one core.", '']
    for result in results:
        until = ('robust' if result['robust_until'] is None
                 else f'not robust from {result["robust_until"]:.2f} s')
        window = f'{result["split"]:.2f}–2.5 s'
        out += [f'**{result["beam"].replace("_", " ")}, ε_b {result["eps_b"]:.2f}** (the '
                f'default: {until}; statistics over {window})', '',
                '| level | robust stretch: error, snaps | ' + ' | '.join(STATISTICS)
                + ' | Δy mean | CPU s per run | statistics all ✓ |',
                '|---|---|' + '---|' * (len(STATISTICS) + 3)]
        first = result['rows'][0]
        out.append(f'| {result["reference"]} (the reference) | – | '
                   + ' | '.join(f'{c[2]:.3g} ± {_sd(c[2], c[3])}' for c in first['compare'])
                   + f' | – | {result["reference_cpu"]:.2f} | – |')
        for row in result['rows']:
            cells = []
            for mean, sd, _, _, within, p in row['compare']:
                cells.append(f'{mean:.3g} ± {_sd(mean, sd)} {"✓" if within else "✗"} '
                             f'(p {p:.2g})')
            if row['path'] is None:
                path_cell = '–'
            else:
                error, right, parted = row['path']
                path_cell = (f'{error:.2%}, {"✓" if right else "✗"}'
                             + ('' if parted is None else f'; 5 % apart from {parted:.2f} s'))
            everything = all(c[4] for c in row['compare'])
            out.append(f'| {row["level"]} | {path_cell} | ' + ' | '.join(cells)
                       + f' | {row["envelope"]:.0%} | {row["cpu_per_run"]:.2f} | '
                       f'{"yes" if everything else "no"} |')
        out.append('')
    return '\n'.join(out).rstrip()


def main(argv=None) -> int:
    """Run the ensembles, print (and with --docs write) the tables."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='one case, 3 copies, a stand-in')
    ap.add_argument('--copies', type=int, default=COPIES)
    ap.add_argument('--docs', action='store_true',
                    help='write the tables into docs/fidelity.md')
    ap.add_argument('--beam', choices=('fixed', 'simply_supported'), default=None,
                    help="one beam's cases only (not with --docs)")
    ap.add_argument('--cache', default='',
                    help='a folder to keep the ensembles in (a rerun reads them back)')
    args = ap.parse_args(argv)
    if args.quick:
        copies = QUICK['copies']
        results = study([QUICK['case']], lambda beam: QUICK['levels'], copies, cache=args.cache)
    else:
        copies = args.copies
        cases = [c for c in CASES if args.beam in (None, c[0])]
        results = study(cases, LEVELS.get, copies, cache=args.cache)
    text = tables(results, copies, 'flock bench/.lock env PYTHONPATH=. python '
                  'bench/pwm_statistics.py --docs')
    print(text)
    if args.docs and not args.quick and args.beam is None:
        write_doc(text, begin=BEGIN, end=END)
    return 0


if __name__ == '__main__':
    sys.exit(main())
