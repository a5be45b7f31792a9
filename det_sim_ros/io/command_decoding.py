"""
Voltage commands read and checked, per channel (the input rules of docs/topics.md).

:class:`CommandDecoder` turns a command's CDR bytes into a :class:`Command`: the full voltage
vector in DET order, or a refusal that names the channel(s).
"""

from __future__ import annotations

import dataclasses
import math
import struct
from typing import Sequence

from .cdr import CdrError
from .messages import (decode_float64_multi_array, decode_joint_state,
                       encode_float64_multi_array, encode_joint_state)
from .topics import COMMAND_TOPIC, JOINT_COMMAND_TOPIC
from ..sim.simulator import inputs_within

__all__ = ['Command', 'CommandDecoder', 'clamp_message']


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
