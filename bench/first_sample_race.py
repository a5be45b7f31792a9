"""
Whether a subscriber started together with sim_node sees the start of the run.

Each start launches two processes at the same moment: ``sim_node`` (real time, no log) and a
subscriber of its ``displacement`` topic. The subscriber reports the first sample it receives:
its index k (sample 0 is t = 0) and the wall seconds from the launch to its arrival. Printed
per start, then: how many starts got sample 0, and how many got their first sample within 1 s.

Run from the repository (own ROS_DOMAIN_ID; localhost discovery unless --range SUBNET)::

    python bench/first_sample_race.py [--starts 10] [--wait-for-subscribers 1] [--quick]
"""

import argparse
import os
import statistics
import subprocess
import sys
import time

SUBSCRIBER = """
import sys, time
t0 = float(sys.argv[1])
time.sleep(float(sys.argv[3]))
import contextlib
import rclpy
from sensor_msgs.msg import JointState
early = contextlib.nullcontext()
if sys.argv[4] == '1':
    from det_sim_ros.ros.discovery import announce_early
    early = announce_early()
with early:
    rclpy.init()
    node = rclpy.create_node('first_sample_race')
got = []
node.create_subscription(JointState, 'displacement', lambda m: got.append(
    (m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, time.time() - t0)), 10)
while not got and time.time() - t0 < float(sys.argv[2]):
    rclpy.spin_once(node, timeout_sec=0.01)
print(f'{got[0][0]:.6f} {got[0][1]:.3f}' if got else 'none')
"""


def one_start(env, wait_for_subscribers, timeout, node_first, delay, early):
    """Launch node and subscriber together; return (first sample's t in s, wall s) or None."""
    t0 = time.time()
    launch = [lambda: subprocess.Popen(
        [sys.executable, '-c', SUBSCRIBER, repr(t0), str(timeout), str(delay), str(int(early))],
        env=env,
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True), lambda: subprocess.Popen(
        [sys.executable, '-m', 'det_sim_ros.cli.sim_node', '--ros-args', '-p',
         'log.enabled:=false', '-p', 'info_period:=0.0', '-p',
         f'wait_for_subscribers:={wait_for_subscribers}'], env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    if node_first:
        node, sub = launch[1](), launch[0]()
    else:
        sub, node = launch[0](), launch[1]()
    try:
        out = sub.communicate(timeout=timeout + 10)[0].strip()
    finally:
        node.send_signal(2)
        try:
            node.wait(10)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()
    if out in ('', 'none'):
        return None
    t, wall = (float(v) for v in out.split())
    return t, wall


def main(argv=None) -> int:
    """Run the starts and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--starts', type=int, default=10)
    parser.add_argument('--wait-for-subscribers', type=int, default=0)
    parser.add_argument('--range', default='LOCALHOST', help='ROS_AUTOMATIC_DISCOVERY_RANGE')
    parser.add_argument('--timeout', type=float, default=15.0, help='s per start')
    parser.add_argument('--node-first', action='store_true', help='launch the node first')
    parser.add_argument('--subscriber-delay', type=float, default=0.0,
                        help='s the subscriber sleeps before rclpy (a heavier process)')
    parser.add_argument('--subscriber-announces-early', action='store_true',
                        help='the subscriber process uses det_sim_ros.ros.discovery too')
    parser.add_argument('--quick', action='store_true', help='one start (a smoke run)')
    args = parser.parse_args(argv)
    if args.quick:
        args.starts = 1
    # PYTHONSAFEPATH: the children import det_sim_ros from PYTHONPATH or the installed package,
    # never from the working directory
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE=args.range, PYTHONSAFEPATH='1')
    env.setdefault('ROS_DOMAIN_ID', '62')
    results = []
    for i in range(args.starts):
        result = one_start(env, args.wait_for_subscribers, args.timeout, args.node_first,
                           args.subscriber_delay, args.subscriber_announces_early)
        results.append(result)
        print(f'start {i + 1}: ' + ('no sample' if result is None else
                                    f'first sample k = {round(result[0] * 1000)} '
                                    f'(t = {result[0]:.3f} s) after {result[1]:.2f} s'),
              flush=True)
    got = [r for r in results if r is not None]
    print(f'wait_for_subscribers={args.wait_for_subscribers}, {args.range}, subscriber delay '
          f'{args.subscriber_delay:g} s, subscriber announces early: '
          f'{args.subscriber_announces_early}: first sample was '
          f'sample 0 in {sum(r[0] == 0.0 for r in got)} of {args.starts}; arrived within 1 s '
          f'of the launch in {sum(r[1] <= 1.0 for r in got)} of {args.starts} (median '
          f'{statistics.median(r[1] for r in got):.2f} s); samples missed (s): '
          f'{" ".join(f"{r[0]:.2f}" for r in got)}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
