"""
sim_node's predictability measure and the plugin's ensemble, seen as a user sees them.

The node steps a perturbed twin beside its run: where the path stops being robust it says so on
/diagnostics, in a WARN line (/rosout) and in its log. In lockstep the run is the offline run
bit for bit, so the node's first stretch starts where det_sim_ros.analysis.predictability's
does (an independent path: one compiled run of the scene and one of its twin, no ROS).
"""

from det_sim_ros.analysis.predictability import PathNotRobustWarning, predictability
from det_sim_ros.analysis.scenarios import pwm_voltage, switching_scene
from det_sim_ros.io.log import LogReader
from det_sim_ros.io.messages import decode_joint_state
# the fixture, as the plugin gives it (F811: each test's det_sim argument redefines it)
from det_sim_ros.ros.testing import det_sim  # noqa: F401
import pytest

pytestmark = pytest.mark.ros

PWM_SCENE = {'scene.beam': 'simply_supported', 'scene.eps_b': 0.20,
             'scene.initial_state': 'released'}


def make_open_loop(context, volts, name='pwm'):
    """Create a controller node that answers sample k with volts(t_k): the PWM through ROS."""
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    node = rclpy.create_node(name, context=context)
    pub = node.create_publisher(Float64MultiArray, 'voltage_command', 10)

    def on_dy(msg):
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        pub.publish(Float64MultiArray(data=[float(volts(t))]))
    node.create_subscription(JointState, 'displacement', on_dy, 10)
    return node


def test_the_node_says_where_its_path_stops_being_robust(det_sim, tmp_path):  # noqa: F811
    """
    Check that the node says where its path stops being robust.

    The simply supported beam under the 10 Hz PWM, in lockstep: /diagnostics names the time the
    path stopped being robust (the offline measure's, to the sample), one WARN line says so with
    what to do, and the log holds the twin's distance beyond the 5 % limit from there.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile
    import rclpy
    volts = pwm_voltage(3000.0)
    offline = predictability(switching_scene('simply_supported', 0.20), volts, 2.5)
    assert offline.robust_until is not None   # the premise: this case is not robust
    sim = det_sim('default', PWM_SCENE, {'log.path': str(tmp_path / 'run.mcap')})
    listener = rclpy.create_node('listener', context=sim.context)
    lines, statuses = [], []
    listener.create_subscription(
        Log, '/rosout', lambda m: lines.append((m.level, m.msg)) if m.name == 'sim_node' else 0,
        QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    listener.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: statuses.append({kv.key: kv.value for kv in m.status[0].values}), 10)
    with pytest.warns(PathNotRobustWarning, match='ensemble'):   # the plugin says so too
        run = sim.run(until=2.5, nodes=[make_open_loop(sim.context, volts), listener])
    assert run.robust_until == pytest.approx(offline.robust_until)
    sim.node.publish_diagnostics()
    sim.spin_until(lambda: statuses and statuses[-1]['sim_time_s'] == '2.500000',
                   '/diagnostics at 2.5 s')
    sim.spin_until(lambda: any('not robust' in text for _, text in lines), 'the WARN line')
    status = statuses[-1]
    assert status['robust_until_s'] == f'{offline.robust_until:.3f}'
    assert status['robust_now'] == 'false'
    # (the key holds 4 digits)
    assert float(status['twin_distance']) == pytest.approx(offline.distance[-1], rel=1e-3)
    warned = [text for level, text in lines if 'not robust' in text]
    assert len(warned) == 1 and f'from t = {offline.robust_until:.3f} s' in warned[0]
    assert 'ensemble' in warned[0] and all(level == 30 for level, text in lines
                                           if 'not robust' in text)   # WARN
    sim.close()
    logged = {}
    for message in LogReader(str(tmp_path / 'run.mcap')).messages(topics=['predictability']):
        logged[round(message.log_time * 1e-6)] = decode_joint_state(message.data).position[0]
    first_ms = round(offline.robust_until * 1e3)
    assert logged[first_ms] > 0.05 and max(v for ms, v in logged.items() if ms < first_ms) <= 0.05
    assert len(logged) >= 25   # 10 Hz over 2.5 s, and the stretch's start
    # det_sim plot's reading: the panel, and the shading from the stretch's first sample
    from det_sim_ros.io.logplot import read_log
    data = read_log(str(tmp_path / 'run.mcap'))
    assert any(channel.unit == '% of stroke' for channel in data.channels)
    assert data.not_robust and data.not_robust[0][0] == pytest.approx(offline.robust_until)


def test_a_lockstep_ensemble_states_what_every_perturbed_copy_shares(det_sim):  # noqa: F811
    """
    Check that a lockstep ensemble states what every perturbed copy shares.

    The plugin's ensemble, closed loop: a PI to 2 mm against 4 perturbed copies of the default,
    each copy its own sim_node and controller node.

    Every copy settles within 5 % and ends on the + branch: what shared() states (ranges over the
    copies) is what a test can assert; the copies differ (the perturbation is real) yet agree on
    it.
    """
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    def make_controllers(sim):
        node = rclpy.create_node('pi', context=sim.context)
        pub = node.create_publisher(Float64MultiArray, 'voltage_command', 10)
        integral = [0.0]

        def on_dy(msg):
            t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            error = 2e-3 - msg.position[0] if t >= 0.6 else 0.0
            integral[0] += error * 1e-3
            pub.publish(Float64MultiArray(
                data=[min(3000.0, max(0.0, 2e4 * error + 6e6 * integral[0]))]))
        node.create_subscription(JointState, 'displacement', on_dy, 10)
        return [node]
    runs = det_sim.ensemble(make_controllers, until=1.2, copies=4)
    assert all(run.robust_until is None for run in runs.runs)   # a settling PI is robust
    shared = runs.shared(start=0.6, target=2e-3, t_step=0.6)
    assert len(runs) == 4 and shared.final_branch == 'buckled+', shared
    assert shared.settling[1] <= 0.5, shared
    assert runs.overrides[0] == {} and all('physics.m' in o for o in runs.overrides[1:])
    assert len({float(run.dy[-1, 0]) for run in runs.runs}) > 1   # the copies differ
