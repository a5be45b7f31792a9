"""
Processes that run beside a benchmarked sim_node, and the analysis of a controller run.

SUBSCRIBER takes every message of the given output topics; CONTROLLER answers every
displacement sample with a voltage command and records when it sent each command and when each
sample arrived; BUSY keeps one core busy. :func:`command_latency` turns a controller run into
command-to-effect latencies and samples lost. Used by bench/node_rate.py and bench/fleet.py.
"""

import json
import os
import subprocess
import sys

from checkouts import THIS_TREE
from det_sim_ros.io.contract import decode_float64_multi_array
from det_sim_ros.io.log import LogReader
import numpy as np

SUBSCRIBER = """
import sys, rclpy
from sensor_msgs.msg import JointState
rclpy.init()
node = rclpy.create_node('bench_listener')
count = [0]
for topic in sys.argv[1].split(','):
    node.create_subscription(JointState, topic, lambda m: count.__setitem__(0, count[0] + 1),
                             10, raw=True)
try:
    rclpy.spin(node)
except BaseException:
    pass
"""

# Answers every displacement sample with a voltage command; records when it published each
# command and when each sample arrived (CLOCK_MONOTONIC is shared by all processes).
CONTROLLER = """
import json, sys, time, rclpy
from rclpy.experimental import EventsExecutor
from rclpy.qos import HistoryPolicy, QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from det_sim_ros.io.contract import decode_joint_state, encode_float64_multi_array
n_det, out_path = int(sys.argv[1]), sys.argv[2]
keep_all = sys.argv[3:4] == ['keep_all']     # reliable KEEP_ALL both ways (lossy links)
rclpy.init()
node = rclpy.create_node('bench_controller')
qos = QoSProfile(history=HistoryPolicy.KEEP_ALL) if keep_all else None
cmd = node.create_publisher(Float64MultiArray, 'voltage_command', qos or 10)
sent, received = [], {}
def on_sample(data):
    now = time.monotonic()
    received[decode_joint_state(data).stamp_ns] = now
    volts = 500.0 + len(sent) % 2000          # a new voltage every sample, identifiable
    cmd.publish(encode_float64_multi_array([volts] * n_det))
    sent.append((time.monotonic(), volts))
node.create_subscription(JointState, 'displacement', on_sample, qos or 1000, raw=True)
executor = EventsExecutor()
executor.add_node(node)
try:
    while rclpy.ok():
        executor.spin_once(timeout_sec=0.1)
except BaseException:
    pass
finally:
    with open(out_path, 'w') as stream:
        json.dump({'sent': sent, 'received': received}, stream)
"""

BUSY = 'while True: pass'


def spawn(code, *args):
    """Start ``code`` in a Python process that imports the package this process imports."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([THIS_TREE] + sys.path))
    return subprocess.Popen([sys.executable, '-c', code, *args], env=env)


def stop(proc):
    """Stop a process with SIGINT (it writes its results), killing it after 20 s."""
    proc.send_signal(2)
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def command_latency(log_path, controller_file, dt, topic='voltage_command'):
    """
    Return the command-to-effect latency of a controller run and the samples lost.

    Matches the commands the controller sent (``controller_file``, written by CONTROLLER) with
    those the node logged (``log_path``) at the period each applied to, and times each
    from its publication to the arrival of the first sample that shows it.
    """
    with open(controller_file) as stream:
        data = json.load(stream)
    sent = data['sent']
    received = {int(k): v for k, v in data['received'].items()}
    applied = [(m.log_time, decode_float64_multi_array(m.data)[0][0])
               for m in LogReader(log_path).messages([topic])]
    # the log holds the commands the node received, in order, each at the period it applied
    # to; a command can be missing (sent before discovery, or after the run): match by value
    latencies, unmatched, j = [], 0, 0
    for log_time, logged in applied:
        start = j
        while j < len(sent) and sent[j][1] != logged and j - start < 1000:
            j += 1
        if j >= len(sent) or sent[j][1] != logged:
            unmatched += 1
            j = start
            continue
        effect = log_time + round(dt * 1e9)   # the first sample that shows the command
        if effect in received:
            latencies.append(received[effect] - sent[j][0])
        j += 1
    stamps = sorted(received)
    step = round(dt * 1e9)
    lost = sum((b - a) // step - 1 for a, b in zip(stamps, stamps[1:]))
    lat = np.array(latencies) * 1e3
    return {'commands_sent': len(sent), 'commands_applied': len(applied),
            'commands_unmatched': unmatched, 'samples_received': len(stamps),
            'samples_lost': int(lost),
            'cmd_to_effect_ms_p50': float(np.percentile(lat, 50)) if lat.size else None,
            'cmd_to_effect_ms_p99': float(np.percentile(lat, 99)) if lat.size else None,
            'cmd_to_effect_ms_max': float(lat.max()) if lat.size else None}
