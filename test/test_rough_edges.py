"""
Test the node's names on /diagnostics, the clamp warning's wording and the ROS_DOMAIN_ID.

A namespaced node names itself fully on /diagnostics; the clamp warning names the channel,
then the value; the test suite respects the user's ROS_DOMAIN_ID.
"""

import os

from conftest import DOMAIN_ID, pick_domain_id
from det_sim_ros.io.contract import clamp_message
from det_sim_ros.ros.node import SimNode
import pytest
from rclpy.parameter import Parameter


@pytest.mark.ros
def test_diagnostics_name_the_fully_qualified_node(ros_context):
    node = SimNode(context=ros_context, namespace='arm1', parameter_overrides=[
        Parameter('real_time', value=False), Parameter('start_paused', value=True),
        Parameter('log.enabled', value=False)])
    try:
        sent = [node.publish_diagnostics()]
    finally:
        node.destroy_node()
    status = sent[-1].status[0]
    assert status.name == '/arm1/sim_node: simulation'
    assert status.hardware_id == '/arm1/sim_node'


def test_clamp_warning_names_channel_then_value():
    """Check the warning the node logs for a clamped command, from the contract's decoding."""
    from det_sim_ros.io.contract import CommandDecoder, encode_float64_multi_array
    for names, volts, expected in (
            (['det0'], [-5.0], 'det0: -5 V clamped to [0, 3000] V (voltage_command)'),
            (['left', 'right'], [3500.0, 10.0],
             'left: 3500 V clamped to [0, 3000] V (voltage_command)')):
        command = CommandDecoder(names, 3000.0).decode(
            'voltage_command', encode_float64_multi_array(volts), [0.0] * len(names))
        assert clamp_message('voltage_command', command.clamped, 3000.0) == expected


def test_domain_id_respects_the_users_setting():
    assert pick_domain_id({'ROS_DOMAIN_ID': '42'}, 7) == 42
    assert pick_domain_id({'ROS_DOMAIN_ID': ' 0 '}, 7) == 0
    assert pick_domain_id({}, 7) == 8 and pick_domain_id({'ROS_DOMAIN_ID': ''}, 7) == 8
    with pytest.raises(pytest.UsageError, match='ROS_DOMAIN_ID'):
        pick_domain_id({'ROS_DOMAIN_ID': 'abc'}, 7)
    assert os.environ['ROS_DOMAIN_ID'] == str(DOMAIN_ID)
