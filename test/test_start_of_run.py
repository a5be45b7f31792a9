"""
The start of a run is not lost: ``wait_for_subscribers`` holds sample 0 until they are there.

The node cannot know that a subscriber is coming; with ``wait_for_subscribers: N`` it publishes
sample 0 and starts stepping only once N subscriptions of ``displacement`` have matched (and
acknowledged sample 0), so such a subscriber's first sample is sample 0 whenever it starts.
"""

import time

from conftest import WALL_TIMEOUT
from det_sim_ros.ros.discovery import announce_early
from det_sim_ros.ros.params import NODE_PARAMS
import pytest


def spin_until(executor, condition, what):
    deadline = time.monotonic() + WALL_TIMEOUT
    while not condition():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        executor.spin_once(timeout_sec=0.01)


@pytest.mark.ros
@pytest.mark.parametrize('mode', ['free_run', 'real_time'])
def test_a_late_subscriber_gets_sample_0(ros_context, mode):
    """
    Check that a subscriber created after the node still gets sample 0 as its first sample.

    The node (wait_for_subscribers 1) publishes nothing and does not step while alone, and says
    it waits for a subscriber of /displacement; once one subscribes, its first sample is t = 0.
    """
    import rclpy
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState
    from det_sim_ros.ros.node import make_executor, SimNode
    node = SimNode(context=ros_context, parameter_overrides=[
        Parameter('mode', value=mode), Parameter('log.enabled', value=False),
        Parameter('info_period', value=0.0), Parameter('wait_for_subscribers', value=1)])
    published = []
    node.on_sample = lambda k, out: published.append(k)
    executor = make_executor(ros_context)
    executor.add_node(node)
    try:
        for _ in range(20):                 # alone: nothing is published, nothing stepped
            executor.spin_once(timeout_sec=0.01)
        assert published == [] and node.simulator.k == 0 and not node.running
        wait = node.waiting()
        assert wait.text().endswith('for 1 subscriber on /displacement (0 of 1)'), wait.text()
        tester = rclpy.create_node('late_subscriber', context=ros_context)
        executor.add_node(tester)
        stamps = []
        tester.create_subscription(JointState, 'displacement', lambda msg: stamps.append(
            msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec), 10)
        spin_until(executor, lambda: len(stamps) >= 5, 'five samples')
        assert stamps[0] == 0 and published[0] == 0
        assert node.running and node.waiting() is None
        tester.destroy_node()
    finally:
        executor.shutdown()
        node.destroy_node()


def test_wait_for_subscribers_is_a_read_only_parameter():
    """Check that wait_for_subscribers is declared read-only, default 0 (publish at once)."""
    param = NODE_PARAMS['wait_for_subscribers']
    assert param.default == 0 and param.read_only and param.bounds[0] == 0


def test_the_node_announces_itself_early_unless_the_user_has_a_dds_profile(
        tmp_path, monkeypatch):
    """
    Check that sim_node's own process gets the early-announcement profile, and only then.

    With no Fast DDS profile of the user's, a profile that announces the participant every
    0.1 s for its first seconds and every 0.25 s after them is in force within the block and
    gone after it; with one, the user's setting is kept.
    """
    monkeypatch.chdir(tmp_path)
    environ = {}
    with announce_early(environ) as used:
        path = environ['FASTRTPS_DEFAULT_PROFILES_FILE']
        with open(path) as stream:
            profile = stream.read()
    assert used and '<initialAnnouncements>' in profile and '<count>20</count>' in profile
    assert '<leaseAnnouncement><sec>0</sec><nanosec>250000000</nanosec>' in profile
    assert environ == {}
    mine = {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/my_dds.xml'}
    with announce_early(mine) as used:
        assert not used and mine == {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/my_dds.xml'}


if __name__ == '__main__':
    pytest.main([__file__])
