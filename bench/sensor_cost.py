#!/usr/bin/env python3
"""
Benchmark the sensors' cost in sim_node: every sensor knob on against every knob off, paired.

Two nodes of one scene in one process, free run with the MCAP log, markers off: one without
sensors (namespace /off), one with every knob of every output topic's sensor on (/on, see
EVERY_KNOB). One subscriber process takes every output topic of both (not the truth topics:
they are published only while subscribed, and always logged). The nodes are spun in randomly
ordered pairs of blocks of ``block_s`` wall seconds, one at a time, so the host's drift hits
both alike; the figure is the process CPU (all threads) per control period of each, and their
ratio (totals, and the mean of the per-pair ratios with its standard error).

With ``--amplifier PRESET`` the /on node also takes that preset's amplifier section (e.g.
``amplifier_lab``: DAC, delay, offset, bandwidth, slew rate, current limit): every knob of both
models on; with ``--topics ''`` as well, the amplifier alone.

Usage: python bench/sensor_cost.py [--scene default] [--pairs 60] [--block-s 0.5] [--quick]
       [--topics displacement,...] [--truth-subscribed] [--amplifier amplifier_lab]
       (``bench/node_rate.py --paired-sensors N`` runs the same with every topic sensed)
"""

import argparse
import json
import os
import random
import tempfile
import time

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 101))

from det_sim_ros.ros.node import make_executor, SimNode  # noqa: E402
from peer_processes import spawn, stop, SUBSCRIBER  # noqa: E402
import rclpy  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

TOPICS = ('deflection', 'displacement', 'charge', 'current')
# every knob on, in each topic's unit (m, m, C, A): noise coloured, a bias, a step, a delay,
# dropout and a range that the run stays inside
SCALE = {'deflection': 1e-5, 'displacement': 1e-5, 'charge': 1e-9, 'current': 1e-5}
EVERY_KNOB = {'noise_std': 0.1, 'correlation_time': 2e-3, 'quantization': 0.01, 'bias': 0.05,
              'delay_samples': 2, 'dropout': 0.01, 'range_min': -1e4, 'range_max': 1e4}


def every_knob_on(topics=TOPICS) -> dict:
    """Return the scene overrides that switch every knob of the topics' sensors on."""
    overrides = {'sensors.seed': 1}
    for topic in topics:
        for key, value in EVERY_KNOB.items():
            scaled = value if key in ('correlation_time', 'delay_samples', 'dropout') \
                else value * SCALE[topic]
            overrides[f'sensors.{topic}.{key}'] = scaled
    return overrides


def _node(context, scene_name, namespace, folder, compression, overrides):
    params = [Parameter('scene_file', value=scene_name), Parameter('real_time', value=False),
              Parameter('info_period', value=0.0), Parameter('log.path', value=folder),
              Parameter('markers.rate_hz', value=0.0),
              Parameter('log.compression', value=compression),
              Parameter('scene.initial_state', value='released')]
    params += [Parameter(key, value=value) for key, value in overrides.items()]
    return SimNode(context=context, namespace=namespace, parameter_overrides=params)


def amplifier_of(preset: str) -> dict:
    """Return a preset's amplifier section as node parameter overrides (amplifier.<knob>)."""
    from det_sim_ros.scenes.scene import load_scene
    return {f'amplifier.{key}': value for key, value in load_scene(preset).amplifier.items()}


def _spin_block(executor, block_s):
    end = time.perf_counter() + block_s
    while time.perf_counter() < end:
        executor.spin_once(timeout_sec=0.05)


