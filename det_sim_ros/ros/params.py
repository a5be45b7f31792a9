"""
The node's parameters, as one ROS-free table.

The node declares them from it, the fleet loader checks fleet files against it, and the
parameter reference in docs/ is generated from it.

``NODE_PARAMS``: name -> :class:`Param` (default, description, read_only, bounds). The type of
the default is the parameter's type (an integer is accepted for a double); ``bounds`` is a
range (lo, hi), the allowed strings, or None. A :class:`Param` is a tuple, so
``default, description, read_only, bounds = NODE_PARAMS[name]`` works too.
"""

from __future__ import annotations

import difflib
import math
from typing import Any, Iterator, NamedTuple

from ..io.log.compression import COMPRESSIONS
from ..scenes.keys import PHYSICS_SPEC
from ..scenes.scene import scene_to_dict, SceneError
from ..scenes.sensors import sensors_to_dict

__all__ = ['NODE_PARAMS', 'Param', 'SCENE_PARAM_DESCRIPTION', 'SCENE_SECTIONS',
           'check_node_value', 'flatten', 'node_parameter_values', 'runtime_refusal',
           'scene_parameters', 'unknown_parameters']

SCENE_SECTIONS = ('scene', 'physics', 'integrator', 'structure', 'dets', 'amplifier',
                  'sensors')
SCENE_PARAM_DESCRIPTION = 'scene value (read-only; set in the scene file or with -p at start)'


class Param(NamedTuple):
    """
    One node parameter: default, description, read-only flag and bounds.

    Its default (whose type is the parameter's), what it does, whether it is fixed at start,
    and its range (lo, hi), allowed strings or None.
    """

    default: Any
    description: str
    read_only: bool
    bounds: tuple | None


