"""
The ``sim_node`` entry point.

It runs as the console script, as ``ros2 run det_sim_ros sim_node`` and as ``python -m
det_sim_ros.cli.sim_node``.

``-h``/``--help`` prints the usage, the modes and the parameters (from the node's parameter
table) and exits 0 without starting anything; any other argument outside ``--ros-args ...
[--]`` is refused with one line (exit 1), since rcl would read a stray ``-p name:=value`` as a
remap rule and ignore the parameter; so is a ``-p`` or ``-r`` rule without ``:=``.

SIGINT and SIGTERM while the node's modules are still importing (rclpy, numpy, the kernel;
before :func:`det_sim_ros.ros.node.main` takes the signals over) exit quietly with code 0
instead of a KeyboardInterrupt traceback or a kill by the signal: nothing has been started
then, so there is nothing to finish. This module imports nothing heavy before that.
"""

import signal
import sys
import textwrap

from . import exit_at_once
from .ros_args import ros_rule_error

USAGE = 'usage: sim_node [-h] [--ros-args -p NAME:=VALUE ... [-r __ns:=/NAMESPACE]]'

HELP_HEAD = """\
Simulate dielectric elastomer actuators on buckled beams as a ROS 2 node: one voltage per DET
in ({inputs}), the actuator's state out ({outputs}; plates also {structure}); services
~/pause, ~/step, ~/reset (docs/topics.md). Stop it with Ctrl-C or SIGTERM.

modes (parameter mode):
  real_time  sim time follows the wall clock, scaled by real_time_factor (the default)
  free_run   as fast as possible; publishes /clock (real_time:=false is the same)
  lockstep   publishes /clock; a period runs only when the controller has answered the last
             sample (lockstep.sources answers, lockstep.timeout)

options:
  -h, --help  print this help and exit

parameters: after --ros-args, as -p NAME:=VALUE (e.g. sim_node --ros-args -p mode:=free_run
-p log.enabled:=false), or in the node: section of a scene file; "runtime" ones may also be
changed while the node runs (ros2 param set). Besides these: scene_file (default 'default': a
scene name in config/ or a path) and every scene key, e.g. -p physics.Rs:=1.0e+3
(docs/parameters.md).
"""


def _literal(value) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    return repr(value)


def _range(bounds) -> str:
    if bounds is None:
        return ''
    if all(isinstance(choice, str) for choice in bounds):
        return 'one of ' + ', '.join(bounds)
    return ' to '.join(str(end) if isinstance(end, int) else f'{end:g}' for end in bounds)


def help_text() -> str:
    """Return the ``--help`` text: usage, modes, options and the node parameters' table."""
    from ..io.contract import COMMAND_TOPICS, OUTPUT_FIELDS, STRUCTURE_TOPIC
    from ..ros.params import NODE_PARAMS
    intro, rest = HELP_HEAD.format(inputs=', '.join(COMMAND_TOPICS),
                                   outputs=', '.join(OUTPUT_FIELDS),
                                   structure=STRUCTURE_TOPIC).split('\n\n', 1)
    lines = [USAGE, '', textwrap.fill(' '.join(intro.split()), 95) + '\n\n' + rest]
    for name, param in NODE_PARAMS.items():
        facts = [f'default {_literal(param.default)}', _range(param.bounds),
                 'fixed at start' if param.read_only else 'runtime']
        lines.append(f'  {name}  ({"; ".join(fact for fact in facts if fact)})')
        lines.extend(textwrap.wrap(param.description, 95, initial_indent='      ',
                                   subsequent_indent='      '))
    return '\n'.join(lines) + '\n'


def stray_arguments(argv) -> list:
    """
    Return the arguments outside ``--ros-args ... [--]`` (``argv`` without the program name).

    These are what rcl does not read as ROS arguments.
    """
    stray, in_ros = [], False
    for arg in argv:
        if arg == '--ros-args':
            in_ros = True
        elif in_ros and arg == '--':
            in_ros = False
        elif not in_ros:
            stray.append(arg)
    return stray


def _quiet_stop(signum, frame):
    exit_at_once(0)   # a stop during start-up (rclpy's imports) is a clean stop


def main(args=None) -> int:
    """
    Run the simulator node (see :func:`det_sim_ros.ros.node.main`); return the exit code.

    ``args`` is the whole command line, program name first (default ``sys.argv``).
    """
    argv = (sys.argv if args is None else args)[1:]
    stray = stray_arguments(argv)
    if any(arg in ('-h', '--help') for arg in stray):
        sys.stdout.write(help_text())
        return 0
    if stray:
        sys.stderr.write(f'sim_node: unknown argument {stray[0]!r}: node parameters go after '
                         '--ros-args (sim_node --ros-args -p NAME:=VALUE); sim_node --help '
                         'lists them\n')
        return 1
    rule = ros_rule_error(argv)
    if rule:   # before rcl reads it: its own error is about lexeme types
        sys.stderr.write(f'sim_node: {rule}\n')
        return 1
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _quiet_stop)
    from ..ros.node import main as run_node
    from ..ros.spinning import limit_teardown
    code = run_node(args)
    limit_teardown()    # the interpreter's exit destroys the DDS participant
    return code


if __name__ == '__main__':
    sys.exit(main())
