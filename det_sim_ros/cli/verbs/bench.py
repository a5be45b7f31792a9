"""
``det_sim bench``: the work-precision benchmark on the 'step' scenario.

The benchmark (det_sim_ros.analysis.benchmark) is written as CSV, markdown and a PNG diagram.
It needs the ``bench`` extra: sympy (the analytic Jacobian; required), python-control and
matplotlib (skipped without).
"""

from __future__ import annotations

import importlib
import os
import shlex
import sys

from .. import common

HELP = 'work-precision diagram of the integration benchmark'
DESCRIPTION = ('Work-precision benchmark on the step scenario: error against CPU time of the '
               "project's steppers, scipy's solve_ivp and python-control (about 10 min per "
               'scene; --quick: one scene, fewer points). Needs: pip install '
               "'det_sim_ros[bench]'.")
EXTRA_HINT = "pip install 'det_sim_ros[bench]'"
REQUIRED = ('sympy',)
OPTIONAL = {'control': 'no python-control runs', 'matplotlib': 'no work_precision.png'}


def add_arguments(parser) -> None:
    """Add --out, --quick, --beams, --eps-b, --repeats, --reference-dir."""
    parser.add_argument('--out', default='bench/out', help='output folder (default: %(default)s)')
    parser.add_argument('--quick', action='store_true',
                        help='one scene (the first beam, eps_b 0.20), fewer points')
    parser.add_argument('--beams', type=common.beam_list, default='fixed,simply_supported',
                        help='comma-separated beams (default: fixed,simply_supported)')
    parser.add_argument('--eps-b', type=common.float_list, default='0.15,0.20,0.25',
                        help='pre-strains (default: 0.15,0.20,0.25)')
    parser.add_argument('--repeats', type=int, default=3,
                        help='timed repeats of each run, the median counts (default: 3)')
    parser.add_argument('--reference-dir', default=None,
                        help='cache the Radau references here (about a minute each)')


def main(args) -> int:
    """Check the extra, run every scene, write the files after each scene."""
    missing = common.missing_modules(REQUIRED)
    if missing:
        print(f"det_sim: error: bench needs {', '.join(missing)}, not installed: {EXTRA_HINT}",
              file=sys.stderr)
        return 1
    benchmark = _benchmark()
    if benchmark is None:
        return 1
    skipped = common.missing_modules(OPTIONAL)
    if skipped:
        print(f"det_sim: {', '.join(skipped)} not installed: "
              f"{'; '.join(OPTIONAL[name] for name in skipped)} (for those: {EXTRA_HINT})",
              file=sys.stderr)
    os.makedirs(args.out, exist_ok=True)
    beams, eps_values = args.beams, args.eps_b
    if args.quick:
        beams, eps_values = beams[:1], [0.20]
    for rows in benchmark.run(beams, eps_values, args.quick, args.repeats,
                              reference_dir=args.reference_dir,
                              log=lambda s: print(s, file=sys.stderr, flush=True)):
        # a long run keeps what it measured; the page names the command that measured it
        benchmark.write_tables(rows, args.out, command=command_line(args))
        if 'matplotlib' not in skipped:
            _plot(rows, args.out)
    kinds = 'csv,md' if 'matplotlib' in skipped else 'csv,md,png'
    print(f'wrote {args.out}/work_precision.{{{kinds}}}')
    return 0


def command_line(args) -> str:
    """Return the ``det_sim bench`` command line that runs what ``args`` ask for."""
    words = ['det_sim', 'bench', '--out', args.out, '--beams', ','.join(args.beams),
             '--eps-b', ','.join(f'{e:g}' for e in args.eps_b), '--repeats', str(args.repeats)]
    if args.quick:
        words.append('--quick')
    if args.reference_dir:
        words += ['--reference-dir', args.reference_dir]
    return shlex.join(words)


def _benchmark():
    """Import det_sim_ros.analysis.benchmark; None (with one line) if this install lacks it."""
    try:
        return importlib.import_module('det_sim_ros.analysis.benchmark')
    except ModuleNotFoundError as exc:
        if exc.name != 'det_sim_ros.analysis.benchmark':
            raise
        print('det_sim: bench is not available (det_sim_ros.analysis.benchmark is not '
              'installed)', file=sys.stderr)
        return None


def _plot(rows, out) -> None:
    """Draw work_precision.png: each solver's runs, error against CPU per simulated second."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np
    fig, ax = plt.subplots(figsize=(7, 5), dpi=90)
    for solver in dict.fromkeys(r['solver'] for r in rows):
        pts = [(r['cpu_per_sim_s'], r['err_dy']) for r in rows
               if r['solver'] == solver and np.isfinite(r['err_dy']) and r['err_dy'] > 0]
        if pts:
            xs, ys = zip(*sorted(pts))
            ax.loglog(xs, ys, 'o-', label=solver)
    ax.set_xlabel('CPU seconds per simulated second')
    ax.set_ylabel('max |Δy − Δy_ref| / stroke')
    ax.set_title('work-precision, step scenario')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out, 'work_precision.png'))
    plt.close(fig)