NODE_PARAMS = {
    'mode': Param('', 'real_time: sim time follows the wall clock; free_run: as fast as '
                  'possible, publishes /clock; lockstep: publishes /clock and advances a period '
                  "only when the controller has answered the last sample ('' = from real_time)",
                  True, None),
    'real_time': Param(True, 'alias of mode: true = real_time, false = free_run (mode, when '
                       'set, wins)', True, None),
    'lockstep.sources': Param(1, 'lockstep: commands that answer a sample before the next '
                              'period runs (one per controller)', False, (1, 10000)),
    'lockstep.timeout': Param(0.0, 'lockstep: wall seconds to wait for the answers, then hold '
                              'the voltages, count a missed deadline and go on (0 = wait '
                              'forever)', False, (0.0, 3600.0)),
    'real_time_factor': Param(1.0, 'real-time mode: sim seconds per wall second', False,
                              (1.0e-3, 1.0e3)),
    'steps_per_tick': Param(10, 'free-run mode: control periods per timer tick', False,
                            (1, 100000)),
    'threads': Param(1, "threads that step the scene's independent coupled groups (the copies "
                     'of an array) in every period; the results do not depend on it', True,
                     (1, 256)),
    'max_catchup_steps': Param(1000, 'real-time mode: most steps run in one tick; the rest run '
                               'in later ticks (never skipped)', False, (1, 1000000)),
    'max_lag': Param(0.05, 'real-time mode: largest lag behind the wall clock, s of sim time; '
                     'beyond it the node slips (drops the excess wall time, never a sim step)',
                     False, (0.0, 3600.0)),
    'realtime_priority': Param(0, "real-time mode: run the node's threads under SCHED_FIFO at "
                               'this priority (1-98; needs CAP_SYS_NICE or an rtprio limit, '
                               'otherwise one warning and normal scheduling); 0 = off', True,
                               (0, 98)),
    'qos_sensor_data': Param(False, 'outputs best-effort SensorDataQoS instead of reliable '
                             'depth 10', True, None),
    'qos_keep_all': Param(False, 'outputs, /clock and command subscriptions reliable KEEP_ALL '
                          'instead of depth 10: over a lossy link every lost sample is '
                          'repaired, none overwritten (docs/fleets.md: QoS on real networks)',
                          True, None),
    'start_paused': Param(False, 'start paused (resume with ~/pause false, or ~/step)', True,
                          None),
    'diagnostics_period': Param(1.0, 'seconds between /diagnostics messages (wall clock)', True,
                                (0.01, 3600.0)),
    'log.enabled': Param(True, 'record the run to MCAP: commands in, outputs out, scene', True,
                         None),
    'log.path': Param('./det_sim_logs', 'MCAP log directory (a new file per run) or a .mcap '
                      'file', True, None),
    'log.split_mb': Param(256.0, 'start a new log file after this many MiB (0 = one file per '
                          'run and reset; then log.max_mb cannot cut a long run)', True,
                          (0.0, 1.0e6)),
    'log.max_mb': Param(2048.0, "keep the log directory's det_sim_*.mcap files under this many "
                        'MiB in all, oldest deleted first (0 = no limit)', True, (0.0, 1.0e9)),
    'log.max_files': Param(100, 'keep at most this many det_sim_*.mcap files in the log '
                           'directory, oldest deleted first (0 = no limit)', True, (0, 1000000)),
    'log.compression': Param('zstd', "MCAP chunk compression: 'zstd' (smallest files), 'lz4' "
                             "(a 100-DET array's log: about two thirds of the CPU in a loop, "
                             "~20 % larger files) or 'none'", True, tuple(COMPRESSIONS)),
    'info_period': Param(5.0, 'seconds between INFO status lines (wall clock), 0 = off', True,
                         (0.0, 3600.0)),
    # shape markers (det_sim_ros.ros.markers)
    'markers.rate_hz': Param(30.0, 'shape markers (visualization_msgs/MarkerArray on markers) '
                             'per simulated second, all logged; viewers get at most twice this '
                             'many per wall second; 0 = off', True, (0.0, 1.0e4)),
    'markers.frame_id': Param('', "'': one frame per DET (<namespace>/<DET name>); else all "
                              'DETs in this one frame, side by side', True, None),
    # the live view (det_sim_ros.ros.live; the 'live' extra): docs/visualization.md
    'live.enabled': Param(False, 'serve the outputs, markers, /diagnostics and sim time to '
                          'Foxglove or Lichtblick over the Foxglove WebSocket protocol (needs '
                          "the 'live' extra)", True, None),
    'live.port': Param(8765, 'live view: TCP port (0 = a free port, named in the start-up '
                       'line)', True, (0, 65535)),
    'live.rate_hz': Param(0.0, 'live view: output samples served per simulated second (0 = '
                          'every sample; the log keeps every sample either way)', True,
                          (0.0, 1.0e6)),
    'live.host': Param('127.0.0.1', "live view: address to listen on ('0.0.0.0': every "
                       'network interface; anyone who reaches it can command the node)', True,
                       None),
    # the predictability measure (det_sim_ros.ros.predictability): docs/predictability.md
    'predictability.mode': Param('auto', "'on': step a perturbed twin beside the run and report "
                                 'how far it drifts (/diagnostics, the predictability topic, the '
                                 "log; a WARN where the path stops being robust); 'auto': on "
                                 'unless the scene is an array (a twin doubles its physics); '
                                 "'off'", True, ('auto', 'on', 'off')),
    'predictability.parameter': Param('m', "the twin's perturbed physics parameter", True,
                                      tuple(k for k in PHYSICS_SPEC if k != 'n')),
    'predictability.relative': Param(1.0e-6, "the twin's parameter is value * (1 + this) (1e-6: "
                                     "a seventh digit; a fitted parameter's relative "
                                     'uncertainty asks whether it decides the path)', True,
                                     (-0.5, 0.5)),
    'predictability.tolerance_factor': Param(0.9, "the twin's integrator tolerance relative to "
                                             "the run's (1: the same)", True, (0.01, 100.0)),
    'predictability.limit': Param(0.05, 'the twin distance (a fraction of the stroke) beyond '
                                  'which the path is not robust', True, (1.0e-6, 10.0)),
    'allow_duplicate_name': Param(False, 'run even if another node of this fully qualified '
                                  'name is running (one warning); false: the newcomer of two '
                                  'stops with one FATAL line, on one host before it publishes '
                                  '(a host lock on the name), across hosts once it hears the '
                                  'established node (docs/topics.md)',
                                  True, None),
    'strict_parameters': Param(False, 'a parameter name the node does not know (-p, a params '
                               'file) stops the start with one FATAL line; false: one warning '
                               'naming the closest known name, and the start goes on', True,
                               None),
    'wait_for_subscribers': Param(0, 'publish sample 0 and start stepping only once this many '
                                  'subscriptions of displacement have matched (and received '
                                  'sample 0); 0 = at once (docs/real_time.md: the start of a '
                                  'run)', True, (0, 10000)),
}


