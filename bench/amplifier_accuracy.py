"""
The amplifier's accuracy: each circuit knob at tolerances 1e-6 and 1e-8 against 1e-11.

The default scene with the knob on, 0 V, 3 kV from 10 ms to 150 ms, 0 V to 0.3 s: the largest
|y - y_ref| over the run relative to the stroke, the same for the charge q_p, the internal steps
and the power-balance residual at the end. The reference is the same kernel at tolerance 1e-11
(self-convergence; the kernel's physics is held to the numpy reference by the tests).
Run: python bench/amplifier_accuracy.py (~20 s); ``--quick``: the amplifier off and one knob,
at 1e-6 against 1e-8, 0.1 s (a smoke run).
"""

import argparse

from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np

CASES = {
    'off': {},
    'current_limit 2 mA': {'amplifier.current_limit': 2e-3},
    'bandwidth 1 kHz': {'amplifier.bandwidth': 1e3},
    'bandwidth 40 kHz': {'amplifier.bandwidth': 4e4},
    'slew_rate 1 V/us': {'amplifier.slew_rate': 1e6},
    'slew_rate 100 V/us, bandwidth 40 kHz': {'amplifier.slew_rate': 1e8,
                                             'amplifier.bandwidth': 4e4},
    'slew 1 V/us, bandwidth 2 kHz, limit 2 mA': {'amplifier.slew_rate': 1e6,
                                                 'amplifier.bandwidth': 2e3,
                                                 'amplifier.current_limit': 2e-3},
}
PROFILE = np.where((np.arange(300) >= 10) & (np.arange(300) < 150), 3000.0, 0.0)


def run(overrides, tolerance, periods=len(PROFILE)):
    """Return (y, q_p, steps, power residual) of one run of the first ``periods``."""
    sim = Simulator(load_scene('default', dict(overrides, **{'integrator.tolerance':
                                                             tolerance})))
    result = simulate(sim, PROFILE[:periods], periods * 1e-3)
    return result['y'], result['q_p'], sim.steps_taken, sim.power_residual()


def main(argv=None) -> None:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--quick', action='store_true', help='two rows, 0.1 s, 1e-8 reference')
    args = parser.parse_args(argv)
    cases, reference, tolerances, periods = CASES, 1e-11, (1e-6, 1e-8), len(PROFILE)
    if args.quick:
        cases = {k: CASES[k] for k in ('off', 'current_limit 2 mA')}
        reference, tolerances, periods = 1e-8, (1e-6,), 100
    print('| amplifier | tolerance | error (stroke) | q_p error | steps | power residual |')
    print('| --- | --- | --- | --- | --- | --- |')
    for name, overrides in cases.items():
        y_ref, q_ref, _, _ = run(overrides, reference, periods)
        for tolerance in tolerances:
            y, q, steps, residual = run(overrides, tolerance, periods)
            print(f'| {name} | {tolerance:g} | {np.max(np.abs(y - y_ref)) / np.ptp(y_ref):.1e} '
                  f'| {np.max(np.abs(q - q_ref)) / np.ptp(q_ref):.1e} | {steps} '
                  f'| {residual:.1e} |')


if __name__ == '__main__':
    main()
