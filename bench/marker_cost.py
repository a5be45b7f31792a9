"""
CPU cost of the shape markers (target: 30 Hz markers add <= 5 % to the node's CPU per sim s).

One sim_node runs in this process (free run by default, the node's cheapest mode per simulated
second, so the markers' largest share; --real-time: the node's default mode, the one a user
watches the markers in; no MCAP log unless --log, which also logs every frame), with a
subscriber in another process on /markers (a viewer: Python MarkerArray objects, or bytes with
--raw-viewer as RViz and the Foxglove bridge take them) and, by default, on the four output
topics (a controller), so every message is delivered.
The markers are switched on and off in alternating blocks of ``--block-s`` wall seconds
(``--blocks`` pairs, the first block of each pair chosen at random) in that one node: the
host's drift hits both states alike, which separate runs of a few seconds could not resolve.
Node CPU = this process's CPU time, all threads (the DDS threads and the log writer too), per
simulated second in each state; reported: the ratio of the totals, the median, quartiles and
mean (with its standard error) of the per-pair ratios, and the split between the executor
thread and the others. The marker code's own share (building, logging and publishing frames:
the executor thread's CPU time in them) is measured directly as well. --control runs the same
switching with 'on' blocks that make no frames (an A/A test): what it reports is the method's
own noise on this host, the floor under which an effect cannot be told. The voltage is a square
wave (``--drive-hz``, 2 Hz: the actuator snaps and creeps most of the time, so most frames
change; a settled actuator sends one frame per simulated second).

    python bench/marker_cost.py [--scene default] [--blocks 30] [--block-s 0.5] [--log] [--quick]
                                [--real-time] [--raw-viewer] [--control] [--drive-hz 2]
"""

import argparse
import math
import os
import statistics
import subprocess
import sys
import time

SUBSCRIBER = """
import rclpy, sys
from visualization_msgs.msg import MarkerArray
rclpy.init()
node = rclpy.create_node('marker_sink')
count = [0]
node.create_subscription(MarkerArray, 'markers', lambda m: count.__setitem__(0, count[0] + 1), 10,
                         raw='raw' in sys.argv)
if 'all' in sys.argv:    # a controller's view too: every output topic is delivered
    from sensor_msgs.msg import JointState
    from det_sim_ros.io.contract import OUTPUT_FIELDS
    for topic in OUTPUT_FIELDS:
        node.create_subscription(JointState, topic, lambda m: None, 10)
try:
    rclpy.spin(node)
except BaseException:
    pass
"""


def _start_node(scene, log_dir, real_time, subscribe):
    """Start one paused sim_node with 30 Hz markers; return (its context, node, executor)."""
    import rclpy
    from rclpy.parameter import Parameter
    from det_sim_ros.ros.node import make_executor, SimNode
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = SimNode(context=context, parameter_overrides=[
        Parameter('scene_file', value=scene), Parameter('real_time', value=real_time),
        Parameter('log.enabled', value=bool(log_dir)), Parameter('log.path', value=log_dir or '.'),
        Parameter('info_period', value=0.0),
        Parameter('start_paused', value=True), Parameter('markers.rate_hz', value=30.0)])
    executor = make_executor(context)   # the node's own executor (EventsExecutor)
    executor.add_node(node)
    deadline = time.monotonic() + 20.0
    # wait for the subscriber, so every message it asks for is delivered
    waits = [node.markers.publisher]
    if subscribe == 'all':
        waits.append(node.output_publishers['deflection'])
    while not all(p.get_subscription_count() for p in waits) and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return context, node, executor


def _time_marker_code(markers, control):
    """
    Wrap the marker code so that its own CPU time is counted; return the one-item counter.

    The counter holds the executor thread's CPU time in frame_for (which runs for every frame
    on the display grid, sent or not, building and logging it) and in publish (for those sent).
    """
    spent = [0.0]

    def timed(inner):
        def call(*a, **k):
            t0 = time.thread_time()
            result = inner(*a, **k)
            spent[0] += time.thread_time() - t0
            return result
        return call
    if control:   # the A/A control: 'on' blocks run the same switch, but no frame is made
        markers.frame_for = lambda *args, **kwargs: None
    markers.frame_for = timed(markers.frame_for)   # building (and logging) a frame
    markers.publish = timed(markers.publish)
    return spent


