"""
sim_node's topic contract, without ROS: names, types, channels, and the bytes on the wire.

One place says what the node publishes and accepts; sim_node, the MCAP recorder and replay use
it (nothing here imports rclpy):

- topics and their types (:data:`OUTPUT_FIELDS`, :data:`COMMAND_TOPICS`, :data:`TOPIC_TYPES`);
- channels: one per DET, in the scene's ``structure.dets`` order (``Model.input_names``), on
  every per-DET output; the displacement is Δy_i = y0_i − y_i with y0_i the end shortening of
  cell i's stable buckled rest state at 0 V (:func:`rest_shortenings`); the structure topic's
  outputs relative to rest (:func:`structure_channels`);
- the CDR bytes (XCDR1, the encoding ROS 2 and rosbag2 use; written and read by
  :mod:`det_sim_ros.io.cdr`) of every output sample, written straight from the simulator's
  output vector (:class:`SampleEncoder`), of /clock, and of the command types
  (:mod:`det_sim_ros.io.messages`); command decoding and validation (:class:`CommandDecoder`).

Units are SI throughout: m, m/s, C, A, V, rad, s; times on the wire are ns of sim time.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import sys
from typing import Mapping, Sequence

import numpy as np

from .cdr import CdrError, HEADER_LE, NS, Writer
from .messages import (decode_float64_multi_array, decode_joint_state, encode_clock,
                       encode_float64_multi_array, encode_joint_state, JointStateData)
from ..core.kernel import SampleCodec
from ..scenes.outputs import output_fields, output_units, relative_to_y0, structure_names
from ..sim.simulator import inputs_within

__all__ = [
    'OUTPUT_FIELDS', 'OUTPUT_UNITS', 'RELATIVE_TO_Y0', 'STRUCTURE_TOPIC', 'STRUCTURE_NAMES',
    'COMMAND_TOPIC', 'JOINT_COMMAND_TOPIC', 'COMMAND_TOPICS', 'CLOCK_TOPIC',
    'DIAGNOSTICS_TOPIC', 'TOPIC_TYPES', 'JOINT_STATE', 'FLOAT64_MULTI_ARRAY', 'CLOCK',
    'rest_shortening', 'rest_shortenings', 'structure_channels', 'OutputContract',
    'SampleEncoder', 'SampleWire', 'Command', 'CommandDecoder', 'CdrError', 'JointStateData',
    'encode_joint_state', 'decode_joint_state', 'encode_float64_multi_array',
    'decode_float64_multi_array', 'encode_clock', 'stamp_ns', 'MODES', 'basename',
]

JOINT_STATE = 'sensor_msgs/msg/JointState'
FLOAT64_MULTI_ARRAY = 'std_msgs/msg/Float64MultiArray'
CLOCK = 'rosgraph_msgs/msg/Clock'

# output topic -> JointState field -> per-DET model output (Model.channel: one value per DET),
# each topic's SI units in field order, and the fields published as y0_i - value: all derived
# from the one output table (det_sim_ros.scenes.outputs.OUTPUTS)
OUTPUT_FIELDS: dict[str, dict[str, str]] = output_fields()
OUTPUT_UNITS = output_units()
RELATIVE_TO_Y0 = relative_to_y0()   # the displacement: y0_i - y_i
# The structure topic (only for structures that have outputs: the plate), relative to rest at
# 0 V and in the displacement's sign: value = sign * (output - output at rest).
# model structure output -> (published name, sign), from the output tables
STRUCTURE_TOPIC = 'structure'
STRUCTURE_NAMES = structure_names()
COMMAND_TOPIC = 'voltage_command'              # Float64MultiArray: all voltages, DET order
JOINT_COMMAND_TOPIC = 'voltage_command_joint'  # JointState: position[i] = voltage of name[i]
COMMAND_TOPICS = (COMMAND_TOPIC, JOINT_COMMAND_TOPIC)
CLOCK_TOPIC = '/clock'
# sim_node's modes: /clock is published in free_run and lockstep; lockstep waits for commands
MODES = ('real_time', 'free_run', 'lockstep')
DIAGNOSTICS_TOPIC = '/diagnostics'
TOPIC_TYPES = {**{topic: JOINT_STATE for topic in OUTPUT_FIELDS}, STRUCTURE_TOPIC: JOINT_STATE,
               COMMAND_TOPIC: FLOAT64_MULTI_ARRAY, JOINT_COMMAND_TOPIC: JOINT_STATE,
               CLOCK_TOPIC: CLOCK, DIAGNOSTICS_TOPIC: 'diagnostic_msgs/msg/DiagnosticArray'}

_LITTLE = sys.byteorder == 'little'


def basename(topic: str) -> str:
    """Return a topic's last name ('/ns/voltage_command' -> 'voltage_command')."""
    return topic.rstrip('/').rsplit('/', 1)[-1]


