"""
What a log says about its types and topics, in the rosbag2 conventions.

Each type's complete ``ros2msg`` definition (the schema), the type name of a message, and
the ``offered_qos_profiles`` channel metadata (Jazzy's YAML form). No rclpy needed.
"""

from __future__ import annotations

import os
import re
import sys
from typing import Mapping

from .cdr import split_type

__all__ = ['message_definition', 'type_name_of', 'qos_profiles_yaml', 'DELIMITER']

DELIMITER = '=' * 80 + '\n'

_PRIMITIVES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                         'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'})
_FIELD_TYPE = re.compile(r'^\s*([A-Za-z][A-Za-z0-9_/]*)')

# Used only when no ROS share directory has the .msg files (ROS-free installs); comments dropped.
_BUILTIN_MSG = {
    'builtin_interfaces/msg/Time': 'int32 sec\nuint32 nanosec\n',
    'std_msgs/msg/Header': 'builtin_interfaces/Time stamp\nstring frame_id\n',
    'std_msgs/msg/MultiArrayDimension': 'string label\nuint32 size\nuint32 stride\n',
    'std_msgs/msg/MultiArrayLayout': 'MultiArrayDimension[] dim\nuint32 data_offset\n',
    'std_msgs/msg/Float64MultiArray': 'MultiArrayLayout layout\nfloat64[] data\n',
    'sensor_msgs/msg/JointState': ('std_msgs/Header header\n\nstring[] name\nfloat64[] position\n'
                                   'float64[] velocity\nfloat64[] effort\n'),
    'rosgraph_msgs/msg/Clock': 'builtin_interfaces/Time clock\n',
}


def _share_dirs() -> list[str]:
    dirs = []
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            dirs.append(os.path.join(prefix, 'share'))
    dirs.append(os.path.join(sys.prefix, 'share'))
    dirs.append(os.path.join(sys.base_prefix, 'share'))
    return list(dict.fromkeys(dirs))


def _msg_text(name: str) -> str:
    package, kind, type_ = split_type(name)
    for share in _share_dirs():
        path = os.path.join(share, package, kind, type_ + '.msg')
        if os.path.isfile(path):
            with open(path, encoding='utf-8') as stream:
                return stream.read()
    full = f'{package}/{kind}/{type_}'
    if full in _BUILTIN_MSG:
        return _BUILTIN_MSG[full]
    raise LookupError(f'no .msg definition found for {name!r} in ' + ', '.join(_share_dirs()))


def _dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for line in text.splitlines():
        line = line.split('#', 1)[0]
        match = _FIELD_TYPE.match(line)
        if not match or not line[match.end():].strip():
            continue
        base = re.split(r'[\[<]', match.group(1))[0]
        if base in _PRIMITIVES:
            continue
        deps.add(base if '/' in base else f'{package}/{base}')
    return sorted(deps)


_DEFINITIONS: dict[str, str] = {}


def message_definition(type_name: str) -> str:
    """
    Return the complete ``ros2msg`` definition of a type, as rosbag2 stores it.

    The type's own ``.msg`` text first, then every dependency once (depth first, sorted), each
    after an 80 ``=`` line and ``MSG: pkg/Type``. The ``.msg`` files are looked up in the
    ``share`` directories of ``AMENT_PREFIX_PATH`` and of this Python's prefix (pip-installed
    ROS wheels); a few core types are built in for ROS-free use.
    """
    if type_name in _DEFINITIONS:
        return _DEFINITIONS[type_name]
    seen = set()

    def expand(name: str, depth: int) -> str:
        if depth > 50:
            raise RecursionError(f'message definition of {type_name!r} is too deep')
        text = _msg_text(name)
        for dep in _dependencies(text, split_type(name)[0]):
            if dep not in seen:
                seen.add(dep)
                text += '\n' + DELIMITER + f'MSG: {dep}\n' + expand(dep, depth + 1)
        return text

    _DEFINITIONS[type_name] = result = expand(type_name, 0)
    return result


def type_name_of(msg_or_class) -> str:
    """``'sensor_msgs/msg/JointState'`` for an rclpy message (or its class)."""
    cls = msg_or_class if isinstance(msg_or_class, type) else type(msg_or_class)
    parts = cls.__module__.split('.')
    if len(parts) < 2:
        raise TypeError(f'{cls!r} is not a generated ROS message class')
    return f'{parts[0]}/{parts[1]}/{cls.__name__}'


# -- QoS metadata --------------------------------------------------------------------------------

_INFINITE = (9223372036, 854775807)  # RMW_DURATION_INFINITE as rosbag2 Jazzy writes it
_RMW_DEFAULTS = {'history': 'keep_last', 'reliability': 'reliable', 'durability': 'volatile',
                 'liveliness': 'automatic'}


def _policy(value, key):
    name = getattr(value, 'name', value)
    name = str(name).lower()
    if name in ('system_default', 'unknown', 'best_available'):
        name = _RMW_DEFAULTS[key]
    return name


def _duration(value):
    ns = getattr(value, 'nanoseconds', value)
    if ns is None or int(ns) <= 0:
        return _INFINITE
    ns = int(ns)
    return ns // 1_000_000_000, ns % 1_000_000_000


def qos_profiles_yaml(qos=None) -> str:
    """
    Return the ``offered_qos_profiles`` channel metadata, in rosbag2 Jazzy's (version 9) YAML form.

    :param qos: an ``rclpy.qos.QoSProfile``, a mapping with the same keys (history, depth,
        reliability, durability, liveliness, deadline/lifespan/liveliness_lease_duration in ns),
        an int (depth, reliable) or None (reliable, keep last 10). System defaults are written
        as the rmw defaults; zero durations as infinite.
    """
    if qos is None or isinstance(qos, int):
        qos = {'depth': 10 if qos is None else qos}
    get = (qos.get if isinstance(qos, Mapping) else lambda key, default=None:
           getattr(qos, key, default))
    lines = [
        f"- history: {_policy(get('history', 'keep_last'), 'history')}",
        f"  depth: {int(get('depth', 10) or 0)}",
        f"  reliability: {_policy(get('reliability', 'reliable'), 'reliability')}",
        f"  durability: {_policy(get('durability', 'volatile'), 'durability')}",
    ]
    for key in ('deadline', 'lifespan'):
        sec, nsec = _duration(get(key, 0))
        lines += [f'  {key}:', f'    sec: {sec}', f'    nsec: {nsec}']
    lines.append(f"  liveliness: {_policy(get('liveliness', 'automatic'), 'liveliness')}")
    sec, nsec = _duration(get('liveliness_lease_duration', 0))
    lines += ['  liveliness_lease_duration:', f'    sec: {sec}', f'    nsec: {nsec}']
    avoid = bool(get('avoid_ros_namespace_conventions', False))
    lines.append(f'  avoid_ros_namespace_conventions: {str(avoid).lower()}')
    return '\n'.join(lines)
