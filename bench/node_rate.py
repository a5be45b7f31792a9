#!/usr/bin/env python3
"""
Benchmark sim_node's I/O: free-run CPU against a plain publishing node, and real time.

A script, not a test. Every figure of one scene is measured in the same run, side by side, so
compare ratios; absolute times depend on the host. Targets: in free run with the MCAP log, the
node costs at most 1.5x the floor (markers off); in real time with a controller answering every
sample, command-to-effect p99 <= 2 ms with no sample lost and the lag not growing.

1. Free-run CPU per control period, all outputs + /clock + /diagnostics + MCAP logging, one
   subscriber process on every output topic (markers off; a run with the default 30 Hz markers
   per round too, a rough figure: bench/marker_cost.py measures their share). Measured next to:
   - the floor: a plain node publishing the same pre-serialized bytes (one sample's CDR) and
     /clock on the same topics to the same subscribers, per period. It runs as the node runs:
     an EventsExecutor timer callback publishing steps_per_tick (10) periods' messages per call,
     so it pays the one executor callback per burst any ROS node pays, and nothing else
     (``floor``). Why bursts: DDS's CPU per message depends on the pace (its threads and the
     subscriber's wake per message when messages come apart), and the node in free run
     publishes each tick's samples as one burst; a floor publishing one period per callback
     would be higher, and the node's own figure no better. A tight publish loop without an
     executor is reported too (``publish_loop``, the lowest possible figure);
   - the physics alone: Simulator.step() per period;
   - the node under the SingleThreadedExecutor (the node uses the EventsExecutor; once).
   CPU is the process's CPU time (all threads: the DDS threads and the MCAP writer thread too)
   per period. The host is shared, so --rounds repeats floor, node and node with markers
   interleaved; medians of each and of the per-round ratios are reported, with min..max.
   --paired N measures node and floor in N randomly ordered pairs of blocks in one process
   instead: the precise node/floor ratio.
2. Real time at the scene rate for --rt-seconds, an outside controller process answering every
   displacement sample with a command, another process keeping one core busy: samples lost at
   the controller's reliable subscriber, command-to-effect latency (controller publishes the
   command -> it receives the first sample that shows it: the log records the period each
   command applied to), the lag behind the wall clock (end, max) and the slipped wall time.
   --realtime-priority N gives the node realtime_priority N (SCHED_FIFO), --controller-priority
   M the controller process SCHED_FIFO M (both need CAP_SYS_NICE or an rtprio limit).

Usage: python bench/node_rate.py [--scenes default,array] [--rt-seconds 60]
       [--free-seconds 3] [--rounds 7] [--realtime-priority 0] [--controller-priority 0]
       [--paired N [--paired-no-log]] [--log-compression zstd|lz4|none]
       [--paired-sensors N] [--paired-predictability N] [--rt-no-predictability]
       [--json out.json] [--quick]

``--quick``: the default scene, one free-run round of 0.1 s, 0.2 s of lockstep and 0.5 s of
real time (a smoke run).
"""

import argparse
import json
import os
import tempfile
import time

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 101))

from det_sim_ros.io.contract import encode_clock  # noqa: E402
from det_sim_ros.ros.node import make_executor, SimNode  # noqa: E402
from det_sim_ros.sim.simulator import Simulator  # noqa: E402
from peer_processes import BUSY, command_latency, CONTROLLER, spawn, stop, SUBSCRIBER  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402


def _cpu():
    return time.process_time()


def _wait_subscribers(publishers, what, timeout=60.0):
    deadline = time.monotonic() + timeout
    while not all(p.get_subscription_count() > 0 for p in publishers):
        if time.monotonic() > deadline:
            raise RuntimeError(f'{what}: subscribers not discovered')
        time.sleep(0.05)


