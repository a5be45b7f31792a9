"""
MCAP run logs in the rosbag2 conventions, and a reader that also recovers unfinished files.

Writing (:class:`Recorder`) follows what ``ros2 bag record`` (Jazzy, mcap storage plugin) writes,
so a log opens in Foxglove, ``ros2 bag info|play`` and any rosbag2/MCAP reader:

- header profile ``ros2``; one channel per topic, message encoding ``cdr`` (rclpy's serializer,
  4-byte encapsulation header included), channel metadata ``offered_qos_profiles`` in the Jazzy
  (metadata version 9) YAML form;
- one schema per type, named ``pkg/msg/Type``, encoding ``ros2msg``: the type's ``.msg`` text
  followed by each dependency (recursively, once) after a line of 80 ``=`` and ``MSG: pkg/Type``;
- ``log_time = publish_time = sim time`` in ns, never decreasing (a smaller time is clamped and
  counted);
- the run is self-describing: an attachment ``scene.yaml`` and a metadata record ``det_sim_ros``
  (package version, scene YAML, stepper, wall start time) at the start of every file, and a
  metadata record ``det_sim_ros.end`` with the counters when the file is closed.

Crash safety. The writer keeps the chunk in progress in memory, so whatever was recorded since
the last flush is not in the file: a SIGKILL loses it. The writer is flushed every
``flush_sim_s`` of log (sim) time (0.05 s) and every ``flush_period_s`` of wall time (0.1 s),
whichever comes first: a SIGKILL loses at most ~50 ms of sim time, in real-time and free-run
mode alike (with ``background=True``, the writer thread's queue too: at most ``max_queue``
items more, which the recording thread writes itself when the writer falls behind) (a
wall-clock period alone lost 7 s of sim time per 0.1 s in a 70x free run). Every
flush is one write: the new records followed by a provisional end (DataEnd, a Footer without
summary, the closing magic), written where the next flush continues. So a killed file is a
valid MCAP up to its last flush, which mcap's reader and rosbags open without a manual step
(they scan a file that has no summary); only the index and the ``det_sim_ros.end`` counters
are missing (:func:`recover` adds the index). A file torn anyway (power loss, a kill inside
that one write) is repaired by :func:`recover_unfinished`, which the node runs on its log
directory at start. :meth:`Recorder.close` (the node's shutdown path on SIGINT/SIGTERM, and
``atexit``) finishes and indexes the file. ``max_total_mb``/``max_files`` bound the log
directory: when a file is opened (start, split, reset) or flushed, the oldest files of this
recorder's name pattern are deleted until the rest fits (never the file being written). A
logging fault (disk full, unwritable path, ...) never raises into the caller: it stops recording,
and :attr:`Recorder.fault` says why.

Reading (:class:`LogReader`) streams records in file order and stops quietly at the end of the
readable data, so a file cut by a crash gives every message of every complete chunk.
"""

from __future__ import annotations

import atexit
import bisect
import collections
import dataclasses
import itertools
import logging
import os
import re
import struct
import sys
import threading
import time
import weakref
from typing import Callable, Iterable, Iterator, Mapping, Sequence

from ..core.kernel import pack_records

__all__ = ['Recorder', 'LogReader', 'LogMessage', 'message_definition', 'qos_profiles_yaml',
           'type_name_of', 'serialize', 'deserialize', 'recover', 'recover_unfinished',
           'is_torn', 'log_files', 'LIBRARY', 'METADATA_NAME']

LIBRARY = 'det_sim_ros'
METADATA_NAME = 'det_sim_ros'
END_METADATA_NAME = 'det_sim_ros.end'
SCENE_ATTACHMENT = 'scene.yaml'
DELIMITER = '=' * 80 + '\n'

_logger = logging.getLogger(__name__)

# -- message definitions (schemas) ----------------------------------------------------------------

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


def _split_type(name: str) -> tuple[str, str, str]:
    parts = name.split('/')
    if len(parts) == 2:
        return parts[0], 'msg', parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise ValueError(f'not a ROS type name (pkg/msg/Type): {name!r}')


def _share_dirs() -> list[str]:
    dirs = []
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            dirs.append(os.path.join(prefix, 'share'))
    dirs.append(os.path.join(sys.prefix, 'share'))
    dirs.append(os.path.join(sys.base_prefix, 'share'))
    return list(dict.fromkeys(dirs))


def _msg_text(name: str) -> str:
    package, kind, type_ = _split_type(name)
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
    The complete ``ros2msg`` definition of a type, as rosbag2 stores it.

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
        for dep in _dependencies(text, _split_type(name)[0]):
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


def _message_class(type_name: str):
    import importlib
    package, kind, type_ = _split_type(type_name)
    return getattr(importlib.import_module(f'{package}.{kind}'), type_)


def deserialize(type_name: str, data: bytes):
    """Deserialize CDR bytes into the rclpy message class of ``type_name``."""
    from rclpy.serialization import deserialize_message
    return deserialize_message(data, _message_class(type_name))


# -- CDR serialization ---------------------------------------------------------------------------
#
# rclpy.serialization (rmw_fastrtps, Jazzy) returns a buffer of the *estimated* size: trailing
# and padding bytes are uninitialized memory, which strict readers (rosbags) refuse and which
# makes logs of the same run differ byte-wise. This plain-CDR writer (XCDR1 little endian, the
# encoding rosbag2 stores) emits exactly the serialized bytes with zero padding; types it does
# not handle (wide strings) fall back to rclpy with the trailing bytes cut by size.

_BASIC = {'boolean': '?', 'octet': 'B', 'char': 'B', 'uint8': 'B', 'int8': 'b', 'int16': 'h',
          'uint16': 'H', 'int32': 'i', 'uint32': 'I', 'int64': 'q', 'uint64': 'Q', 'float': 'f',
          'double': 'd'}
_ZEROS = bytes(8)


class _Unsupported(TypeError):
    pass


