"""
The CDR messages of sim_node's topic contract, without ROS: JointState, Float64MultiArray, Clock.

Written and read by :mod:`det_sim_ros.io.cdr`; :mod:`det_sim_ros.io.contract` gives them with
the rest of the contract. Times are ns of sim time.
"""

from __future__ import annotations

import dataclasses
import struct
from typing import Sequence

from .cdr import HEADER_LE, NS, Reader, Writer

__all__ = ['JointStateData', 'encode_joint_state', 'decode_joint_state',
           'encode_float64_multi_array', 'decode_float64_multi_array', 'encode_clock']


@dataclasses.dataclass
class JointStateData:
    """The fields of a sensor_msgs/JointState (stamp in ns)."""

    stamp_ns: int = 0
    frame_id: str = ''
    name: list = dataclasses.field(default_factory=list)
    position: list = dataclasses.field(default_factory=list)
    velocity: list = dataclasses.field(default_factory=list)
    effort: list = dataclasses.field(default_factory=list)


def encode_joint_state(name=(), position=(), velocity=(), effort=(), stamp_ns: int = 0,
                       frame_id: str = '') -> bytes:
    """CDR bytes of a sensor_msgs/JointState."""
    w = Writer()
    w.stamp(stamp_ns)
    w.string(frame_id)
    w.strings(list(name))
    for values in (position, velocity, effort):
        w.doubles(values)
    return w.to_bytes()


def decode_joint_state(data) -> JointStateData:
    """Return the fields of a CDR sensor_msgs/JointState. :raises CdrError: malformed bytes."""
    r = Reader(data)
    return JointStateData(r.stamp(), r.string(), r.strings(), r.doubles(), r.doubles(),
                          r.doubles())


def encode_float64_multi_array(data=(), dims: Sequence[tuple] = (), data_offset: int = 0) -> bytes:
    """CDR bytes of a std_msgs/Float64MultiArray (``dims``: (label, size, stride) tuples)."""
    w = Writer()
    w.u32(len(dims))
    for label, size, stride in dims:
        w.string(label)
        w.u32(size)
        w.u32(stride)
    w.u32(data_offset)
    w.doubles(data)
    return w.to_bytes()


def decode_float64_multi_array(data) -> tuple[list[float], list[tuple], int]:
    """Return (data, dims, data_offset) of a CDR std_msgs/Float64MultiArray."""
    r = Reader(data)
    dims = [(r.string(), r.u32(), r.u32()) for _ in range(r.count(12))]
    offset = r.u32()
    return r.doubles(), dims, offset


# a Clock is the header and one stamp: Writer.stamp's layout in one pack (it is published
# every step of a free run); test_contract holds it to the Writer's bytes
_CLOCK = struct.Struct('<4siI')


def encode_clock(t_ns: int) -> bytes:
    """CDR bytes of a rosgraph_msgs/Clock at sim time ``t_ns``."""
    sec, nanosec = divmod(int(t_ns), NS)
    return _CLOCK.pack(HEADER_LE, sec, nanosec)
