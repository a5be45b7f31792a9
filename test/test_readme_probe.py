"""
The README's probe script ("Send a voltage and watch the outputs") against a running sim_node.

The script is taken from README.md as it is and run as its own process beside a sim_node
process on the test domain: it must print every 0.1 s of sim time without a gap (before the
command, through the transient, settled at the Δy the README names) and stop on Ctrl-C with
exit code 0 and nothing on stderr.
"""

import queue
import re
import signal
import subprocess
import sys
import threading
import time

from conftest import child_env
import pytest
from test_node_startup import Node, READY

pytestmark = pytest.mark.ros

README = __file__.rsplit('/test/', 1)[0] + '/README.md'
SECTION = '## Send a voltage and watch the outputs'
LINE = re.compile(r'^t = +(?P<t>[\d.]+) s   Δy = (?P<dy>-?[\d.]+) mm$')
SETTLED_PRINTS = 15      # prints after the rise: 1.5 s of sim time, ~9 decay times of the mode
TIMEOUT = 60.0           # s, a safety net only


def _probe_and_settled():
    """Return the section's python block and the settled Δy (mm) the text after it names."""
    with open(README, encoding='utf-8') as stream:
        text = stream.read()
    section = text[text.index(SECTION):]
    code = re.search(r'^```python\n(.*?)^```$', section, re.S | re.M).group(1)
    settled = float(re.search(r'settles at ([\d.]+) mm', section).group(1))
    return code, settled


def _lines(proc, sink):
    for line in proc.stdout:
        sink.put(line.rstrip('\n'))
    sink.put(None)


def test_the_readme_probe_prints_every_tenth_of_a_second_and_stops_on_ctrl_c(tmp_path):
    code, settled = _probe_and_settled()
    node = Node(tmp_path, '--ros-args', '-p', 'log.enabled:=false', '-p', 'info_period:=0.0')
    try:
        node.wait_for(READY)
        probe = subprocess.Popen(
            [sys.executable, '-c', code], cwd=tmp_path, text=True, encoding='utf-8',
            env=child_env(PYTHONUNBUFFERED='1', PYTHONIOENCODING='utf-8'),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        printed, lines = [], queue.Queue()
        threading.Thread(target=_lines, args=(probe, lines), daemon=True).start()
        deadline, risen = time.monotonic() + TIMEOUT, None
        while risen is None or len(printed) < risen + SETTLED_PRINTS:
            line = lines.get(timeout=max(deadline - time.monotonic(), 0.01))
            assert line is not None, f'the probe ended: {printed} {probe.stderr.read()}'
            printed.append(line)
            found = LINE.match(line)
            assert found, line
            if risen is None and float(found['dy']) > 0.0:
                risen = len(printed) - 1
        probe.send_signal(signal.SIGINT)
        _, err = probe.communicate(timeout=TIMEOUT)
    finally:
        node_stopped = node.stop()
    assert node_stopped == 0
    assert probe.returncode == 0 and err == '', err
    values = [LINE.match(line) for line in printed]
    ticks = [round(float(v['t']) * 10) for v in values]
    assert ticks == list(range(ticks[0], ticks[0] + len(ticks))), printed   # no print lost
    assert all(float(v['dy']) == 0.0 for v in values[:risen])               # before the command
    assert abs(float(values[-1]['dy']) - settled) <= 0.01, printed          # the README's value


def test_with_the_readme_setting_a_subscriber_started_first_gets_every_sample_from_0(
        tmp_path, ros_context):
    """
    Check the README's way to miss no sample: the subscriber first, then the node as it says.

    A subscriber with the probe's QoS (reliable, 1000 deep) exists before the node starts with
    the setting the README names; its samples start at t = 0 and go on 1 ms apart, none lost.
    """
    import rclpy
    from sensor_msgs.msg import JointState
    with open(README, encoding='utf-8') as stream:
        section = stream.read().split(SECTION, 1)[1].split('\n## ', 1)[0]
    setting = re.search(r'`sim_node --ros-args (-p wait_for_subscribers:=\d+)`', section)
    assert setting, 'the README names no setting for a subscriber started before the node'
    probe = rclpy.create_node('probe', context=ros_context)
    stamps = []
    probe.create_subscription(JointState, 'displacement', lambda msg: stamps.append(
        msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec), 1000)
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    for _ in range(20):                       # the subscriber exists and spins first
        executor.spin_once(timeout_sec=0.01)
    node = Node(tmp_path, '--ros-args', *setting.group(1).split(), '-p', 'log.enabled:=false',
                '-p', 'info_period:=0.0')
    try:
        deadline = time.monotonic() + TIMEOUT
        while len(stamps) < 500:
            assert time.monotonic() < deadline, f'{len(stamps)} samples: {"".join(node.lines)}'
            executor.spin_once(timeout_sec=0.01)
    finally:
        executor.shutdown()
        probe.destroy_node()
        stopped = node.stop()
    assert stopped == 0, ''.join(node.lines)
    assert stamps[0] == 0, stamps[:5]
    assert {b - a for a, b in zip(stamps, stamps[1:])} == {1_000_000}   # no gap