def stamp_ns(k: int, dt: float) -> int:
    """Sim time of sample k on the grid t = k dt, in integer ns (the stamp and log time)."""
    return int(round(k * dt * 1e9))


# -- rest state and structure outputs -----------------------------------------------------------

def rest_shortening(scene) -> float:
    """End shortening y0 (m) of a single cell's stable buckled equilibrium at 0 V."""
    from ..physics.statics import rest_shortening as solve
    return float(solve(scene))


def rest_shortenings(scene) -> list[float]:
    """
    Return the rest shortening y0_i (m) of each cell in DET order.

    Cell i is alone at 0 V (``scene.cell_scene(i)``). Cells with identical physics share one
    statics solve, so an array of identical copies costs one solve; an array with spread costs
    one per copy (about 20 ms).
    """
    cells = scene.cell_physics()
    template = scene.cell_scene(0)
    solved = {}
    for physics in cells:
        if physics not in solved:
            solved[physics] = rest_shortening(dataclasses.replace(template, physics=physics))
    return [solved[physics] for physics in cells]


def structure_channels(model, y0) -> tuple:
    """
    Return the structure topic's contract for a model.

    The contract is (output indices, published names, signs, rest values); empty for
    structures without outputs ('single', 'array').

    The structure outputs are linear in the cells' end shortenings (Model.structure_map P), so
    their rest values are P @ y0.
    """
    names = tuple(model.structure_output_names)
    if not names:
        return (), (), (), ()
    P = np.asarray(model.structure_map, dtype=float)
    rest = P @ np.asarray(y0, dtype=float)
    indices = tuple(model.output_names.index(name) for name in names)
    published = tuple(STRUCTURE_NAMES.get(name, (name, 1.0))[0] for name in names)
    signs = tuple(STRUCTURE_NAMES.get(name, (name, 1.0))[1] for name in names)
    return indices, published, signs, tuple(float(r) for r in rest)


class OutputContract:
    """
    What sim_node publishes for a model, as arrays.

    Per-DET channels (names ``det_names``, rest shortenings ``y0``) and the structure topic
    (``structure_names``, empty if none).

    :param y0: per-DET rest shortenings (default: computed as the node does).
    """

    def __init__(self, model, y0: Sequence[float] | None = None,
                 fields: Mapping[str, Mapping[str, str]] | None = None):
        self.det_names = list(model.input_names)
        self.y0 = np.array(rest_shortenings(model.scene) if y0 is None else y0, dtype=float)
        if self.y0.shape != (len(self.det_names),):
            raise ValueError(f'y0: expected {len(self.det_names)} values, got {self.y0.size}')
        self.fields = {topic: dict(mapping)
                       for topic, mapping in (fields or OUTPUT_FIELDS).items()}
        self.index = {(topic, field): np.array(model.channel(output), dtype=np.intp)
                      for topic, mapping in self.fields.items()
                      for field, output in mapping.items()}
        self.structure_topic = STRUCTURE_TOPIC
        self.structure_outputs = tuple(model.structure_output_names)
        idx, self.structure_names, signs, rest = structure_channels(model, self.y0)
        self._s_idx = np.array(idx, dtype=np.intp)
        self._s_sign, self._s_rest = np.array(signs, dtype=float), np.array(rest, dtype=float)

    @property
    def topics(self) -> list[str]:
        """Return the output topics, structure topic last (if the model has one)."""
        return list(self.fields) + ([self.structure_topic] if self.structure_names else [])

    def names(self, topic: str) -> list[str]:
        """Return the JointState ``name`` list of an output topic."""
        return list(self.structure_names) if topic == self.structure_topic else self.det_names

    def values(self, out, topic: str, field: str) -> np.ndarray:
        """Return one topic field's published array from an output vector (output_names order)."""
        values = np.asarray(out)[self.index[(topic, field)]]
        return self.y0 - values if (topic, field) in RELATIVE_TO_Y0 else values

    def structure(self, out) -> np.ndarray:
        """Return the structure topic's positions from an output vector."""
        return self._s_sign * (np.asarray(out)[self._s_idx] - self._s_rest)

    def encoder(self) -> 'SampleEncoder':
        """
        Return a :class:`SampleEncoder` for this contract.

        Its buffers are preallocated, one per topic.
        """
        return SampleEncoder(self)