def flatten(data: dict, prefix: str = '') -> Iterator[tuple[str, Any]]:
    """Yield nested mappings as (dotted name, value) pairs: {'a': {'b': 1}} -> ('a.b', 1)."""
    for key, value in data.items():
        if isinstance(value, dict):
            yield from flatten(value, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', value


def scene_parameters(scene) -> Iterator[tuple[str, Any]]:
    """
    Yield the loaded scene's values as (parameter name, value).

    Its ``node:`` section is left out (those are the node parameters); the ``amplifier``
    section and the ``sensors`` keys are all there, off or not.
    """
    data = scene_to_dict(scene)
    data.setdefault('amplifier', dict(scene.amplifier))
    data['sensors'] = sensors_to_dict(scene.sensors, full=True)
    for name, value in flatten(data):
        if not name.startswith('node.'):
            yield name, value


def check_node_value(name: str, value, where: str = 'scene key node.'):
    """
    Return a node parameter's value checked against its type and range.

    An integer is accepted for a double; a value that does not fit raises :class:`SceneError`
    naming the key.
    """
    default, bounds = NODE_PARAMS[name].default, NODE_PARAMS[name].bounds
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    kind = {bool: 'true or false', int: 'an integer', str: 'a string',
            float: 'a number'}[type(default)]
    if not ok:
        raise SceneError(f'{where}{name}: must be {kind} (got {value!r})')
    if isinstance(default, str) and bounds is not None:
        if value not in bounds:
            raise SceneError(f"{where}{name}: one of {', '.join(bounds)} (got {value!r})")
    elif bounds is not None and not (math.isfinite(value) and bounds[0] <= value <= bounds[1]):
        raise SceneError(f'{where}{name}: out of range [{bounds[0]:g}, {bounds[1]:g}] '
                         f'(got {value!r})')
    return value


def node_parameter_values(scene_node: dict, overrides: dict) -> dict:
    """
    Return every node parameter's checked start value, in table order.

    A ``-p name:=value`` override (``overrides``: name -> value) wins over the scene file's
    ``node:`` section (``scene_node``, nested or dotted; ``-p node.name:=value`` overrides it
    too), which wins over the default. Raise :class:`SceneError` for an unknown key or a value
    that does not fit.
    """
    node_section = dict(flatten(scene_node))       # node: {log: {enabled: ...}} too
    for name, value in overrides.items():
        if name.startswith('node.'):
            node_section[name[5:]] = value
    unknown = sorted(set(node_section) - set(NODE_PARAMS))
    if unknown:
        raise SceneError(f"scene key 'node.{unknown[0]}': unknown (allowed: "
                         + ', '.join(NODE_PARAMS) + ')')
    values = {}
    for name, param in NODE_PARAMS.items():
        if name in overrides:
            values[name] = check_node_value(name, overrides[name], 'parameter ')
        else:
            values[name] = check_node_value(name, node_section.get(name, param.default))
    return values


def runtime_refusal(name: str, value) -> str:
    """
    Return why a change of parameter ``name`` to ``value`` while running is refused.

    The answer is '' if it is not refused. These are the checks beyond the declared type and
    range (finite, positive, ...).
    """
    if name == 'real_time_factor':
        ok, need = isinstance(value, float) and math.isfinite(value) and value > 0.0, '> 0'
    elif name in ('steps_per_tick', 'max_catchup_steps', 'lockstep.sources'):
        ok, need = isinstance(value, int) and value >= 1, '>= 1'
    elif name in ('lockstep.timeout', 'max_lag'):
        ok, need = isinstance(value, float) and math.isfinite(value) and value >= 0.0, '>= 0 s'
    else:
        return ''
    return '' if ok else f'{name} must be {need} (got {value!r})'


def unknown_parameters(given, known) -> list:
    """
    Return one sentence per name in ``given`` that is not in ``known``, naming the closest known.

    ``given``: the names the node was started with (``-p``, a params file); ``known``: every
    name it declares. The closest is by difflib's similarity among the known names of the same
    section first (``lockstep.timout`` -> ``lockstep.timeout``), then among all of them.
    """
    known = sorted(known)
    sentences = []
    for name in sorted(set(given) - set(known)):
        section = name.rpartition('.')[0]
        same_section = [k for k in known if k.rpartition('.')[0] == section] if section else []
        close = (difflib.get_close_matches(name, same_section, 1, 0.5)
                 or difflib.get_close_matches(name, known, 1, 0.6))
        hint = f"; did you mean '{close[0]}'?" if close else ' (sim_node --help lists them)'
        sentences.append(f"unknown parameter '{name}' (ignored){hint}")
    return sentences
