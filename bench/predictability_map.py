"""
Where the path is predictable: drive frequency x eps_b x beam, the time until it is not robust.

Every case is the 'switching' scene at the default level (released at 0 V; from 0.5 s to 2.5 s
a 3 kV / 0 V drive), under two drives at each frequency of FREQUENCIES:

- 'square': a 50 % square wave (``analysis.scenarios.switching_voltage``);
- 'pwm': the PWM of the 'pwm' scenario at that carrier (duty 30 %, 50 %, 70 %, 50 % for 0.5 s
  each, ``analysis.scenarios.pwm_voltage``).

Per case, ``analysis.predictability.predictability()`` with its stated twin (interface mass
x (1 + 1e-6), tolerance x 0.9): the time the path first stopped being robust (the twin beyond
5 % of the stroke; empty: robust over the whole run) and the twin's largest distance; and a
second twin of another kind (the mass 1 ppm lighter, the tolerance left): whether the verdict
depends on the twin picked. The snaps (sign changes of q from 0.5 s) of the run.

The cost of the measure: the CPU of ``predictability()`` against one ``simulate()`` of the same
case from the same scene, run side by side (alternating, REPEATS pairs, medians; the ratio per
case and its median over the cases).

Writes bench/data/predictability_map.csv (one row per case), prints the markdown tables, and
with ``--docs`` rewrites their section of docs/fidelity.md. Under the bench lock:

    flock bench/.lock env PYTHONPATH=. python bench/predictability_map.py [--quick] [--docs]

--quick: 2 and 10 Hz, eps_b 0.20, one pair per case (seconds; the CSV into a temporary file
unless --out names one; --docs is ignored).
--level refined: the same map at a refined level (exact kinematics, polynomial n_r 9 at
tolerance 1e-4, within 0.11 % of the converged beam on the step and 2 Hz cases; the predictability
only, no cost pairs; bench/data/predictability_map_refined.csv): whether a verdict is the
beam's or the default level's.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import os
import statistics
import sys
import tempfile
import time

from det_sim_ros.analysis.predictability import Perturbation, predictability
from det_sim_ros.analysis.scenarios import (pwm_voltage, snap_times, SWITCHING_END,
                                            switching_scene, switching_voltage)
from det_sim_ros.sim.simulator import simulate
from fidelity_choice import _commit, MACHINE, write_doc
import numpy as np

FREQUENCIES = (1.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0)   # Hz
QUICK_FREQUENCIES = (2.0, 10.0)
EPS_B = (0.15, 0.20)
BEAMS = ('fixed', 'simply_supported')
DRIVES = ('square', 'pwm')
V_HIGH = 3000.0      # V
REPEATS = 3          # side-by-side pairs of (simulate, predictability) per case
SECOND_TWIN = Perturbation(relative=-1e-6, tolerance_factor=1.0)
LEVELS = {'default': {},
          'refined': {'scene.fidelity': 'exact', 'scene.shapes': 'polynomial',
                      'scene.n_ritz': 9, 'integrator.tolerance': 1e-4}}
HERE = os.path.dirname(os.path.abspath(__file__))
CSV = os.path.join(HERE, 'data', 'predictability_map.csv')
BEGIN, END = '<!-- predictability_map: begin -->', '<!-- predictability_map: end -->'
FIELDS = ('beam', 'eps_b', 'drive', 'hz', 'robust_until', 'peak', 'stretches',
          'second_robust_until', 'second_peak', 'snaps', 'cpu_simulate', 'cpu_predictability',
          'ratio')


def drive_volts(drive: str, hz: float, dt: float) -> np.ndarray:
    """Return the per-period volts of one drive at ``hz`` over the run."""
    voltage = (switching_voltage if drive == 'square' else pwm_voltage)(V_HIGH, hz)
    return np.array([voltage(k * dt) for k in range(int(round(SWITCHING_END / dt)))])


def run_case(beam: str, eps_b: float, drive: str, hz: float, repeats: int,
             level: str = 'default') -> dict:
    """
    Return the row of one case: its robustness under both twins, its snaps, the costs.

    ``repeats`` 0: the stated twin only, no cost pairs (the second twin's and the cost columns
    empty).
    """
    scene = switching_scene(beam, eps_b, **LEVELS[level])
    volts = drive_volts(drive, hz, scene.dt)
    cpu_sim, cpu_pred = [], []
    for _ in range(repeats):   # side by side: the host's load moves both alike
        start = time.process_time()
        simulate(scene, volts, SWITCHING_END)
        cpu_sim.append(time.process_time() - start)
        start = time.process_time()
        measured = predictability(scene, volts, SWITCHING_END)
        cpu_pred.append(time.process_time() - start)
    if not repeats:
        measured = predictability(scene, volts, SWITCHING_END)
        second = measured
    else:
        second = predictability(scene, volts, SWITCHING_END, SECOND_TWIN)
    nan = float('nan')
    sim_s, pred_s = ((statistics.median(cpu_sim), statistics.median(cpu_pred)) if repeats
                     else (nan, nan))
    return {'beam': beam, 'eps_b': eps_b, 'drive': drive, 'hz': hz,
            'robust_until': '' if measured.robust else measured.robust_until,
            'peak': float(np.max(measured.distance)), 'stretches': len(measured.stretches),
            'second_robust_until': '' if second.robust else second.robust_until,
            'second_peak': float(np.max(second.distance)),
            'snaps': len(snap_times(measured.t, measured.run['q'])),
            'cpu_simulate': sim_s, 'cpu_predictability': pred_s, 'ratio': pred_s / sim_s}


def _until(value) -> str:
    return 'robust' if value in ('', None) else f'{float(value):.2f} s'


def _rows_of(rows):
    out = []
    for r in rows:
        r = dict(r)
        for key in ('eps_b', 'hz', 'peak', 'second_peak', 'cpu_simulate', 'cpu_predictability',
                    'ratio'):
            r[key] = float(r[key])
        r['stretches'], r['snaps'] = int(r['stretches']), int(r['snaps'])
        out.append(r)
    return out


def _robust(row) -> bool:
    return row['robust_until'] in ('', None)


def tables(rows, command: str, level: str = 'default', refined=None) -> str:
    """
    Return the markdown: the time until not robust per case, then the measure's cost.

    ``refined``: the rows of the same map at the refined level: ‡ marks a verdict it reverses.
    """
    rows = _rows_of(rows)
    refined = {(r['beam'], r['eps_b'], r['drive'], r['hz']): r
               for r in _rows_of(refined or [])}
    paired = bool(rows) and all(r['ratio'] == r['ratio'] for r in rows)
    freqs = sorted({r['hz'] for r in rows})
    out = [f'Measured {datetime.date.today().isoformat()}, commit {_commit()}, {MACHINE}, by '
           f'`{command}`. The {level} level; released at 0 V, from 0.5 s to 2.5 s a 3 kV / 0 V '
           "square wave (50 %) or the 'pwm' scenario's PWM (duty 30, 50, 70, 50 % for 0.5 s "
           'each) at each frequency. A cell: the time the path first stopped being robust '
           "(`predictability()`'s twin, interface mass × (1 + 1e-6) and tolerance × 0.9, "
           'beyond 5 % of the stroke), "robust" if never over the 2.5 s; the snaps of the run '
           'in parentheses'
           + ('; † where a second twin (mass × (1 − 1e-6), tolerance left) gives the other '
              'verdict' if paired else '')
           + ('; ‡ where the refined level (exact, polynomial n_r 9 at 1e-4: `--level '
              'refined`) gives the other verdict' if refined else '') + '.', '',
           '| beam | ε_b | drive | ' + ' | '.join(f'{f:g} Hz' for f in freqs) + ' |',
           '|---|---|---|' + '---|' * len(freqs)]
    keys = sorted({(r['beam'], r['eps_b'], r['drive']) for r in rows},
                  key=lambda k: (BEAMS.index(k[0]), k[1], DRIVES.index(k[2])))
    for beam, eps_b, drive in keys:
        cells = []
        for f in freqs:
            r = next((r for r in rows if (r['beam'], r['eps_b'], r['drive'], r['hz'])
                      == (beam, eps_b, drive, f)), None)
            if r is None:
                cells.append('–')
                continue
            disagree = paired and _robust(r) != (r['second_robust_until'] in ('', None))
            other = refined.get((beam, eps_b, drive, f))
            bold = '' if _robust(r) else '**'
            cells.append(f'{bold}{_until(r["robust_until"])}{bold}'
                         f'{" †" if disagree else ""}'
                         f'{" ‡" if other and _robust(other) != _robust(r) else ""}'
                         f' ({r["snaps"]})')
        out.append(f'| {beam.replace("_", " ")} | {eps_b:.2f} | {drive} | '
                   + ' | '.join(cells) + ' |')
    robust = sum(_robust(r) for r in rows)
    disagree = sum(_robust(r) != (r['second_robust_until'] in ('', None)) for r in rows)
    reversed_ = [r for r in rows if (r['beam'], r['eps_b'], r['drive'], r['hz']) in refined
                 and _robust(refined[(r['beam'], r['eps_b'], r['drive'], r['hz'])])
                 != _robust(r)]
    out += ['', f'{robust} of {len(rows)} cases robust'
            + (f'; the second twin gives the other verdict in {disagree}' if paired else '')
            + (f'; the refined level in {len(reversed_)} (robust there in '
               f'{sum(_robust(refined[k]) for k in refined)} of {len(refined)})'
               if refined else '') + '.']
    if not paired:
        return '\n'.join(out)
    out += ['', 'The cost of the measure: CPU of `predictability()` (the run, its twin, the '
            'distances) over one `simulate()` of the same case from the same scene, the median '
            'of side-by-side pairs, per beam and drive over its frequencies and ε_b:', '',
            '| beam | drive | simulate() CPU s (2.5 s run) | predictability() CPU s | '
            'ratio: median (range) |', '|---|---|---|---|---|']
    for beam in BEAMS:
        for drive in DRIVES:
            mine = [r for r in rows if r['beam'] == beam and r['drive'] == drive
                    and r['ratio'] == r['ratio']]
            if not mine:
                continue
            ratios = [r['ratio'] for r in mine]
            out.append(f'| {beam.replace("_", " ")} | {drive} | '
                       f'{statistics.median(r["cpu_simulate"] for r in mine):.3f} | '
                       f'{statistics.median(r["cpu_predictability"] for r in mine):.3f} | '
                       f'{statistics.median(ratios):.2f} ({min(ratios):.2f}–{max(ratios):.2f}) |')
    return '\n'.join(out)


def read_csv(path=CSV):
    """Return the rows of a written map."""
    with open(path, encoding='utf-8') as fh:
        return list(csv.DictReader(fh))


def main(argv=None) -> int:
    """Run the map, write the CSV, print (and with --docs write) the tables."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='2 and 10 Hz, eps_b 0.20, one pair')
    ap.add_argument('--docs', action='store_true',
                    help='write the tables into docs/fidelity.md')
    ap.add_argument('--tables-only', action='store_true', help='print the tables from the CSV')
    ap.add_argument('--level', choices=tuple(LEVELS), default='default',
                    help='refined: polynomial n_r 9 at 1e-4, no cost pairs')
    ap.add_argument('--out', default=None)
    args = ap.parse_args(argv)
    if args.out is None:   # a quick run writes nothing into the repository
        args.out = (os.path.join(tempfile.mkdtemp(prefix='predictability_map_'), 'quick.csv')
                    if args.quick else CSV if args.level == 'default'
                    else CSV.replace('.csv', f'_{args.level}.csv'))
    if args.level != 'default':
        args.docs = False   # the docs quote the refined level's verdicts beside the default's
    command = 'flock bench/.lock env PYTHONPATH=. python bench/predictability_map.py --docs'
    refined = CSV.replace('.csv', '_refined.csv')
    refined = read_csv(refined) if args.level == 'default' and os.path.exists(refined) else None
    if args.tables_only:
        text = tables(read_csv(args.out), command, args.level, refined)
    else:
        freqs = QUICK_FREQUENCIES if args.quick else FREQUENCIES
        eps_bs = (0.20,) if args.quick else EPS_B
        repeats = 0 if args.level != 'default' else 1 if args.quick else REPEATS
        simulate(switching_scene('fixed', 0.20), np.zeros(10), 0.01)   # warm up
        rows = []
        for beam in BEAMS:
            for eps_b in eps_bs:
                for drive in DRIVES:
                    for hz in freqs:
                        row = run_case(beam, eps_b, drive, hz, repeats, args.level)
                        rows.append(row)
                        print(f'  {beam:>16} {eps_b:.2f} {drive:>6} {hz:4g} Hz: '
                              f'{_until(row["robust_until"]):>8} (peak {row["peak"]:.1%}; '
                              f'second {_until(row["second_robust_until"])}) '
                              f'{row["snaps"]} snaps, cost x{row["ratio"]:.2f}', flush=True)
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, 'w', encoding='utf-8', newline='') as fh:
            writer = csv.DictWriter(fh, FIELDS)
            writer.writeheader()
            writer.writerows(rows)
        print(f'wrote {os.path.normpath(args.out)}')
        text = tables([{k: str(v) for k, v in r.items()} for r in rows], command, args.level,
                      refined)
    print(text)
    if args.docs and not args.quick:
        write_doc(text, begin=BEGIN, end=END)
    return 0


if __name__ == '__main__':
    sys.exit(main())