def floor(scene_name, topics, samples, n, with_clock):
    """CPU per period of publishing pre-serialized bytes on the node's topics (no executor)."""
    from sensor_msgs.msg import JointState
    from rosgraph_msgs.msg import Clock
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('bench_floor', context=context)
    pubs = [node.create_publisher(JointState, t, QoSProfile(depth=10)) for t in topics]
    clock = node.create_publisher(Clock, '/clock', QoSProfile(depth=10)) if with_clock else None
    _wait_subscribers(pubs, 'floor')
    time.sleep(0.5)
    # the node's own publish call (Publisher.publish of serialized bytes) on the same bytes
    pairs = [(pub.publish, data) for pub, data in zip(pubs, samples)]
    clock_bytes = encode_clock(0)
    publish_clock = clock.publish if clock is not None else None
    for publish, data in pairs:   # warm-up
        publish(data)
    c0 = _cpu()
    for _ in range(n):
        for publish, data in pairs:
            publish(data)
        if publish_clock is not None:
            publish_clock(clock_bytes)
    cpu = (_cpu() - c0) / n
    node.destroy_node()
    rclpy.shutdown(context=context)
    return cpu


def _make_floor_node(context, name, topics, samples, burst):
    """
    Build a plain node publishing pre-serialized bytes from a timer.

    It publishes one sample's outputs and /clock per period, ``burst`` periods per callback.
    Returns (node, its publishers, a list whose one item counts the periods published).
    """
    from sensor_msgs.msg import JointState
    from rosgraph_msgs.msg import Clock
    node = rclpy.create_node(name, context=context)
    pubs = [node.create_publisher(JointState, t, QoSProfile(depth=10)) for t in topics]
    clock = node.create_publisher(Clock, '/clock', QoSProfile(depth=10))
    pairs = [(pub.publish, data) for pub, data in zip(pubs, samples)]
    publish_clock, clock_bytes = clock.publish, encode_clock(0)
    done = [0]

    def tick():
        for _ in range(burst):
            publish_clock(clock_bytes)
            for publish, data in pairs:
                publish(data)
        done[0] += burst
    node.create_timer(1.0e-6, tick)
    return node, pubs, done


def floor_node(topics, samples, n, burst):
    """
    Return the CPU per period of a plain node publishing pre-serialized bytes.

    It publishes one sample's outputs and /clock per period from an EventsExecutor timer,
    ``burst`` periods per callback.
    """
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node, pubs, done = _make_floor_node(context, 'bench_floor_node', topics, samples, burst)
    _wait_subscribers(pubs, 'floor node')
    executor = make_executor(context)
    executor.add_node(node)
    executor.spin_once(timeout_sec=0.1)
    k0, c0, m0 = done[0], _cpu(), time.thread_time()
    while done[0] - k0 < n:
        executor.spin_once(timeout_sec=0.1)
    cpu = (_cpu() - c0) / (done[0] - k0)
    floor_node.main_thread = (time.thread_time() - m0) / (done[0] - k0)
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=context)
    return cpu


