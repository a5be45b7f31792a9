"""
Work-precision benchmark on the 'step' scenario (scenarios.md): error against CPU time.

Everything is measured side by side in one run: the project's steppers at several substep counts,
scipy's solve_ivp (RK45, DOP853, Radau, BDF, LSODA) restarted every 1 ms control period (zero-order
hold) at several rtol, and python-control's input_output_response. Error: max |Delta-y -
Delta-y_ref| / stroke over the 1 ms samples, reference Radau rtol 1e-12 restarted every period.
Cost: process CPU seconds per simulated second, median of ``--repeats`` runs.

Writes ``work_precision.csv``, ``work_precision.md`` and (with matplotlib) ``work_precision.png``.
Run: ``python bench/work_precision.py --out bench/out`` (about 10 min per scene; ``--quick``: one
scene, fewer points).
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import sys
import time

import numpy as np
from scipy.integrate import solve_ivp

from .model import build_model
from .scenarios import (reference_solution, step_error, step_scene, step_voltage, STEP_END,
                        STEP_SWITCH_TIMES)
from .simulator import simulate, Simulator

__all__ = ['main', 'run_scene']


def _cpu(fn, repeats):
    times, result = [], None
    for _ in range(repeats):
        start = time.process_time()
        result = fn()
        times.append(time.process_time() - start)
    return statistics.median(times), result


def _rhs_for_solvers(model):
    """f(t, x, u) that returns NaN outside the model's domain instead of raising: an implicit
    solver's Newton iterate or a rejected trial step may leave the domain, and scipy's
    solvers answer NaN with a smaller step (an exception would end the run)."""
    nan = np.full(model.n_states, np.nan)

    def f(t, x, u):
        try:
            return model.f(t, x, u)
        except ArithmeticError:
            return nan
    return f


def _scipy_run(model, method, rtol, t_end):
    volts = step_voltage(model.scene.physics.v_max)
    dt = model.scene.dt
    n = int(round(t_end / dt))
    x = model.initial_state()
    scale = np.maximum(np.abs(x), 1e-3)
    X = np.empty((n + 1, model.n_states))
    X[0] = x
    f = _rhs_for_solvers(model)
    for k in range(n):
        u = np.array([volts(k * dt)])
        sol = solve_ivp(lambda t, z: f(t, z, u), (k * dt, (k + 1) * dt), x,
                        method=method, rtol=rtol, atol=rtol * scale * 1e-3)
        if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
            raise ArithmeticError(f'{method} failed at t = {k * dt:g} s: {sol.message}')
        x = sol.y[:, -1]
        X[k + 1] = x
    return X


def _control_run(model, rtol, t_end):
    import control
    volts = step_voltage(model.scene.physics.v_max)
    f = _rhs_for_solvers(model)
    sys_ = control.nlsys(lambda t, x, u, params: f(t, x, u), None,
                         inputs=1, states=model.n_states, outputs=model.n_states)
    dt = model.scene.dt
    samples = np.arange(int(round(t_end / dt)) + 1) * dt
    # python-control interpolates the input linearly between time points: a point 1 ns before
    # every switch makes that a zero-order hold up to a 1 ns ramp
    switches = np.array([ts for ts in STEP_SWITCH_TIMES if ts < t_end])
    t = np.sort(np.concatenate([samples, switches - 1e-9]))
    u = np.array([volts(tk) for tk in t])
    resp = control.input_output_response(sys_, t, u, model.initial_state(),
                                         solve_ivp_method='Radau',
                                         solve_ivp_kwargs={'rtol': rtol, 'atol': rtol * 1e-6})
    keep = np.searchsorted(t, samples)
    return resp.states.T[keep]


def run_scene(beam, eps_b, quick=False, repeats=3, log=print, reference_dir=None):
    """All competitors on one scene; returns a list of result rows (dicts)."""
    scene = step_scene(beam, eps_b)
    model = build_model(scene)
    t_end = STEP_END
    cached = (os.path.join(reference_dir, f'ref_{beam}_{eps_b:g}_rc.npy') if reference_dir
              else None)
    if cached and os.path.exists(cached):
        t, X_ref = np.arange(int(round(t_end / scene.dt)) + 1) * scene.dt, np.load(cached)
        log(f'[{beam} eps_b={eps_b}] reference from {cached}')
    else:
        log(f'[{beam} eps_b={eps_b}] reference (Radau rtol 1e-12) ...')
        t, X_ref = reference_solution(scene, t_end)
        if cached:
            os.makedirs(reference_dir, exist_ok=True)
            np.save(cached, X_ref)
    rows = []

    def add(solver, setting, cpu, X, steps=np.nan):
        err_y, err_q = step_error(model, t, X, X_ref) if X is not None else (np.nan, np.nan)
        rows.append(dict(beam=beam, eps_b=eps_b, solver=solver, setting=setting,
                         cpu_per_sim_s=cpu / t_end, err_dy=err_y, err_qp=err_q,
                         realtime_factor=t_end / cpu, steps_per_period=steps))
        log(f'  {solver:>14} {setting:>10}  cpu/sim-s {cpu / t_end:9.4f}  err {err_y:.2e}')

    volts = step_voltage(scene.physics.v_max)
    reduced = {'ideal source': {'scene.source': 'ideal'}, 'no creep': {'scene.creep': False},
               'no power monitor': {'scene.monitor_power': False}}
    for method, subs in (('etdrk4', (4, 8, 16, 32, 64)), ('lawson5', (8, 16, 32, 64)),
                         ('etd2', (32, 128)), ('rk4', (64, 128, 256))):
        for sub in (subs[1:3] if quick else subs):
            simulate(scene, volts, 0.01, method=method, substeps=sub)   # compile outside timing
            try:
                cpu, r = _cpu(lambda: simulate(scene, volts, t_end, method=method,
                                               substeps=sub), repeats)
                add(method, f'{sub} sub', cpu, r.x)
            except ArithmeticError:
                add(method, f'{sub} sub', np.nan, None)
    # default 'auto' stepper at several tolerances, and the reductions at equal settings
    for tol in ((1e-4, 1e-6) if quick else (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)):
        sc = step_scene(beam, eps_b, **{'integrator.tolerance': tol})
        simulate(sc, volts, 0.01)
        cpu, r = _cpu(lambda: simulate(sc, volts, t_end), repeats)
        counted = Simulator(sc)   # the same run once more, to count its internal steps
        simulate(counted, volts, t_end)
        add('auto', f'tol {tol:g}', cpu, r.x, counted.steps_taken / round(t_end / sc.dt))
    # reductions at the same tolerance (auto picks method and substeps for each model)
    for label, over in {'full model': {}, **reduced}.items():
        sc = step_scene(beam, eps_b, **over)
        simulate(sc, volts, 0.01)
        cpu, r = _cpu(lambda: simulate(sc, volts, t_end), repeats)
        sim = Simulator(sc)
        simulate(sim, volts, t_end)
        rows.append(dict(beam=beam, eps_b=eps_b, solver=f'auto ({label})',
                         setting=f'tol 1e-06, {sim.method.name}',
                         cpu_per_sim_s=cpu / t_end, err_dy=np.nan, err_qp=np.nan,
                         realtime_factor=t_end / cpu,
                         steps_per_period=sim.steps_taken / round(t_end / sc.dt)))
        log(f'  {label:>24}  cpu/sim-s {cpu / t_end:9.4f} (reduced model: own error not shown)')
    for method in ('RK45', 'DOP853', 'Radau', 'BDF', 'LSODA'):
        for rtol in ((1e-6,) if quick else (1e-4, 1e-6, 1e-8)):
            try:
                cpu, X = _cpu(lambda: _scipy_run(model, method, rtol, t_end), 1)
            except (ArithmeticError, ValueError):   # solver failure (domain, NaN Jacobian)
                cpu, X = np.nan, None
            add(f'scipy {method}', f'rtol {rtol:g}', cpu, X)
    try:
        import control  # noqa: F401
    except ImportError:
        log('  python-control not installed: skipped')
    else:
        # input_output_response integrates the whole run with the input interpolated linearly
        # between the 1 ms samples (not a zero-order hold): its error includes that difference
        for rtol in ((1e-6,) if quick else (1e-6, 1e-8)):
            try:
                cpu, X = _cpu(lambda: _control_run(model, rtol, t_end), 1)
            except (ArithmeticError, ValueError):   # solver failure (domain, NaN Jacobian)
                cpu, X = np.nan, None
            add('python-control', f'rtol {rtol:g}', cpu, X)
    return rows


def _write(rows, out):
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, 'work_precision.csv'), 'w', newline='') as stream:
        writer = csv.DictWriter(stream, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    with open(os.path.join(out, 'work_precision.md'), 'w') as stream:
        stream.write('| beam | eps_b | solver | setting | CPU s / sim s | RTF | err Δy | err q_p '
                     '| steps / period |\n')
        stream.write('|---|---|---|---|---|---|---|---|---|\n')
        for r in rows:
            steps = r['steps_per_period']
            stream.write(f"| {r['beam']} | {r['eps_b']} | {r['solver']} | {r['setting']} | "
                         f"{r['cpu_per_sim_s']:.4g} | {r['realtime_factor']:.3g} | "
                         f"{r['err_dy']:.2e} | {r['err_qp']:.2e} | "
                         f"{'' if np.isnan(steps) else f'{steps:.1f}'} |\n")
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print('matplotlib not installed: CSV and markdown written; pip install .[plots] for the PNG')
        return
    fig, ax = plt.subplots(figsize=(7, 5), dpi=90)
    for solver in dict.fromkeys(r['solver'] for r in rows):
        pts = [(r['cpu_per_sim_s'], r['err_dy']) for r in rows
               if r['solver'] == solver and np.isfinite(r['err_dy']) and r['err_dy'] > 0]
        if pts:
            xs, ys = zip(*sorted(pts))
            ax.loglog(xs, ys, 'o-', label=solver)
    ax.set_xlabel('CPU seconds per simulated second')
    ax.set_ylabel('max |Δy − Δy_ref| / stroke')
    ax.set_title('work-precision, step scenario')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out, 'work_precision.png'))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='work_precision', description=__doc__.split('\n')[1])
    parser.add_argument('--out', default='bench/out')
    parser.add_argument('--quick', action='store_true', help='one scene, fewer points')
    parser.add_argument('--beams', default='fixed,simply_supported')
    parser.add_argument('--eps-b', default='0.15,0.20,0.25')
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--reference-dir', default=None,
                        help='cache the Radau references here (about a minute each)')
    args = parser.parse_args(argv)
    beams = args.beams.split(',')
    eps = [float(e) for e in args.eps_b.split(',')]
    if args.quick:
        beams, eps = beams[:1], [0.20]
    rows = []
    for beam in beams:
        for e in eps:
            rows += run_scene(beam, e, args.quick, args.repeats,
                              log=lambda s: print(s, file=sys.stderr, flush=True),
                              reference_dir=args.reference_dir)
            _write(rows, args.out)   # after every scene: a long run keeps what it measured
    _write(rows, args.out)
    print(f'wrote {args.out}/work_precision.{{csv,md,png}}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