def _cdr_writer(slot_type) -> Callable:
    """A function ``write(buffer, value)`` for one rosidl field type."""
    import struct

    from rosidl_parser import definition as d

    def align(buf, size):
        pad = -(len(buf) - 4) % size
        if pad:
            buf += _ZEROS[:pad]

    if isinstance(slot_type, d.BasicType):
        code = _BASIC.get(slot_type.typename)
        if code is None:
            raise _Unsupported(slot_type.typename)
        packer = struct.Struct('<' + code)
        size = packer.size

        def write_basic(buf, value):
            align(buf, size)
            if code == 'B' and isinstance(value, (bytes, str)):
                value = ord(value)
            buf += packer.pack(value)
        return write_basic
    if isinstance(slot_type, (d.UnboundedString, d.BoundedString)):
        def write_string(buf, value):
            data = value.encode()
            align(buf, 4)
            buf += struct.pack('<I', len(data) + 1)
            buf += data
            buf += b'\0'
        return write_string
    if isinstance(slot_type, d.NamespacedType):
        import importlib
        module = importlib.import_module('.'.join(slot_type.namespaces))
        return _struct_writer(getattr(module, slot_type.name))
    if isinstance(slot_type, (d.AbstractSequence, d.Array)):
        is_array = isinstance(slot_type, d.Array)
        item = slot_type.value_type
        if isinstance(item, d.BasicType) and item.typename in _BASIC:
            code = _BASIC[item.typename]
            size = struct.calcsize(code)
            typecode = {'d': 'd', 'f': 'f'}.get(code)
            native = sys.byteorder == 'little'

            def write_numbers(buf, values):
                n = len(values)
                if not is_array:
                    align(buf, 4)
                    buf += struct.pack('<I', n)
                if n:
                    align(buf, size)
                    if isinstance(values, (bytes, bytearray)):
                        buf += values
                    elif native and getattr(values, 'typecode', None) == typecode:
                        buf += values.tobytes()  # array.array, as rclpy stores sequences
                    elif code == 'B' and isinstance(values[0], bytes):
                        buf += b''.join(values)
                    else:
                        buf += struct.pack(f'<{n}{code}', *values)
            return write_numbers
        write_item = _cdr_writer(item)

        def write_items(buf, values):
            if not is_array:
                align(buf, 4)
                buf += struct.pack('<I', len(values))
            for value in values:
                write_item(buf, value)
        return write_items
    raise _Unsupported(type(slot_type).__name__)


_STRUCT_WRITERS: dict[type, Callable] = {}


def _struct_writer(cls) -> Callable:
    writer = _STRUCT_WRITERS.get(cls)
    if writer is None:
        names = list(cls.get_fields_and_field_types())
        parts = [(name, _cdr_writer(slot)) for name, slot in zip(names, cls.SLOT_TYPES)]
        if not parts:  # an empty message holds one uint8
            def writer(buf, msg):
                buf += b'\0'
        else:
            def writer(buf, msg):
                for name, write in parts:
                    write(buf, getattr(msg, name))
        _STRUCT_WRITERS[cls] = writer
    return writer


def serialize(msg) -> bytes:
    """CDR bytes of an rclpy message, as rosbag2 stores them (encapsulation header included)."""
    cls = type(msg)
    try:
        writer = _STRUCT_WRITERS.get(cls) or _struct_writer(cls)
    except _Unsupported:
        _STRUCT_WRITERS[cls] = writer = None
    if writer is None:
        from rclpy.serialization import serialize_message
        return serialize_message(msg)
    buf = bytearray(b'\x00\x01\x00\x00')
    writer(buf, msg)
    return bytes(buf)


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
    The ``offered_qos_profiles`` channel metadata, in rosbag2 Jazzy's (version 9) YAML form.

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


# -- writing -------------------------------------------------------------------------------------

_MESSAGE_HEAD = struct.Struct('<BQHIQQ')   # MCAP Message record: opcode, length, channel, seq, times


class _FastMessages:
    """
    mcap.Writer.add_message for many messages at once: the same records, chunk message index
    and statistics, written with one struct.pack per message instead of ~20 Python calls
    (6.5 -> ~1.5 us per message). It uses the writer's internals (mcap 1.x); :meth:`attach`
    returns None when they are not there, and the caller falls back to add_message.
    """

    def __init__(self, writer):
        self.writer = writer
        self.stats = writer._Writer__statistics
        self.chunk = writer._Writer__chunk_builder
        self.finalize = writer._Writer__maybe_finalize_chunk
        self.chunk_size = writer._Writer__chunk_size
        self.index_type = _MessageIndex
        self._sample_offsets = {}   # (channel ids, payload sizes) -> record offsets

    @classmethod
    def attach(cls, writer):
        if _MessageIndex is None:
            return None
        try:
            fast = cls(writer)
            fast.chunk.record_writer._buffer.tell()
            fast.stats.channel_message_counts
        except AttributeError:
            return None
        return fast if fast.chunk is not None else None

    @staticmethod
    def _cover(record, empty: bool, log_time: int) -> None:
        """Widen ``record``'s message_start_time..message_end_time (the file's statistics or
        the chunk's) to ``log_time``; ``empty``: it has no message yet."""
        if empty or log_time < record.message_start_time:
            record.message_start_time = log_time
        if log_time > record.message_end_time:
            record.message_end_time = log_time

    def add(self, items, log_time: int) -> None:
        """Write (channel id, sequence, data) items, all at ``log_time``, as add_message would
        (a chunk ends after the message that makes it exceed the chunk size)."""
        stats, chunk = self.stats, self.chunk
        self._cover(stats, stats.message_count == 0, log_time)
        counts, indices, pack = stats.channel_message_counts, chunk.message_indices, \
            _MESSAGE_HEAD.pack
        for channel_id, sequence, data in items:
            self._cover(chunk, chunk.num_messages == 0, log_time)
            index = indices.get(channel_id)
            if index is None:
                index = indices[channel_id] = self.index_type(channel_id=channel_id, records=[])
            buffer = chunk.record_writer._buffer    # replaced when a chunk ends
            index.records.append((log_time, buffer.tell()))
            buffer.write(pack(0x05, 22 + len(data), channel_id, sequence, log_time, log_time))
            buffer.write(data)
            counts[channel_id] += 1
            stats.message_count += 1
            chunk.num_messages += 1
            self.finalize()

    def _offsets(self, channel_ids: tuple, sizes: tuple) -> tuple:
        """((channel id, record offset), ...) of one sample's records (a sample's payload sizes
        are fixed for a model, so this is computed once per layout)."""
        offsets = self._sample_offsets.get((channel_ids, sizes))
        if offsets is None:
            starts, at = [], 0
            for size in sizes:
                starts.append(at)
                at += _MESSAGE_HEAD.size + size
            offsets = self._sample_offsets[(channel_ids, sizes)] = tuple(zip(channel_ids,
                                                                             starts))
        return offsets

    def add_sample(self, channel_ids: tuple, sequences, payloads, log_time: int) -> None:
        """The messages of one sample (one per channel, all at ``log_time``) as one write:
        a run of one (:meth:`add_run`). A sample that would end the chunk, or whose payloads
        are not ``bytes``, goes message by message (:meth:`add`), so chunks end where
        add_message ends them."""
        sizes = tuple(map(len, payloads))
        if self.chunk.record_writer._buffer.tell() + sum(sizes) \
                + _MESSAGE_HEAD.size * len(sizes) <= self.chunk_size:
            records, count = pack_records(channel_ids, sequences, (log_time,), (payloads,),
                                          sizes)
            if count:
                self.add_run(channel_ids, sizes, records, (log_time,))
                return
        self.add(list(zip(channel_ids, sequences, payloads)), log_time)

    def add_run(self, channel_ids: tuple, sizes: tuple, records: bytes, times) -> None:
        """
        Consecutive samples of one layout, as add_sample would write them one by one:
        ``records`` are their Message records (``_ckernel.pack_records``: a sample's records
        in channel order, ``sizes`` its payload sizes), ``times`` their log times. The caller
        guarantees the run fits in the chunk, so no message ends it.
        """
        stats, chunk = self.stats, self.chunk
        buffer = chunk.record_writer._buffer
        base = buffer.tell()
        self._cover(stats, stats.message_count == 0, times[0])
        self._cover(stats, False, times[-1])
        self._cover(chunk, chunk.num_messages == 0, times[0])
        self._cover(chunk, False, times[-1])
        buffer.write(records)
        offsets = self._offsets(channel_ids, sizes)
        width = len(sizes)
        sample_bytes = sum(sizes) + _MESSAGE_HEAD.size * width
        k = len(times)
        indices, counts = chunk.message_indices, stats.channel_message_counts
        for channel_id, offset in offsets:
            index = indices.get(channel_id)
            if index is None:
                index = indices[channel_id] = _MessageIndex(channel_id=channel_id, records=[])
            start = base + offset
            index.records.extend(zip(times, range(start, start + k * sample_bytes,
                                                  sample_bytes)))
            counts[channel_id] += k
        stats.message_count += k * width
        chunk.num_messages += k * width
        self.finalize()