def paired_node_floor(scene_name, topics, samples, pairs, block_s, folder, seed=1, log=True,
                      compression='zstd'):
    """
    Measure node and floor in one process, in ``pairs`` randomly ordered pairs of blocks.

    Each block is ``block_s`` wall seconds (only one of the two is spun at a time): the host's
    drift hits both alike, which separate runs of a few seconds could not resolve (their rounds
    spread by +-30 %). The node runs free with the MCAP log (unless ``log`` is false), markers off;
    the floor is floor_node's timer. Returns the CPU per period of each (totals over all blocks),
    the ratio of the totals and the mean of the per-pair ratios with its standard error.
    """
    import random
    contexts = [rclpy.context.Context(), rclpy.context.Context()]
    for context in contexts:
        rclpy.init(context=context)
    sim_node = SimNode(context=contexts[0], parameter_overrides=[
        Parameter('scene_file', value=scene_name), Parameter('real_time', value=False),
        Parameter('info_period', value=0.0), Parameter('log.path', value=folder),
        Parameter('log.enabled', value=log), Parameter('markers.rate_hz', value=0.0),
        Parameter('log.compression', value=compression),
        Parameter('scene.initial_state', value='released')])
    floor, pubs, floor_done = _make_floor_node(contexts[1], 'bench_paired_floor', topics,
                                               samples, 10)   # as floor_node in the rounds
    executors = [make_executor(context) for context in contexts]
    executors[0].add_node(sim_node)
    executors[1].add_node(floor)
    _wait_subscribers([*sim_node.output_publishers.values(), *pubs], 'paired node and floor')
    done = [lambda: sim_node.simulator.k, lambda: floor_done[0]]
    rng = random.Random(seed)
    totals = [[0.0, 0], [0.0, 0]]   # CPU s, periods: node, floor
    ratios = []
    for which in (0, 1):   # warm both
        end = time.perf_counter() + 0.5
        while time.perf_counter() < end:
            executors[which].spin_once(timeout_sec=0.05)
    for _ in range(pairs):
        per = [0.0, 0.0]
        for which in ((0, 1) if rng.random() < 0.5 else (1, 0)):
            k0, c0 = done[which](), _cpu()
            end = time.perf_counter() + block_s
            while time.perf_counter() < end:
                executors[which].spin_once(timeout_sec=0.05)
            cpu, periods = _cpu() - c0, done[which]() - k0
            totals[which][0] += cpu
            totals[which][1] += periods
            per[which] = cpu / max(periods, 1)
        ratios.append(per[0] / per[1])
    for executor in executors:
        executor.shutdown()
    sim_node.destroy_node()
    floor.destroy_node()
    for context in contexts:
        rclpy.try_shutdown(context=context)
    node_us, floor_us = (totals[i][0] / totals[i][1] * 1e6 for i in (0, 1))
    mean = sum(ratios) / len(ratios)
    error = (sum((r - mean) ** 2 for r in ratios) / (len(ratios) - 1)) ** 0.5 / len(ratios) ** 0.5
    return {'pairs': pairs, 'block_s': block_s, 'log': log, 'node_us_per_period': node_us,
            'floor_us_per_period': floor_us, 'node_over_floor_totals': node_us / floor_us,
            'node_over_floor_mean_of_pairs': mean, 'standard_error': error}


