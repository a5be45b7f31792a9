"""
Work-precision benchmark on the 'step' scenario (scenarios.md): error against CPU time.

Everything is measured side by side in one run: the project's steppers at several substep counts,
scipy's solve_ivp (RK45, DOP853, Radau, BDF, LSODA) two ways, and python-control's
input_output_response:

- per period: one solve_ivp call per 1 ms control period (zero-order hold), what a ROS node
  stepping period by period with scipy would do;
- whole run (offline): one solve_ivp call per constant-voltage segment of the 4.5 s run, dense
  1 kHz output (t_eval), and an analytic Jacobian for Radau/BDF/LSODA (:func:`one_term_jacobian`):
  what a user simulating offline would pick instead.

Error: max |Delta-y - Delta-y_ref| / stroke over the 1 ms samples, reference Radau rtol 1e-12
restarted every period. Cost: process CPU seconds per simulated second, median of ``--repeats``.
Every solver gets the same start: the model built and the inputs prepared outside the timing
(scipy the voltage per segment or period, the project's runs the per-period voltage array);
the project's timing includes constructing its Simulator (stepper set-up), scipy's its
solve_ivp set-up.
The summary table (:func:`speedups`) gives, per error level, the CPU of the cheapest competitor
run that reaches it divided by the CPU of 'auto' at that error.

:func:`run` measures, :func:`write_tables` writes ``work_precision.csv`` and
``work_precision.md``, the page opening with :func:`provenance`'s line (the date, the checkout's
commit, the machine and the command that wrote it), so a regenerated page is dated. Run:
``det_sim bench --out bench/out`` (about 10 min per scene; ``--quick``: one scene, fewer
points), which also draws ``work_precision.png``; it needs the ``bench`` extra (sympy for the
analytic Jacobian, python-control, matplotlib).
"""

from __future__ import annotations

import csv
import os
import platform
import statistics
import subprocess
import time

import numpy as np
from scipy.integrate import solve_ivp

from .scenarios import (reference_solution, STEP_END, step_error, step_scene, STEP_SWITCH_TIMES,
                        step_voltage)
from ..physics.model import build_model
from ..physics.statics import initial_state
from ..sim.simulator import simulate, Simulator

__all__ = ['run', 'run_scene', 'write_tables', 'provenance', 'checkout_commit', 'cost_at_error',
           'speedups', 'one_term_jacobian']


def _cpu(fn, repeats):
    times, result = [], None
    for _ in range(repeats):
        start = time.process_time()
        result = fn()
        times.append(time.process_time() - start)
    return statistics.median(times), result


def _rhs_for_solvers(model):
    """
    Return f(t, x, u) that returns NaN outside the model's domain instead of raising.

    An implicit solver's Newton iterate or a rejected trial step may leave the domain, and
    scipy's solvers answer NaN with a smaller step (an exception would end the run).
    """
    nan = np.full(model.n_states, np.nan)

    def f(t, x, u):
        try:
            return model.f(t, x, u)
        except ArithmeticError:
            return nan
    return f


def _run_start(model, t_end):
    """
    Return what every solver run starts from.

    That is: the voltage profile, dt, the number of samples, the initial state, the
    absolute-tolerance scale, the sample array and the rhs.
    """
    dt = model.scene.dt
    n = int(round(t_end / dt))
    x = initial_state(model)
    X = np.empty((n + 1, model.n_states))
    X[0] = x
    return (step_voltage(model.scene.physics.v_max), dt, n, x, np.maximum(np.abs(x), 1e-3), X,
            _rhs_for_solvers(model))


def _scipy_run(model, method, rtol, t_end):
    volts, dt, n, x, scale, X, f = _run_start(model, t_end)
    for k in range(n):
        u = np.array([volts(k * dt)])
        sol = solve_ivp(lambda t, z: f(t, z, u), (k * dt, (k + 1) * dt), x,
                        method=method, rtol=rtol, atol=rtol * scale * 1e-3)
        if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
            raise ArithmeticError(f'{method} failed at t = {k * dt:g} s: {sol.message}')
        x = sol.y[:, -1]
        X[k + 1] = x
    return X


