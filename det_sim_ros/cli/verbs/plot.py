"""
``det_sim plot``: every channel of a sim_node MCAP log against sim time, and a summary.

The plot is a PNG, the summary text, per run (named after the run's first file); a log
directory means its newest run (``--each-run``: every run apart, det_sim_ros.io.log.runs);
det_sim_ros.io.logplot reads and draws the log. The
summary file holds every channel; the screen gets one row per quantity for a log of many DETs
(det_sim_ros.cli.plot_summary), or every channel with ``--all``.
"""

from __future__ import annotations

import os
import sys

from .. import common
from ..plot_summary import screen_summary

HELP = 'PNG of every channel of a sim_node MCAP log against sim time, and a text summary'


def add_arguments(parser) -> None:
    """Add the log file(s), --out, --dpi."""
    parser.add_argument('log', nargs='+',
                        help='MCAP file(s) or a log directory (its newest run; the files of a '
                        'run split or reset stay one run)')
    parser.add_argument('--out', default=None,
                        help='output folder (default: the folder of the log)')
    parser.add_argument('--dpi', type=int, default=80, help='PNG resolution (default: 80)')
    parser.add_argument('--all', action='store_true', dest='all_channels',
                        help='print every channel (default: one row per quantity when the '
                        'log has more than 4 DETs; the summary file always has every channel)')
    parser.add_argument('--each-run', action='store_true',
                        help='every run among the files apart, each its own PNG and summary '
                        '(default: the newest run)')


def main(args) -> int:
    """Print and write the summary, draw the PNG (with matplotlib): per run, named after it."""
    from ...io import logplot
    files = []
    for run in common.log_runs_to_use(args.log, 'plot', each=args.each_run):
        files += _plot_run(logplot, run, args)
    common.print_written(files)
    return 0


def _plot_run(logplot, paths, args) -> list:
    data = logplot.read_log(paths)
    first = data.files[0]
    out = args.out or os.path.dirname(os.path.abspath(first))
    os.makedirs(out, exist_ok=True)
    stem = os.path.splitext(os.path.basename(first))[0]   # the run's name: one PNG per run
    text = logplot.summary(data)
    print(text if args.all_channels else screen_summary(data, text), end='')
    files = [common.write_text(os.path.join(out, f'{stem}_summary.txt'), text)]
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print(f'det_sim: {common.PLOTS_HINT}', file=sys.stderr)
    else:
        files.append(logplot.plot_log(data, os.path.join(out, f'{stem}.png'), dpi=args.dpi))
    return files