@dataclasses.dataclass(frozen=True)
class SampleWire:
    """
    The named fields the compiled encoder (``_ckernel.SampleCodec``) is built from.

    The messages' bytes with their constant parts (``template``, each message from
    ``message_start[k]``), and per published double its ``source`` in the output vector, its
    ``op`` (0: v; 1: a - v, the displacement y0 - y; 2: a (v - b), the structure outputs
    sign (v - rest)), constants ``a`` and ``b``, and byte ``position``; each message's header
    stamp at ``stamp_position``.
    """

    template: bytes
    message_start: np.ndarray   # int64, messages + 1
    stamp_position: np.ndarray  # int64, per message
    source: np.ndarray          # int64, per published double
    op: np.ndarray              # int64
    a: np.ndarray               # float64
    b: np.ndarray               # float64
    position: np.ndarray        # int64


class SampleEncoder:
    """
    The CDR bytes of every output topic for one sample, from the simulator's output vector.

    :meth:`encode` is one compiled call (``_ckernel.SampleCodec``, built from the
    :class:`SampleWire` fields here): it reads the published doubles, computes y0 - y and the
    structure outputs, and writes them and the stamp into each message's preallocated bytes
    (~1 us per sample; the struct packs below cost 4-7 us for one DET and ~50 us for 100).

    :meth:`encode_values` is the readable reference the tests hold it to byte for byte: per
    topic one precompiled ``struct.Struct`` whose format is the whole message (the constant
    parts, names and counts with their padding, as ``s`` fields; the stamp; the doubles).
    The doubles are the simulator's values bit for bit: the displacement is y0 - y and the
    structure outputs sign * (output - rest), the same IEEE operations
    :meth:`OutputContract.values` and :meth:`OutputContract.structure` do in numpy.
    """

    def __init__(self, contract: OutputContract):
        self.contract = contract
        self.topics = contract.topics
        self.slots = {}   # (topic, field) -> its doubles' slice of the published doubles
        gather, y0_slots = [], []
        structure_slot = None
        layouts = []   # per topic: (pack, parts), parts: bytes (constant) or a gather slice
        messages, positions = [], []   # per topic: its bytes; per double: its byte offset
        for topic in self.topics:
            w = Writer()
            w.stamp(0)
            w.string('')
            w.strings(contract.names(topic))
            structure = topic == contract.structure_topic
            mapping = {'position': None} if structure else contract.fields[topic]
            blocks = []   # (offset in the message, gather slice)
            message_start = sum(map(len, messages))
            for field in ('position', 'velocity', 'effort'):
                n = len(contract.names(topic)) if field in mapping else 0
                offset = w.doubles(np.zeros(n))
                if not n:
                    continue
                start = len(gather)
                index = contract._s_idx if structure else contract.index[(topic, field)]
                gather.extend(int(i) for i in index)
                positions.extend(message_start + offset + 8 * j for j in range(n))
                if (topic, field) in RELATIVE_TO_Y0:
                    y0_slots.append(slice(start, start + n))
                if structure:
                    structure_slot = slice(start, start + n)
                blocks.append((offset, slice(start, start + n)))
                self.slots[(topic, field)] = slice(start, start + n)
            raw = w.to_bytes()
            messages.append(raw)
            fmt, parts, at = ['<4siI'], [], 12       # header, stamp (sec, nanosec)
            for offset, block in blocks:
                fmt.append(f'{offset - at}s{block.stop - block.start}d')
                parts += [raw[at:offset], block]
                at = offset + 8 * (block.stop - block.start)
            if at < len(raw):
                fmt.append(f'{len(raw) - at}s')
                parts.append(raw[at:])
            layouts.append((struct.Struct(''.join(fmt)).pack, tuple(parts)))
        self._layouts = layouts
        self._gather = tuple(gather)
        self._y0 = [(slot, [float(v) for v in contract.y0]) for slot in y0_slots]
        self._structure = (structure_slot, [float(v) for v in contract._s_sign],
                           [float(v) for v in contract._s_rest]) if structure_slot else None
        op, a, b = np.zeros(len(gather), np.int64), np.zeros(len(gather)), np.zeros(len(gather))
        for slot, y0 in self._y0:
            op[slot], a[slot] = 1, y0
        if self._structure is not None:
            slot, signs, rest = self._structure
            op[slot], a[slot], b[slot] = 2, signs, rest
        starts = np.cumsum([0] + [len(m) for m in messages]).astype(np.int64)
        self.wire = SampleWire(
            template=b''.join(messages), message_start=starts, stamp_position=starts[:-1] + 4,
            source=np.array(gather, np.int64), op=op, a=a, b=b,
            position=np.array(positions, np.int64))
        self._codec = SampleCodec(self.wire)
        if not _LITTLE:  # pragma: no cover - the kernel writes little endian; so does the wire
            raise NotImplementedError('SampleEncoder needs a little-endian host')

    def values(self, out) -> list[float]:
        """
        Return the published doubles of a sample, all topics, in message order.

        y0 - y and the structure outputs are computed.
        """
        values = out.tolist() if hasattr(out, 'tolist') else list(out)
        published = [values[i] for i in self._gather]
        for slot, y0 in self._y0:
            published[slot] = [a - b for a, b in zip(y0, published[slot])]
        if self._structure is not None:
            slot, signs, rest = self._structure
            published[slot] = [s * (v - r) for s, v, r in zip(signs, published[slot], rest)]
        return published

    def encode(self, out, t_ns: int) -> list[bytes]:
        """
        Return the bytes of each topic of :attr:`topics` for output vector ``out``.

        The topics in the same order; ``out`` is float64; stamped ``t_ns``. The bytes objects are
        new (earlier ones are not changed).
        """
        if type(out) is not np.ndarray or out.dtype != np.float64 or not out.flags.c_contiguous:
            out = np.ascontiguousarray(out, dtype=np.float64)
        return self._codec.encode(out, t_ns)

    def encode_values(self, published: list, t_ns: int) -> list[bytes]:
        """Return the bytes of each topic from :meth:`values` (:meth:`encode`'s reference)."""
        sec, nanosec = divmod(t_ns, NS)
        result = []
        for pack, parts in self._layouts:
            args = [HEADER_LE, sec, nanosec]
            for part in parts:
                if type(part) is bytes:
                    args.append(part)
                else:
                    args += published[part]
            result.append(pack(*args))
        return result