IMPLICIT = ('Radau', 'BDF', 'LSODA')


def one_term_jacobian(model):
    """
    Return the analytic Jacobian df/dx(x, u) of a one-cell, one-term model.

    The six 'step' scenes are such models. It is model.py's Lagrange equations for that case
    written in closed form with the model's own constants and differentiated by sympy. Returns
    jac(x, v) -> (n_state, n_state) array. Checked against central differences in
    :func:`run_scene` before it is used.
    """
    import sympy as sp
    a = model.arrays
    if a.n_cells != 1 or a.n_q != 1 or a.kinematics[0] not in (0, 1):
        raise ValueError('one_term_jacobian: a one-cell, one-term paper/consistent model only')
    q, qd, eps, qp, v = sp.symbols('q qd eps qp v')
    c2, c4 = float(a.c2[0]), float(a.c4[0]) * (a.kinematics[0] == 1)
    K, D, Mb, e4, mi = (float(a.K[0, 0]), float(a.D[0, 0]), float(a.Mb[0, 0]), float(a.e4[0]),
                        float(a.mi_val.sum()))
    l, l0, VY, C0, V = (float(a.length[0]), float(a.l0[0]), float(a.VY[0]), float(a.C0[0]),
                        float(a.volume[0]))
    E_M, eta_M, eta_v, Rs, Rp = (float(a.E_M[0]), float(a.eta_M[0]), float(a.eta_v[0]),
                                 float(a.Rs[0]), float(a.Rp[0]))
    y = c2 * q ** 2 + c4 * q ** 4
    J = sp.diff(y, q)
    h = sp.diff(y, q, 2) * qd ** 2
    lam = (l - y) / l0
    creep = eps if a.creep else 0
    relax = E_M / eta_M if eta_M > 0 else 0.0
    lzd = J * qd / (l0 * lam ** 2)
    if a.rc_source:
        vp = qp / (C0 * lam ** 2)
        dU = VY / 3 * (lam - lam ** -3) - qp * vp / lam
        i_de = (v - vp) / Rs
        p_ohm = (v - vp) * i_de
    else:
        vp = v
        dU = VY / 3 * (lam - lam ** -3) - C0 * lam * v ** 2
        i_de = -2 * C0 * lam * J * qd / l0 * v + v / Rp
        p_ohm = 0
    visc = V * (E_M * creep + eta_v * lzd)
    F = -K * q - D * qd - 4 * e4 * q ** 3 - mi * J * h + (dU - visc / lam ** 2) / l0 * J
    states, f = [q, qd], [qd, F / (Mb + mi * J ** 2)]
    if a.creep:
        states.append(eps)
        f.append(lzd - relax * eps)
    if a.rc_source:
        states.append(qp)
        f.append(v / Rs - (1 / Rs + 1 / Rp) * vp)
    if a.power_monitor:
        states += list(sp.symbols('W_in W_diss'))
        f += [v * i_de, qd * D * qd + p_ohm + vp ** 2 / Rp + V * eta_v * lzd ** 2
              + V * E_M * relax * creep ** 2]
    jac = sp.lambdify((states, v), sp.Matrix(f).jacobian(states), 'numpy')
    return lambda x, volts: np.asarray(jac(list(x), float(volts)), dtype=float)


