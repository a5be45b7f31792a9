#!/usr/bin/env python3
"""
SUNDIALS CVODE and scipy's LSODA against the kernel's default stepper, 2 Hz switching, one process.

The 2 Hz switching cases at eps_b 0.20 (released, a 3 kV square wave from 0.5 s to 2.5 s), each
beam at its default level (the kernel's stepper as 'auto' picks it). CVODE (scikit-sundae,
BDF with Newton and its own dense Jacobian) and LSODA (scipy's odeint) integrate the same
compiled right-hand side (``Model.f``, a Python call per evaluation), one solve per constant
voltage, at a ladder of relative tolerances (absolute: rtol times each state's scale). Every
run is scored against the stored continuum reference as the map scores switching (max |y -
y_ref| from 0.5 s over the travel; every snap within 2 ms) and timed by the calling thread's
CPU: once scikit-sundae is imported, the kernel's runs cost twice their wall time in process
CPU (a second thread busy while they run), which halved the kernel's figure measured that way.
Compare a solver with the kernel at equal error: the ratio of their x real time.

Without scikit-sundae (``pip install '.[bench]'``) the CVODE rows are skipped with one line.

Usage: python bench/cvode_compare.py [--quick] [--beams simply_supported,fixed]
"""

import argparse
import sys
import time

from continuum_reference import load_reference, switching_inputs
from det_sim_ros.analysis.scenarios import (_state_scale, snap_times, step_scene,
                                            SWITCHING_END, switching_error)
from det_sim_ros.physics.model import build_model
from det_sim_ros.physics.statics import initial_state
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
from scipy.integrate import odeint

RTOLS = {'cvode': (1e-4, 1e-5, 1e-6, 1e-7), 'lsoda': (1e-4, 1e-5, 1e-6, 1e-7)}


def score(reference, t, y, q):
    """Return (max |y - y_ref| from 0.5 s / travel, every snap made within 2 ms)."""
    made, expected = snap_times(t, q), snap_times(reference['t'], reference['q'])
    snaps = len(made) == len(expected) and (not len(made)
                                            or np.max(np.abs(made - expected)) <= 2e-3)
    return switching_error(t, y, reference['y']), snaps


def _cvode_rhs(model, u):
    """Return CVODE's right-hand side at the held voltage ``u`` (three arguments: it counts)."""
    def rhs(_t, y, yp):
        yp[:] = model.f(0.0, y, u)
    return rhs


def solve(model, volts, t, rtol, solver):
    """Return the states at ``t``: one solve per constant voltage."""
    scale = _state_scale(model)
    edges = [0] + [k for k in range(1, len(volts)) if volts[k] != volts[k - 1]] + [len(t) - 1]
    x = initial_state(model)
    X = np.empty((len(t), model.n_states))
    X[0] = x
    for a, b in zip(edges[:-1], edges[1:]):
        u = np.array([volts[a]])
        if solver == 'cvode':
            from sksundae.cvode import CVODE
            X[a:b + 1] = CVODE(_cvode_rhs(model, u), method='BDF', rtol=rtol,
                               atol=rtol * scale).solve(t[a:b + 1], x).y
        else:
            X[a:b + 1] = odeint(lambda z, _t, u=u: model.f(0.0, z, u), x, t[a:b + 1],
                                rtol=rtol, atol=rtol * scale, mxstep=10**6)
        x = X[b]
    return X


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--beams', default='simply_supported,fixed')
    parser.add_argument('--quick', action='store_true',
                        help='the fixed beam to 0.8 s, one tolerance per solver')
    args = parser.parse_args(argv)
    try:
        import sksundae  # noqa: F401
        solvers = ('cvode', 'lsoda')
    except ImportError:
        print("scikit-sundae is not installed (pip install '.[bench]'): no CVODE rows")
        solvers = ('lsoda',)
    reference = load_reference()
    beams = ['fixed'] if args.quick else args.beams.split(',')
    t_end = 0.8 if args.quick else SWITCHING_END
    print('| beam | solver | rtol | error | every snap | x real time |')
    print('| --- | --- | --- | --- | --- | --- |')
    for beam in beams:
        overrides, volts = switching_inputs(beam, 0.20, 2.0, 1e-3)
        n = int(round(t_end / 1e-3))
        volts = volts[:n]
        scene = step_scene(beam, 0.20, **{'scene.fidelity': 'exact', 'scene.shapes': 'auto',
                                          'scene.n_ritz': 0, 'scene.monitor_power': False},
                           **overrides)
        ref = {key: value[:n + 1] for key, value in
               reference[f'switching_2hz/{beam}_0.20'].items()}
        best = np.inf
        for _ in range(1 if args.quick else 3):
            sim = Simulator(scene)
            start = time.thread_time()
            run = simulate(sim, volts, t_end)
            best = min(best, time.thread_time() - start)
        error, snaps = score(ref, run.t, run['y'], run['q'])
        print(f'| {beam} | kernel ({sim.method.name}, tolerance {sim.tolerance:g}) | - | '
              f'{error:.2e} | {snaps} | {t_end / best:.1f} |', flush=True)
        model = build_model(scene)
        t = np.arange(n + 1) * scene.dt
        y_at, q_at = model.output_names.index('y'), model.output_names.index('q')
        for solver in solvers:
            for rtol in RTOLS[solver][1:2] if args.quick else RTOLS[solver]:
                start = time.thread_time()
                X = solve(model, volts, t, rtol, solver)
                cpu = time.thread_time() - start
                out = np.array([model.output_vector(x, np.zeros(1)) for x in X])
                error, snaps = score(ref, t, out[:, y_at], out[:, q_at])
                print(f'| {beam} | {solver} | {rtol:.0e} | {error:.2e} | {snaps} | '
                      f'{t_end / cpu:.1f} |', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
