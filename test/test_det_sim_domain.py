"""
The det_sim fixture runs on the ROS domain the user set, as the package's tests do.

ROS_DOMAIN_ID, when set, is the fixture's domain; unset, the fixture picks one from the pid
(never 0); a value that is not a domain id is refused with one line.
"""

import os

from conftest import DOMAIN_ID, pick_domain_id as suite_domain_id
from det_sim_ros.ros.testing import LockstepSim, pick_domain_id
import pytest
import rclpy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray


def _other_than_the_pid_default():
    """
    Return a domain id the pid would not give, so that the test tells the two apart.

    The session's own domain (conftest sets ROS_DOMAIN_ID) unless the pid happens to give it.
    """
    from_pid = 1 + os.getpid() % 101
    session = int(os.environ['ROS_DOMAIN_ID'])
    return str(session if session != from_pid else from_pid + 101)


@pytest.mark.ros
def test_the_fixture_runs_on_the_users_domain(det_sim, monkeypatch):
    users = _other_than_the_pid_default()
    monkeypatch.setenv('ROS_DOMAIN_ID', users)
    sim = det_sim('default')
    assert sim.domain_id == int(users) and sim.context.get_domain_id() == int(users)
    node = rclpy.create_node('hold', context=sim.context)
    cmd = node.create_publisher(Float64MultiArray, 'voltage_command', 10)
    node.create_subscription(JointState, 'displacement', lambda msg: cmd.publish(
        Float64MultiArray(data=[1000.0])), 10)     # answers every sample
    run = sim.run(until=0.005, nodes=[node])
    assert run.t[-1] == pytest.approx(0.005) and run.voltage[-1, 0] == 1000.0


def test_without_ros_domain_id_the_pid_picks_a_nonzero_domain(monkeypatch):
    monkeypatch.delenv('ROS_DOMAIN_ID', raising=False)
    assert pick_domain_id() == 1 + os.getpid() % 101
    assert pick_domain_id({}, 100) == 101 and pick_domain_id({'ROS_DOMAIN_ID': ' 7 '}, 3) == 7


@pytest.mark.parametrize('text', ['abc', '233', '-1'])
def test_a_bad_ros_domain_id_is_one_line(monkeypatch, text):
    monkeypatch.setenv('ROS_DOMAIN_ID', text)
    with pytest.raises(ValueError, match=r'^ROS_DOMAIN_ID=.*expected a number in 0\.\.232$'):
        LockstepSim('default')


def test_the_suite_runs_on_the_users_ros_domain_id():
    """Check the suite's domain: ROS_DOMAIN_ID trimmed, else 1 + pid % 101; junk refused."""
    assert suite_domain_id({'ROS_DOMAIN_ID': '42'}, 7) == 42
    assert suite_domain_id({'ROS_DOMAIN_ID': ' 0 '}, 7) == 0
    assert suite_domain_id({}, 7) == 8 and suite_domain_id({'ROS_DOMAIN_ID': ''}, 7) == 8
    with pytest.raises(pytest.UsageError, match='ROS_DOMAIN_ID'):
        suite_domain_id({'ROS_DOMAIN_ID': 'abc'}, 7)
    assert os.environ['ROS_DOMAIN_ID'] == str(DOMAIN_ID)
