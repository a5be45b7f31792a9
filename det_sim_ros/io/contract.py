"""
sim_node's topic contract, without ROS: its public import path.

One place says what the node publishes and accepts; sim_node, the MCAP recorder and replay use
it (nothing here imports rclpy). By job:

- topics and their types (:data:`OUTPUT_FIELDS`, :data:`COMMAND_TOPICS`, :data:`TOPIC_TYPES`):
  :mod:`det_sim_ros.io.topics`;
- channels and the bytes of every output sample (:class:`OutputContract`,
  :class:`SampleEncoder`): :mod:`det_sim_ros.io.sample_encoding`; the rest shortenings y0_i
  they are relative to: :mod:`det_sim_ros.physics.statics`;
- the CDR bytes (XCDR1, the encoding ROS 2 and rosbag2 use) of /clock and of the command
  types: :mod:`det_sim_ros.io.messages`; command decoding and validation
  (:class:`CommandDecoder`): :mod:`det_sim_ros.io.command_decoding`.

Units are SI throughout: m, m/s, C, A, V, rad, s; times on the wire are ns of sim time.
"""

from __future__ import annotations

from .cdr import CdrError
from .command_decoding import clamp_message, Command, CommandDecoder
from .messages import (decode_float64_multi_array, decode_joint_state, encode_clock,
                       encode_float64_multi_array, encode_joint_state, JointStateData)
from .sample_encoding import OutputContract, SampleEncoder, SampleWire, structure_channels
from .topics import (basename, CLOCK, CLOCK_TOPIC, COMMAND_TOPIC, COMMAND_TOPICS,
                     DIAGNOSTICS_TOPIC, FLOAT64_MULTI_ARRAY, JOINT_COMMAND_TOPIC, JOINT_STATE,
                     MODES, OUTPUT_FIELDS, OUTPUT_UNITS, PREDICTABILITY_RATE_HZ,
                     PREDICTABILITY_TOPIC, RELATIVE_TO_Y0, stamp_ns, STRUCTURE_NAMES,
                     STRUCTURE_TOPIC, TOPIC_TYPES)
from ..physics.statics import rest_shortening, rest_shortenings

__all__ = [
    'OUTPUT_FIELDS', 'OUTPUT_UNITS', 'RELATIVE_TO_Y0', 'STRUCTURE_TOPIC', 'STRUCTURE_NAMES',
    'COMMAND_TOPIC', 'JOINT_COMMAND_TOPIC', 'COMMAND_TOPICS', 'CLOCK_TOPIC',
    'DIAGNOSTICS_TOPIC', 'PREDICTABILITY_TOPIC', 'PREDICTABILITY_RATE_HZ', 'TOPIC_TYPES',
    'JOINT_STATE', 'FLOAT64_MULTI_ARRAY', 'CLOCK',
    'rest_shortening', 'rest_shortenings', 'structure_channels', 'OutputContract',
    'SampleEncoder', 'SampleWire', 'Command', 'CommandDecoder', 'CdrError', 'JointStateData',
    'encode_joint_state', 'decode_joint_state', 'encode_float64_multi_array',
    'decode_float64_multi_array', 'encode_clock', 'stamp_ns', 'MODES', 'basename',
    'clamp_message',
]