try:
    from mcap.records import MessageIndex as _McapMessageIndex

    class _MessageIndex(_McapMessageIndex):
        """mcap's MessageIndex, written with one pack instead of two calls per entry (the
        index of a 50-sample chunk was a quarter of the recorder's cost)."""

        def write(self, stream):
            records = self.records
            stream.start_record(0x07)   # Opcode.MESSAGE_INDEX
            stream.write(struct.pack(f'<HI{2 * len(records)}Q', self.channel_id,
                                     16 * len(records), *itertools.chain.from_iterable(records)))
            stream.finish_record()
except ImportError:  # pragma: no cover - mcap is a dependency; the recorder reports its absence
    _MessageIndex = None


def _scene_yaml(scene) -> str:
    if scene is None:
        return ''
    if isinstance(scene, str):
        return scene
    import yaml
    from ..scenes.scene import scene_to_dict
    data = scene if isinstance(scene, Mapping) else scene_to_dict(scene, wrap=True)
    return yaml.safe_dump(data, sort_keys=False)


def _fully_qualified(topic: str) -> str:
    return topic if topic.startswith('/') else '/' + topic


_MAGIC = b'\x89MCAP0\r\n'
# DataEnd (opcode 0x0f, crc 0 = not computed) + Footer (0x02: summary_start 0 = no summary,
# summary_offset_start 0, crc 0) + magic: the smallest valid end of an MCAP file
_PROVISIONAL_END = (b'\x0f' + (4).to_bytes(8, 'little') + bytes(4)
                    + b'\x02' + (20).to_bytes(8, 'little') + bytes(20) + _MAGIC)


class _TailStream:
    """
    The writer's output file: records are collected in memory and written at each flush in one
    ``pwrite``, followed by the provisional end, at the offset where the next flush continues
    (so the provisional end is overwritten by it). Between flushes the file on disk is always a
    complete MCAP. :meth:`finish` writes the writer's real end (after ``Writer.finish``).
    """

    def __init__(self, path: str):
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._committed = 0
        self._pending = bytearray()

    def write(self, data) -> int:
        self._pending += data
        return len(data)

    def tell(self) -> int:
        return self._committed + len(self._pending)

    def _commit(self, tail: bytes) -> None:
        data = memoryview(bytes(self._pending) + tail)
        offset = self._committed
        while data:
            n = os.pwrite(self._fd, data, offset)
            offset += n
            data = data[n:]
        self._committed += len(self._pending)
        self._pending.clear()

    def flush(self) -> None:
        self._commit(_PROVISIONAL_END)

    def finish(self) -> None:
        """Write what is pending (the writer's real end) and cut off any stale bytes."""
        self._commit(b'')
        os.ftruncate(self._fd, self._committed)

    def close(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)


def is_torn(path: str) -> bool:
    """True for an MCAP file that does not end in a valid footer (a cut file)."""
    try:
        with open(path, 'rb') as stream:
            stream.seek(0, os.SEEK_END)
            size = stream.tell()
            if size < 8 + 37:
                return True
            stream.seek(0)
            if stream.read(8) != _MAGIC:
                return True
            stream.seek(size - 37)
            end = stream.read(37)
    except OSError:
        return False
    return end[-8:] != _MAGIC or end[:9] != b'\x02' + (20).to_bytes(8, 'little')


