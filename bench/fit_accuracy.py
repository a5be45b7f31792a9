"""
Accuracy of ``det_sim fit`` over noise seeds: 10 s step-and-sine logs at 1 kHz.

For each seed a synthetic log is made from the default scene (Gaussian noise on Δy at 1 % of
the stroke) and the parameters (--params, default m, eta_b, eps_r, Rp) are fitted from every
one 2x off (alternately above and below).
Per parameter: how often it comes back within 2 %, how often its 95 % interval holds the true
value, how often it is flagged as not identifiable, and its median relative standard error. A
parameter counts as well identified in a seed when it is not flagged and its relative standard
error is below 1 % (Rp, the leakage resistance, has a time constant of ~100 s: a 10 s log cannot
identify it, and it must be flagged).

The fit runs as ``det_sim fit`` does: the search at the coarse level, the polish at the default
scene's (docs/calibration.md, Two levels). Run: ``flock bench/.lock python
bench/fit_accuracy.py --seeds 0:5`` (each fit of four parameters takes ~20-60 s on a shared
2-core host; split the seeds over runs of <= 3 min). ``--quick``: one seed, a 0.5 s log, m only (a
smoke run).
"""

import argparse
import statistics

import det_sim_ros
from det_sim_ros.calibration.synthetic import step_and_sine, synthetic_measurement
from det_sim_ros.scenes.scene import load_scene

PARAMS = ['m', 'eta_b', 'eps_r', 'Rp']
WITHIN = 0.02
WELL_IDENTIFIED_SE = 0.01


def one_seed(scene, seed, t_end, params):
    """Return name -> (relative error, in 95 %, flagged, relative se) for one noise seed."""
    log = synthetic_measurement(scene, step_and_sine(t_end, scene.dt), noise=0.01, seed=seed)
    start = {name: getattr(scene.physics, name) * (2.0 if i % 2 == 0 else 0.5)
             for i, name in enumerate(params)}
    result = det_sim_ros.fit([log], params, scene=scene, start=start)
    rows = {}
    for e in result.estimates:
        true = getattr(scene.physics, e.name)
        rows[e.name] = (e.value / true - 1.0, e.lower95 <= true <= e.upper95, bool(e.flags),
                        e.relative_se)
    return rows, result


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', default='0:10', help='START:STOP (default: 0:10)')
    parser.add_argument('--t-end', type=float, default=10.0)
    parser.add_argument('--params', default=','.join(PARAMS))
    parser.add_argument('--quick', action='store_true', help='one seed, a 0.5 s log, m only')
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.t_end, args.params = '0:1', 0.5, 'm'
    params = args.params.split(',')
    first, last = (int(v) for v in args.seeds.split(':'))
    scene = load_scene('default')
    table = {name: [] for name in params}
    for seed in range(first, last):
        rows, result = one_seed(scene, seed, args.t_end, params)
        print(f'seed {seed}: converged {result.converged}, {result.simulate_calls} calls, '
              f'{result.wall_time:.1f} s: ' + ', '.join(
                  f'{n} {r[0] * 100:+.2f} %{"" if r[1] else " (outside)"}'
                  f'{" flagged" if r[2] else ""}' for n, r in rows.items()), flush=True)
        for name, row in rows.items():
            table[name].append(row)
    n = last - first
    print('\n| parameter | well identified | within 2 % | inside 95 % interval | flagged | '
          'median relative se |\n|---|---|---|---|---|---|')
    for name, rows in table.items():
        well = [r for r in rows if not r[2] and r[3] < WELL_IDENTIFIED_SE]
        within = sum(abs(r[0]) <= WITHIN for r in rows)
        inside = sum(r[1] for r in rows)
        se = statistics.median(r[3] for r in rows)
        print(f'| {name} | {len(well)}/{n} | {within}/{n} | {inside}/{n} | '
              f'{sum(r[2] for r in rows)}/{n} | '
              + ('-' if se == float('inf') else f'{se * 100:.2f} %') + ' |')


if __name__ == '__main__':
    main()
