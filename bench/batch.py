"""
Batch benchmark (issue 7): N independent SISO actuators stepped together at a 1 kHz control rate.

An 'array' scene (config/array.yaml) holds N copies of the default cell with spread parameters;
the simulator steps all of them in one compiled call per control period, so the fixed cost of a
period (Python, dispatch, outputs) is shared. Measured side by side in one run:

- ``array step``: one Simulator.step() per 1 ms period for all N (what sim_node does);
- ``array run``: the offline path, simulate() with the whole input record (one call);
- ``N x SISO step``: N separate single-cell Simulators stepped one after another (the baseline
  the array replaces), for N up to --max-separate.

Inputs: each actuator gets its own 0 / v_max square wave (period 0.2 s, phase spread over N), so
charge transients start at different periods; the batch shares one step size, so a period with a
transient anywhere takes the graded fine steps for every copy. ``--synchronized``: all switch
together. Cost: process CPU seconds per simulated second,
median of --repeats; RTF = 1 / cost. Run: ``python bench/batch.py`` (about 2 min).
"""

import argparse
import statistics
import sys
import time

import numpy as np

from det_sim_ros.scene import load_scene
from det_sim_ros.simulator import simulate, Simulator


def _commands(n, periods, dt, v_max, synchronized=False):
    phase = np.zeros(n) if synchronized else np.arange(n) / max(n, 1) * 0.2
    t = np.arange(periods)[:, None] * dt
    return v_max * (((t + phase[None, :]) % 0.2) < 0.1)


def _cpu(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.process_time()
        fn()
        times.append(time.process_time() - start)
    return statistics.median(times)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--sizes', default='1,10,100,1000')
    parser.add_argument('--sim-time', type=float, default=0.5, help='simulated seconds per run')
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--max-separate', type=int, default=100)
    parser.add_argument('--tolerance', type=float, default=1e-6)
    parser.add_argument('--synchronized', action='store_true', help='all copies switch together')
    parser.add_argument('--substeps', type=int, default=0, help='fixed steps per period (0: adaptive)')
    args = parser.parse_args(argv)
    rows = []
    for n in (int(s) for s in args.sizes.split(',')):
        scene = load_scene('array', {'structure.copies': n, 'integrator.tolerance': args.tolerance,
                                     'integrator.substeps': args.substeps,
                                     'scene.initial_state': 'released'})
        sim = Simulator(scene)
        periods = int(round(args.sim_time / sim.dt))
        U = _commands(n, periods, sim.dt, scene.physics.v_max, args.synchronized)
        simulate(Simulator(scene), U[:20], 20 * sim.dt)       # compile outside the timing
        warm = Simulator(sim.model)
        warm.set_input(U[0])
        warm.step()

        def stepping():
            s = Simulator(sim.model)
            for k in range(periods):
                s.set_input(U[k])
                s.step()
        cost_step = _cpu(stepping, args.repeats) / args.sim_time
        cost_run = _cpu(lambda: simulate(Simulator(sim.model), U, args.sim_time),
                        args.repeats) / args.sim_time
        cost_sep = float('nan')
        if n <= args.max_separate:
            singles = [Simulator(scene.cell_scene(i)) for i in range(n)]

            def separate():
                for s in singles:
                    s.reset()
                for k in range(periods):
                    for i, s in enumerate(singles):
                        s.set_input([U[k, i]])
                        s.step()
            cost_sep = _cpu(separate, args.repeats) / args.sim_time
        rows.append((n, sim.describe_stepper(), cost_step, cost_run, cost_sep))
        print(f'N={n:5d} {sim.describe_stepper()}: step {cost_step:.4f} '
              f'run {cost_run:.4f} separate {cost_sep:.4f} CPU s/sim s', file=sys.stderr,
              flush=True)
    print('| N | stepper | array step: CPU s/sim s | RTF | per actuator (us/period) | '
          'array run: CPU s/sim s | RTF | N x SISO step: CPU s/sim s | array vs separate |')
    print('|---|---|---|---|---|---|---|---|---|')
    for n, stepper, step, run, sep in rows:
        per_act = step / n * 1e3   # us of CPU per actuator per 1 ms period
        ratio = sep / step if np.isfinite(sep) else float('nan')
        print(f'| {n} | {stepper} | {step:.4g} | {1 / step:.3g} | {per_act:.3g} | '
              f'{run:.4g} | {1 / run:.3g} | {sep:.4g} | {ratio:.3g}x |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