class Recorder:
    """
    Record ROS messages of one run to MCAP (see the module docstring for the format).

    Usable without a ROS graph: only ``rclpy.serialization`` is needed (and not even that when
    :meth:`record` is given CDR bytes).

    :param path: a ``.mcap`` file (or an existing non-directory such as a device), or a
        directory in which ``det_sim_<date>-<time>_<pid>.mcap`` is created.
    :param scene: the :class:`~det_sim_ros.scenes.scene.Scene` (or its YAML text / mapping) stored
        in every file.
    :param qos_by_topic: topic -> QoS (``rclpy.qos.QoSProfile``, mapping or depth) for the
        ``offered_qos_profiles`` metadata; topics not listed get reliable, keep last 10.
    :param flush_period_s: wall time between flushes (ends the chunk and writes it out); bounds
        what a SIGKILL loses. 0 flushes after every message.
    :param flush_sim_s: log (sim) time between flushes; bounds what a SIGKILL loses in sim
        time whatever the speed (0: wall time only).
    :param max_total_mb: keep this recorder's files in the log directory under this many MiB
        in all (oldest deleted first; 0: no limit).
    :param max_files: keep at most this many of them (0: no limit).
    :param chunk_size: chunk size limit in bytes (a chunk is also ended by every flush, so at
        the default flush periods a chunk holds at most 50 ms of sim time; mcap's default size:
        with 64 KiB, a 100-DET array's samples (9 KB) ended a chunk every 7 and its log cost a
        third more).
    :param compression: 'zstd', 'lz4' or 'none'.
    :param split_mb: start a new file when the current one exceeds this many MiB (0: never).
    :param split_s: start a new file every this many seconds of log time (0: never).
    :param metadata: extra string key/values for the ``det_sim_ros`` metadata record (e.g. the
        stepper ``method`` and ``substeps``, the ``output_map``).
    :param on_fault: called once with the fault text when recording stops on an error.
    :param clock: wall clock for the flush period (``time.monotonic``).
    :param namespace: the node namespace that relative topic names are resolved in.
    :param background: write from a writer thread: :meth:`record` and :meth:`record_sample`
        only queue the (already serialized) bytes, the thread writes, compresses and flushes
        them in order every ``drain_period_s``. Counters and :attr:`fault` are updated by the
        thread; :meth:`close` writes everything queued before it finishes the file.
    :param max_queue: background mode: when this many records wait, the recording thread
        writes the queue itself (with the writer thread's lock) before it goes on. The writer
        thread gets the GIL only now and then while the node's thread runs flat out, so in a
        free run it fell behind without bound (124k samples, 82 % of a 4 s run, were still
        queued: memory, and the crash guarantee, lost); this keeps both bounded.
    """

    def __init__(self, path, scene=None, *, qos_by_topic: Mapping | None = None,
                 flush_period_s: float = 0.1, flush_sim_s: float = 0.05,
                 chunk_size: int = 1024 * 1024,
                 max_total_mb: float = 0.0, max_files: int = 0,
                 compression: str = 'zstd', split_mb: float = 0.0, split_s: float = 0.0,
                 metadata: Mapping[str, object] | None = None,
                 on_fault: Callable[[str], None] | None = None,
                 clock: Callable[[], float] = time.monotonic, prefix: str = 'det_sim',
                 namespace: str = '/', background: bool = False,
                 drain_period_s: float = 0.01, max_queue: int = 64):
        self.fault = ''
        self.paths: list[str] = []
        self.messages = 0       # messages written
        self.bytes = 0          # serialized payload bytes written
        self.clamped = 0        # log times raised to keep them non-decreasing
        self.dropped = 0        # messages not written because of a fault
        self.flushes = 0
        self.flushed_messages = 0   # messages on disk at the last flush (a SIGKILL keeps them)
        self.record_time_s = 0.0  # wall time spent in record()
        self._ns = '/' + namespace.strip('/') + '/' if namespace.strip('/') else '/'
        self.qos_by_topic = {self._resolve(k): v for k, v in (qos_by_topic or {}).items()}
        self.flush_period_s = float(flush_period_s)
        self.flush_sim_ns = int(float(flush_sim_s) * 1e9)
        self.max_total_bytes = int(float(max_total_mb) * 1024 * 1024)
        self.max_files = int(max_files)
        self.deleted: list[str] = []   # old files removed to respect the limits
        self._old_files: list[tuple[str, int]] = []   # (path, size), oldest first
        self.chunk_size = int(chunk_size)
        self.split_bytes = int(float(split_mb) * 1024 * 1024)
        self.split_ns = int(float(split_s) * 1e9)
        self.on_fault = on_fault
        self._clock = clock
        self._compression = compression
        self._metadata = {str(k): str(v) for k, v in (metadata or {}).items()}
        self._writer = None
        self._fast = None
        self._stream = None
        self._last_t = 0
        self._file_start_t = None
        self._channels: dict[str, int] = {}
        self._sample_plans: dict[tuple, tuple] = {}   # sample topics -> (names, channel ids)
        self._schemas: dict[str, int] = {}
        self._types: dict[str, str] = {}
        self._sequence: dict[str, int] = {}
        self._type_cache: dict[type, str] = {}
        try:
            from .. import __version__
            self.version = __version__
        except Exception:  # pragma: no cover - partial installs
            self.version = 'unknown'
        try:
            self.scene_yaml = _scene_yaml(scene)
            self._prefix = prefix
            self._prefix_dir = not (os.fspath(path).endswith('.mcap')
                                    or (os.path.exists(path) and not os.path.isdir(path)))
            self._base = self._first_path(os.fspath(path), prefix)
            self._open(self._base)
        except Exception as exc:  # noqa: BLE001 - a logging fault must not stop the simulation
            self._set_fault(exc)
        self._queue = None
        self._thread = None
        if background and self._writer is not None:
            self._queue = collections.deque()   # append/popleft are atomic
            self._drain_lock = threading.RLock()   # one writer at a time: thread or recorder
            self._max_queue = max(1, int(max_queue))
            self.caught_up = 0    # times the recording thread wrote the queue itself
            self._drain_period_s = float(drain_period_s)
            self._stop = threading.Event()
            self._thread = threading.Thread(target=self._drain_loop, name='mcap-writer',
                                            daemon=True)
            self._thread.start()
        _open_recorders.add(self)

    def _resolve(self, topic: str) -> str:
        return topic if topic.startswith('/') else self._ns + topic

    # -- files -------------------------------------------------------------------------------
    @staticmethod
    def _first_path(path: str, prefix: str) -> str:
        if path.endswith('.mcap') or (os.path.exists(path) and not os.path.isdir(path)):
            folder = os.path.dirname(path)
            if folder:
                os.makedirs(folder, exist_ok=True)
            return path
        os.makedirs(path, exist_ok=True)
        stamp = time.strftime('%Y%m%d-%H%M%S')
        base = os.path.join(path, f'{prefix}_{stamp}_{os.getpid()}')
        candidate, n = base + '.mcap', 1
        while os.path.exists(candidate):
            candidate, n = f'{base}-{n}.mcap', n + 1
        return candidate

    def _split_path(self) -> str:
        stem = self._base[:-5] if self._base.endswith('.mcap') else self._base
        return f'{stem}_{len(self.paths):03d}.mcap'

    def _open(self, path: str) -> None:
        from mcap.writer import CompressionType, Writer
        compression = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                       'none': CompressionType.NONE, '': CompressionType.NONE}[self._compression]
        self._stream = _TailStream(path)
        self.paths.append(path)
        writer = Writer(self._stream, chunk_size=self.chunk_size, compression=compression)
        writer.start(profile='ros2', library=f'{LIBRARY} {self.version}')
        wall_ns = time.time_ns()
        info = {'version': self.version, 'scene_yaml': self.scene_yaml, 'time_base': 'sim_time',
                'ros_distro': os.environ.get('ROS_DISTRO', 'jazzy'),
                'wall_start_ns': str(wall_ns), 'file_index': str(len(self.paths) - 1)}
        info.update(self._metadata)
        writer.add_metadata(METADATA_NAME, info)
        if self.scene_yaml:
            writer.add_attachment(create_time=wall_ns, log_time=self._last_t,
                                  name=SCENE_ATTACHMENT, media_type='application/yaml',
                                  data=self.scene_yaml.encode())
        writer.flush()
        self._writer = writer
        self._fast = _FastMessages.attach(writer)
        self._channels.clear()
        self._sample_plans.clear()
        self._schemas.clear()
        self._file_start_t = None
        self._last_flush = self._clock()
        self._last_flush_t = self._last_t
        self._scan_old_files(path)
        self._enforce_limits()

    # -- bounded log directory -------------------------------------------------------------
    def _pattern(self):
        stem = self._base[:-5] if self._base.endswith('.mcap') else self._base
        folder = os.path.dirname(stem) or '.'
        if self._prefix_dir:
            return folder, re.compile(re.escape(self._prefix) + r'_.*\.mcap$')
        return folder, re.compile(re.escape(os.path.basename(stem)) + r'(_\d{3})?\.mcap$')

    def _scan_old_files(self, current: str) -> None:
        """The other files of this recorder's pattern in its directory, oldest first."""
        if not (self.max_total_bytes or self.max_files):
            return
        folder, pattern = self._pattern()
        found = []
        for name in os.listdir(folder):
            path = os.path.join(folder, name)
            if pattern.match(name) and os.path.abspath(path) != os.path.abspath(current):
                try:
                    st = os.stat(path)
                except OSError:
                    continue
                found.append((st.st_mtime, name, path, st.st_size))
        self._old_files = [(path, size) for _, _, path, size in sorted(found)]

    def _enforce_limits(self) -> None:
        """Delete the oldest files until the directory is within max_total_mb / max_files."""
        if not (self.max_total_bytes or self.max_files) or not self._old_files:
            return
        current = self._stream.tell() if self._stream is not None else 0
        while self._old_files and (
                (self.max_files and len(self._old_files) + 1 > self.max_files)
                or (self.max_total_bytes
                    and sum(size for _, size in self._old_files) + current
                    > self.max_total_bytes)):
            path, _ = self._old_files.pop(0)
            try:
                os.remove(path)
                self.deleted.append(path)
            except FileNotFoundError:
                pass

    def _close_file(self) -> None:
        writer, stream = self._writer, self._stream
        self._writer = self._stream = None
        if writer is None:
            return
        try:
            writer.add_metadata(END_METADATA_NAME, self.counters(strings=True))
            writer.finish()
            stream.finish()
        finally:
            stream.close()
        if self.paths:
            try:
                self._old_files.append((self.paths[-1], os.path.getsize(self.paths[-1])))
            except OSError:
                pass

    # -- recording ---------------------------------------------------------------------------
    def _channel(self, topic: str, msg, type_name: str | None) -> int:
        type_name = type_name or self._types.get(topic)
        if type_name is None:
            cls = type(msg)
            type_name = self._type_cache.get(cls) or self._type_cache.setdefault(
                cls, type_name_of(cls))
        self._types[topic] = type_name
        writer = self._writer
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            schema_id = writer.register_schema(name=type_name, encoding='ros2msg',
                                               data=message_definition(type_name).encode())
            self._schemas[type_name] = schema_id
        channel_id = writer.register_channel(
            topic=topic, message_encoding='cdr', schema_id=schema_id,
            metadata={'offered_qos_profiles': qos_profiles_yaml(self.qos_by_topic.get(topic)),
                      'topic_type_hash': ''})
        self._channels[topic] = channel_id
        return channel_id

    def record(self, topic: str, msg, log_time_ns: int, type_name: str | None = None) -> bool:
        """
        Write one message at sim time ``log_time_ns`` (also its publish time).

        :param msg: an rclpy message, or its CDR bytes (then give ``type_name`` on first use).
        :returns: True if written (queued, in background mode); False when recording has
            stopped on a fault.
        """
        if self._queue is not None:
            # (the writer thread owns _writer: between two files it is None for a moment,
            # so queueing depends only on whether recording has stopped)
            if self.fault or self._thread is None:
                self.dropped += 1
                return False
            if isinstance(msg, (bytearray, memoryview)):
                msg = bytes(msg)
            elif not isinstance(msg, bytes):   # serialized here: the queue holds bytes only
                type_name = type_name or self._type_of(msg, topic)
                msg = serialize(msg)
            self._queue.append((topic, msg, log_time_ns, type_name))
            if len(self._queue) > self._max_queue:
                self._catch_up()
            return True
        if self._writer is None:
            self.dropped += 1
            return False
        return self._write(topic, msg, log_time_ns, type_name)

    def record_sample(self, log_time_ns: int, topics: Sequence[str], data: Sequence[bytes],
                      types: Mapping[str, str]) -> bool:
        """
        Write one CDR message per topic, all at ``log_time_ns`` (one sample of the node's
        outputs); ``types`` maps each topic to its type name.
        """
        if self._queue is not None:
            if self.fault or self._thread is None:   # stopped (see record)
                self.dropped += len(data)
                return False
            self._queue.append((log_time_ns, topics, data, types))
            if len(self._queue) > self._max_queue:
                self._catch_up()
            return True
        if self._writer is None:
            self.dropped += len(data)
            return False
        return self._write_sample(log_time_ns, topics, data, types)

    def _write_sample(self, log_time_ns, topics, data, types) -> bool:
        """Several messages at one log time: the checks once, then the fast path."""
        fast = self._fast
        key = topics if type(topics) is tuple else tuple(topics)
        plan = self._sample_plans.get(key)
        if fast is None or plan is None or self._writer is None:
            ok = True   # the first sample registers its channels: message by message
            last = len(data) - 1
            for j, (topic, payload) in enumerate(zip(topics, data)):   # (flushed after all)
                ok = self._write(topic, payload, log_time_ns, types[topic], j == last) and ok
            if fast is not None and self._writer is not None:
                names = tuple(self._resolve(topic) for topic in key)
                if all(name in self._channels for name in names):
                    self._sample_plans[key] = (names, tuple(self._channels[n] for n in names))
            return ok
        start = self._clock()
        try:
            t = int(log_time_ns)
            if t < self._last_t:
                t = self._last_t
                self.clamped += len(data)
            self._last_t = t
            if self._split_if_due(t):      # (the new file registers its channels again)
                return self._write_sample(log_time_ns, topics, data, types)
            names, channel_ids = plan
            sequence = self._sequence
            sequences = []
            for name in names:
                n = sequence.get(name, 0)
                sequence[name] = n + 1
                sequences.append(n)
            fast.add_sample(channel_ids, sequences, data, t)
            self.bytes += sum(map(len, data))
            self.messages += len(names)
            if self._flush_due(start, t):
                self._flush(start)
            return True
        except Exception as exc:  # noqa: BLE001 - never raise into the node
            self.dropped += len(data)
            self._set_fault(exc)
            return False
        finally:
            self.record_time_s += self._clock() - start

    def _write_sample_run(self, items) -> None:
        """
        Consecutive samples from the writer's queue: the bytes _write_sample writes one by one,
        in runs packed at once. A run stops before a sample that would end the chunk, split
        the file or come after a due flush, so inside it only the records change and the
        lookups, checks and counters are done once. (The Python per sample was most of the
        log's cost: 10 us per sample in a loop; packed in C, with the run's end found by
        bisection, 3.5 us.)
        """
        i, n = 0, len(items)
        while i < n:
            start = self._clock()
            try:
                taken = self._pack_run(items, i, start)
            except Exception as exc:  # noqa: BLE001 - never raise into the node
                self.dropped += sum(len(item[2]) for item in items[i:])
                self._set_fault(exc)
                return
            finally:
                self.record_time_s += self._clock() - start
            if taken:
                i += taken
            else:   # a first sample, a chunk's end, a split or a flush: the one-by-one path
                self._write_sample(*items[i])
                i += 1

    def _pack_run(self, items, i: int, start: float) -> int:
        """Write the run of samples from items[i] (see _write_sample_run); how many (0: the
        sample at i needs _write_sample)."""
        fast, topics = self._fast, items[i][1]
        key = topics if type(topics) is tuple else tuple(topics)
        plan = self._sample_plans.get(key)
        if (fast is None or plan is None or self._writer is None or self._file_start_t is None
                or start - self._last_flush >= self.flush_period_s
                or (self.split_bytes and self._stream.tell() >= self.split_bytes)):
            return 0
        names, channel_ids = plan
        sizes = tuple(map(len, items[i][2]))
        sample_bytes = sum(sizes) + _MESSAGE_HEAD.size * len(sizes)
        room = (fast.chunk_size - fast.chunk.record_writer._buffer.tell()) // sample_bytes
        window = items[i:i + room]
        for j, item in enumerate(window):   # (the node gives the same topics object)
            if item[1] is not topics and tuple(item[1]) != key:
                window = window[:j]
                break
        if not window:
            return 0
        given = [int(item[0]) for item in window]
        times = list(itertools.accumulate(given, max, initial=self._last_t))[1:]  # clamped
        end = len(times)
        if self.split_ns:   # (_write_sample splits the file before the first one past it)
            end = bisect.bisect_left(times, self._file_start_t + self.split_ns, 0, end)
        if self.flush_sim_ns:   # a flush is due after it (the wall-time part is not, above)
            end = min(end, bisect.bisect_left(times, self._last_flush_t + self.flush_sim_ns)
                      + 1)
        if not end:
            return 0
        sequence = self._sequence
        firsts = [sequence.get(name, 0) for name in names]
        records, count = pack_records(channel_ids, firsts, times,
                                      [item[2] for item in window[:end]], sizes)
        if not count:
            return 0
        del times[count:]
        for name, first in zip(names, firsts):
            sequence[name] = first + count
        fast.add_run(channel_ids, sizes, records, times)
        self._last_t = times[-1]
        self.clamped += len(sizes) * sum(a != b for a, b in zip(given, times))
        self.bytes += sum(sizes) * count
        self.messages += len(names) * count
        if self._flush_due(start, times[-1]):
            self._flush(start)
        return count

    def _type_of(self, msg, topic):
        return self._types.get(topic) or type_name_of(msg)

    def _write(self, topic: str, msg, log_time_ns: int, type_name: str | None,
               flush: bool = True) -> bool:
        """One message; then a flush if one is due, unless not ``flush`` (a sample's messages
        but its last: a sample is never split by a flush)."""
        if self._writer is None:
            self.dropped += 1
            return False
        start = self._clock()
        try:
            topic = topic if topic.startswith('/') else self._ns + topic
            t = int(log_time_ns)
            if t < self._last_t:
                t = self._last_t
                self.clamped += 1
            self._last_t = t
            if isinstance(msg, (bytes, bytearray, memoryview)):
                data = bytes(msg)
            else:
                data = serialize(msg)
            self._split_if_due(t)
            channel_id = self._channels.get(topic)
            if channel_id is None:
                channel_id = self._channel(topic, msg, type_name)
            sequence = self._sequence.get(topic, 0)
            self._sequence[topic] = sequence + 1
            if self._fast is not None:   # the same records, one pack (a marker frame: 26 -> 8 us)
                self._fast.add(((channel_id, sequence, data),), t)
            else:
                self._writer.add_message(channel_id=channel_id, log_time=t, data=data,
                                         publish_time=t, sequence=sequence)
            self.messages += 1
            self.bytes += len(data)
            if flush and self._flush_due(start, t):
                self._flush(start)
            return True
        except Exception as exc:  # noqa: BLE001 - never raise into the node
            self.dropped += 1
            self._set_fault(exc)
            return False
        finally:
            self.record_time_s += self._clock() - start

    def _split_if_due(self, t: int) -> bool:
        """Continue in a new file when this one has reached split_mb or its time span (t: the
        log time being written); True if it did."""
        if self._file_start_t is None:
            self._file_start_t = t
            return False
        if ((self.split_ns and t - self._file_start_t >= self.split_ns)
                or (self.split_bytes and self._stream.tell() >= self.split_bytes)):
            self._close_file()
            self._open(self._split_path())
            self._file_start_t = t
            return True
        return False

    # -- the writer thread (background=True) -------------------------------------------------
    _NEW_FILE = object()

    def _drain(self, yield_gil: bool = True) -> None:
        """Write everything queued, in order (under _drain_lock: the writer thread, the
        recording thread when the writer fell behind, or close()). ``yield_gil``: release the
        GIL every 16 samples (the writer thread, so the node's thread is not held up; the node's
        own catch-up must not: each release cost it ~0.3 ms of waiting for the GIL back)."""
        queue, new_file = self._queue, self._NEW_FILE
        written = 0
        while queue:
            item = queue.popleft()
            if item is new_file:
                self._new_file_now()
            elif isinstance(item[0], str):      # (topic, data, time, type): one message
                self._write(*item)
            else:                               # samples: the ones queued after it too
                run = [item]
                while (queue and (len(run) < 16 or not yield_gil) and queue[0] is not new_file
                       and not isinstance(queue[0][0], str)):
                    run.append(queue.popleft())
                self._write_sample_run(run)
                written += len(run) - 1
            written += 1
            if written >= 16 and yield_gil:
                # hand the GIL to the node's thread now and then: a waiting publisher is held
                # up by at most ~16 samples' writes (~0.1 ms), not by the whole queue; a
                # release per sample costs more CPU than the writes
                written = 0
                time.sleep(0)

    def _drain_loop(self) -> None:
        try:
            while not self._stop.wait(self._drain_period_s):
                with self._drain_lock:
                    self._drain()
                    self.maybe_flush()
        except Exception as exc:  # noqa: BLE001 - a logging fault stops logging, nothing else
            self._set_fault(exc)

    def _catch_up(self) -> None:
        """The writer thread is behind by more than max_queue records: write them here."""
        self.caught_up += 1
        try:
            with self._drain_lock:
                self._drain(yield_gil=False)
        except Exception as exc:  # noqa: BLE001 - a logging fault stops logging, nothing else
            self._set_fault(exc)

    def _flush_due(self, now: float, t: int) -> bool:
        """A flush is due after the message at log time t: flush_period_s of wall time or
        flush_sim_s of log time since the last one (sim time bounds what a kill loses)."""
        return (now - self._last_flush >= self.flush_period_s
                or bool(self.flush_sim_ns and t - self._last_flush_t >= self.flush_sim_ns))

    def _flush(self, now: float) -> None:
        self._writer.flush()
        self.flushed_messages = self.messages
        self.flushes += 1
        self._last_flush = now
        self._last_flush_t = self._last_t
        if self.max_total_bytes and self._old_files:
            self._enforce_limits()

    def new_file(self) -> None:
        """Finish the current file and continue in a new one (e.g. when sim time restarts)."""
        if self._queue is not None and self._writer is not None:
            self._queue.append(self._NEW_FILE)   # in order with what is queued before it
            return
        self._new_file_now()

    def _new_file_now(self) -> None:
        if self._writer is None:
            return
        try:
            self._close_file()
            self._last_t = 0
            self._open(self._split_path())
        except Exception as exc:  # noqa: BLE001
            self._set_fault(exc)

    def maybe_flush(self) -> None:
        """Flush if the flush period has passed (call from a timer when messages are sparse)."""
        if self._writer is None:
            return
        now = self._clock()
        if now - self._last_flush >= self.flush_period_s:
            try:
                self._flush(now)
            except Exception as exc:  # noqa: BLE001
                self._set_fault(exc)

    def _set_fault(self, exc: BaseException) -> None:
        if self.fault:
            return
        where = f' ({self.paths[-1]})' if self.paths else ''
        self.fault = f'logging stopped{where}: {type(exc).__name__}: {exc}'
        _logger.error(self.fault)
        writer, stream = self._writer, self._stream
        self._writer = self._stream = None
        if stream is not None:
            try:  # keep what can be kept: finish the file if the error allows it
                writer.finish()
                stream.finish()
            except Exception:  # noqa: BLE001
                pass
            try:
                stream.close()
            except Exception:  # noqa: BLE001
                pass
        if self.on_fault is not None:
            try:
                self.on_fault(self.fault)
            except Exception:  # noqa: BLE001
                _logger.exception('on_fault callback failed')

    @property
    def active(self) -> bool:
        """True while messages are being written."""
        return self._writer is not None

    @property
    def path(self) -> str:
        """The file being written (the last one after a split)."""
        return self.paths[-1] if self.paths else ''

    def counters(self, strings: bool = False) -> dict:
        """Messages, bytes, clamped and dropped counts, flushes, files, fault."""
        values = {'messages': self.messages, 'bytes': self.bytes, 'clamped': self.clamped,
                  'dropped': self.dropped, 'flushes': self.flushes, 'files': len(self.paths),
                  'fault': self.fault}
        return {k: str(v) for k, v in values.items()} if strings else values

    def close(self) -> None:
        """Write what is queued, finish and index the file (idempotent; never raises)."""
        _open_recorders.discard(self)
        if self._thread is not None:
            self._stop.set()
            if self._thread is not threading.current_thread():
                self._thread.join()
            self._thread = None
            with self._drain_lock:
                self._drain()
        if self._writer is None:
            return
        try:
            self._close_file()
        except Exception as exc:  # noqa: BLE001
            self._set_fault(exc)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


