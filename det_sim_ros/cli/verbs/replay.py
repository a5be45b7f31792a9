"""
``det_sim replay`` (also the ``det_sim_replay`` command): tools for sim_node logs.

Re-simulate a logged run and compare (``resim``), republish a log with its recorded timing
(``play``), summarize a log (``info``), rewrite an unfinished log as a finished file
(``recover``). A log directory means its newest run, as for plot and view (one line says so
when it holds several; det_sim_ros.io.log.runs): files of unrelated runs are never chained.
"""

from __future__ import annotations

import argparse

from .. import common, log_checks
from ..ros_args import ros_rule_error

HELP = 're-simulate, republish, summarize or recover sim_node MCAP logs'
DESCRIPTION = 'Re-simulate or republish det_sim_ros MCAP logs.'
PROG = 'det_sim_replay'


def add_arguments(parser) -> None:
    """
    Add the subcommands resim, play, info, recover and their options.

    Each takes ``--ros-args ...`` at the end of the line; only ``play`` passes them on, to its
    node.
    """
    sub = parser.add_subparsers(dest='command', required=True)
    resim = sub.add_parser('resim', help='re-simulate a log and compare with its outputs')
    resim.add_argument('log', nargs='+', help='MCAP file(s) or a directory of split files')
    resim.add_argument('--tolerance', type=float, default=0.0,
                       help='largest accepted |deviation| (default 0: bit-exact)')
    resim.add_argument('--method', default=None, help='stepper (default: as logged)')
    resim.add_argument('--substeps', type=int, default=None, help='substeps (default: as logged)')
    resim.set_defaults(action=_resim)
    play = sub.add_parser('play', help='republish a log with its recorded timing')
    play.add_argument('log', nargs='+')
    play.add_argument('-r', '--rate', type=float, default=1.0, help='rate factor (0: max)')
    play.add_argument('--start-offset', type=float, default=0.0, help='skip the first S s')
    play.add_argument('-l', '--loop', action='store_true')
    play.add_argument('--clock', action='store_true', help='publish /clock from log time')
    play.add_argument('--topics', nargs='*', default=None)
    play.set_defaults(action=_play)
    info = sub.add_parser('info', help='summarize a log')
    info.add_argument('log', nargs='+')
    info.set_defaults(action=_info)
    rec = sub.add_parser('recover', help='rewrite an unfinished log as a finished file')
    rec.add_argument('log')
    rec.add_argument('output')
    rec.set_defaults(action=_recover)
    for name, subparser in sub.choices.items():
        # ROS arguments end the line; only the player node uses them
        subparser.add_argument('--ros-args', dest='ros_args', nargs=argparse.REMAINDER,
                               default=None, help='ROS arguments for the player node (the rest '
                               'of the line)' if name == 'play' else argparse.SUPPRESS)


def main(args) -> int:
    """Run the chosen subcommand; return its exit code."""
    return args.action(args)


def _open_run(args):
    """Return a LogReader of the run ``args.log`` names (a directory: its newest run)."""
    from ...io.log import log_files
    try:
        log_files(args.log)
    except FileNotFoundError:   # nothing to tell apart: the checks say what is wrong
        return log_checks.open_log(args.log)
    [files] = common.log_runs_to_use(args.log, f'replay {args.command}')
    return log_checks.open_log(files)


def _resim(args) -> int:
    from ...io.replay import resimulate
    reader = _open_run(args)
    result = resimulate(reader.files, method=args.method, substeps=args.substeps)
    print(result.table())
    ok = result.ok(args.tolerance)
    print('bit-exact' if ok and not any(result.max_deviation.values()) else
          ('within tolerance' if ok else 'MISMATCH'))
    return _torn_exit(reader.files, 0 if ok else 1)


def _torn_exit(files, code: int) -> int:
    """Return ``code``; raise the one line (exit code 1) if some of ``files`` are torn."""
    note = log_checks.torn_note(log_checks.torn_files(files))
    if note:
        raise log_checks.LogFileError(note)
    return code


def _info(args) -> int:
    reader = _open_run(args)
    counts: dict[str, int] = {}
    first = last = None
    for message in reader.messages():
        counts[message.topic] = counts.get(message.topic, 0) + 1
        first = message.log_time if first is None else first
        last = message.log_time
    print(f'files: {", ".join(reader.files)}')
    print(f"profile: {reader.profile}; det_sim_ros {reader.info.get('version', '?')}; "
          f"{'finished' if reader.complete else 'unfinished (the readable part)'}")
    if first is not None:
        print(f'log time: {first / 1e9:.6f} .. {last / 1e9:.6f} s')
    for topic, count in counts.items():
        print(f'  {topic}  [{reader.topics.get(topic, "?")}]  {count} messages')
    return _torn_exit(reader.files, 0)


def _recover(args) -> int:
    from ...io.log import recover
    reader = log_checks.open_log(args.log)
    outcome = recover(reader.files, args.output)
    print(f"{outcome['messages']} messages written to {args.output}"
          + ('' if outcome['complete'] else ' (source was unfinished)'))
    return 0


def _play(args) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from ...ros.play import play
    ros_args = [] if args.ros_args is None else ['--ros-args', *args.ros_args]
    rule = ros_rule_error(ros_args)
    if rule:
        raise common.CliError(rule)
    files = _open_run(args).files
    torn = log_checks.torn_files(files)
    if torn:   # nothing is published from a file that may end anywhere
        raise log_checks.LogFileError(log_checks.torn_note(torn, 'not played'))
    rclpy.init(args=[PROG, *ros_args])
    try:
        stats = play(files, rate=args.rate, start_offset=args.start_offset, loop=args.loop,
                     clock=args.clock, topics=args.topics)
        print(f'published {sum(stats.published.values())} messages'
              + (f', {stats.clock} clock ticks' if args.clock else ''))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    return 0
