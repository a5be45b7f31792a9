"""
Test what the package relies on in rclpy beyond its documented behaviour, on the installed rclpy.

The two reaches past rclpy's public API (det_sim_ros.ros.rclpy_facade) and what the node's
parameter declaration assumes of rclpy (det_sim_ros.ros.declaration). These fail when rclpy
changes what they rely on; the first names the version the facade was checked against, so an
upgrade says where to look.
"""

from importlib.metadata import version

import pytest

pytestmark = pytest.mark.ros


def test_the_facade_was_checked_against_the_installed_rclpy():
    from det_sim_ros.ros.rclpy_facade import CHECKED_AGAINST
    installed = version('rclpy')
    assert installed.split('.')[:2] == CHECKED_AGAINST.split('.')[:2], (
        f'rclpy {installed} is installed, the facade was checked against {CHECKED_AGAINST}: '
        're-check det_sim_ros/ros/rclpy_facade.py and det_sim_ros/ros/declaration.py')


def test_take_serialized_gives_the_bytes_published_and_none_when_nothing_waits(ros_context):
    import time
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64MultiArray
    import rclpy
    from det_sim_ros.ros.rclpy_facade import take_serialized
    node = rclpy.create_node('facade_take', context=ros_context)
    try:
        sub = node.create_subscription(Float64MultiArray, 'facade_take', lambda data: None, 10,
                                       raw=True)
        pub = node.create_publisher(Float64MultiArray, 'facade_take', 10)
        assert take_serialized(sub) is None
        deadline = time.monotonic() + 10.0   # (safety net: local delivery takes ms)
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        sent = [Float64MultiArray(data=[float(i), 2.5]) for i in range(3)]
        for msg in sent:
            pub.publish(msg)
        taken = []
        while len(taken) < len(sent) and time.monotonic() < deadline:
            data = take_serialized(sub)
            if data is None:
                time.sleep(0.001)
            else:
                taken.append(data)
        # in order, each the serialized message (read back by rclpy's public deserializer)
        assert all(isinstance(data, bytes) for data in taken)
        assert [deserialize_message(data, Float64MultiArray) for data in taken] == sent
        assert take_serialized(sub) is None
    finally:
        node.destroy_node()


def test_rclerror_is_what_rclpy_raises_for_arguments_rcl_cannot_parse():
    from rclpy.context import Context
    import rclpy
    from det_sim_ros.ros.rclpy_facade import RCLError
    with pytest.raises(RCLError, match="parameter override rule: '-p bad'"):
        rclpy.init(args=['sim_node', '--ros-args', '-p', 'bad'], context=Context())


def test_a_plain_node_declares_exactly_the_parameters_the_declaration_counts_as_rclpys(
        ros_context):
    import rclpy
    from det_sim_ros.ros.declaration import RCLPY_OWN_PARAMETERS
    node = rclpy.create_node('facade_plain', context=ros_context)
    try:
        assert set(node.get_parameters_by_prefix('')) == RCLPY_OWN_PARAMETERS
    finally:
        node.destroy_node()


def test_start_up_values_are_declared_as_checked_and_unknown_names_not_at_all(harness):
    from rcl_interfaces.msg import ParameterType
    h = harness(**{'physics.Rs': 1500, 'modee': 'free_run', 'max_lag': 1, 'use_sim_time': False})
    node = h.node
    # an integer given for a double is declared a double (rclpy refuses the other type later)
    rs = node.get_parameter('physics.Rs')
    assert rs.type_.value == ParameterType.PARAMETER_DOUBLE and rs.value == 1500.0
    assert node.scene.physics.Rs == 1500.0
    assert node.describe_parameter('physics.Rs').read_only
    lag = node.get_parameter('max_lag')
    assert lag.type_.value == ParameterType.PARAMETER_DOUBLE and lag.value == 1.0
    assert not node.has_parameter('modee')           # warned about, then not declared
    assert node.has_parameter('use_sim_time')        # rclpy's own, given or not
    assert node.get_parameter('scene_file').value == 'default'