def _check_jacobian(model, jac):
    """
    Check the analytic Jacobian against central differences of the compiled rhs.

    The state is a buckled beam in motion under 2 kV. Raises if they disagree; returns the
    worst relative difference.
    """
    typical = {'q[0]': 5e-3 / model.bases[0].reference_row()[0], 'q_dot[0]': 0.2,
               'eps_E[0]': 2e-3, 'q_p[0]': model.arrays.C0[0] * 1500.0, 'W_in': 1e-3,
               'W_diss': 1e-4}
    x = np.array([typical[name] for name in model.state_names])
    u = np.array([2000.0])
    numeric = np.empty((model.n_states, model.n_states))
    for j in range(model.n_states):
        step = 1e-6 * abs(x[j])
        up, down = x.copy(), x.copy()
        up[j] += step
        down[j] -= step
        numeric[:, j] = (model.f(0, up, u) - model.f(0, down, u)) / (2 * step)
    analytic = jac(x, 2000.0)
    scale = np.maximum(np.abs(numeric), np.abs(numeric).max(axis=1, keepdims=True) * 1e-8)
    worst = float(np.max(np.abs(analytic - numeric) / np.maximum(scale, 1e-300)))
    if worst > 1e-4:
        raise AssertionError(f'analytic Jacobian differs from finite differences: {worst:.1e}')
    return worst


def _scipy_offline_run(model, method, rtol, t_end, jac=None):
    """
    Solve the whole run the way an offline user would.

    One solve_ivp call per constant-voltage segment, dense output at the 1 kHz samples, the
    analytic Jacobian for implicit methods.
    """
    volts, dt, n, x, scale, X, f = _run_start(model, t_end)
    edges = [0] + [int(round(ts / dt)) for ts in STEP_SWITCH_TIMES if ts < t_end] + [n]
    for k0, k1 in zip(edges[:-1], edges[1:]):
        v = volts(k0 * dt)
        u = np.array([v])
        kwargs = {'jac': (lambda t, z: jac(z, v))} if jac is not None else {}
        sol = solve_ivp(lambda t, z: f(t, z, u), (k0 * dt, k1 * dt), x, method=method,
                        t_eval=np.arange(k0, k1 + 1) * dt, rtol=rtol, atol=rtol * scale * 1e-3,
                        **kwargs)
        if not sol.success or not np.all(np.isfinite(sol.y)):
            raise ArithmeticError(f'{method} failed in [{k0 * dt:g}, {k1 * dt:g}] s: '
                                  f'{sol.message}')
        X[k0:k1 + 1] = sol.y.T
        x = sol.y[:, -1]
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
    resp = control.input_output_response(sys_, t, u, initial_state(model),
                                         solve_ivp_method='Radau',
                                         solve_ivp_kwargs={'rtol': rtol, 'atol': rtol * 1e-6})
    keep = np.searchsorted(t, samples)
    return resp.states.T[keep]


def _reference(scene, beam, eps_b, t_end, reference_dir, log):
    """
    Return the sample times and the Radau rtol 1e-12 reference of a scene.

    The reference is cached as .npy in ``reference_dir`` if given.
    """
    cached = (os.path.join(reference_dir, f'ref_{beam}_{eps_b:g}_rc.npy') if reference_dir
              else None)
    if cached and os.path.exists(cached):
        log(f'[{beam} eps_b={eps_b}] reference from {cached}')
        return np.arange(int(round(t_end / scene.dt)) + 1) * scene.dt, np.load(cached)
    log(f'[{beam} eps_b={eps_b}] reference (Radau rtol 1e-12) ...')
    t, X_ref = reference_solution(scene, t_end)
    if cached:
        os.makedirs(reference_dir, exist_ok=True)
        np.save(cached, X_ref)
    return t, X_ref


class _Rows:
    """The result rows of one scene: each run's cost and its error against the reference."""

    def __init__(self, beam, eps_b, model, t, X_ref, t_end, log):
        self.beam, self.eps_b, self.model = beam, eps_b, model
        self.t, self.X_ref, self.t_end, self.log = t, X_ref, t_end, log
        self.rows = []

    def add(self, solver, setting, cpu, X, steps=np.nan):
        """Add a run with its error (NaN if it failed: ``X`` None)."""
        err_y, err_q = (step_error(self.model, self.t, X, self.X_ref) if X is not None
                        else (np.nan, np.nan))
        self.rows.append({'beam': self.beam, 'eps_b': self.eps_b, 'solver': solver,
                          'setting': setting, 'cpu_per_sim_s': cpu / self.t_end,
                          'err_dy': err_y, 'err_qp': err_q,
                          'realtime_factor': self.t_end / cpu, 'steps_per_period': steps})
        self.log(f'  {solver:>14} {setting:>10}  cpu/sim-s {cpu / self.t_end:9.4f}  '
                 f'err {err_y:.2e}')

    def add_reduced(self, label, setting, cpu, steps):
        """Add a run of a reduced model (its own error is not measured)."""
        self.rows.append({'beam': self.beam, 'eps_b': self.eps_b, 'solver': f'auto ({label})',
                          'setting': setting, 'cpu_per_sim_s': cpu / self.t_end,
                          'err_dy': np.nan, 'err_qp': np.nan,
                          'realtime_factor': self.t_end / cpu, 'steps_per_period': steps})
        self.log(f'  {label:>24}  cpu/sim-s {cpu / self.t_end:9.4f} '
                 '(reduced model: own error not shown)')


