"""
Test the ``det_sim`` verbs that talk to a running sim_node, against a real node.

sim_node (plate scene, namespace /arm1, started paused) runs in this process, spun in a
thread of its own context on the test domain; the verbs reach it over DDS like any other
process would: send, watch, pause, resume, advance, reset, param get and set.
"""

import threading

from det_sim_ros.cli import main
import pytest

pytestmark = pytest.mark.ros

NS = ['--ns', 'arm1']
RATE = 0.1   # real_time_factor: 100 samples per wall second


@pytest.fixture(scope='module')
def node():
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from det_sim_ros.ros.node import SimNode
    from conftest import DOMAIN_ID
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    params = {'scene_file': 'plate', 'start_paused': True, 'log.enabled': False,
              'info_period': 0.0, 'real_time_factor': RATE}
    sim = SimNode(context=context, namespace='/arm1',
                  parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(sim)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    yield sim
    executor.shutdown()
    sim.destroy_node()
    rclpy.try_shutdown(context=context)
    thread.join(timeout=10.0)


def _charge(node):
    return dict(zip(node.det_names,
                    node.contract.values(node.current_outputs(), 'charge', 'position')))


def _ok(capsys, argv):
    assert main(argv + NS) == 0, capsys.readouterr().err
    return capsys.readouterr().out


def _error(capsys, argv, code):
    assert main(argv) == code
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('det_sim: error: '), err
    return err


def test_send_by_name_and_in_det_order_then_advance(node, capsys):
    assert 'paused' in _ok(capsys, ['pause'])
    assert node.paused
    assert 'right=1500 V on /arm1/voltage_command_joint' in _ok(capsys, ['send', 'right=1500'])
    assert 'advanced 3 period(s): t = 0.003 s' in _ok(capsys, ['advance', '3'])
    charge = _charge(node)
    assert charge['left'] == 0.0 and charge['right'] > 0.0
    assert 'left=2000, right=0 V on /arm1/voltage_command' in _ok(capsys, ['send', '2000', '0'])
    _ok(capsys, ['advance'])
    assert _charge(node)['left'] > 0.0
    assert 'reset to t = 0' in _ok(capsys, ['reset'])
    assert _charge(node) == {'left': 0.0, 'right': 0.0}


@pytest.mark.parametrize('argv, code, message', [
    (['send', '1000'] + NS, 2, '1 voltage(s) for 2 DET(s)'),
    (['send', 'middle=5'] + NS, 2, "unknown or repeated DET 'middle'; the DETs: left, right"),
    (['send', 'left=1', '2'] + NS, 2, 'not both'),
    (['send', 'left=1', 'left=2'] + NS, 2, "unknown or repeated DET 'left'"),
    (['send', 'left=nan'] + NS, 2, 'finite'),
    (['param', 'set', 'real_time_factor', '-1'] + NS, 1, 'real_time_factor not set'),
    (['param', 'get', 'no_such_thing'] + NS, 1, "no parameter 'no_such_thing'"),
    (['pause', '--ns', 'nowhere', '--timeout', '0.5'], 1, 'no service /nowhere/sim_node/pause'),
    (['send', '5', '--ns', 'nowhere', '--timeout', '0.5'], 1, 'no service'),
])
def test_bad_values_and_no_node_are_one_line(node, capsys, argv, code, message):
    assert message in _error(capsys, argv, code)


def test_parameters_get_and_set(node, capsys):
    assert _ok(capsys, ['param', 'get', 'real_time_factor']).strip() == str(RATE)
    assert _ok(capsys, ['param', 'get', 'structure.dets']).strip() == "['left', 'right']"
    assert _ok(capsys, ['param', 'get', 'mode']).strip() == "''"
    assert _ok(capsys, ['param', 'set', 'max_lag', '1']).strip() == 'max_lag = 1.0'
    assert node.get_parameter('max_lag').value == 1.0


def test_watch_csv_and_live_lines(node, capfd):
    """Watch with a real stderr (capfd): rclpy's EventsExecutor, as on a terminal."""
    def ok(argv):
        assert main(argv + NS) == 0
        return capfd.readouterr().out

    ok(['send', 'left=3000'])
    assert 'running' in ok(['resume'])
    try:
        lines = ok(['watch', '--csv', '--count', '3']).splitlines()
        assert lines[0].startswith('t,deflection.position.left,deflection.position.right,'
                                   'deflection.velocity.left')
        assert len(lines) == 4 and len(lines[1].split(',')) == 1 + 5 * 2
        steps = [round(float(line.split(',')[0]) * 1000) for line in lines[1:]]
        assert steps == list(range(steps[0], steps[0] + 3))   # consecutive samples
        live = ok(['watch', '--count', '2']).splitlines()
        assert len(live) == 2 and all(line.startswith('t = ') for line in live)
        assert 'left: dy' in live[-1] and 'right: dy' in live[-1]
        assert main(['advance'] + NS) == 1
        assert 'not paused' in capfd.readouterr().err
    finally:
        ok(['pause'])
