"""
``det_sim fit``: scene parameters fitted to measured logs; a scene file, a report and a plot.

    det_sim fit LOG [LOG ...] --params E_M,eta_M,eta_v,Rs [--scene base.yaml] [-o fitted.yaml]

A log is sim_node's MCAP log, a rig's MCAP log with ``--map`` (which topic and field is the
voltage and which the measured outputs) or a CSV file (t, v, dy / charge / current). The
progress goes to stderr, the report to stdout and beside the scene file. Exit code 0 when the
fit converged, 1 when it did not (the files are still written), 2 for bad input.
"""

from __future__ import annotations

import argparse
import sys

from .. import common

HELP = 'fit scene parameters to measured logs (MCAP or CSV): a scene file, a report, a plot'
DESCRIPTION = (
    'Replay the logged voltage commands through the model and fit the named parameters by '
    'weighted least squares (log scale, several starts). Writes the fitted scene (loadable by '
    'sim_node and load_scene), a report (residuals, standard errors, 95 % intervals, '
    'correlations, parameters the log cannot identify) and a PNG of measured vs simulated. '
    'docs/calibration.md describes it.')


def _pairs(kind):
    def parse(text):
        key, sep, value = text.partition('=')
        if not sep or not key.strip() or not value.strip():
            raise argparse.ArgumentTypeError(f'expected NAME={kind}, got {text!r}')
        return key.strip(), value.strip()
    return parse


def add_arguments(parser) -> None:
    """Add the logs, --params, --scene, -o, the mapping and the search options."""
    parser.add_argument('logs', nargs='+', metavar='LOG',
                        help='MCAP log (file or directory) or CSV file; several fit together')
    parser.add_argument('--params', required=True,
                        help='parameters to fit, comma-separated scene keys: E_M,eta_M,Rs,...')
    parser.add_argument('--scene', default=None,
                        help="base scene (default: the scene sim_node's log recorded, else "
                             "'default')")
    parser.add_argument('-o', '--output', default='fitted.yaml',
                        help='fitted scene file; the report and the PNG go beside it '
                             '(default: %(default)s)')
    parser.add_argument('--map', dest='mapping', action='append', default=[],
                        metavar='CHANNEL=TOPIC[.FIELD][[INDEX]][*SCALE]',
                        help="a rig log's channel: voltage, dy, charge or current (repeat)")
    parser.add_argument('--start', action='append', type=_pairs('VALUE'), default=[],
                        metavar='NAME=VALUE', help="start value (default: the scene's)")
    parser.add_argument('--bounds', action='append', type=_pairs('LOW:HIGH'), default=[],
                        metavar='NAME=LOW:HIGH',
                        help='bounds; either side may be empty (default: start/100..start*100)')
    parser.add_argument('--sigma', action='append', type=_pairs('VALUE'), default=[],
                        metavar='CHANNEL=VALUE',
                        help='noise level of a channel, SI units (default: from the data)')
    parser.add_argument('--starts', type=int, default=3, help='local searches (default: 3)')
    parser.add_argument('--max-evaluations', type=int, default=60,
                        help='residual evaluations per local search (default: 60)')
    parser.add_argument('--parallel', default='auto',
                        choices=('auto', 'threads', 'processes', 'serial'),
                        help='how the sensitivity runs share the cores (default: auto = threads '
                             'when one run takes 0.5 s or more, else serial)')
    parser.add_argument('--no-coarse', action='store_true',
                        help="search at the scene's own level alone, not at the coarse level "
                             'first (slower: docs/calibration.md, Two levels)')
    parser.add_argument('--no-plots', action='store_true', help='write no PNG')
    parser.add_argument('--quiet', action='store_true', help='no progress on stderr')


def _number(name: str, text: str) -> float:
    import math
    try:
        value = float(text)
    except ValueError:
        raise common.CliError(f'{name}: {text!r} is not a number') from None
    if not math.isfinite(value):
        raise common.CliError(f'{name}: {text!r} is not a finite number')
    return value


def _bounds(pairs) -> dict:
    bounds = {}
    for name, text in pairs:
        low, sep, high = text.partition(':')
        if not sep:
            raise common.CliError(f'--bounds {name}={text}: expected LOW:HIGH (either may be '
                                  'empty)')
        bounds[name] = tuple(_number(f'--bounds {name}', v) if v.strip() else None
                             for v in (low, high))
    return bounds


def main(args) -> int:
    """Fit, write the scene, report and PNG, print the report; 1 if it did not converge."""
    if common.missing_modules(['scipy']):
        raise common.CliError("det_sim fit needs scipy: pip install 'scipy>=1.11'")
    if args.starts < 1 or args.max_evaluations < 1:
        raise common.CliError('--starts and --max-evaluations must be at least 1')
    from ...calibration import fit
    from ...calibration.report import output_paths
    start = {name: _number(f'--start {name}', text) for name, text in args.start}
    sigma = {name: _number(f'--sigma {name}', text) for name, text in args.sigma}

    def progress(line):
        print(f'det_sim fit: {line}', file=sys.stderr, flush=True)
    result = fit(args.logs, args.params, args.scene, mapping=args.mapping or None, start=start,
                 bounds=_bounds(args.bounds), sigma=sigma, starts=args.starts,
                 max_evaluations=args.max_evaluations, parallel=args.parallel,
                 coarse=not args.no_coarse, progress=None if args.quiet else progress)
    written = result.write(args.output, plot=not args.no_plots)
    print(result.report(), end='')
    common.print_written(written)
    if not args.no_plots and output_paths(args.output)[2] not in written:
        print(f'det_sim fit: {common.PLOTS_HINT}', file=sys.stderr)
    if not result.converged:
        print(f'det_sim fit: the fit {result.message} (the report is in {written[1]})',
              file=sys.stderr)
        return 1
    return 0