def run_scene(beam, eps_b, quick=False, repeats=3, log=print, reference_dir=None):
    """Run all competitors on one scene; return a list of result rows (dicts)."""
    scene = step_scene(beam, eps_b)
    model = build_model(scene)
    t_end = STEP_END
    t, X_ref = _reference(scene, beam, eps_b, t_end, reference_dir, log)
    rows = _Rows(beam, eps_b, model, t, X_ref, t_end, log)
    volts = step_voltage(scene.physics.v_max)
    U = np.array([volts(k * scene.dt) for k in range(int(round(t_end / scene.dt)))])
    _project_runs(rows, model, U, quick, repeats)
    _scipy_runs(rows, model, quick, log)
    _control_runs(rows, model, quick, log)
    return rows.rows


def _project_runs(rows, model, U, quick, repeats):
    """
    Run the project's steppers at fixed substeps and 'auto' at several tolerances.

    Then 'auto' on the reduced models (ideal source, no creep, no power monitor).
    """
    beam, eps_b, t_end = rows.beam, rows.eps_b, rows.t_end
    n_periods = round(t_end / model.scene.dt)
    for method, subs in (('etdrk4', (4, 8, 16, 32, 64)), ('lawson5', (8, 16, 32, 64)),
                         ('etd2', (32, 128)), ('rk4', (64, 128, 256))):
        for sub in (subs[1:3] if quick else subs):
            try:
                cpu, r = _cpu(lambda: simulate(Simulator(model, method, sub), U, t_end),
                              repeats)
                rows.add(method, f'{sub} sub', cpu, r.x)
            except ArithmeticError:
                rows.add(method, f'{sub} sub', np.nan, None)
    # default 'auto' stepper at several tolerances, and the reductions at equal settings
    for tol in ((1e-4, 1e-6) if quick else (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)):
        tol_model = build_model(step_scene(beam, eps_b, **{'integrator.tolerance': tol}))
        cpu, r = _cpu(lambda: simulate(Simulator(tol_model), U, t_end), repeats)
        counted = Simulator(tol_model)   # the same run once more, to count its internal steps
        simulate(counted, U, t_end)
        rows.add('auto', f'tol {tol:g}', cpu, r.x, counted.steps_taken / n_periods)
    # reductions at the same tolerance (auto picks method and substeps for each model)
    reduced = {'ideal source': {'scene.source': 'ideal'}, 'no creep': {'scene.creep': False},
               'no power monitor': {'scene.monitor_power': False}}
    for label, over in {'full model': {}, **reduced}.items():
        reduced_model = build_model(step_scene(beam, eps_b, **over))
        cpu, r = _cpu(lambda: simulate(Simulator(reduced_model), U, t_end), repeats)
        sim = Simulator(reduced_model)
        simulate(sim, U, t_end)
        rows.add_reduced(label, f'tol 1e-06, {sim.method.name}', cpu,
                         sim.steps_taken / n_periods)


