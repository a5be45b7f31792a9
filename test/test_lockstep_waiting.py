"""
A waiting node says what it waits for: its log, its INFO line, /diagnostics, and the fleet.

A lockstep node without a controller waits for the answer to sample 0; once that wait passes
a short time the node logs it once (topics, answers still missing, answers of how many), its
INFO line and /diagnostics name it while it lasts, and a line says when it is over.
"""

import re
import signal

from conftest import WALL_TIMEOUT
import pytest
from test_fleet import start_fleet, text, wait_for_text, write_fleet

pytestmark = pytest.mark.ros

WAIT = re.compile(r'^waiting \d+\.\d s for 1 answer to t = 0 s on /voltage_command or '
                  r'/voltage_command_joint \(0 of 1\)$')


def listen_to_rosout(h):
    """Collect the messages the node under test logs (its /rosout records)."""
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile
    lines = []
    h.test.create_subscription(
        Log, '/rosout', lambda msg: lines.append(msg.msg) if msg.name == 'sim_node' else None,
        QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    return lines


def status(msg):
    """Return (message, key -> value) of the node's /diagnostics status."""
    (st,) = msg.status
    return st.message, {kv.key: kv.value for kv in st.values}


def test_a_lockstep_node_says_what_it_waits_for(harness):
    """
    Check that a lockstep node waiting for its controller says so, and when it stops waiting.

    No answer comes: /diagnostics (every 0.5 s) and the INFO line name the topics and the
    answers (0 of 1) once the wait is long enough (at most six messages, 3 s); one log line
    says the wait started. An answer ends the wait: one line says it is over.
    """
    h = harness(mode='lockstep', diagnostics_period=0.5, info_period=0.5)
    lines = listen_to_rosout(h)
    h.spin_until(lambda: len(h.diagnostics) >= 6 or (
        h.diagnostics and status(h.diagnostics[-1])[0].startswith('waiting')), 'a status')
    message, values = status(h.diagnostics[-1])
    assert WAIT.match(message), message
    assert values['waiting_for'].startswith('waiting') and float(values['waiting_s']) > 0
    assert h.node.simulator.k == 0
    h.spin_until(lambda: any(line.startswith('t=') and 'waiting' in line for line in lines)
                 and any(line.startswith('waiting') for line in lines), 'the log lines')
    started = [line for line in lines if line.startswith('waiting')]
    assert len(started) == 1 and WAIT.match(started[0]), lines
    h.command([100.0])                         # the answer to sample 0
    h.spin_until(lambda: any(line.startswith('wait over after') for line in lines),
                 'the end of the wait')
    assert h.node.simulator.k == 1


def test_the_fleet_shows_which_node_waits(tmp_path):
    """
    Check that ``det_sim fleet`` says which node waits for its controller, and what for.

    A lockstep node with no controller (INFO line off): the fleet's output names the node,
    the topics and the answers missing.
    """
    fleet_file = write_fleet(tmp_path / 'fleet.yaml', [
        {'namespace': '/free'},
        {'namespace': '/held', 'mode': 'lockstep'},
    ], defaults={'params': {'info_period': 0.0, 'log.enabled': False}}, log_dir='logs')
    proc = start_fleet(fleet_file)
    try:
        wait_for_text(proc, 'fleet: /held waiting')
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=WALL_TIMEOUT) == 0, text(proc.out)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out = text(proc.out)
    assert re.search(r'fleet: /held waiting \d+\.\d s for 1 answer to t = 0 s on '
                     r'/held/voltage_command or /held/voltage_command_joint \(0 of 1; no '
                     r'publisher matched\)', out), out
    assert 'fleet: /free waiting' not in out


if __name__ == '__main__':
    pytest.main([__file__])
