"""
Measurements from MCAP logs: sim_node's own, or a rig's rosbag2 MCAP through a channel mapping.

sim_node's log holds its scene, its commands at the period they applied to and its outputs
stamped with sim time, so it goes on the grid as it is. A rig's log names its topics and types
its own way: a mapping says which topic and field is the voltage and which the measured outputs,
one entry per channel, ``CHANNEL=TOPIC[.FIELD][[INDEX]][*SCALE]``::

    voltage=/rig/amplifier.data               std_msgs/Float64 (or Float64MultiArray [0])
    dy=/rig/joints.position[slider]*1e-3      JointState position of joint 'slider', mm -> m
    current=/rig/adc.data[2]                  Float64MultiArray element 2

The field defaults to ``position`` for a JointState and ``data`` for the others; the index to
0; the scale to 1 (it converts to SI units: V, m, C, A). A sample's time is its header stamp
when the message has a non-zero one, else its log time. Messages are read with the package's
generic CDR codec (det_sim_ros.io.cdr), so any message type whose Python class is installed
works.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Mapping

import numpy as np

from .measurement import CalibrationError, CHANNELS, Measurement, on_grid
from ..scenes.outputs import fit_channels

__all__ = ['ChannelSource', 'parse_mapping', 'read_log', 'NODE_TOPICS']

# sim_node's output topic -> the measured channel it is (position field, one entry per DET)
NODE_TOPICS = {row.topic: name for name, row in fit_channels().items()}
MAPPED = ('voltage', *CHANNELS)
_SPEC = re.compile(r'^(?P<topic>/?[A-Za-z_~{][\w/{}~]*?)(?:\.(?P<field>[A-Za-z_]\w*))?'
                   r'(?:\[(?P<index>[^\]]+)\])?(?:\*(?P<scale>.+))?$')
_DEFAULT_FIELD = {'sensor_msgs/msg/JointState': 'position'}


@dataclasses.dataclass(frozen=True)
class ChannelSource:
    """Where a channel is in a rig's log: topic, field, element (number or joint name), scale."""

    topic: str
    field: str = ''
    index: int | str = 0
    scale: float = 1.0

    def value(self, msg) -> float:
        """Return the channel's value in a decoded message, SI units."""
        field = self.field or _DEFAULT_FIELD.get(_type_name(msg), 'data')
        try:
            value = getattr(msg, field)
        except AttributeError:
            raise CalibrationError(f'{self.topic}: the message has no field {field!r}') from None
        if isinstance(value, (int, float)):
            return float(value) * self.scale
        index = self.index
        if isinstance(index, str):
            names = list(getattr(msg, 'name', []))
            if index not in names:
                raise CalibrationError(f'{self.topic}: no joint {index!r} (names: {names})')
            index = names.index(index)
        if index >= len(value):
            raise CalibrationError(f'{self.topic}.{field}: no element {index} (the message has '
                                   f'{len(value)})')
        return float(value[index]) * self.scale


def _type_name(msg) -> str:
    module = type(msg).__module__.split('.')[0]
    return f'{module}/msg/{type(msg).__name__}'


def _parse_source(channel: str, text: str) -> ChannelSource:
    match = _SPEC.match(text.strip())
    if match is None:
        raise CalibrationError(f'mapping {channel}={text!r}: expected TOPIC[.FIELD][[INDEX]]'
                               '[*SCALE], e.g. /rig/joints.position[0]*1e-3')
    index = match['index'] or '0'
    try:
        scale = float(match['scale']) if match['scale'] else 1.0
    except ValueError:
        raise CalibrationError(f'mapping {channel}={text!r}: the scale {match["scale"]!r} is '
                               'not a number') from None
    topic = match['topic'] if match['topic'].startswith('/') else '/' + match['topic']
    return ChannelSource(topic, match['field'] or '',
                         int(index) if index.isdigit() else index.strip(), scale)


def parse_mapping(mapping: Mapping[str, str] | list) -> dict:
    """
    Return channel -> :class:`ChannelSource` from ``{'dy': '/rig/joints.position[0]'}``.

    Also takes a list of ``CHANNEL=SPEC`` strings (the command line's ``--map``).
    """
    if not isinstance(mapping, Mapping):
        pairs = {}
        for item in mapping:
            channel, sep, spec = str(item).partition('=')
            if not sep:
                raise CalibrationError(f'mapping {item!r}: expected CHANNEL=TOPIC[.FIELD]...')
            pairs[channel.strip()] = spec
        mapping = pairs
    sources = {}
    for channel, spec in mapping.items():
        if channel not in MAPPED:
            raise CalibrationError(f'mapping: unknown channel {channel!r}; the channels are '
                                   + ', '.join(MAPPED))
        sources[channel] = spec if isinstance(spec, ChannelSource) else \
            _parse_source(channel, spec)
    if 'voltage' not in sources:
        raise CalibrationError('mapping: no voltage channel (voltage=TOPIC...)')
    return sources


