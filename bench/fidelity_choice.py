"""
How to choose the fidelity: each level's error against the converged reference and its cost.

On the three 'step' cases of bench/continuum_reference.py (fixed beam eps_b 0.15 and 0.20,
simply supported 0.20; released from q0, 3 kV from 1.5 s to 3.0 s, 4.5 s), for each of LEVELS
(the shipped default, 'auto': per beam its Ritz family and terms), each run through
``simulate()`` with the scene's integrator (auto, at the level's own tolerance:
integrator.tolerance 0, AUTO_TOLERANCE):

- the max |dy - dy_ref| over the 3 kV phase as a fraction of the stroke (the travel of the beam
  end over the run, max y_ref - min y_ref: from the released, nearly straight start to the
  buckled rest state), and of the stricter peak displacement (max |dy_ref| over the 3 kV phase),
  dy_ref from the stored reference (exact kinematics, n_r 11, rtol 1e-10);
- whether the beam switches (sign of q at the end of the 3 kV phase against its start) as the
  reference does;
- CPU seconds per simulated second (time.process_time, median of 3 runs when a run takes under
  2 s, else one) and the real-time factor (simulated s per CPU s); internal steps per period.

Then the shipped scenes (default, plate, array of 100 on two threads) at the paper's level and
as shipped, 1 s at rest and 1 s through a 3 kV step: real-time factor (wall clock) and steps
per period per coupled group.

Prints the smallest 'exact' n_r within 1 % on all three cases (by either scale) and writes the
"How to choose" section of docs/fidelity.md (between its markers) with date, commit and machine.
Run it under the bench lock on a quiet host:

    flock bench/.lock env PYTHONPATH=. python bench/fidelity_choice.py [--no-docs]

``--quick``: the shipped default level only, one run per case, the default scene only, docs/
left alone (a smoke run).
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import subprocess
import sys
import time

from continuum_reference import (case_name, CASES, load_reference, peak_displacement, stroke,
                                 stroke_error, switched)
from det_sim_ros.analysis.scenarios import delta_y, STEP_END, step_scene, step_voltage
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.integrators import integration_tolerance
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np

POLY, MODES = 'polynomial', 'buckling_modes'
# (fidelity, Ritz family, terms); ('exact', 'auto', 0) is the shipped default
LEVELS = (('paper', POLY, 1), ('consistent', POLY, 3), ('consistent', POLY, 5),
          ('exact', POLY, 3), ('exact', POLY, 5), ('exact', POLY, 7), ('exact', POLY, 9),
          ('exact', MODES, 3), ('exact', MODES, 4), ('exact', 'auto', 0))
SCENES = (('default', 1), ('plate', 1), ('array', 2))   # shipped scenes, stepping threads
SCENE_RUN = 1.0         # s simulated per shipped-scene run
LIMIT = 0.01            # of the stroke: the default level must stay within it on every case
MACHINE = '2-core x86-64 VM'
HERE = os.path.dirname(os.path.abspath(__file__))
DOC = os.path.join(HERE, os.pardir, 'docs', 'fidelity.md')
BEGIN, END = '<!-- fidelity_choice: begin -->', '<!-- fidelity_choice: end -->'


def run_level(beam, eps_b, fidelity, n_r, repeats=3, shapes=POLY, **overrides):
    """
    Return (run, CPU s per run, internal steps per period) of one case at one level.

    CPU: the median of ``repeats`` runs when the first takes under 2 s, else that one.
    ``overrides``: further scene keys (``{'integrator.tolerance': 1e-4}``).
    """
    scene = step_scene(beam, eps_b, **{'scene.fidelity': fidelity, 'scene.n_ritz': n_r,
                                       'scene.shapes': shapes, **overrides})
    voltage = step_voltage(scene.physics.v_max)
    times = []
    while len(times) < (repeats if not times or times[0] < 2.0 else 1):
        sim = Simulator(scene)
        start = time.process_time()
        run = simulate(sim, voltage, STEP_END)
        times.append(time.process_time() - start)
        run.scene = scene
        run.periods_repeated = sim.stepper.periods_repeated
    periods = round(STEP_END / scene.dt)
    return run, statistics.median(times), sim.steps_taken / periods


def study(reference, levels=LEVELS, repeats=3):
    """Return one row per level: errors, switching and cost per case."""
    rows = []
    for fidelity, shapes, n_r in levels:
        level = {'scene.fidelity': fidelity, 'scene.n_ritz': n_r, 'scene.shapes': shapes}
        row = {'fidelity': fidelity, 'n_r': n_r, 'shapes': shapes, 'error': [],
               'error_peak': [], 'switch_ok': [], 'cpu': [], 'steps': [], 'labels': [],
               'tolerance': [integration_tolerance(step_scene(beam, eps_b, **level))
                             for beam, eps_b in CASES]}
        for beam, eps_b in CASES:
            ref = reference[case_name(beam, eps_b)]
            run, cpu, steps = run_level(beam, eps_b, fidelity, n_r, repeats, shapes=shapes)
            row['labels'].append(run.scene.fidelity_label)
            dy, _ = delta_y(run.t, run['y'], run.scene.beam_length)
            row['error'].append(stroke_error(run.t, dy, ref['dy'], stroke(ref['y'])))
            row['error_peak'].append(stroke_error(run.t, dy, ref['dy'],
                                                  peak_displacement(ref['t'], ref['dy'])))
            row['switch_ok'].append(switched(run.t, run['q']) == switched(ref['t'], ref['q']))
            row['cpu'].append(cpu / STEP_END)
            row['steps'].append(steps)
            outcome = 'right' if row['switch_ok'][-1] else 'WRONG'
            print(f'  {run.scene.fidelity_label} {case_name(beam, eps_b)}: error '
                  f'{row["error"][-1]:.2%} ({row["error_peak"][-1]:.2%} of the peak), '
                  f'switching {outcome}, {cpu / STEP_END:.3f} CPU s/s, '
                  f'{steps:.1f} steps/period', flush=True)
        rows.append(row)
    return rows


def _scene_run(name, overrides, volts, threads):
    """Return (wall s per simulated s, steps per period per group) of 1 s of a shipped scene."""
    scene = load_scene(name, overrides)
    sim = Simulator(scene, threads=threads)
    profile = np.array([volts(k * scene.dt) for k in range(round(SCENE_RUN / scene.dt))])
    start = time.perf_counter()
    simulate(sim, np.repeat(profile[:, None], scene.n_dets, axis=1), SCENE_RUN)
    wall = (time.perf_counter() - start) / SCENE_RUN
    return wall, sim.steps_taken / len(profile) / sim.model.arrays.n_groups


def scene_costs(scenes=SCENES):
    """Return markdown rows: each shipped scene at rest and through a 3 kV step, both levels."""
    profiles = (lambda t: 0.0, lambda t: 3000.0 * (0.2 <= t < 0.6))   # at rest; a 3 kV step
    lines = []
    for name, threads in scenes:
        for level, overrides in (('paper', {'scene.fidelity': 'paper'}), ('shipped', {})):
            cells = []
            for volts in profiles:
                wall, steps = _scene_run(name, overrides, volts, threads)
                cells.append(f'{1 / wall:.3g} | {steps:.0f}')
            label = level if level == 'paper' else load_scene(name).fidelity_label
            print(f'  {name} {label}: ' + '; '.join(cells), flush=True)
            lines.append(f'| {name} ({threads} thread{"s" if threads > 1 else ""}) | {label} | '
                         + ' | '.join(cells) + ' |')
    head = ['', f'The shipped scenes themselves ({SCENE_RUN:g} s simulated through '
            '`simulate()`, wall clock; × real time is what a free-running node could reach; '
            'steps per period per coupled group: the plate is one, each copy of the array one):',
            '',
            '| scene | level | × real time at rest | steps | × real time, 3 kV 0.2–0.6 s '
            '| steps |',
            '|---|---|---|---|---|---|']
    return '\n'.join(head + lines)


def choice(rows, key='error'):
    """Return the smallest exact polynomial n_r within LIMIT on every case (None if none)."""
    ok = [r['n_r'] for r in rows
          if r['fidelity'] == 'exact' and r['shapes'] == POLY and max(r[key]) <= LIMIT]
    return min(ok) if ok else None


def _commit() -> str:
    try:
        return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True,
                              text=True, check=True, cwd=HERE).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


def _range_mm(values) -> str:
    return f'{min(values) * 1e3:.1f}–{max(values) * 1e3:.1f} mm'


def table(rows, reference) -> str:
    """Return the markdown "How to choose" table with its provenance line."""
    meta = reference['meta']
    cases = [reference[case_name(b, e)] for b, e in CASES]
    strokes = _range_mm([stroke(c['y']) for c in cases])
    peaks = _range_mm([peak_displacement(c['t'], c['dy']) for c in cases])
    names = ', '.join(f'{b.replace("_", " ")} {e:.2f}' for b, e in CASES)
    lines = [f'Measured {datetime.date.today().isoformat()}, commit {_commit()}, {MACHINE}, by '
             '`flock bench/.lock env PYTHONPATH=. python bench/fidelity_choice.py` (CPU times '
             f'vary ±30 %; ratios between rows are side by side in one run). Cases: {names}; '
             'error = max |Δy − Δy_ref| over the 3 kV phase as a fraction of the stroke (the '
             'travel of the beam end over the run, from the released '
             f'start to the buckled rest state: {strokes}) and, in parentheses, of the peak '
             f'displacement in the 3 kV phase (max |Δy_ref|: {peaks}); '
             f'Δy_ref the exact kinematics at n_r {meta["n_ritz"]}, tolerance {meta["rtol"]:g} '
             '(bench/continuum_reference.py); integrator: auto at the own tolerance of each level '
             '(`integrator.tolerance: 0`, the table in det_sim_ros/sim/integrators.py).', '',
             '| level | tolerance | '
             + ' | '.join(f'error {b.replace("_", " ")} {e:.2f}' for b, e in CASES)
             + ' | switching right | CPU s per simulated s | × real time | steps per period |',
             '|---|---|' + '---|' * (len(CASES) + 4)]
    for r in rows:
        level = ' / '.join(dict.fromkeys(r['labels']))
        if r['shapes'] == 'auto':
            level = f'default ({level})'
        tolerance = ' / '.join(f'{t:g}' for t in dict.fromkeys(r['tolerance']))
        cpu_lo, cpu_hi = min(r['cpu']), max(r['cpu'])
        lines.append(f'| {level} | {tolerance} | '
                     + ' | '.join(f'{e:.2%} ({p:.2%})'
                                  for e, p in zip(r['error'], r['error_peak']))
                     + f' | {sum(r["switch_ok"])} of {len(CASES)}'
                     + f' | {cpu_lo:.3g}–{cpu_hi:.3g} | {1 / cpu_hi:.3g}–{1 / cpu_lo:.3g}'
                     + ' | ' + '–'.join(f'{s:.0f}' for s in (min(r['steps']), max(r['steps'])))
                     + ' |')
    return '\n'.join(lines)


def _dated(meta) -> str:
    """Return ', <date>' for the stored reference: its own date, else its commit's."""
    if meta.get('date'):
        return f', {meta["date"]}'
    try:
        day = subprocess.run(['git', 'show', '-s', '--format=%cs', meta['commit']],
                             capture_output=True, text=True, check=True, cwd=HERE).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ''
    return f' (of {day})' if day else ''