_open_recorders: 'weakref.WeakSet[Recorder]' = weakref.WeakSet()


@atexit.register
def _close_open_recorders() -> None:  # pragma: no cover - runs at interpreter exit
    for recorder in list(_open_recorders):
        recorder.close()


# -- reading -------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class LogMessage:
    """One logged message: CDR ``data`` of ``type_name`` on ``topic``."""

    topic: str
    type_name: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes

    def decode(self):
        """The rclpy message."""
        return deserialize(self.type_name, self.data)


def log_files(paths) -> list[str]:
    """Expand files and directories (their ``*.mcap``, sorted) into a list of MCAP files."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    files = []
    for path in map(os.fspath, paths):
        if os.path.isdir(path):
            files += sorted(os.path.join(path, f) for f in os.listdir(path) if f.endswith('.mcap'))
        else:
            files.append(path)
    if not files:
        raise FileNotFoundError(f'no MCAP files in {list(map(os.fspath, paths))}')
    return files


class LogReader:
    """
    Stream an MCAP log (one file, several split files or a directory of them) in file order.

    Works on finished and unfinished files alike: reading stops at the first record that is
    missing or torn (a file cut by SIGKILL or power loss), and :attr:`complete` then says
    False. Metadata, attachments and channels seen so far are available as attributes.
    """

    def __init__(self, paths):
        self.files = log_files(paths)
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.channels: dict[int, tuple[str, str, dict]] = {}  # per current file
        self.topics: dict[str, str] = {}                       # topic -> type name
        self.qos: dict[str, str] = {}                          # topic -> offered_qos_profiles
        self.definitions: dict[str, bytes] = {}                # type name -> schema data
        self.profile = ''
        self.complete = True
        self.errors: list[str] = []
        self._scanned = False

    def _records(self, path: str, stop_at_message: bool = False) -> Iterator:
        from mcap.records import (Attachment, Channel, Footer, Header, Message, Metadata,
                                  Schema)
        from mcap.stream_reader import StreamReader
        schemas: dict[int, str] = {}
        self.channels = {}
        finished = False
        with open(path, 'rb') as stream:
            records = StreamReader(stream, validate_crcs=True).records
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    finished = True
                    break
                except Exception as exc:  # noqa: BLE001 - the end of the readable data
                    self.errors.append(f'{path}: {type(exc).__name__}: {exc}')
                    break
                if isinstance(record, Message):
                    if stop_at_message:
                        return
                    channel = self.channels.get(record.channel_id)
                    if channel is None:
                        continue
                    yield LogMessage(channel[0], channel[1], record.log_time,
                                     record.publish_time, record.sequence, record.data)
                elif isinstance(record, Schema):
                    schemas[record.id] = record.name
                    self.definitions.setdefault(record.name, record.data)
                elif isinstance(record, Channel):
                    type_name = schemas.get(record.schema_id, '')
                    self.channels[record.id] = (record.topic, type_name, dict(record.metadata))
                    self.topics.setdefault(record.topic, type_name)
                    if 'offered_qos_profiles' in record.metadata:
                        self.qos.setdefault(record.topic, record.metadata['offered_qos_profiles'])
                elif isinstance(record, Metadata):
                    self.metadata.setdefault(record.name, dict(record.metadata))
                elif isinstance(record, Attachment):
                    self.attachments.setdefault(record.name, record.data)
                elif isinstance(record, Header):
                    self.profile = record.profile
                elif isinstance(record, Footer):
                    # no summary: a provisional end (the writer was killed after a flush)
                    finished = record.summary_start != 0
                    if not finished and not stop_at_message:
                        self.errors.append(f'{path}: unfinished (no summary: the writer '
                                           'stopped without closing the file)')
                    break
        if not finished and not stop_at_message:
            self.complete = False

    def scan_info(self) -> 'LogReader':
        """Read the header records of the first file (metadata, scene) without the messages."""
        if not self._scanned:
            for _ in self._records(self.files[0], stop_at_message=True):
                pass
            self._scanned = True
        return self

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
        """All readable messages of all files, in file order (= non-decreasing log time)."""
        wanted = None if topics is None else {_fully_qualified(t) for t in topics}
        self.complete = True
        for path in self.files:
            for message in self._records(path):
                if wanted is None or message.topic in wanted:
                    yield message
        self._scanned = True

    @property
    def info(self) -> dict[str, str]:
        """The ``det_sim_ros`` metadata record (version, scene_yaml, stepper, ...)."""
        self.scan_info()
        return self.metadata.get(METADATA_NAME, {})

    @property
    def scene_yaml(self) -> str:
        """The scene YAML the run used ('' if the log has none)."""
        self.scan_info()
        data = self.attachments.get(SCENE_ATTACHMENT)
        return data.decode() if data is not None else self.info.get('scene_yaml', '')


def recover(source, target: str, compression: str = 'zstd') -> dict:
    """
    Rewrite the readable part of a (possibly unfinished) log into a finished, indexed MCAP.

    :returns: ``{'messages': n, 'complete': bool}`` (complete: the source was finished).
    """
    from mcap.writer import CompressionType, Writer
    reader = LogReader(source)
    kind = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
            'none': CompressionType.NONE}[compression]
    count = 0
    with open(target, 'wb') as stream:
        writer = None
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for message in reader.messages():
            if writer is None:
                writer = Writer(stream, compression=kind)
                writer.start(profile=reader.profile or 'ros2', library=f'{LIBRARY} recover')
                for name, data in reader.metadata.items():
                    writer.add_metadata(name, data)
                for name, data in reader.attachments.items():
                    writer.add_attachment(0, 0, name, 'application/yaml', data)
            if message.topic not in channels:
                if message.type_name not in schemas:
                    schemas[message.type_name] = writer.register_schema(
                        message.type_name, 'ros2msg', reader.definitions[message.type_name])
                meta = {'offered_qos_profiles': reader.qos.get(message.topic,
                                                               qos_profiles_yaml())}
                channels[message.topic] = writer.register_channel(
                    message.topic, 'cdr', schemas[message.type_name], meta)
            writer.add_message(channels[message.topic], message.log_time, message.data,
                               message.publish_time, message.sequence)
            count += 1
        if writer is None:
            writer = Writer(stream, compression=kind)
            writer.start(profile=reader.profile or 'ros2', library=f'{LIBRARY} recover')
        writer.finish()
    return {'messages': count, 'complete': reader.complete}


def recover_unfinished(folder: str, exclude: Iterable[str] = ()) -> list[tuple[str, dict]]:
    """
    Repair every torn ``*.mcap`` in ``folder`` (one that does not end in a valid footer: power
    loss, or a kill inside a flush's write) in place: its readable part is rewritten as a
    finished, indexed file (:func:`recover`, through a temporary file and an atomic rename).
    Files that end in the writer's provisional end are valid MCAP already and left alone.

    :returns: ``[(path, {'messages': n, 'complete': False}), ...]`` for the repaired files.
    """
    done = []
    skip = {os.path.abspath(p) for p in exclude}
    if not os.path.isdir(folder):
        return done
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        if (not name.endswith('.mcap') or os.path.abspath(path) in skip
                or not os.path.isfile(path) or not is_torn(path)):
            continue
        temporary = path + '.recovering'
        try:
            outcome = recover(path, temporary)
            os.replace(temporary, path)
        except Exception as exc:  # noqa: BLE001 - a file we cannot repair is left as it is
            _logger.warning('cannot recover %s: %s', path, exc)
            try:
                os.remove(temporary)
            except OSError:
                pass
            continue
        done.append((path, outcome))
    return done