def paired_sensors(scene_name, pairs, block_s, folder, compression='zstd', seed=1,
                   truth_subscribed=False, topics=TOPICS, amplifier=None, warm_s=0.5,
                   off_overrides=None, on_overrides=None):
    """
    Measure the nodes without and with sensors in ``pairs`` random-order pairs of blocks.

    ``off_overrides``, ``on_overrides``: more node parameters of each (e.g. another feature
    off and on: bench/node_rate.py --paired-predictability).
    """
    names = [f'/{ns}/{topic}' for ns in ('off', 'on') for topic in TOPICS]
    if truth_subscribed:
        names += [f'/on/sim_node/truth/{topic}' for topic in topics]
    listener = spawn(SUBSCRIBER, ','.join(names))
    contexts = [rclpy.context.Context(), rclpy.context.Context()]
    for context in contexts:
        rclpy.init(context=context)
    try:
        knobs = {**(every_knob_on(topics) if topics else {}),
                 **(amplifier_of(amplifier) if amplifier else {}), **(on_overrides or {})}
        nodes = [_node(contexts[0], scene_name, 'off', folder, compression, off_overrides or {}),
                 _node(contexts[1], scene_name, 'on', folder, compression, knobs)]
        executors = [make_executor(context) for context in contexts]
        for executor, node in zip(executors, nodes):
            executor.add_node(node)
        deadline = time.monotonic() + 60.0
        publishers = [p for node in nodes for p in node.output_publishers.values()]
        while not all(p.get_subscription_count() for p in publishers):
            if time.monotonic() > deadline:
                raise RuntimeError('subscribers not discovered')
            time.sleep(0.05)
        for executor in executors:   # warm both
            _spin_block(executor, warm_s)
        rng = random.Random(seed)
        totals, ratios = [[0.0, 0], [0.0, 0]], []
        for _ in range(pairs):
            per = [0.0, 0.0]
            for which in ((0, 1) if rng.random() < 0.5 else (1, 0)):
                k0, c0 = nodes[which].simulator.k, time.process_time()
                _spin_block(executors[which], block_s)
                cpu, periods = time.process_time() - c0, nodes[which].simulator.k - k0
                totals[which][0] += cpu
                totals[which][1] += periods
                per[which] = cpu / max(periods, 1)
            ratios.append(per[1] / per[0])
        logged = [node.recorder.messages for node in nodes]
        for executor in executors:
            executor.shutdown()
        for node in nodes:
            node.destroy_node()
    finally:
        for context in contexts:
            rclpy.try_shutdown(context=context)
        stop(listener)
    off_us, on_us = (totals[i][0] / totals[i][1] * 1e6 for i in (0, 1))
    mean = sum(ratios) / len(ratios)
    error = (sum((r - mean) ** 2 for r in ratios) / (len(ratios) - 1)) ** 0.5 / len(ratios) ** 0.5
    return {'pairs': pairs, 'block_s': block_s, 'truth_subscribed': truth_subscribed,
            'sensed_topics': list(topics), 'amplifier': amplifier,
            'off_us_per_period': off_us, 'on_us_per_period': on_us,
            'on_over_off_totals': on_us / off_us, 'on_over_off_mean_of_pairs': mean,
            'standard_error': error, 'periods': [totals[0][1], totals[1][1]],
            'messages_logged': logged}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--scene', default='default')
    parser.add_argument('--pairs', type=int, default=60)
    parser.add_argument('--block-s', type=float, default=0.5)
    parser.add_argument('--log-compression', default='zstd', choices=('zstd', 'lz4', 'none'))
    parser.add_argument('--topics', default=','.join(TOPICS),
                        help='the sensed topics (every knob on for each; empty: none)')
    parser.add_argument('--truth-subscribed', action='store_true',
                        help='the subscriber process takes the truth topics too')
    parser.add_argument('--amplifier', default=None,
                        help='a preset whose amplifier section the /on node takes too')
    parser.add_argument('--quick', action='store_true',
                        help='two pairs of 0.05 s blocks after a 0.05 s warm-up (a smoke run)')
    args = parser.parse_args()
    warm_s = 0.5
    if args.quick:
        args.pairs, args.block_s, warm_s = 2, 0.05, 0.05
    with tempfile.TemporaryDirectory() as folder:
        result = paired_sensors(args.scene, args.pairs, args.block_s, folder,
                                args.log_compression, truth_subscribed=args.truth_subscribed,
                                topics=tuple(t for t in args.topics.split(',') if t),
                                amplifier=args.amplifier, warm_s=warm_s)
    result.update(cpus=os.cpu_count(), load_avg=os.getloadavg())
    print(json.dumps(result, indent=2))


if __name__ == '__main__':
    main()