def _open(path: str):
    from ..io.log.reader import LogReader
    try:
        return LogReader(path)
    except FileNotFoundError as exc:
        raise CalibrationError(str(exc)) from None


def read_log(path: str, mapping: Mapping | None = None, scene=None) -> Measurement:
    """
    Read an MCAP log into a :class:`Measurement`.

    Without ``mapping``: sim_node's log (its scene is recorded in it). With one: a rig's log,
    one DET, on the grid of its measured samples' median spacing.
    """
    reader = _open(path)
    if mapping:
        return _read_mapped(path, reader, parse_mapping(mapping), scene)
    try:
        has_scene = bool(reader.scene_yaml)
    except OSError as exc:
        raise CalibrationError(f'{path}: {exc}') from None
    if not has_scene:
        detail = f' ({reader.errors[0]})' if reader.errors else ''
        raise CalibrationError(f'{path}: not a sim_node log (no scene recorded){detail}; for a '
                               "rig's log give the mapping (--map voltage=TOPIC dy=TOPIC ...)")
    return _read_node_log(path, reader)


def _read_node_log(path: str, reader) -> Measurement:
    from ..io.contract import basename, COMMAND_TOPICS, CommandDecoder, decode_joint_state
    from ..io.replay import scene_from_log
    logged = scene_from_log(reader)
    decoder = CommandDecoder(list(logged.det_names), logged.physics.v_max)
    held = [0.0] * logged.n_dets
    times, volts = [], []
    samples = {channel: ([], []) for channel in NODE_TOPICS.values()}
    for message in reader.messages():
        name = basename(message.topic)
        if name in COMMAND_TOPICS:
            command = decoder.decode(name, message.data, held)
            if command.volts is not None:   # a refused command is logged, not applied
                held = list(command.volts)
                times.append(message.log_time * 1e-9)
                volts.append(held)
        elif name in NODE_TOPICS:
            msg = decode_joint_state(message.data)
            if len(msg.position) == logged.n_dets:
                stamps, values = samples[NODE_TOPICS[name]]
                stamps.append(msg.stamp_ns * 1e-9)
                values.append(list(msg.position))
    if reader.errors and not times:
        raise CalibrationError(f'{path}: {reader.errors[0]}')
    return on_grid(path, (times, np.array(volts).reshape(len(times), logged.n_dets)), samples,
                   logged.dt, logged)


def _stamp_ns(msg, log_time: int) -> int:
    stamp = getattr(getattr(msg, 'header', None), 'stamp', None)
    if stamp is not None and (stamp.sec or stamp.nanosec):
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return log_time


def _read_mapped(path: str, reader, sources: dict, scene) -> Measurement:
    from ..io.cdr import CdrError, deserialize
    by_topic = {}
    for channel, source in sources.items():
        by_topic.setdefault(source.topic, []).append((channel, source))
    found = {channel: ([], []) for channel in sources}
    for message in reader.messages(by_topic):
        try:
            msg = deserialize(message.type_name, message.data)
        except (CdrError, ImportError, AttributeError, ValueError) as exc:
            raise CalibrationError(f'{path}: {message.topic}: cannot decode a '
                                   f'{message.type_name!r}: {exc}') from None
        t_ns = _stamp_ns(msg, message.log_time)
        for channel, source in by_topic[message.topic]:
            stamps, values = found[channel]
            stamps.append(t_ns)
            values.append(source.value(msg))
    missing = [f'{c} ({sources[c].topic})' for c, (t, _) in found.items() if not t]
    if missing and len(missing) == len(found):
        raise CalibrationError(f'{path}: none of the mapped topics is in the log; topics: '
                               + ', '.join(sorted(reader.topics)))
    origin = min(min(t) for t, _ in found.values() if t)
    seconds = {c: ((np.array(t, dtype=np.int64) - origin) * 1e-9, np.array(v))
               for c, (t, v) in found.items()}
    commands = seconds.pop('voltage')
    return on_grid(path, commands, seconds, None, scene)
