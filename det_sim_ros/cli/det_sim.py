"""
``det_sim``: the model offline (no ROS) and the ROS tools, one verb per module.

The offline verbs write data (CSV, JSON) and plots (PNG); the ROS tools are ``fleet`` and
``replay play``. There is one verb per module in det_sim_ros.cli.verbs::

    det_sim statics [--beams fixed,simply_supported] [--eps-range 0:0.3:61]
                    [--eps-b 0.15,0.20,0.25]
    det_sim step    [--beams fixed,simply_supported] [--eps-b 0.15,0.20,0.25] [--t-end 4.5]
    det_sim bench   [--quick] [--out DIR] ...   (work-precision benchmark; the 'bench' extra)
    det_sim plot LOG.mcap [--out DIR] [--all]         (every channel of a sim_node log, PNG)
    det_sim linearize [--voltage 1500] [--branch buckled+] [--json]   (A, B, C, D; Bode)
    det_sim predictability [--input pwm|switching|step] [--hz 10] | --log LOG   [--check]
                    (a perturbed twin beside a run: where its path stops being robust)
    det_sim fit LOG [LOG ...] --params E_M,eta_M [--scene S] [-o fitted.yaml] [--map ...]
                    (scene parameters fitted to measured logs: scene file, report, PNG)
    det_sim fleet FLEET.yaml [--host NAME] [--log-dir DIR]   (sim_node processes, one per
                    namespace; Ctrl-C stops them all; det_sim_ros.ros.fleet describes the file)
    det_sim replay {resim,play,info,recover} LOG ...   (also the command det_sim_replay)
    det_sim view LOG [--port 8765] [--speed 1]   (a log in Foxglove or Lichtblick; 'live' extra)
    det_sim send det0=2000 | 2000 0   det_sim watch [--csv]   det_sim pause | resume | reset
    det_sim advance N   det_sim param get|set NAME [VALUE]   (a running sim_node, found by
                    --ns and --node; docs/shell.md: the ros2 commands they stand in for)

The scene verbs (statics, step, linearize) take ``--scene PATH_OR_NAME`` (default 'default'),
``--set key=value`` (repeatable, e.g. ``--set physics.Rs=1e3 --set scene.fidelity=consistent``),
``--out DIR`` (default ./det_sim_out), ``--dpi N`` and ``--no-plots``. Plots need matplotlib
(``pip install .[plots]``); without it the CSV files are still written. Bad arguments and
invalid scenes give one line on stderr and exit code 2; no command prints a traceback
(det_sim_ros.cli.common.run gives the exit codes).

A verb module has ``HELP`` (its line in ``det_sim --help``), optionally ``DESCRIPTION``,
``add_arguments(parser)`` and ``main(args) -> exit code``; it imports what it runs (numpy, the
model, matplotlib, rclpy) inside its functions, so building the parser stays cheap.
"""

from __future__ import annotations

import argparse
import sys

from . import common
from .verbs import (bench, fit, fleet, linearize, node, plot, predictability, replay, statics,
                    step, view)

__all__ = ['main', 'main_replay', 'build_parser', 'VERBS']

PROG = 'det_sim'
VERBS = {'statics': statics, 'step': step, 'bench': bench, 'plot': plot,
         'linearize': linearize, 'predictability': predictability, 'fit': fit, 'fleet': fleet,
         'replay': replay, 'view': view,
         **node.VERBS}


def build_parser() -> argparse.ArgumentParser:
    """Build the ``det_sim`` parser: one sub-parser per verb."""
    parser = argparse.ArgumentParser(
        prog=PROG, description='Run the DET-buckled-beam model offline (no ROS): statics '
        '(Fig. 5), step responses (Fig. 6), integration benchmark, plots of sim_node logs, '
        'linear models. Writes CSV, JSON and PNG files. And with ROS: fleet starts several '
        'sim_node processes from one YAML file; replay re-simulates or republishes logs; '
        'send, watch, pause, resume, advance, reset and param talk to a running sim_node.')
    sub = parser.add_subparsers(dest='verb', metavar='{' + ','.join(VERBS) + '}')
    for name, verb in VERBS.items():
        verb_parser = sub.add_parser(name, help=verb.HELP,
                                     description=getattr(verb, 'DESCRIPTION', None))
        verb.add_arguments(verb_parser)
        verb_parser.set_defaults(run=verb.main)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``det_sim`` console script; returns the exit code."""
    parser = build_parser()
    args = _parse(parser, argv)
    if isinstance(args, int):
        return args
    if args.verb is None:
        parser.print_usage(sys.stderr)
        names = list(VERBS)
        print(f'{PROG}: error: choose a subcommand: {", ".join(names[:-1])} or {names[-1]}',
              file=sys.stderr)
        return 2
    if args.verb not in node.VERBS:
        common.interruptible()
    return common.run(args.run, args, PROG)


def main_replay(argv=None) -> int:
    """Entry point of the ``det_sim_replay`` console script: ``det_sim replay`` on its own."""
    parser = argparse.ArgumentParser(prog=replay.PROG, description=replay.DESCRIPTION)
    replay.add_arguments(parser)
    args = _parse(parser, argv)
    if isinstance(args, int):
        return args
    common.interruptible()
    return common.run(replay.main, args, replay.PROG)


def _parse(parser, argv):
    """Return the parsed arguments, or argparse's exit code (--help: 0, a bad argument: 2)."""
    try:
        return parser.parse_args(sys.argv[1:] if argv is None else list(argv))
    except SystemExit as exc:
        return int(exc.code or 0)


if __name__ == '__main__':
    sys.exit(main())
