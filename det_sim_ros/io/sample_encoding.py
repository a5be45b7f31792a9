"""
sim_node's output samples as arrays and as CDR bytes, from the simulator's output vector.

:class:`OutputContract` says what the node publishes for a model: one channel per DET, in the
scene's ``structure.dets`` order (``Model.input_names``), on every per-DET output; the
displacement is Δy_i = y0_i − y_i with y0_i the end shortening of cell i's stable buckled rest
state at 0 V (:func:`~det_sim_ros.physics.statics.rest_shortenings`); the structure topic's
outputs relative to rest (:func:`structure_channels`). :class:`SampleEncoder` writes a sample's
CDR bytes (XCDR1, :mod:`det_sim_ros.io.cdr`) straight from the output vector.
"""

from __future__ import annotations

import dataclasses
import struct
import sys
from typing import Mapping, Sequence

import numpy as np

from .cdr import HEADER_LE, NS, Writer
from .topics import OUTPUT_FIELDS, RELATIVE_TO_Y0, STRUCTURE_NAMES, STRUCTURE_TOPIC
from ..core.kernel import SampleCodec
from ..physics.statics import rest_shortenings

__all__ = ['structure_channels', 'OutputContract', 'SampleEncoder', 'SampleWire']


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
        # the structure topic's positions: sign * (output vector[index] - rest)
        self.structure_index = np.array(idx, dtype=np.intp)
        self.structure_signs = np.array(signs, dtype=float)
        self.structure_rest = np.array(rest, dtype=float)

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
        return self.structure_signs * (np.asarray(out)[self.structure_index]
                                       - self.structure_rest)

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
    structure outputs, and writes them and the stamp into each message's preallocated bytes, at
    a fraction of the cost of the struct packs below (docs/performance.md).

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
                index = contract.structure_index if structure else contract.index[(topic, field)]
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
        self._structure = (structure_slot, [float(v) for v in contract.structure_signs],
                           [float(v) for v in contract.structure_rest]) if structure_slot else None
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
        if sys.byteorder != 'little':  # pragma: no cover - the kernel and the wire: little endian
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