def _scipy_runs(rows, model, quick, log):
    """Run solve_ivp per period, then per constant-voltage segment with the analytic Jacobian."""
    t_end = rows.t_end
    for method in ('RK45', 'DOP853', 'Radau', 'BDF', 'LSODA'):
        for rtol in ((1e-6,) if quick else (1e-4, 1e-6, 1e-8)):
            try:
                cpu, X = _cpu(lambda: _scipy_run(model, method, rtol, t_end), 1)
            except (ArithmeticError, ValueError):   # solver failure (domain, NaN Jacobian)
                cpu, X = np.nan, None
            rows.add(f'scipy {method}', f'rtol {rtol:g}', cpu, X)
    jac = one_term_jacobian(model)
    log(f'  analytic Jacobian vs central differences: {_check_jacobian(model, jac):.1e}')
    for method in ('RK45', 'DOP853', 'Radau', 'BDF', 'LSODA'):
        for rtol in ((1e-6,) if quick else (1e-4, 1e-6, 1e-8, 1e-10)):
            try:
                cpu, X = _cpu(lambda: _scipy_offline_run(
                    model, method, rtol, t_end, jac if method in IMPLICIT else None), 1)
            except (ArithmeticError, ValueError):   # solver failure (domain, NaN Jacobian)
                cpu, X = np.nan, None
            rows.add(f'scipy {method} whole run', f'rtol {rtol:g}', cpu, X)


def _control_runs(rows, model, quick, log):
    """Run python-control's input_output_response, if installed."""
    try:
        import control  # noqa: F401
    except ImportError:
        log('  python-control not installed: skipped')
        return
    # input_output_response integrates the whole run with the input interpolated linearly
    # between the 1 ms samples (not a zero-order hold): its error includes that difference
    for rtol in ((1e-6,) if quick else (1e-6, 1e-8)):
        try:
            cpu, X = _cpu(lambda: _control_run(model, rtol, rows.t_end), 1)
        except (ArithmeticError, ValueError):   # solver failure (domain, NaN Jacobian)
            cpu, X = np.nan, None
        rows.add('python-control', f'rtol {rtol:g}', cpu, X)


ERROR_LEVELS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)


def cost_at_error(points, level):
    """
    Return the CPU needed to reach an error ``level`` along a solver's work-precision curve.

    The curve is the runs' Pareto front (cheapest for their error), interpolated log-log between
    the two front points that bracket the level; the cheapest run when every run reaches it; NaN
    when none does. ``points``: (error, cost) of one solver's runs.
    """
    points = sorted((e, c) for e, c in points if np.isfinite(e) and np.isfinite(c) and e > 0)
    front = []                          # error ascending, cost strictly descending
    for err, cost in points:
        if not front or cost < front[-1][1]:
            front.append((err, cost))
    if not front or front[0][0] > level:
        return np.nan
    if front[-1][0] <= level:
        return front[-1][1]
    for (e0, c0), (e1, c1) in zip(front, front[1:]):
        if e0 <= level < e1:
            w = np.log(level / e0) / np.log(e1 / e0)
            return float(np.exp(np.log(c0) + w * np.log(c1 / c0)))
    return np.nan


def speedups(rows, competitors):
    """
    Return the speed-up of 'auto' over the cheapest competitor, per scene and error level.

    Per scene and error level: the CPU the cheapest of ``competitors(solver)`` needs to reach
    that error, divided by what 'auto' needs (both from :func:`cost_at_error`: each solver's
    Pareto front, interpolated log-log; NaN where either cannot reach the level). Returns
    {(beam, eps_b): [ratio per ERROR_LEVELS]}.
    """
    table = {}
    for key in dict.fromkeys((r['beam'], r['eps_b']) for r in rows):
        scene = [r for r in rows if (r['beam'], r['eps_b']) == key]
        solvers = dict.fromkeys(r['solver'] for r in scene)

        def cost(solver, level):
            return cost_at_error([(r['err_dy'], r['cpu_per_sim_s']) for r in scene
                                  if r['solver'] == solver], level)
        ratios = []
        for level in ERROR_LEVELS:
            best = [cost(s, level) for s in solvers if competitors(s)]
            best = min((c for c in best if np.isfinite(c)), default=np.nan)
            ratios.append(best / cost('auto', level))
        table[key] = ratios
    return table


