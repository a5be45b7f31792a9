"""
Test that a log sim_node recorded with a controller in the loop, in lockstep, fits.

The node records its own log (its scene, each command at the period it applied to, its
outputs); the fit replays those commands open loop, which reproduces the closed-loop run, and
finds the modulus and the beam damping of the scene that ran from a start well off both; the
fitted scene file runs in sim_node.
"""

import det_sim_ros
# The fixture, as the plugin gives it. pyflakes reads the test's det_sim argument as a
# redefinition of this import, hence the F811 noqa on the test.
from det_sim_ros.ros.testing import det_sim  # noqa: F401
from det_sim_ros.scenes.scene import load_scene
import pytest

pytestmark = pytest.mark.ros

T_STEP, TARGET, KP, KI = 0.1, 2.0e-3, 2.0e4, 6.0e6   # s, m, V/m, V/(m s)


def make_controller(context):
    """Return a PI controller node that answers every displacement sample."""
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    node = rclpy.create_node('pi', context=context)
    pub = node.create_publisher(Float64MultiArray, 'voltage_command', 10)
    integral = [0.0]

    def on_dy(msg):
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        error = TARGET - msg.position[0] if t >= T_STEP - 1e-9 else 0.0
        integral[0] += error * 1e-3
        volts = min(3000.0, max(0.0, KP * error + KI * integral[0]))
        pub.publish(Float64MultiArray(data=[volts]))
    node.create_subscription(JointState, 'displacement', on_dy, 10)
    return node


def test_a_lockstep_log_with_a_controller_fits(det_sim, tmp_path):  # noqa: F811
    path = tmp_path / 'lockstep.mcap'
    sim = det_sim('default', params={'log.path': str(path)})
    first = sim.run(until=0.4, nodes=[make_controller(sim.context)])
    sim.close()
    scene = load_scene('default')
    result = det_sim_ros.fit(str(path), ['Y', 'eta_b'], start={'Y': 1.4e6, 'eta_b': 0.7e6},
                             starts=1, parallel='serial')
    assert result.converged, result.message
    truth = {'Y': scene.physics.Y, 'eta_b': scene.physics.eta_b}
    for estimate in result.estimates:
        assert estimate.identified, estimate
        assert estimate.value == pytest.approx(truth[estimate.name], rel=1e-3)
    # the closed loop is reproduced: residuals at the integration's tolerance, not the noise's
    assert max(result.rms_after.values()) < 1e-3 * min(result.rms_before.values())
    # sim_node runs the fitted scene file as it is
    fitted = tmp_path / 'fitted.yaml'
    result.write(str(fitted), plot=False)
    again = det_sim(str(fitted))
    # past the controller's step to 2 mm: the beam moves as in the recorded run
    run = again.run(until=T_STEP + 0.02, nodes=[make_controller(again.context)])
    k = len(run.t) - 1
    assert run.t[k] == pytest.approx(first.t[k]) == pytest.approx(T_STEP + 0.02)
    assert run.signal('dy')[k] > 1e-5
    assert run.signal('dy')[k] == pytest.approx(first.signal('dy')[k], rel=1e-2)
