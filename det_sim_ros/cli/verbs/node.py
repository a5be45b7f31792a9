"""
The ``det_sim`` verbs that talk to a running sim_node (for installs without the ros2 CLI).

``send``, ``watch``, ``pause``, ``resume``, ``advance``, ``reset`` and ``param``, each a
:class:`Verb` here, on top of det_sim_ros.ros.shell; docs/shell.md gives the ros2 command each
stands in for. Every verb takes ``--ns`` (the node's namespace), ``--node`` (its name,
default sim_node) and ``--timeout`` (wall seconds to wait for the node). A node that does not
answer, a refusal or a bad value: one line on stderr, exit code 1 (a bad argument: 2).
"""

from __future__ import annotations

import math
import sys
import time
from typing import Callable, NamedTuple

from .. import common

__all__ = ['Verb', 'VERBS']


class Verb(NamedTuple):
    """A verb of ``det_sim``: its help line, description, parser setup and action."""

    HELP: str
    DESCRIPTION: str
    add_arguments: Callable
    main: Callable


def _target_arguments(parser) -> None:
    parser.add_argument('--ns', default='', help="the node's namespace, e.g. arm1 (default: "
                        'none)')
    parser.add_argument('--node', default='sim_node', help="the node's name (default: "
                        '%(default)s)')
    parser.add_argument('--timeout', type=common.positive, default=5.0,
                        help='wall seconds to wait for the node (default: %(default)g)')


def _run(args, action) -> int:
    """Open a shell on the node, run ``action(shell)``; a ShellError is one line, exit 1."""
    from ...ros.shell import NodeShell, ShellError
    try:
        with NodeShell(args.ns, args.node, args.timeout) as shell:
            return int(action(shell) or 0)
    except ShellError as exc:
        print(f'det_sim: error: {exc}', file=sys.stderr)
        return 1


# -- send -----------------------------------------------------------------------------------
def _send_arguments(parser) -> None:
    parser.add_argument('voltages', nargs='+', metavar='NAME=VOLTS|VOLTS',
                        help='a voltage per DET name (det0=2000), or one value per DET in '
                        'command order (2000 0)')
    _target_arguments(parser)


def _parse_voltages(items) -> tuple[list[str] | None, list[float]]:
    """Return (DET names or None for plain values in DET order, voltages)."""
    names, volts = [], []
    for item in items:
        name, sep, text = item.rpartition('=')
        try:
            volts.append(float(text))
        except ValueError:
            raise common.CliError(f'expected NAME=VOLTS or VOLTS, got {item!r}') from None
        if not math.isfinite(volts[-1]):
            raise common.CliError(f'{item!r}: the voltage must be a finite number')
        names.append(name if sep else None)
    if any(n is None for n in names) and any(n is not None for n in names):
        raise common.CliError('give either NAME=VOLTS for some DETs or plain VOLTS for all, '
                              'not both')
    return (None if names[0] is None else names), volts


def _send(args) -> int:
    names, volts = _parse_voltages(args.voltages)

    def action(shell):
        # one call for both: a send costs one parameter round trip, clamped or not
        dets, v_max = shell.get_parameters(['structure.dets', 'physics.v_max'])
        dets, v_max = list(dets), float(v_max)
        if names is None and len(volts) != len(dets):
            raise common.CliError(f'{len(volts)} voltage(s) for {len(dets)} DET(s): give one per '
                                  f"DET in command order [{', '.join(dets)}]")
        bad = [n for i, n in enumerate(names or ()) if n not in dets or n in names[:i]]
        if bad:
            raise common.CliError(f'unknown or repeated DET {bad[0]!r}; the DETs: '
                                  + ', '.join(dets))
        topic = shell.send(volts, names)
        pairs = list(zip(names or dets, volts))
        print(f"sent {', '.join(f'{n}={v:g}' for n, v in pairs)} V on {topic}")
        clamped = [f'{n}: {v:g} V' for n, v in pairs if not 0.0 <= v <= v_max]
        if clamped:   # the node clamps them (and warns): say so here too
            from ...io.contract import clamp_message
            print(f'det_sim: note: the node applies {clamp_message(topic, clamped, v_max)}',
                  file=sys.stderr)
    return _run(args, action)


