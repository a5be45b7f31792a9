"""
Speed of ``det_sim fit``: a 10 s, 1 kHz log, 5 parameters, on this machine's cores.

Measured side by side in one run (run it alone: ``flock bench/.lock python
bench/fit_speed.py``):

- one simulate() call of the 10 s log (the fit's unit of work) at ``fidelity: paper`` and at
  ``fidelity: exact`` with n_ritz 5, median of --repeats;
- one Jacobian (5 sensitivity runs) serially, on threads (the compiled run releases the GIL)
  and in processes, wall time, median of --repeats; at ``paper`` on the 10 s log and at
  ``exact`` n_r 5 on a 1 s log (once: its runs are long enough that a pool's overhead is small);
- whole fits of the synthetic log of bench/fit_accuracy.py made at the default level (every
  parameter 2x off), ``--fits``: each ``N:MODE`` fits the first N of m, eta_b, eps_r, E_M, Rp
  at the default level, MODE ``two-level`` (the search at the coarse level, the polish at the
  scene's, what ``det_sim fit`` does) or ``scene-only`` (the search at the scene's level: the
  fit before the coarse level), or at ``paper``; wall time, process CPU time, simulate() calls
  per pass and the largest error of the parameters the log identifies.

The Jacobian timings (--jacobians) and the paper fits are the evaluator's measurements: what
'auto' picks. Keep each locked run short: a scene-only fit of three parameters takes ~3 min.
``--quick``: a 1 s log, one call each, one parameter fitted at paper (a smoke run).
"""

import argparse
import statistics
import time

import det_sim_ros
from det_sim_ros.calibration.levels import fit_levels
from det_sim_ros.calibration.parameters import fit_parameters, to_z
from det_sim_ros.calibration.problem import Evaluator, Problem
from det_sim_ros.calibration.synthetic import step_and_sine, synthetic_measurement
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate

PARAMS = ['m', 'eta_b', 'eps_r', 'E_M', 'Rp']   # the first three: what a Δy log identifies


def _median_time(run, repeats):
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        run()
        times.append(time.perf_counter() - began)
    return statistics.median(times)


def call_times(volts, repeats):
    """Return fidelity label -> seconds per simulate() call of the log."""
    coarse = fit_levels(load_scene('default'))[0]
    scenes = {'paper': load_scene('default', {'scene.fidelity': 'paper'}),
              'exact n_r 5': load_scene('default', {'scene.fidelity': 'exact',
                                                    'scene.n_ritz': 5}),
              f'the coarse level ({coarse.describe()})': coarse.scene}
    return {label: _median_time(lambda s=scene: simulate(s, volts, len(volts) * s.dt),
                                1 if label == 'exact n_r 5' else repeats)
            for label, scene in scenes.items()}


def jacobian_times(scene, log, repeats):
    """Return evaluator kind -> seconds per 5-column Jacobian."""
    parameters = fit_parameters(PARAMS, scene, start={'Rp': 1e10})
    problem = Problem(scene, [log], parameters)
    z = to_z(parameters, [p.start for p in parameters])
    f0 = problem.residual(z)
    result = {}
    for kind in ('serial', 'threads', 'processes'):
        evaluator = Evaluator(problem, kind, 2)
        evaluator.evaluate([z, z])   # start the workers outside the timing
        result[kind] = _median_time(lambda e=evaluator: problem.jacobian(z, f0, e), repeats)
        evaluator.close()
    return result


def whole_fit(scene, log, names, coarse=True, parallel='auto'):
    """Return (wall s, CPU s, the FitResult) of the fit of ``names`` from 2x off."""
    start = {name: getattr(scene.physics, name) * (2.0 if i % 2 == 0 else 0.5)
             for i, name in enumerate(names)}
    began, cpu = time.perf_counter(), time.process_time()
    result = det_sim_ros.fit([log], names, scene=scene, start=start, parallel=parallel,
                             coarse=coarse)
    return time.perf_counter() - began, time.process_time() - cpu, result


def print_fit(label, scene, wall, cpu, result):
    """Print a fit's times, calls per pass and its largest error of an identified parameter."""
    errors = {e.name: e.value / getattr(scene.physics, e.name) - 1.0
              for e in result.estimates if e.identified}
    worst = max(errors, key=lambda name: abs(errors[name]))
    print(f'fit {label}: {wall:.1f} s wall, {cpu:.1f} s CPU, {result.simulate_calls} '
          f'simulate() calls, converged {result.converged}, worst identified {worst} '
          f'{errors[worst] * 100:+.2f} %, flagged {result.flagged}', flush=True)
    for p in result.passes:
        print(f'  {p.role} ({p.level}): {p.simulate_calls} calls, {p.wall_time:.1f} s, '
              f'{p.parallel}: {p.work}', flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--t-end', type=float, default=10.0)
    parser.add_argument('--fits', default='3:two-level,5:two-level',
                        help='N:MODE,... with MODE two-level, scene-only or paper')
    parser.add_argument('--jacobians', action='store_true',
                        help='also time one Jacobian serially, on threads and in processes')
    parser.add_argument('--quick', action='store_true',
                        help='a 1 s log, one call each, one parameter fitted at paper')
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.t_end, args.fits = 1, 1.0, '1:paper'
    default = load_scene('default')
    volts = step_and_sine(args.t_end, default.dt)
    calls = call_times(volts, args.repeats)
    for label, seconds in calls.items():
        print(f'simulate() of the {args.t_end:g} s log, {label}: {seconds * 1e3:.1f} ms',
              flush=True)
    paper = load_scene('default', {'scene.fidelity': 'paper'})
    if args.jacobians:
        log = synthetic_measurement(paper, volts, noise=0.01, seed=0)
        exact = load_scene('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 5})
        short = synthetic_measurement(exact, step_and_sine(1.0, exact.dt), noise=0.01, seed=0)
        for label, times in (('paper, 10 s log', jacobian_times(paper, log, args.repeats)),
                             ('exact n_r 5, 1 s log', jacobian_times(exact, short, 1))):
            for kind, seconds in times.items():
                print(f'Jacobian (5 runs), {label}, {kind}: {seconds * 1e3:.0f} ms '
                      f'({times["serial"] / seconds:.2f}x serial)', flush=True)
    logs = {}
    for spec in args.fits.split(','):
        count, _, mode = spec.partition(':')
        scene = paper if mode == 'paper' else default
        if mode not in logs:
            logs[mode] = synthetic_measurement(scene, volts, noise=0.01, seed=0)
        wall, cpu, result = whole_fit(scene, logs[mode], PARAMS[:int(count)],
                                      coarse=mode != 'scene-only')
        print_fit(f'{count} parameters, {mode}', scene, wall, cpu, result)


if __name__ == '__main__':
    main()
