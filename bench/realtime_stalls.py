#!/usr/bin/env python3
"""
Where a real-time node's stalled periods went: the node's side of bench/realtime_switching.py.

A script, not a test. The same set-up (the switching controller process answering every
sample, another process keeping one core busy), with the node in this process so that each
period can be timed: ``on_sample`` stamps each publication, ``run_period`` is wrapped to take
its wall and thread CPU time and the integrator's internal steps, ``gc.callbacks`` time every
garbage collection. Reports the publications' lateness against the best of the run, the
periods' own cost, the gaps of more than 5 ms between two publications and the collections
inside them, and where the node slipped. ``--freeze`` freezes the start-up's objects before
spinning, as ``sim_node`` does (``gc.freeze()``).

Usage: python bench/realtime_stalls.py [--seconds 10] [--freeze] [-p NAME:=VALUE ...] [--quick]
"""

import argparse
import gc
import json
import os
import tempfile
import time

import numpy as np

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

from peer_processes import BUSY, spawn, stop  # noqa: E402
from realtime_switching import analyse, SWITCHING_CONTROLLER  # noqa: E402


def _value(text):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return {'true': True, 'false': False}.get(text, text)


class Trace:
    """What one run's periods did (wall times in s)."""

    def __init__(self):
        self.published = []     # (k, wall time)
        self.periods = []       # (k, wall s, thread CPU s, internal steps so far)
        self.collections = []   # (start, duration, generation)
        self.slips = []         # (k, slipped s so far)
        self._gc_start = 0.0

    def on_gc(self, phase, info):
        """Time a garbage collection (gc.callbacks)."""
        if phase == 'start':
            self._gc_start = time.perf_counter()
        else:
            self.collections.append((self._gc_start, time.perf_counter() - self._gc_start,
                                     info['generation']))


def run(seconds, params, freeze):
    """Run the node here beside the controller and the busy process; return the trace."""
    import rclpy
    from rclpy.parameter import Parameter
    from det_sim_ros.ros.node import make_executor, SimNode
    folder = tempfile.mkdtemp()
    trace = Trace()
    gc.callbacks.append(trace.on_gc)
    busy = spawn(BUSY)
    out = os.path.join(folder, 'controller.json')
    controller = spawn(SWITCHING_CONTROLLER, '1', out, str(seconds), '10')
    rclpy.init()
    node = SimNode(parameter_overrides=[
        Parameter('log.path', value=folder), Parameter('info_period', value=0.0)]
        + [Parameter(name, value=value) for name, value in params.items()])

    def on_sample(k, outputs):
        trace.published.append((k, time.perf_counter()))
        slipped = node.pacing.slipped_s
        if slipped and (not trace.slips or trace.slips[-1][1] != slipped):
            trace.slips.append((k, slipped))
    node.on_sample = on_sample
    run_period = node.run_period

    def timed_period(batch=None):
        wall, cpu = time.perf_counter(), time.thread_time()
        result = run_period(batch)
        trace.periods.append((node.simulator.k, time.perf_counter() - wall,
                              time.thread_time() - cpu, node.simulator.steps_taken))
        return result
    node.run_period = timed_period
    executor = make_executor(node.context)
    executor.add_node(node)
    if freeze:
        gc.freeze()
    end = time.perf_counter() + seconds + 3
    try:
        while time.perf_counter() < end and controller.poll() is None:
            executor.spin_once(timeout_sec=0.05)
    finally:
        stop(controller)
        busy.kill()
        busy.wait()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    with open(out) as stream:
        return trace, analyse(json.load(stream), 1e-3)


def report(trace, controller):
    """Return the figures of one trace as a dict."""
    start = min(t - k * 1e-3 for k, t in trace.published)
    late = np.array([(t - k * 1e-3 - start) * 1e3 for k, t in trace.published])
    wall = np.array([p[1] for p in trace.periods]) * 1e3
    cpu = np.array([p[2] for p in trace.periods]) * 1e3
    steps = np.diff([p[3] for p in trace.periods])
    times = [t for _, t in trace.published]
    gaps = sorted(((times[i] - times[i - 1], trace.published[i][0], times[i - 1])
                   for i in range(1, len(times)) if times[i] - times[i - 1] > 0.005),
                  reverse=True)
    return {
        'controller': controller,
        'publication_lateness_ms_p50_p99_max': [
            round(float(v), 2) for v in np.percentile(late, [50, 99, 100])],
        'period_wall_ms_p50_p99_max': [round(float(v), 3) for v in
                                       np.percentile(wall, [50, 99, 100])],
        'period_cpu_ms_p99_max': [round(float(v), 3) for v in np.percentile(cpu, [99, 100])],
        'internal_steps_per_period_mean_max': [round(float(steps.mean()), 2), int(steps.max())],
        'longest_periods_wall_cpu_ms_k': [
            (round(w * 1e3, 2), round(c * 1e3, 2), k) for w, c, k in
            sorted(((p[1], p[2], p[0]) for p in trace.periods), reverse=True)[:8]],
        'gaps_over_5ms': len(gaps),
        'longest_gaps_ms_before_k_collections_in_it_ms': [
            (round(g * 1e3, 1), k, [round(d * 1e3, 2) for s, d, _ in trace.collections
                                    if t0 <= s <= t0 + g]) for g, k, t0 in gaps[:8]],
        'collections': len(trace.collections),
        'full_collections': sum(1 for c in trace.collections if c[2] == 2),
        'longest_collection_ms': round(
            max((c[1] for c in trace.collections), default=0) * 1e3, 2),
        'slips_k_total_s': trace.slips[:10]}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--seconds', type=float, default=10.0)
    parser.add_argument('--freeze', action='store_true', help='gc.freeze() before spinning')
    parser.add_argument('-p', action='append', default=[], metavar='NAME:=VALUE',
                        help='a node parameter, e.g. -p realtime_priority:=50')
    parser.add_argument('--quick', action='store_true', help='0.5 s (a smoke run)')
    args = parser.parse_args(argv)
    if args.quick:
        args.seconds = 0.5
    params = {name: _value(value) for name, value in
              (item.split(':=', 1) for item in args.p)}
    trace, controller = run(args.seconds, params, args.freeze)
    print(json.dumps(report(trace, controller), indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
