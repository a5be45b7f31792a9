"""
Batch benchmark: N independent SISO actuators stepped together at a 1 kHz control rate.

An 'array' scene (config/array.yaml) holds N copies of the default cell with spread parameters;
the simulator steps all of them in one compiled call per control period, so the fixed cost of a
period (Python, dispatch, outputs) is shared. Measured side by side in one run:

- ``array step``: one Simulator.step() per 1 ms period for all N (what sim_node does);
- ``array run``: the offline path, simulate() with the whole input record (one call);
- ``N x SISO step``: N separate single-cell Simulators stepped one after another (the baseline
  the array is compared with), for N up to --max-separate.

Inputs (--commands): each actuator gets its own 0 / v_max square wave (period 0.2 s: 'square') or
one v_max step of 0.3 s ('step'), either staggered (phases or switch times spread over N, so charge
transients and snaps start at different periods) or synchronized (all switch together). Every copy
is its own coupled group with its own adaptive step count, so one copy snapping does not make the
others take its steps. ``array run`` is also timed on ``--threads`` threads (groups spread over
them; results are identical). Cost: process CPU seconds per simulated second, median of --repeats;
RTF = wall-clock real-time factor (for threads > 1, wall time is what a user waits); the figure of
merit is CPU us per actuator and period (1000 actuators at 1x real time on two cores need <= 2 us
with perfect scaling). The simulators are built outside the timing (reset() between runs): building
a 1000-copy array takes ~5 s, mostly its copies' rest-state solves. Run: ``python bench/batch.py``;
``--quick``: 1 and 2 copies, 0.05 s, one repeat, the square wave (a smoke run).
"""

import argparse
import statistics
import sys
import time

from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np


def _commands(n, periods, dt, v_max, synchronized=False, kind='square'):
    """
    Return the per-period voltages (periods x n).

    'square': a 0 / v_max square wave of period 0.2 s per copy (a snap every 0.1 s: the hard
    case); 'step': the 'step' profile per copy, v_max for 0.3 s from a switch-on time (what a
    controller test does), spread over the first half of the run. Staggered: phases / switch
    times spread over the copies; synchronized: all equal.
    """
    t = np.arange(periods)[:, None] * dt
    if kind == 'step':
        on = np.full(n, 0.1) if synchronized else 0.1 + 0.5 * periods * dt * np.arange(n) / n
        return v_max * ((t >= on[None, :]) & (t < on[None, :] + 0.3))
    phase = np.zeros(n) if synchronized else np.arange(n) / max(n, 1) * 0.2
    return v_max * (((t + phase[None, :]) % 0.2) < 0.1)


def _cpu(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.process_time()
        fn()
        times.append(time.process_time() - start)
    return statistics.median(times)


def _wall(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _parse(argv):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--sizes', default='1,10,100,1000')
    parser.add_argument('--sim-time', type=float, default=1.0, help='simulated seconds per run')
    parser.add_argument('--commands', default='square,step',
                        help="workloads: 'square' (a snap every 0.1 s), 'step' (one step each)")
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--max-separate', type=int, default=100)
    parser.add_argument('--tolerance', type=float, default=1e-6)
    parser.add_argument('--threads', default='1,2', help='thread counts for the array run')
    parser.add_argument('--substeps', type=int, default=0,
                        help='fixed steps per period (0: adaptive)')
    parser.add_argument('--initial-state', default='rest', choices=('rest', 'released'),
                        help="the scene's start: 'rest' (config/array.yaml's) or 'released' "
                             '(every copy buckles from q0 first)')
    parser.add_argument('--quick', action='store_true',
                        help='1 and 2 copies, 0.05 s, one repeat, the square wave')
    args = parser.parse_args(argv)
    if args.quick:
        args.sizes, args.sim_time, args.repeats, args.commands = '1,2', 0.05, 1, 'square'
    return args


def _row(scene, sim, n, kind, synchronized, threads, args):
    """Measure one workload on an N-copy array and print its table row."""
    periods = int(round(args.sim_time / sim.dt))
    U = _commands(n, periods, sim.dt, scene.physics.v_max, synchronized, kind)
    sim.stepper.threads = 1
    steps0 = sim.steps_taken
    sim.reset()
    simulate(sim, U, args.sim_time)
    steps = (sim.steps_taken - steps0) / (n * periods)

    def stepping():
        sim.reset()
        for k in range(periods):
            sim.set_input(U[k])
            sim.step()
    per = 1e6 / (n * periods)     # seconds per run -> us per actuator and period
    cost_step = _cpu(stepping, args.repeats) * per

    def offline(threads):
        sim.stepper.threads = threads
        sim.reset()
        simulate(sim, U, args.sim_time)
    runs = [_wall(lambda: offline(t), args.repeats) * per for t in threads]
    sim.stepper.threads = 1
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
        cost_sep = _cpu(separate, args.repeats) * per
    rtf = lambda us: 1e3 / (us * n)  # noqa: E731 - 1 ms of sim time per period
    print(f"| {n} | {kind}, {'synchronized' if synchronized else 'staggered'} | "
          f'{steps:.1f} | {cost_step:.3g} | {rtf(cost_step):.3g} | '
          + ' | '.join(f'{r:.3g} | {rtf(r):.3g}' for r in runs)
          + f' | {cost_sep:.3g} |', flush=True)


def main(argv=None) -> int:
    args = _parse(argv)
    threads = [int(t) for t in args.threads.split(',')]
    print('| N | commands | steps / period | array step(): µs CPU per actuator and period | RTF | '
          + ' | '.join(f'simulate() {t} thread(s): µs wall per actuator and period | RTF'
                       for t in threads)
          + ' | N × single-cell step(): µs per actuator and period |')
    print('|---|---|---|---|---|' + '---|---|' * len(threads) + '---|')
    for n in (int(s) for s in args.sizes.split(',')):
        scene = load_scene('array', {'structure.copies': n, 'integrator.tolerance': args.tolerance,
                                     'integrator.substeps': args.substeps,
                                     'scene.initial_state': args.initial_state})
        sim = Simulator(scene)   # built once: a 1000-copy array takes ~5 s (rest states)
        for kind, synchronized in ((k, sync) for k in args.commands.split(',')
                                   for sync in (False, True)):
            _row(scene, sim, n, kind, synchronized, threads, args)
    return 0


if __name__ == '__main__':
    sys.exit(main())
