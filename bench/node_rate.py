#!/usr/bin/env python3
"""
Benchmark the ROS 2 node (a script, not a test).

1. Real-time mode at the scene rate (1 kHz) for --rt-seconds: lost steps (gaps in the published
   sample sequence; target 0), the backlog at the end (steps due by the wall clock but not yet
   run), overrun ticks (ticks that had to catch up) and p50/p99/max step lateness (wall time
   between when a step was due and when it ran).
2. Free-run mode for --free-seconds with all four output topics published every step: the
   real-time factor (sim seconds per wall second; target >= 3), with and without a subscriber
   process on the four topics, and with MCAP logging on.

Usage: PYTHONPATH=. python bench/node_rate.py [--rt-seconds 60] [--free-seconds 10]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 101))

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from det_sim_ros.sim_node import SimNode  # noqa: E402

SUBSCRIBER = '''
import rclpy, sys
from sensor_msgs.msg import JointState
rclpy.init()
node = rclpy.create_node('bench_listener')
count = [0]
for topic in ('deflection', 'displacement', 'charge', 'current'):
    node.create_subscription(JointState, topic, lambda m: count.__setitem__(0, count[0] + 1), 10)
try:
    rclpy.spin(node)
except BaseException:
    pass
'''


class SequenceChecker:
    """A stand-in recorder: checks that every step's sample is published once, in order."""

    def __init__(self, dt, inner=None):
        self.dt = dt
        self.inner = inner  # the node's MCAP recorder, when logging is on
        self.path, self.messages, self.fault = '', 0, ''  # as a Recorder reports on /diagnostics
        self.last_k = {}
        self.gaps = 0
        self.published = 0

    def record(self, topic, msg, sim_time_ns):
        if self.inner is not None:
            self.inner.record(topic, msg, sim_time_ns)
            self.path, self.messages, self.fault = (self.inner.path, self.inner.messages,
                                                    self.inner.fault)
        k = int(round(sim_time_ns * 1e-9 / self.dt))
        if topic in ('voltage_command', 'voltage_command_joint'):
            return
        self.published += 1
        last = self.last_k.get(topic)
        if last is not None and k != last + 1:
            self.gaps += abs(k - last - 1)
        self.last_k[topic] = k


def run(seconds, **params):
    context = rclpy.context.Context()
    rclpy.init(context=context)
    params.setdefault('scene.initial_state', 'released')   # the benchmarked (paper's) start
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    node = SimNode(context=context, parameter_overrides=overrides)
    checker = SequenceChecker(node._dt, node._recorder)
    node._recorder = checker
    node.lateness_log = []
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.spin_once(timeout_sec=0)
    node.set_parameters([Parameter('steps_per_tick', value=params.get('steps_per_tick', 10))])
    node._resync()
    k0, t0 = node._sim.k, time.perf_counter()
    end = t0 + seconds
    while time.perf_counter() < end:
        executor.spin_once(timeout_sec=0.1)
    wall = time.perf_counter() - t0
    steps = node._sim.k - k0
    due = int((time.perf_counter() - node._wall0) * node._rtf / node._dt) + node._k0 - node._sim.k
    result = {
        'wall_s': wall, 'steps': steps, 'sim_s': steps * node._dt,
        'rtf': steps * node._dt / wall, 'overrun_ticks': node.overruns,
        'sequence_gaps': checker.gaps, 'backlog_at_end': max(0, due - 1),
        'lateness': np.array(node.lateness_log),
    }
    executor.shutdown()
    node._recorder = checker.inner
    node.destroy_node()
    rclpy.shutdown(context=context)
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--rt-seconds', type=float, default=60.0)
    parser.add_argument('--free-seconds', type=float, default=10.0)
    parser.add_argument('--json', help='write the numbers to this file')
    args = parser.parse_args()
    report = {}

    listener = subprocess.Popen([sys.executable, '-c', SUBSCRIBER])
    try:
        time.sleep(2.0)
        rt = run(args.rt_seconds, real_time=True, info_period=0.0, **{'log.enabled': False})
        lat = rt.pop('lateness') * 1e6
        rt.update({'lost_steps': rt['sequence_gaps'],
                   'lateness_us_p50': float(np.percentile(lat, 50)),
                   'lateness_us_p99': float(np.percentile(lat, 99)),
                   'lateness_us_max': float(lat.max())})
        report['real_time_1kHz_with_subscriber'] = rt
        free = run(args.free_seconds, real_time=False, info_period=0.0,
                   **{'log.enabled': False})
        free.pop('lateness')
        report['free_run_with_subscriber'] = free
    finally:
        listener.terminate()
        listener.wait()
    free = run(args.free_seconds, real_time=False, info_period=0.0, **{'log.enabled': False})
    free.pop('lateness')
    report['free_run_no_subscriber'] = free
    with tempfile.TemporaryDirectory() as folder:
        free = run(args.free_seconds, real_time=False, info_period=0.0,
                   **{'log.enabled': True, 'log.path': folder})
    free.pop('lateness')
    report['free_run_mcap_logging'] = free

    for name, numbers in report.items():
        print(name)
        for key, value in numbers.items():
            print(f'  {key:>18}: {value:.4g}' if isinstance(value, float)
                  else f'  {key:>18}: {value}')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(report, stream, indent=2)


if __name__ == '__main__':
    main()
