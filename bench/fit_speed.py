"""
Speed of ``det_sim fit``: a 10 s, 1 kHz log, 5 parameters, on this machine's cores.

Measured side by side in one run (run it alone: ``flock /work/bench.lock python
bench/fit_speed.py``):

- one simulate() call of the 10 s log (the fit's unit of work) at ``fidelity: paper`` and at
  ``fidelity: exact`` with n_ritz 5, median of --repeats;
- one Jacobian (5 sensitivity runs) serially, on threads (the compiled run releases the GIL)
  and in processes, wall time, median of --repeats; at ``paper`` on the 10 s log and at
  ``exact`` n_r 5 on a 1 s log (once: its runs are long enough that a pool's overhead is small);
- the whole fit at ``paper`` (the synthetic log of bench/fit_accuracy.py, every parameter 2x
  off), wall time, process CPU time and simulate() calls, serially (what 'auto' picks for
  these short runs) and on threads.

The time of an ``exact`` fit is estimated from its call time and the paper fit's call count.
"""

import argparse
import statistics
import time

import det_sim_ros
from det_sim_ros.calibration.parameters import fit_parameters, to_z
from det_sim_ros.calibration.problem import Evaluator, Problem
from det_sim_ros.calibration.synthetic import step_and_sine, synthetic_measurement
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate

PARAMS = ['m', 'eta_b', 'eps_r', 'E_M', 'Rp']


def _median_time(run, repeats):
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        run()
        times.append(time.perf_counter() - began)
    return statistics.median(times)


def call_times(volts, repeats):
    """Return fidelity label -> seconds per simulate() call of the log."""
    scenes = {'paper': load_scene('default', {'scene.fidelity': 'paper'}),
              'exact n_r 5': load_scene('default', {'scene.fidelity': 'exact',
                                                    'scene.n_ritz': 5})}
    return {label: _median_time(lambda s=scene: simulate(s, volts, len(volts) * s.dt),
                                1 if label != 'paper' else repeats)
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


def whole_fit(scene, log, parallel):
    """Return (wall s, simulate() calls, converged) of the 5-parameter fit from 2x off."""
    start = {name: getattr(scene.physics, name) * (2.0 if i % 2 == 0 else 0.5)
             for i, name in enumerate(PARAMS)}
    began, cpu = time.perf_counter(), time.process_time()
    result = det_sim_ros.fit([log], PARAMS, scene=scene, start=start, parallel=parallel)
    return (time.perf_counter() - began, time.process_time() - cpu, result.simulate_calls,
            result.converged)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--t-end', type=float, default=10.0)
    parser.add_argument('--fits', default='serial,threads', help='whole fits to time')
    args = parser.parse_args()
    scene = load_scene('default')
    volts = step_and_sine(args.t_end, scene.dt)
    log = synthetic_measurement(scene, volts, noise=0.01, seed=0)
    calls = call_times(volts, args.repeats)
    for label, seconds in calls.items():
        print(f'simulate() of the {args.t_end:g} s log, {label}: {seconds * 1e3:.1f} ms')
    exact = load_scene('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 5})
    short = synthetic_measurement(exact, step_and_sine(1.0, exact.dt), noise=0.01, seed=0)
    for label, times in (('paper, 10 s log', jacobian_times(scene, log, args.repeats)),
                         ('exact n_r 5, 1 s log', jacobian_times(exact, short, 1))):
        for kind, seconds in times.items():
            print(f'Jacobian (5 runs), {label}, {kind}: {seconds * 1e3:.0f} ms '
                  f'({times["serial"] / seconds:.2f}x serial)')
    for parallel in args.fits.split(','):
        wall, cpu, n_calls, converged = whole_fit(scene, log, parallel)
        print(f'fit ({parallel}): {wall:.1f} s wall, {cpu:.1f} s CPU, {n_calls} simulate() '
              f'calls, {wall / n_calls * 1e3:.0f} ms per call, converged {converged}')
        if parallel == 'serial':
            ratio = calls['exact n_r 5'] / calls['paper']
            print(f'  exact n_r 5 estimate: {wall * ratio:.0f} s ({ratio:.0f}x the paper call)')


if __name__ == '__main__':
    main()
