"""
Real-time factor on the 'step' scenario at the paper's level, offline and stepped per period.

The 4.5 s 'step' scenario on six scenes (both beams at eps_b 0.15, 0.20, 0.25) at the level
``step_scene`` names, the paper's one-term model, at integrator.tolerance 1e-6 (``--tolerance``;
``--fidelity exact`` with tolerance 0 runs the shipped default's level, exact kinematics at its
own tolerance): the whole run in one simulate() call as the offline path and Simulator.step()
per period as the node does. Cost = process CPU seconds per simulated second; min and median of
--repeats (a shared host only ever adds time, so the min is the closest to the code's own cost).
The error at these settings: ``det_sim bench``. Run: python bench/realtime.py (~1 min);
``--quick``: one scene, one repeat (a smoke run).
"""

import argparse
import statistics
import time

from det_sim_ros.analysis.scenarios import STEP_END, step_scene, step_voltage
from det_sim_ros.sim.simulator import simulate, Simulator


def _cpu(fn):
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def _stepped(scene, volts):
    sim = Simulator(scene)
    for k in range(int(round(STEP_END / sim.dt))):
        sim.set_input([volts(k * sim.dt)])
        sim.step()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--repeats', type=int, default=7)
    parser.add_argument('--tolerance', type=float, default=1e-6)
    parser.add_argument('--fidelity', default='paper', help="'paper' (one term) or 'exact'")
    parser.add_argument('--quick', action='store_true', help='one scene, one repeat')
    args = parser.parse_args(argv)
    cases = [(beam, eps_b) for beam in ('fixed', 'simply_supported')
             for eps_b in (0.15, 0.20, 0.25)]
    if args.quick:
        args.repeats, cases = 1, cases[1:2]
    print('| beam | ε_b | steps / period | simulate(): CPU s/sim s min (median) | RTF (min) '
          '| step() per period: CPU s/sim s min (median) | RTF (min) |')
    print('|---|---|---|---|---|---|---|')
    for beam, eps_b in cases:
        scene = step_scene(beam, eps_b, **{'integrator.tolerance': args.tolerance,
                                           'scene.fidelity': args.fidelity})
        volts = step_voltage(scene.physics.v_max)
        counted = Simulator(scene)
        simulate(counted, volts, STEP_END)   # compiles, and counts the internal steps
        steps = counted.steps_taken / counted.k
        run = [_cpu(lambda: simulate(scene, volts, STEP_END)) / STEP_END
               for _ in range(args.repeats)]
        step = [_cpu(lambda: _stepped(scene, volts)) / STEP_END
                for _ in range(args.repeats if args.quick else max(3, args.repeats // 2))]
        print(f"| {beam.replace('_', ' ')} | {eps_b:.2f} | {steps:.1f} | {min(run):.4f} "
              f'({statistics.median(run):.4f}) | {1 / min(run):.0f}× | {min(step):.4f} '
              f'({statistics.median(step):.4f}) | {1 / min(step):.0f}× |', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