def _per_period(solver):
    return (solver.startswith('scipy') and not solver.endswith('whole run')) \
        or solver == 'python-control'


def _whole_run(solver):
    return solver.endswith('whole run')


def checkout_commit() -> str:
    """
    Return ``git describe --always --dirty`` of the checkout this package runs from.

    'unknown' when the package is not run from a git checkout (an installed copy) or git is
    missing: a page must not name the commit of some other repository around it.
    """
    source = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    try:
        top = subprocess.run(['git', '-C', source, 'rev-parse', '--show-toplevel'],
                             capture_output=True, text=True, timeout=10)
        if top.returncode != 0 or os.path.realpath(top.stdout.strip()) != os.path.realpath(source):
            return 'unknown'
        described = subprocess.run(['git', '-C', source, 'describe', '--always', '--dirty'],
                                   capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return 'unknown'
    return described.stdout.strip() if described.returncode == 0 else 'unknown'


def provenance(command: str) -> str:
    """Return the line that dates a written page: UTC date, commit, machine, the command."""
    machine = f"{os.cpu_count()}-core {platform.machine().replace('_', '-') or 'unknown'}"
    return (f"Measured {time.strftime('%Y-%m-%d', time.gmtime())}, commit {checkout_commit()}, "
            f'{machine}, by `{command}` (CPU times vary with the host and its load: compare '
            'the rows of one page, side by side in one run).')


def write_tables(rows, out, command='det_sim bench'):
    """
    Write the result tables into the folder ``out``.

    ``work_precision.csv`` (one row per run) and ``work_precision.md`` (:func:`provenance`'s
    line for ``command``, the command line that ran the benchmark, then the runs and the
    speed-up tables).
    """
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, 'work_precision.csv'), 'w', newline='') as stream:
        writer = csv.DictWriter(stream, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    with open(os.path.join(out, 'work_precision.md'), 'w') as stream:
        stream.write(provenance(command) + '\n\n')
        stream.write('| beam | eps_b | solver | setting | CPU s / sim s | RTF | err Δy | err q_p '
                     '| steps / period |\n')
        stream.write('|---|---|---|---|---|---|---|---|---|\n')
        for r in rows:
            steps = r['steps_per_period']
            stream.write(f"| {r['beam']} | {r['eps_b']} | {r['solver']} | {r['setting']} | "
                         f"{r['cpu_per_sim_s']:.4g} | {r['realtime_factor']:.3g} | "
                         f"{r['err_dy']:.2e} | {r['err_qp']:.2e} | "
                         f"{'' if np.isnan(steps) else f'{steps:.1f}'} |\n")
        for title, pick in (('per period (solve_ivp per 1 ms period, python-control)',
                             _per_period),
                            ('whole run (solve_ivp per voltage segment, dense output, analytic '
                             'Jacobian)', _whole_run)):
            stream.write(f'\nCPU that the cheapest scipy/python-control solver, {title}, needs '
                         "to reach an error level, divided by what 'auto' needs (each solver's "
                         'runs interpolated log-log along their error-cost Pareto front):\n\n')
            stream.write('| beam | eps_b | ' + ' | '.join(f'≤{e:g}' for e in ERROR_LEVELS)
                         + ' |\n|---|---|' + '---|' * len(ERROR_LEVELS) + '\n')
            for (beam, eps_b), ratios in speedups(rows, pick).items():
                stream.write(f'| {beam} | {eps_b} | ' + ' | '.join(
                    '—' if not np.isfinite(r) else f'{r:.0f}×' for r in ratios) + ' |\n')


def run(beams, eps_values, quick=False, repeats=3, reference_dir=None, log=print):
    """
    Run :func:`run_scene` on each beam and pre-strain in turn.

    Yields the rows measured so far after each scene (so that a long run can write what it
    measured as it goes).
    """
    rows = []
    for beam in beams:
        for eps_b in eps_values:
            rows += run_scene(beam, eps_b, quick, repeats, log=log, reference_dir=reference_dir)
            yield rows