def _drive(node, drive_hz):
    """Drive the node with a square wave 0 V <-> 2.5 kV at ``drive_hz`` (sim time)."""
    # the actuator snaps and creeps, so frames change (a settled actuator sends one frame per
    # simulated second)
    half = max(1, int(round(0.5 / drive_hz / node.dt)))
    simulator, step = node.simulator, node.simulator.step

    def driven_step():
        k = simulator.k
        if k % half == 0:
            simulator.set_input([2500.0 if (k // half) % 2 == 0 else 0.0]
                                * len(simulator.u))
        return step()
    simulator.step = driven_step


def run(scene, blocks, block_s, subscribe, log_dir='', drive_hz=2.0, seed=1, real_time=False,
        control=False, warm_s=1.0):
    """
    Measure the node with markers on and off in ``blocks`` randomly ordered pairs of blocks.

    Returns the per-pair CPU s per sim s (off, on), the totals per state (CPU s, sim s, executor
    CPU s), the frames sent per simulated second on and the marker code's own CPU s per sim s.
    """
    import random
    import rclpy
    context, node, executor = _start_node(scene, log_dir, real_time, subscribe)
    markers = node.markers
    every, OFF = markers.every, 1 << 62
    spent = _time_marker_code(markers, control)
    if drive_hz > 0:
        _drive(node, drive_hz)
    node.set_paused(False)
    warm = time.perf_counter() + warm_s
    while time.perf_counter() < warm:
        executor.spin_once(timeout_sec=0.1)
    rng = random.Random(seed)
    pairs = []   # (CPU s per sim s off, on)
    totals = {False: [0.0, 0.0, 0.0], True: [0.0, 0.0, 0.0]}   # CPU s, sim s, executor CPU s
    frames0, spent0, on_sim = markers.published, spent[0], 0.0
    for _ in range(blocks):
        pair = {}
        for on in ((False, True) if rng.random() < 0.5 else (True, False)):
            markers.every = every if on else OFF   # off: no sample is on the display grid
            k0, c0, m0 = node.simulator.k, time.process_time(), time.thread_time()
            end = time.perf_counter() + block_s
            while time.perf_counter() < end:
                executor.spin_once(timeout_sec=0.1)
            cpu, sim = time.process_time() - c0, (node.simulator.k - k0) * node.dt
            totals[on][0] += cpu
            totals[on][1] += sim
            totals[on][2] += time.thread_time() - m0   # the executor's (this) thread
            pair[on] = cpu / sim
            on_sim += sim if on else 0.0
        pairs.append((pair[False], pair[True]))
    frames = markers.published - frames0
    own = spent[0] - spent0
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    return pairs, totals, frames / on_sim, own / on_sim


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('--scene', default='default')
    parser.add_argument('--blocks', type=int, default=30, help='on/off pairs')
    parser.add_argument('--block-s', type=float, default=0.5, help='wall seconds per block')
    parser.add_argument('--drive-hz', type=float, default=2.0,
                        help='square-wave voltage 0 <-> 2.5 kV at this frequency (sim time); '
                        '0 = none (the actuator stays at rest)')
    parser.add_argument('--log', action='store_true',
                        help='with the MCAP log (the node default; frames are logged too)')
    parser.add_argument('--control', action='store_true',
                        help="A/A control: the 'on' blocks make no frames, so what they add "
                        "is the method's own noise on this host")
    parser.add_argument('--real-time', action='store_true',
                        help='the node in real time at 1 kHz (as a user watching the markers '
                        'runs it) instead of free run')
    parser.add_argument('--raw-viewer', action='store_true',
                        help='the viewer takes the frames as bytes (as RViz and the Foxglove '
                        'bridge, both C++, do) instead of building Python MarkerArray objects')
    parser.add_argument('--subscribe', choices=('markers', 'all'), default='all',
                        help='the other process subscribes to /markers only, or to the outputs '
                        'too (a controller and a viewer; default)')
    parser.add_argument('--quick', action='store_true',
                        help='two pairs of 0.05 s blocks after a 0.05 s warm-up (a smoke run)')
    args = parser.parse_args()
    warm_s = 1.0
    if args.quick:
        args.blocks, args.block_s, warm_s = 2, 0.05, 0.05
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    sink = subprocess.Popen([sys.executable, '-c', SUBSCRIBER]
                            + (['all'] if args.subscribe == 'all' else [])
                            + (['raw'] if args.raw_viewer else []))
    import tempfile
    try:
        with tempfile.TemporaryDirectory() as folder:
            pairs, totals, fps, own = run(args.scene, args.blocks, args.block_s, args.subscribe,
                                          folder if args.log else '', args.drive_hz,
                                          real_time=args.real_time, control=args.control,
                                          warm_s=warm_s)
    finally:
        sink.terminate()
        sink.wait()
    off = totals[False][0] / totals[False][1]
    on = totals[True][0] / totals[True][1]
    main_off, main_on = (totals[state][2] / totals[state][1] for state in (False, True))
    ratios = sorted(b / a - 1 for a, b in pairs)
    q = [ratios[int(round(f * (len(ratios) - 1)))] for f in (0.25, 0.5, 0.75)]
    mean = statistics.fmean(ratios)
    error = statistics.stdev(ratios) / math.sqrt(len(ratios)) if len(ratios) > 1 else math.nan
    print(f'{"A/A CONTROL (no frames made), " if args.control else ""}'
          f'{args.scene}{" with the MCAP log" if args.log else ""}, '
          f'{"real time" if args.real_time else "free run"}, '
          f'{"raw" if args.raw_viewer else "Python"} viewer, square wave '
          f'{args.drive_hz:g} Hz: {len(pairs)} on/off pairs of {args.block_s:g} s; node CPU per '
          f'simulated s: {off * 1e3:.2f} ms (markers off) vs {on * 1e3:.2f} ms (30 Hz, '
          f'{fps:.1f} frames per sim s): {(on / off - 1) * 100:+.1f} % (totals); per pair: '
          f'median {q[1] * 100:+.1f} %, quartiles {q[0] * 100:+.1f} .. {q[2] * 100:+.1f} %, '
          f'mean {mean * 100:+.1f} % +- {error * 100:.1f} % (standard error); '
          f'marker code alone {own * 1e3:.2f} ms per sim s = {own / on * 100:.1f} % of the '
          f'node, {own / fps * 1e6 if fps else 0.0:.0f} us per frame sent; added per sim s: '
          f'executor thread '
          f'{(main_on - main_off) * 1e3:+.2f} ms, other threads (DDS, log writer) '
          f'{(on - main_on - off + main_off) * 1e3:+.2f} ms')


if __name__ == '__main__':
    main()