def convergence_table(meta) -> str:
    """Return the reference's convergence check (stored with it) as markdown."""
    lines = [f'The reference\'s own convergence ({meta["solver"]}; computed at commit '
             f'{meta["commit"]}{_dated(meta)} by `python bench/continuum_reference.py`): the same '
             'error measure against the stored reference, exact n_r '
             f'{meta["n_ritz"]} at tolerance {meta["rtol"]:g}.', '',
             '| case | n_r | tolerance | CPU s | error | switched (step) / snaps |',
             '|---|---|---|---|---|---|']
    for name, n_r, rtol, cpu, error, outcome in meta['convergence']:
        if (n_r, rtol) != (meta['n_ritz'], meta['rtol']):
            lines.append(f'| {name.replace("_", " ")} | {n_r} | {rtol:g} | {cpu:g} | '
                         f'{error:.1e} | {outcome} |')
    return '\n'.join(lines)


def write_doc(text: str, path: str = DOC, begin: str = BEGIN, end: str = END) -> None:
    """Replace the text between the markers ``begin`` and ``end`` of docs/fidelity.md."""
    with open(path, encoding='utf-8') as fh:
        doc = fh.read()
    head, rest = doc.split(begin, 1)
    _, tail = rest.split(end, 1)
    with open(path, 'w', encoding='utf-8') as fh:
        fh.write(f'{head}{begin}\n{text}\n{end}{tail}')


def main(argv=None) -> int:
    """Run the study, print the table and the choice, and write the docs section."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--no-docs', action='store_true', help='print only; leave docs/ alone')
    ap.add_argument('--quick', action='store_true',
                    help='the default level, one run per case, the default scene; no docs')
    args = ap.parse_args(argv)
    levels, repeats, scenes = LEVELS, 3, SCENES
    if args.quick:
        levels, repeats, scenes, args.no_docs = LEVELS[-1:], 1, SCENES[:1], True
    reference = load_reference()
    simulate(Simulator(step_scene('fixed', 0.20)), np.zeros(10), 0.01)   # warm up
    rows = study(reference, levels, repeats)
    text = (table(rows, reference) + '\n' + scene_costs(scenes) + '\n\n'
            + convergence_table(reference['meta']))
    print(text)
    print(f'smallest exact n_r within {LIMIT:.0%} of the stroke on all cases: '
          f'{choice(rows)}; of the peak displacement: {choice(rows, "error_peak")}')
    if not args.no_docs:
        write_doc(text)
        print(f'wrote the table into {os.path.normpath(DOC)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
