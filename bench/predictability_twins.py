#!/usr/bin/env python3
"""
The predictability measure against hand-made twins, and its cost (docs/predictability.md).

For each case at the default level (10 Hz PWM, 2 Hz switching, the controller case, the step),
two twins made by hand (the tolerance x 0.9; the interface mass x (1 + 1e-6)), scored as
docs/fidelity.md scores switching (max |y - y_twin| from 0.5 s over the run's travel there,
and the first time beyond 5 %), beside the measure's first stretch and largest distance
(det_sim_ros.analysis.predictability, default perturbation). Then the measure's CPU against
one simulate() of the same case, side by side (median of --repeats pairs, process time).

Usage: python bench/predictability_twins.py [--quick] [--repeats 5]
"""

import argparse
import sys

from batch import _cpu as cpu   # median process time of repeated calls, s
from det_sim_ros.analysis.predictability import predictability
from det_sim_ros.analysis.scenarios import (pwm_voltage, step_scene, step_voltage,
                                            switching_scene, switching_voltage)
from det_sim_ros.sim.integrators import integration_tolerance
from det_sim_ros.sim.simulator import simulate
import numpy as np

START = 0.5   # s


def controller_volts(n):
    """Return the controller case's commands (bench/continuum_reference.py's, seed 0)."""
    from continuum_reference import controller_volts as volts
    return volts(n, 1e-3)[:, 0]


def cases(quick):
    """Yield (label, scene, volts, t_end) of every case."""
    pwm = [('fixed', 0.15), ('simply_supported', 0.20), ('fixed', 0.20),
           ('simply_supported', 0.15)]
    for beam, eps in pwm[:2] if quick else pwm:
        yield f'10 Hz PWM {beam} {eps:g}', switching_scene(beam, eps), pwm_voltage(3000.0), 2.5
    if quick:
        return
    for beam in ('fixed', 'simply_supported'):
        for eps in (0.15, 0.20):
            yield (f'2 Hz switching {beam} {eps:g}', switching_scene(beam, eps),
                   switching_voltage(3000.0), 2.5)
        yield (f'controller {beam} 0.2', switching_scene(beam, 0.20, **{
            'scene.initial_state': 'rest'}), controller_volts(2500), 2.5)
        for eps in (0.15, 0.20, 0.25):
            yield (f'step {beam} {eps:g}', step_scene(beam, eps, **{'scene.fidelity': 'exact'}),
                   step_voltage(3000.0), 4.5)


def hand_twin(scene, volts, t_end, change):
    """Return (first time beyond 5 % of the travel or None, largest |y - y_twin| / travel)."""
    run = simulate(scene, volts, t_end)
    twin = simulate(scene.replace(**change), volts, t_end)
    after = run.t >= START - 1e-9
    gap = np.abs(run['y'] - twin['y'])[after] / np.ptp(run['y'][after])
    beyond = np.nonzero(gap > 0.05)[0]
    return (float(run.t[after][beyond[0]]) if beyond.size else None), float(gap.max())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--quick', action='store_true', help='the two PWM cases only, 1 repeat')
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args(argv)
    repeats = 1 if args.quick else args.repeats
    print('| case | tolerance x 0.9: beyond 5 % from / max | m x (1 + 1e-6): from / max | '
          'measure: not robust from / max distance | measure CPU / one run |')
    print('| --- | --- | --- | --- | --- |')
    for label, scene, volts, t_end in cases(args.quick):
        tol = hand_twin(scene, volts, t_end,
                        {'integrator.tolerance': 0.9 * integration_tolerance(scene)})
        mass = hand_twin(scene, volts, t_end, {'physics.m': scene.physics.m * (1 + 1e-6)})
        measured = predictability(scene, volts, t_end)
        ratio = (cpu(lambda: predictability(scene, volts, t_end), repeats)
                 / cpu(lambda: simulate(scene, volts, t_end), repeats))

        def when(t):
            return '-' if t is None else f'{t:.3f} s'
        print(f'| {label} | {when(tol[0])} / {100 * tol[1]:.3g} % | {when(mass[0])} / '
              f'{100 * mass[1]:.3g} % | {when(measured.robust_until)} / '
              f'{100 * float(measured.distance.max()):.3g} % | {ratio:.2f} |', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