def _median(values):
    values = sorted(values)
    return values[len(values) // 2] if len(values) % 2 else 0.5 * (
        values[len(values) // 2 - 1] + values[len(values) // 2])


def _spread(values):
    return {'median': _median(values), 'min': min(values), 'max': max(values),
            'runs': [round(v, 2) for v in values]}


def physics(scene, n):
    sim = Simulator(scene)
    sim.set_input([1500.0] * sim.model.n_inputs)
    for _ in range(50):
        sim.step()
    c0 = _cpu()
    for _ in range(n):
        sim.step()
    return (_cpu() - c0) / n


def run_node(seconds, executor_kind, folder, wait_topics=None, **params):
    """Run SimNode in this process; returns (node numbers, log path)."""
    context = rclpy.context.Context()
    rclpy.init(context=context)
    params.setdefault('info_period', 0.0)
    params.setdefault('log.path', folder)
    params.setdefault('scene.initial_state', 'released')   # the benchmarked (paper's) start
    node = SimNode(context=context,
                   parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    executor = (make_executor(context) if executor_kind == 'events'
                else SingleThreadedExecutor(context=context))
    executor.add_node(node)
    _wait_subscribers([p for t, p in node.output_publishers.items()
                       if wait_topics is None or t in wait_topics], 'node')
    executor.spin_once(timeout_sec=0.1)
    node.pacing.resync()
    k0, c0, w0, m0 = node.simulator.k, _cpu(), time.perf_counter(), time.thread_time()
    slipped0, late0 = node.pacing.slipped_s, node.pacing.late_ticks
    max_lag = 0
    end = w0 + seconds
    real_time = node.mode == 'real_time'
    while time.perf_counter() < end:
        executor.spin_once(timeout_sec=0.05)
        if real_time:
            max_lag = max(max_lag, node.pacing.max_lag_seen)
    cpu, wall, main = _cpu() - c0, time.perf_counter() - w0, time.thread_time() - m0
    steps = node.simulator.k - k0
    result = {'steps': steps, 'wall_s': wall, 'rtf': steps * node.dt / wall,
              'cpu_us_per_period': cpu / steps * 1e6,
              'main_thread_us_per_period': main / steps * 1e6}
    if real_time:
        result.update({'lag_at_end_ms': max(0, node.pacing.steps_due(node.wall_clock()) - 1)
                       * node.dt * 1e3, 'max_lag_ms': max_lag * node.dt * 1e3,
                       'slipped_s': node.pacing.slipped_s - slipped0,
                       'late_ticks': node.pacing.late_ticks - late0})
    recorder = node.recorder
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=context)
    # every file (after close: the writer thread may still switch files while it drains): a
    # long run splits the log (the array's marker frames are ~0.3 MB each)
    path = list(recorder.paths) if recorder is not None else []
    return result, path


def lockstep_in_process(scene_name, sim_seconds):
    """
    Run lockstep with an in-process P controller answering every sample (one executor).

    Returns sim seconds per wall second, CPU per period and the missed deadlines.
    """
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    from det_sim_ros.io.contract import decode_joint_state, encode_float64_multi_array
    from det_sim_ros.ros.testing import LockstepSim
    sim = LockstepSim(scene_name, domain_id=1 + (os.getpid() + 7) % 101)
    try:
        node = rclpy.create_node('bench_p', context=sim.context)
        pub = node.create_publisher(Float64MultiArray, 'voltage_command', 10)

        def on_dy(data):
            dy = decode_joint_state(data).position
            volts = [min(3000.0, max(0.0, 1500.0 + 2.0e5 * (2.0e-3 - v))) for v in dy]
            pub.publish(encode_float64_multi_array(volts))
        node.create_subscription(JointState, 'displacement', on_dy, 10, raw=True)
        sim.start([node])
        k0, w0, c0 = sim.node.simulator.k, time.perf_counter(), _cpu()
        sim.run(until=sim_seconds, nodes=[node])
        wall, cpu = time.perf_counter() - w0, _cpu() - c0
        steps = sim.node.simulator.k - k0
        return {'steps': steps, 'rtf': steps * sim.node.dt / wall,
                'cpu_us_per_period': cpu / steps * 1e6,
                'missed_deadlines': sim.node.pacing.missed_deadlines}
    finally:
        sim.close()


def _free_run_rounds(scene_name, topics, samples, n, args, folder):
    """
    Measure the free-run figures in ``args.rounds`` interleaved rounds.

    Each round: the publish loop, the floor node, the node and the node with 30 Hz markers;
    then the node once under the SingleThreadedExecutor. Returns the report's entries.
    """
    rounds = {'publish_loop': [], 'floor': [], 'node': [], 'node_with_markers': [],
              'floor_main_thread': [], 'node_main_thread': []}
    for _ in range(args.rounds):   # interleaved: the host's drift hits all alike
        rounds['publish_loop'].append(floor(scene_name, topics, samples, n, True) * 1e6)
        rounds['floor'].append(floor_node(topics, samples, n, 10) * 1e6)
        rounds['floor_main_thread'].append(floor_node.main_thread * 1e6)
        for key, rate in (('node', 0.0), ('node_with_markers', 30.0)):
            result, _ = run_node(args.free_seconds, 'events', folder, scene_file=scene_name,
                                 real_time=False, **{'markers.rate_hz': rate})
            rounds[key].append(result['cpu_us_per_period'])
            if key == 'node':
                rounds['node_main_thread'].append(result['main_thread_us_per_period'])
    report = {'free_run_us_per_period': {key: _spread(v) for key, v in rounds.items()}}
    ratios = [a / b for a, b in zip(rounds['node'], rounds['floor'])]
    report['node_over_floor'] = _spread(ratios)
    report['node_over_publish_loop'] = _spread(
        [a / b for a, b in zip(rounds['node'], rounds['publish_loop'])])
    report['markers_30hz_added'] = _spread(
        [b / a - 1 for a, b in zip(rounds['node'], rounds['node_with_markers'])])
    result, _ = run_node(args.free_seconds, 'single', folder, scene_file=scene_name,
                         real_time=False, **{'markers.rate_hz': 0.0})
    report['free_run_single_threaded_executor'] = result
    return report


def _paired_runs(scene_name, topics, samples, args, folder, physics_us):
    """Measure node and floor in paired blocks (and without the log if asked); report entries."""
    report = {'paired_node_and_floor': paired_node_floor(
        scene_name, topics, samples, args.paired, args.paired_block_s, folder,
        compression=args.log_compression)}
    paired = report['paired_node_and_floor']
    # the I/O alone: an array's physics is itself about the floor (100 DETs held: ~40 us per
    # period), which no I/O work can take off
    paired['node_minus_physics_over_floor'] = (
        (paired['node_us_per_period'] - physics_us) / paired['floor_us_per_period'])
    if args.paired_no_log:   # the log's share, measured the same way
        report['paired_node_without_log_and_floor'] = paired_node_floor(
            scene_name, topics, samples, args.paired, args.paired_block_s, folder, log=False)
    return report


def _real_time_run(scene_name, n_det, dt, args, folder):
    """Run the node in real time with an outside controller and a busy core; its figures."""
    controller_file = os.path.join(folder, f'controller_{scene_name}.json')
    busy = spawn(BUSY)
    controller = spawn(CONTROLLER, str(n_det), controller_file)
    if args.controller_priority:   # the user's controller at SCHED_FIFO too (chrt -f)
        os.sched_setscheduler(controller.pid, os.SCHED_FIFO,
                              os.sched_param(args.controller_priority))
    try:
        time.sleep(0.2 if args.quick else 2.0)   # the controller up (the node waits for it too)
        result, log_path = run_node(args.rt_seconds, 'events', folder, ['displacement'],
                                    scene_file=scene_name, real_time=True,
                                    realtime_priority=args.realtime_priority,
                                    **({'predictability.mode': 'off'}
                                       if args.rt_no_predictability else {}),
                                    **({'log.enabled': False} if args.rt_no_log else
                                       {'log.compression': args.log_compression}))
    finally:
        stop(controller)
        busy.kill()
        busy.wait()
    if not args.rt_no_log:
        result.update(command_latency(log_path, controller_file, dt))
    return result


def bench_scene(scene_name, args, folder):
    """Measure every figure of one scene that ``args`` asks for; return them as a dict."""
    from det_sim_ros.io.contract import OutputContract
    from det_sim_ros.scenes.scene import load_scene
    report = {}
    scene = load_scene(scene_name)
    sim = Simulator(scene)
    encoder = OutputContract(sim.model).encoder()
    samples = encoder.encode(sim.step().copy(), 1_000_000)
    topics = encoder.topics
    n = int(args.floor_periods)
    listener = spawn(SUBSCRIBER, ','.join(topics)) if args.rounds > 0 else None
    try:
        report['physics_us_per_period'] = physics(scene, n) * 1e6
        if listener is not None:   # --rounds 0: no free-run figures
            report['physics_us_per_period'] = physics(scene, n) * 1e6
            report.update(_free_run_rounds(scene_name, topics, samples, n, args, folder))
        if args.paired > 0:
            if listener is None:
                listener = spawn(SUBSCRIBER, ','.join(topics))
            report.update(_paired_runs(scene_name, topics, samples, args, folder,
                                       report['physics_us_per_period']))
    finally:
        if listener is not None:
            stop(listener)
    if args.paired_predictability > 0:   # the twin on (the default) against off
        from sensor_cost import paired_sensors
        report['paired_predictability_on_and_off'] = paired_sensors(
            scene_name, args.paired_predictability, args.paired_block_s, folder,
            args.log_compression, topics=(), off_overrides={'predictability.mode': 'off'})
    if args.paired_sensors > 0:   # every sensor knob on against off (bench/sensor_cost.py)
        from sensor_cost import paired_sensors
        report['paired_sensors_on_and_off'] = paired_sensors(
            scene_name, args.paired_sensors, args.paired_block_s, folder, args.log_compression)
    if args.lockstep_seconds > 0:
        report['lockstep_in_process_controller'] = lockstep_in_process(scene_name,
                                                                       args.lockstep_seconds)
    if args.rt_seconds > 0:
        report['real_time_with_controller_and_busy_core'] = _real_time_run(
            scene_name, sim.model.n_inputs, sim.dt, args, folder)
    return report


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--scenes', default='default,array')
    parser.add_argument('--rt-seconds', type=float, default=60.0)
    parser.add_argument('--free-seconds', type=float, default=3.0, help='per free run')
    parser.add_argument('--rounds', type=int, default=7, help='interleaved free-run rounds')
    parser.add_argument('--floor-periods', type=int, default=20000)
    parser.add_argument('--lockstep-seconds', type=float, default=5.0, help='sim seconds')
    parser.add_argument('--realtime-priority', type=int, default=0,
                        help="real-time run: the node's realtime_priority (SCHED_FIFO; 0 = off)")
    parser.add_argument('--controller-priority', type=int, default=0,
                        help="real-time run: the controller process's SCHED_FIFO priority "
                        '(set right after it starts: its threads inherit it)')
    parser.add_argument('--rt-no-log', action='store_true', help='real-time run without the '
                        'MCAP log (then no command-to-effect figures)')
    parser.add_argument('--paired', type=int, default=0,
                        help='node and floor in this many interleaved pairs of blocks in one '
                        'process (free run, the log on; 0 = off): the precise node/floor ratio')
    parser.add_argument('--paired-block-s', type=float, default=0.5)
    parser.add_argument('--log-compression', default='zstd', choices=('zstd', 'lz4', 'none'),
                        help="the node's log.compression in the paired and real-time runs")
    parser.add_argument('--paired-no-log', action='store_true',
                        help="a second paired run with the log off (the log's share)")
    parser.add_argument('--paired-sensors', type=int, default=0,
                        help='the node with every sensor knob on and off in this many '
                        'interleaved pairs of blocks (bench/sensor_cost.py; 0 = off)')
    parser.add_argument('--rt-no-predictability', action='store_true',
                        help='real-time run without the predictability twin')
    parser.add_argument('--paired-predictability', type=int, default=0,
                        help='N pairs: the node with the predictability twin (the default) '
                             'against the node without it, paired blocks in one process')
    parser.add_argument('--json', help='write the numbers to this file')
    parser.add_argument('--quick', action='store_true',
                        help='the default scene, every part for a fraction of a second')
    args = parser.parse_args()
    if args.quick:
        args.scenes, args.rt_seconds, args.free_seconds, args.rounds = 'default', 0.5, 0.1, 1
        args.floor_periods, args.lockstep_seconds = 500, 0.2
    report = {'cpus': os.cpu_count(), 'load_avg_at_start': os.getloadavg()}
    with tempfile.TemporaryDirectory() as folder:
        for scene_name in args.scenes.split(','):
            report[scene_name] = bench_scene(scene_name, args, folder)
            print(json.dumps({scene_name: report[scene_name]}, indent=2), flush=True)
    report['load_avg_at_end'] = os.getloadavg()
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(report, stream, indent=2)


if __name__ == '__main__':
    main()
