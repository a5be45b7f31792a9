"""
Converged reference of the three 'step' cases: the exact kinematics at many Ritz terms.

The cases: fixed beam eps_b 0.15 and 0.20, simply supported eps_b 0.20; released from q0, 0 V,
3 kV from 1.5 s to 3.0 s, 0 V to 4.5 s, sampled at 1 kHz. The model is the simulator's own
'exact' kinematics (w' = sin theta, no truncation) with n_r Ritz terms, its right-hand side
the compiled kernel's (``Model.f``), integrated by LSODA (scipy's odeint: stiff BDF
formulas with their Jacobian by differences; the stiff beam modes, decay rates up to ~1e8 1/s
at n_r 11, do not limit its step) at a relative tolerance ``rtol`` (absolute: rtol times each
state's scale), one solve per constant voltage, the 1 ms samples from its interpolant (of the
order of its steps). A Radau solve of the first 0.3 s at n_r 11 agrees with it to 5e-9 of the
deflection; LSODA is 7x faster there (its step loop is compiled).

Convergence: n_r 9, 11 and 12 at rtol 1e-10, and n_r 11 at rtol 1e-9 and 1e-11, compared by
the max |dy - dy'| over the 3 kV phase as a fraction of the stroke (the travel of the beam end
over the run, max y - min y of the reference); the reference stored is n_r 11 at 1e-10, with
this table in its 'meta'.

Writes bench/data/continuum_reference.npz (t, and per case y, dy, q; its settings in 'meta')
and prints the convergence table:

    PYTHONPATH=. python bench/continuum_reference.py [--quick] [--out bench/data]

--quick: n_r 9 at rtol 1e-9 only (a smoke run; the file is not written).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

from det_sim_ros.analysis.scenarios import (delta_y, STEP_END, step_scene, STEP_SWITCH_TIMES,
                                            step_voltage)
from det_sim_ros.physics.model import build_model
from det_sim_ros.physics.statics import initial_state
import numpy as np
from scipy.integrate import odeint

CASES = (('fixed', 0.15), ('fixed', 0.20), ('simply_supported', 0.20))
REFERENCE_N_R = 11
REFERENCE_RTOL = 1e-10
DATA_FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'data',
                         'continuum_reference.npz')


def case_name(beam: str, eps_b: float) -> str:
    """Return the key of a case in the reference file, e.g. 'fixed_0.20'."""
    return f'{beam}_{eps_b:.2f}'


def _state_scale(model) -> np.ndarray:
    """Return a typical magnitude of each state, for the absolute tolerance."""
    p = model.scene.physics
    scale = {'q_dot': 1.0, 'q_p': p.C0 * p.v_max, 'q[': 0.01, 'eps_E': 0.01}
    return np.array([next(v for k, v in scale.items() if name.startswith(k))
                     for name in model.state_names])


def solve_case(beam: str, eps_b: float, n_r: int, rtol: float) -> dict:
    """Return the 1 kHz samples t, y, q, dy of one case (exact kinematics, n_r terms)."""
    scene = step_scene(beam, eps_b, **{'scene.fidelity': 'exact', 'scene.n_ritz': n_r,
                                       'scene.monitor_power': False})
    model = build_model(scene)
    v_max = scene.physics.v_max
    t = np.arange(int(round(STEP_END / scene.dt)) + 1) * scene.dt
    atol = rtol * _state_scale(model)
    X = np.empty((len(t), model.n_states))
    x = initial_state(model)
    edges = [0] + [int(np.searchsorted(t, s - 1e-9)) for s in STEP_SWITCH_TIMES] + [len(t) - 1]
    for first, last in zip(edges[:-1], edges[1:]):   # one solve per constant voltage
        u = np.array([step_voltage(v_max)(t[first])])
        X[first:last + 1], info = odeint(lambda z, _t: model.f(0.0, z, u), x, t[first:last + 1],
                                         rtol=rtol, atol=atol, mxstep=10 ** 6,
                                         full_output=True)
        if info['message'] != 'Integration successful.':
            raise RuntimeError(f'{beam} {eps_b} n_r {n_r}: {info["message"]}')
        x = X[last]
    zero = np.zeros(1)
    out = np.array([model.output_vector(s, zero) for s in X])
    y = out[:, model.output_names.index('y')]
    q = out[:, model.output_names.index('q')]
    dy, _ = delta_y(t, y, scene.beam_length)
    return {'t': t, 'y': y, 'q': q, 'dy': dy}


def high_phase(t) -> np.ndarray:
    """Return the mask of the 3 kV phase, 1.5 s <= t <= 3.0 s."""
    return (t >= STEP_SWITCH_TIMES[0] - 1e-9) & (t <= STEP_SWITCH_TIMES[1] + 1e-9)


def stroke(y_ref) -> float:
    """
    Return the stroke of a run: the travel of the beam end, max y_ref - min y_ref, m.

    From the released, nearly straight start (y ~ 0) to the buckled rest state: the scale the
    1 % target is stated on.
    """
    return float(np.max(y_ref) - np.min(y_ref))


def peak_displacement(t, dy_ref) -> float:
    """Return max |dy_ref| over the 3 kV phase, m: a stricter scale than the stroke."""
    return float(np.max(np.abs(dy_ref[high_phase(t)])))


def stroke_error(t, dy, dy_ref, scale) -> float:
    """Return max |dy - dy_ref| over the 3 kV phase over ``scale`` (the stroke, say)."""
    mask = high_phase(t)
    return float(np.max(np.abs(dy[mask] - dy_ref[mask])) / scale)


def switched(t, q) -> bool:
    """Return whether the sign of q at the end of the 3 kV phase differs from its start."""
    i0 = int(np.searchsorted(t, STEP_SWITCH_TIMES[0] - 1e-9))
    i1 = int(np.searchsorted(t, STEP_SWITCH_TIMES[1] - 1e-9))
    return bool(np.sign(q[i1]) != np.sign(q[i0]))


def load_reference(path: str = DATA_FILE) -> dict:
    """Return {case name: {'t', 'y', 'q', 'dy'}} and 'meta' from the stored reference."""
    with np.load(path) as data:
        t = data['t']
        ref = {}
        for beam, eps_b in CASES:
            name = case_name(beam, eps_b)
            ref[name] = {'t': t, **{k: data[f'{name}/{k}'] for k in ('y', 'q', 'dy')}}
        ref['meta'] = json.loads(str(data['meta']))
    return ref


def _commit() -> str:
    try:
        return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True,
                              text=True, check=True,
                              cwd=os.path.dirname(os.path.abspath(__file__))).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


def main(argv=None) -> int:
    """Compute the reference and its convergence checks; write the data file."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true')
    ap.add_argument('--out', default=os.path.dirname(DATA_FILE))
    args = ap.parse_args(argv)
    runs = [(REFERENCE_N_R, REFERENCE_RTOL), (9, REFERENCE_RTOL), (12, REFERENCE_RTOL),
            (REFERENCE_N_R, 1e-9), (REFERENCE_N_R, 1e-11)]
    if args.quick:
        runs = [(9, 1e-9)]
    print('| case | n_r | rtol | CPU s | max |dy - dy_ref| / stroke | switched |')
    print('|---|---|---|---|---|---|')
    results, convergence = {}, []
    for beam, eps_b in CASES:
        name = case_name(beam, eps_b)
        for n_r, rtol in runs:
            start = time.process_time()
            run = solve_case(beam, eps_b, n_r, rtol)
            cpu = time.process_time() - start
            results[(name, n_r, rtol)] = run
            ref = results[(name, *runs[0])]
            error = stroke_error(run['t'], run['dy'], ref['dy'], stroke(ref['y']))
            row = [name, n_r, rtol, round(cpu, 1), error, switched(run['t'], run['q'])]
            convergence.append(row)
            print(f'| {name} | {n_r} | {rtol:.0e} | {cpu:.1f} | {row[4]:.2e} | '
                  f'{"yes" if row[5] else "no"} |', flush=True)
    if args.quick:
        return 0
    arrays = {'t': results[(case_name(*CASES[0]), *runs[0])]['t']}
    for beam, eps_b in CASES:
        name = case_name(beam, eps_b)
        for key in ('y', 'q', 'dy'):
            arrays[f'{name}/{key}'] = results[(name, *runs[0])][key]
    meta = {'fidelity': 'exact', 'n_ritz': REFERENCE_N_R, 'rtol': REFERENCE_RTOL,
            'solver': 'scipy odeint (LSODA) on Model.f, one solve per constant voltage',
            'commit': _commit(), 'cases': [case_name(b, e) for b, e in CASES],
            'convergence': convergence}
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, os.path.basename(DATA_FILE))
    np.savez_compressed(path, meta=json.dumps(meta), **arrays)
    print(f'wrote {path} ({os.path.getsize(path) / 1e3:.0f} kB)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