# -- watch ----------------------------------------------------------------------------------
def _watch_arguments(parser) -> None:
    parser.add_argument('--csv', action='store_true',
                        help='one CSV row per sample (default: a line per wall second)')
    parser.add_argument('--count', type=int, default=0,
                        help='stop after this many rows or lines (default: until Ctrl-C)')
    parser.add_argument('--duration', type=common.positive, default=None,
                        help='stop after this many wall seconds')
    _target_arguments(parser)


def _watch(args) -> int:
    from ..watch import Watcher
    watcher = Watcher(csv=args.csv, count=args.count, stream=sys.stdout)

    def action(shell):
        from ...ros.shell import ShellError
        watcher.subscribe(shell)
        start = time.monotonic()
        end = math.inf if args.duration is None else start + args.duration
        check_at = start + args.timeout
        try:
            while not watcher.done() and time.monotonic() < end:
                shell.spin(0.05)
                now = time.monotonic()
                watcher.tick(now)
                if watcher.waiting() and now > check_at:
                    check_at = math.inf
                    topic = shell.topic('displacement')
                    if not shell.node_publishes('displacement'):   # no node: nothing will come
                        raise ShellError(f'no sample on {topic} within {args.timeout:g} s: '
                                         f'{shell.target} does not publish it (is sim_node '
                                         'running, with this --ns and --node?)')
                    print(f'det_sim: {shell.target} has published no sample on {topic} yet '
                          '(paused?); waiting', file=sys.stderr)
        except KeyboardInterrupt:   # the usual way to stop watching
            pass
        loss = watcher.loss_line() if args.csv else ''
        if loss:
            print(f'det_sim: watch: {loss}', file=sys.stderr)
        return 0
    try:
        return _run(args, action)
    except KeyboardInterrupt:       # also before the first sample, or while it winds up
        return 0


# -- pause, resume, advance, reset ------------------------------------------------------------
def _pause(args) -> int:
    return _run(args, lambda shell: print(shell.pause(True)))


def _resume(args) -> int:
    return _run(args, lambda shell: print(shell.pause(False)))


def _reset(args) -> int:
    return _run(args, lambda shell: print(shell.trigger('reset')))


def _advance_arguments(parser) -> None:
    parser.add_argument('periods', type=int, nargs='?', default=1,
                        help='control periods to advance (default: 1)')
    _target_arguments(parser)


def _advance(args) -> int:
    if args.periods < 1:
        raise common.CliError(f'periods must be >= 1, got {args.periods}')

    def action(shell):
        for _ in range(args.periods):
            answer = shell.trigger('step')
        print(f'advanced {args.periods} period(s): {answer}')
    return _run(args, action)


# -- param --------------------------------------------------------------------------------------
def _param_arguments(parser) -> None:
    parser.add_argument('action', choices=('get', 'set'))
    parser.add_argument('name', help='parameter name, e.g. real_time_factor')
    parser.add_argument('value', nargs='?', default=None,
                        help='set: the new value (read as YAML: 2.0, 10, true, text)')
    _target_arguments(parser)


def _param(args) -> int:
    import yaml
    if (args.action == 'set') != (args.value is not None):
        raise common.CliError('param get NAME, or param set NAME VALUE')

    def action(shell):
        if args.action == 'get':
            value = shell.get_parameter(args.name)
            print("''" if value == '' else value)
            return
        try:
            value = yaml.safe_load(args.value)
        except yaml.YAMLError:
            value = args.value
        shell.set_parameter(args.name, value)
        print(f'{args.name} = {shell.get_parameter(args.name)}')
    return _run(args, action)


VERBS = {
    'send': Verb('send voltages to a running sim_node (ros2 topic pub)', 'Publish one voltage '
                 'command: NAME=VOLTS for some DETs (the others hold) or VOLTS for every DET.',
                 _send_arguments, _send),
    'watch': Verb("watch a running sim_node's outputs (ros2 topic echo)", 'Print a line per '
                  'wall second, or with --csv every sample, of the node outputs.',
                  _watch_arguments, _watch),
    'pause': Verb('pause a running sim_node (ros2 service call ~/pause true)', None,
                  _target_arguments, _pause),
    'resume': Verb('resume a paused sim_node (ros2 service call ~/pause false)', None,
                   _target_arguments, _resume),
    'advance': Verb('advance a paused sim_node by N control periods (~/step N times)', None,
                    _advance_arguments, _advance),
    'reset': Verb('reset a running sim_node to t = 0 (ros2 service call ~/reset)', None,
                  _target_arguments, _reset),
    'param': Verb("get or set a running sim_node's parameter (ros2 param get/set)", None,
                  _param_arguments, _param),
}
