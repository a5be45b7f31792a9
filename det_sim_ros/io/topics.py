"""
sim_node's topic names and types, without ROS: what it publishes and accepts, and its modes.

The output topics and their fields, units and the fields published relative to rest come from
the one output table (:mod:`det_sim_ros.scenes.outputs`); times on the wire are ns of sim time.
"""

from __future__ import annotations

from ..scenes.outputs import output_fields, output_units, relative_to_y0, structure_names

__all__ = [
    'OUTPUT_FIELDS', 'OUTPUT_UNITS', 'RELATIVE_TO_Y0', 'STRUCTURE_TOPIC', 'STRUCTURE_NAMES',
    'COMMAND_TOPIC', 'JOINT_COMMAND_TOPIC', 'COMMAND_TOPICS', 'CLOCK_TOPIC',
    'DIAGNOSTICS_TOPIC', 'PREDICTABILITY_TOPIC', 'PREDICTABILITY_RATE_HZ', 'TOPIC_TYPES',
    'JOINT_STATE', 'FLOAT64_MULTI_ARRAY', 'CLOCK',
    'stamp_ns', 'MODES', 'basename',
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
# JointState, one channel 'twin_distance': how far the perturbed twin is from the run, a
# fraction of the stroke (det_sim_ros.analysis.predictability), at PREDICTABILITY_RATE_HZ of sim
# time and at every stretch's start and end. Not every sample: a message between two samples
# ends the log writer's packed run of samples (docs/predictability.md: the node's cost)
PREDICTABILITY_TOPIC = 'predictability'
PREDICTABILITY_RATE_HZ = 10.0
TOPIC_TYPES = {**{topic: JOINT_STATE for topic in OUTPUT_FIELDS}, STRUCTURE_TOPIC: JOINT_STATE,
               COMMAND_TOPIC: FLOAT64_MULTI_ARRAY, JOINT_COMMAND_TOPIC: JOINT_STATE,
               CLOCK_TOPIC: CLOCK, DIAGNOSTICS_TOPIC: 'diagnostic_msgs/msg/DiagnosticArray',
               PREDICTABILITY_TOPIC: JOINT_STATE}


def basename(topic: str) -> str:
    """Return a topic's last name ('/ns/voltage_command' -> 'voltage_command')."""
    return topic.rstrip('/').rsplit('/', 1)[-1]


def stamp_ns(k: int, dt: float) -> int:
    """Sim time of sample k on the grid t = k dt, in integer ns (the stamp and log time)."""
    return int(round(k * dt * 1e9))
