"""
CPU cost of the shape markers (issue 18 target: 30 Hz markers add <= 5 % to the node's CPU per
simulated second).

Runs sim_node in free-run mode (no MCAP log) in this process for ``--sim-s`` simulated seconds
with markers.rate_hz = 0 and = 30, alternately (``--repeats`` each; medians reported, since the
host is shared), with a subscriber in another process (to /markers and, by default, to the four
output topics as a controller would) so the messages are really delivered. Node CPU = this
process's user + system time per simulated second; the marker code's share is the executor
thread's CPU time in building and publishing the frames (time.thread_time), measured directly
because whole-run differences are smaller than the host's run-to-run noise.

    python bench/marker_cost.py [--scene default] [--sim-s 20] [--repeats 3]
"""

import argparse
import os
import subprocess
import sys
import time

SUBSCRIBER = '''
import rclpy, sys
from visualization_msgs.msg import MarkerArray
rclpy.init()
node = rclpy.create_node('marker_sink')
count = [0]
node.create_subscription(MarkerArray, 'markers', lambda m: count.__setitem__(0, count[0] + 1), 10)
if 'all' in sys.argv:    # a controller's view too: every output topic is delivered
    from sensor_msgs.msg import JointState
    for topic in ('deflection', 'displacement', 'charge', 'current'):
        node.create_subscription(JointState, topic, lambda m: None, 10)
try:
    rclpy.spin(node)
except BaseException:
    pass
'''


def run(scene, rate, sim_s, subscribe):
    import rclpy
    from rclpy.parameter import Parameter
    from det_sim_ros.sim_node import make_executor, SimNode
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = SimNode(context=context, parameter_overrides=[
        Parameter('scene_file', value=scene), Parameter('real_time', value=False),
        Parameter('log.enabled', value=False), Parameter('info_period', value=0.0),
        Parameter('start_paused', value=True), Parameter('markers.rate_hz', value=rate)])
    executor = make_executor(context)   # the node's own executor (EventsExecutor)
    executor.add_node(node)
    deadline = time.monotonic() + 10.0
    # wait for the subscriber, so every message it asks for is delivered
    waits = [node._markers.publisher] if rate else []
    if subscribe == 'all':
        waits.append(node._output_pubs[node._encoder.topics.index('deflection')])
    while not all(p.get_subscription_count() for p in waits) and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    spent = [0.0, 0.0, 0.0]
    if rate:    # the markers' own share, measured directly (the difference of runs is noisy):
        # building and publishing a frame (timing every on_sample call would cost more than
        # its k % every test)
        markers = node._markers

        def timed(inner, slot):
            def call(*a, **k):
                t0 = time.thread_time()        # this thread: the executor's
                result = inner(*a, **k)
                spent[slot] += time.thread_time() - t0
                return result
            return call
        markers.frames.frame = timed(markers.frames.frame, 1)
        markers.publisher = type('P', (), {'publish': staticmethod(
            timed(markers.publisher.publish, 2))})()
    node.paused = False
    node._run_timer(True)
    steps = int(round(sim_s / node._dt))
    start_k = node._sim.k
    cpu0, thread0 = time.process_time(), time.thread_time()
    while node._sim.k - start_k < steps:
        executor.spin_once(timeout_sec=0.1)
    cpu = time.process_time() - cpu0
    thread = time.thread_time() - thread0
    sim_time = (node._sim.k - start_k) * node._dt
    frames = node._markers.published if node._markers else 0
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    per_frame = 1e6 / max(frames, 1)
    print(f'  executor thread {thread / (steps * node._dt) * 1e3:.2f} ms per sim s; '
          f'frame {spent[1] * per_frame:.0f} us, publish {spent[2] * per_frame:.0f} us per frame')
    return cpu / sim_time, frames / sim_time, (spent[1] + spent[2]) / sim_time


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('--scene', default='default')
    parser.add_argument('--sim-s', type=float, default=20.0)
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--subscribe', choices=('markers', 'all'), default='all',
                        help="the other process subscribes to /markers only, or to the outputs "
                        "too (a controller and a viewer; default)")
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    sink = subprocess.Popen([sys.executable, '-c', SUBSCRIBER]
                            + (['all'] if args.subscribe == 'all' else []))
    try:
        results = {0.0: [], 30.0: []}
        share = []
        for _ in range(args.repeats):
            for rate in (0.0, 30.0):
                cost, fps, own = run(args.scene, rate, args.sim_s, args.subscribe)
                results[rate].append(cost)
                if rate:
                    share.append(own / cost)
                print(f'markers {rate:>4g} Hz: {cost * 1e3:7.2f} ms CPU per sim s '
                      f'({fps:.1f} frames per sim s'
                      + (f'; in the marker code {own * 1e3:.2f} ms = {own / cost * 100:.1f} %'
                         f', {own / fps * 1e6:.0f} us per frame' if rate else '') + ')',
                      flush=True)
    finally:
        sink.terminate()
        sink.wait()
    off = sorted(results[0.0])[len(results[0.0]) // 2]
    on = sorted(results[30.0])[len(results[30.0]) // 2]
    print(f'{args.scene}: median {off * 1e3:.2f} ms (off) vs {on * 1e3:.2f} ms (30 Hz) CPU per '
          f'simulated s: {(on / off - 1) * 100:+.1f} %; marker code alone: median '
          f'{sorted(share)[len(share) // 2] * 100:.1f} % of the node CPU')


if __name__ == '__main__':
    main()
