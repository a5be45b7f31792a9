"""
``det_sim plot``: every channel of a sim_node MCAP log against sim time, and a summary.

The plot is a PNG, the summary text; det_sim_ros.io.logplot reads and draws the log.
"""

from __future__ import annotations

import os
import sys

from .. import common

HELP = 'PNG of every channel of a sim_node MCAP log against sim time, and a text summary'


def add_arguments(parser) -> None:
    """Add the log file(s), --out, --dpi."""
    parser.add_argument('log', nargs='+', help='MCAP file(s) or a directory of split files')
    parser.add_argument('--out', default=None,
                        help='output folder (default: the folder of the log)')
    parser.add_argument('--dpi', type=int, default=80, help='PNG resolution (default: 80)')


def main(args) -> int:
    """Print and write the summary, draw the PNG (with matplotlib)."""
    from ...io import logplot
    data = logplot.read_log(args.log)
    first = data.files[0]
    out = args.out or os.path.dirname(os.path.abspath(first))
    os.makedirs(out, exist_ok=True)
    stem = os.path.splitext(os.path.basename(first))[0]
    text = logplot.summary(data)
    print(text, end='')
    files = [common.write_text(os.path.join(out, f'{stem}_summary.txt'), text)]
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print(f'det_sim: {common.PLOTS_HINT}', file=sys.stderr)
    else:
        files.append(logplot.plot_log(data, os.path.join(out, f'{stem}.png'), dpi=args.dpi))
    common.print_written(files)
    return 0