# -- commands ------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Command:
    """
    A decoded voltage command: the full voltage vector in DET order, or a refusal.

    ``volts``: the voltage vector, or None for a refusal (``reason`` says why). ``clamped``
    names the channels outside [0, v_max] (the simulator clamps them). ``canonical``: the
    message's CDR bytes re-encoded with zero padding (what the log stores, so equal commands give
    equal logs).
    """

    volts: list | None
    reason: str = ''
    clamped: tuple = ()
    canonical: bytes = b''
    stamp_ns: int | None = None   # JointState header stamp (None for Float64MultiArray)


def _name_list(names, limit=6) -> str:
    names = list(names)
    if len(names) <= limit:
        return ', '.join(names)
    return ', '.join(names[:limit]) + f', ... ({len(names)} channels)'


class CommandDecoder:
    """
    Read and check voltage commands (the input rules of docs/topics.md), per channel.

    - ``voltage_command`` (Float64MultiArray): ``data`` = one voltage per DET, in DET order.
    - ``voltage_command_joint`` (JointState): ``position[i]`` = voltage of DET ``name[i]``; a
      subset may be named, the other DETs keep their ``held`` voltage.

    NaN/±inf in any channel, a wrong length, an unknown or missing name or malformed bytes:
    the whole command is refused with a reason naming the channel(s). Values outside
    [0, ``v_max``] are accepted and listed in ``clamped`` (the simulator clamps them).
    """

    def __init__(self, det_names: Sequence[str], v_max: float):
        self.det_names = list(det_names)
        self.index = {name: i for i, name in enumerate(self.det_names)}
        self.v_max = float(v_max)
        # the common command, a little-endian Float64MultiArray without dims holding one
        # voltage per DET, read by one unpack: its canonical bytes are these 20 (the header,
        # no dims, data_offset 0, the count, zero padding) and its doubles as they came
        n = len(self.det_names)
        self._vector_head = encode_float64_multi_array([0.0] * n)[:20]
        self._vector_size = 20 + 8 * n
        self._unpack_vector = struct.Struct(f'<{n}d').unpack_from

    def decode(self, topic: str, data, held: Sequence[float]) -> Command:
        """
        Decode CDR ``data`` received on ``topic`` (a name of :data:`COMMAND_TOPICS`).

        ``held``: the voltages now (a JointState may name a subset).
        """
        if topic == COMMAND_TOPIC and len(data) >= self._vector_size \
                and data[4:16] == self._vector_head[4:16] and data[:2] == b'\x00\x01':
            volts = list(self._unpack_vector(data, 20))
            if inputs_within(volts, self.v_max):   # (False for NaN: the checks below)
                return Command(volts, '', (), self._vector_head + data[20:self._vector_size])
        try:
            if topic == JOINT_COMMAND_TOPIC:
                msg = decode_joint_state(data)
                canonical = encode_joint_state(msg.name, msg.position, msg.velocity, msg.effort,
                                               msg.stamp_ns, msg.frame_id)
                return self.from_joint(msg.name, msg.position, held, canonical, msg.stamp_ns)
            values, dims, offset = decode_float64_multi_array(data)
            return self.from_vector(values, encode_float64_multi_array(values, dims, offset))
        except CdrError as exc:
            return Command(None, f'{topic}: malformed message ({exc})')

    def from_vector(self, values, canonical: bytes = b'') -> Command:
        """Return the command of a full voltage vector in DET order."""
        volts = [float(v) for v in values]
        n = len(self.det_names)
        if len(volts) != n:
            return Command(None, f'{COMMAND_TOPIC}: expected {n} voltage(s) '
                                 f'[{_name_list(self.det_names)}], got {len(volts)}',
                           canonical=canonical)
        return self._checked(COMMAND_TOPIC, volts, self.det_names, canonical, None)

    def from_joint(self, names, values, held, canonical: bytes = b'',
                   stamp: int | None = None) -> Command:
        """Named voltages; the DETs not named keep ``held``."""
        names, values = list(names), [float(v) for v in values]
        if len(names) != len(values):
            return Command(None, f'{JOINT_COMMAND_TOPIC}: {len(names)} name(s) but '
                                 f'{len(values)} position value(s)', canonical=canonical)
        if not names:
            return Command(None, f'{JOINT_COMMAND_TOPIC}: empty JointState (no DET name); name '
                                 f'one or more of {self.det_names}', canonical=canonical)
        unknown = [name for name in names if name not in self.index]
        if unknown:
            return Command(None, f'{JOINT_COMMAND_TOPIC}: unknown DET name(s) {unknown} '
                                 f'(expected {self.det_names})', canonical=canonical)
        twice = sorted({name for name in names if names.count(name) > 1})
        if twice:
            return Command(None, f'{JOINT_COMMAND_TOPIC}: DET name(s) {twice} given more '
                                 'than once; name each DET at most once', canonical=canonical)
        volts = [float(v) for v in held]
        for name, value in zip(names, values):
            volts[self.index[name]] = value
        return self._checked(JOINT_COMMAND_TOPIC, volts, names, canonical, stamp, values)

    def _checked(self, topic, volts, names, canonical, stamp, given=None) -> Command:
        given = volts if given is None else given
        bad = [name for name, v in zip(names, given) if not math.isfinite(v)]
        if bad:
            return Command(None, f'{topic}: non-finite voltage on {_name_list(bad)}',
                           canonical=canonical, stamp_ns=stamp)
        clamped = tuple(f'{name}: {v:g} V' for name, v in zip(names, given)
                        if not 0.0 <= v <= self.v_max)
        return Command(volts, '', clamped, canonical, stamp)


def clamp_message(topic: str, clamped: Sequence[str], v_max: float) -> str:
    """
    Return the clamp warning for a command's ``clamped`` channels.

    ``clamped`` as in :attr:`Command.clamped`; e.g. 'det0: -5 V clamped to [0, 3000] V
    (voltage_command)'.
    """
    return f'{_name_list(clamped)} clamped to [0, {v_max:g}] V ({topic})'
