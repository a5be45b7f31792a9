#!/usr/bin/env python3
"""
Real time through switching on a busy host: samples lost and arrival lag at a controller.

A script, not a test. ``sim_node`` runs as its own process in real time with its MCAP log on;
a controller process answers every ``displacement`` sample with a voltage command, a square
wave 0 / 2.5 kV that switches the beam between its two states twice a second (each level held
0.5 s) plus a small per-sample dither (+-5 V); another process keeps one core busy. For
``--seconds`` after the controller's first sample it reports:

- samples lost: gaps in the stamps the controller received (reliable QoS; the controller's
  subscription depth is ``--controller-depth``, 10 as most user code has it);
- arrival lag: the wall time a sample arrived minus the wall time it was due, p50 / p99 / max
  (ms). Sample k is due k dt after the start; the start is estimated as the earliest arrival
  less its sim time, so the lag is measured from the best arrival of the run (~0.1-0.3 ms
  after the true due time on an idle host). A slip moves the node's schedule for good, so
  every later sample counts as late by it; ``own_lag`` is the lag against the node's own
  schedule instead: a sample's arrival offset less the smallest offset of it and the 999
  samples after it (a slip is then not a lag, a stall still is);
- the node's real-time factor over the run (sim time received per wall second) and its
  /diagnostics level and message at the end.

``--pairs N`` runs N pairs of configurations in random order (``--a`` and ``--b``: extra
``-p NAME:=VALUE`` parameters of the node, comma separated; ``--a-repo`` / ``--b-repo``: the
node from another checkout of this repository, its kernel built in place, e.g. the code
before a change), so a before/after is measured in one run on the same host; each run holds
the busy process for its whole duration. The host is shared, so compare within a run.

Usage: python bench/realtime_switching.py [--seconds 30] [--pairs 1]
       [--a 'realtime_priority:=0'] [--b 'realtime_priority:=50'] [--a-repo CHECKOUT] [--quick]
       [--controller-depth 10] [--controller-priority 0] [--json out.json]
"""

import argparse
import collections
import json
import os
import random
import subprocess
import sys
import tempfile
import time

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

from checkouts import THIS_TREE, tree_env  # noqa: E402
from peer_processes import BUSY, spawn, stop  # noqa: E402

REPO = THIS_TREE

# Answers every displacement sample at once; records (stamp, arrival) per sample. Exits by
# itself after its run (SIGINT also ends it), writing what it saw.
SWITCHING_CONTROLLER = """
import json, sys, time, rclpy
from rclpy.experimental import EventsExecutor
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from diagnostic_msgs.msg import DiagnosticArray
from det_sim_ros.io.contract import decode_joint_state, encode_float64_multi_array
n_det, out_path = int(sys.argv[1]), sys.argv[2]
seconds, depth = float(sys.argv[3]), int(sys.argv[4])
rclpy.init()
node = rclpy.create_node('switching_controller')
cmd = node.create_publisher(Float64MultiArray, 'voltage_command', 10)
stamps, arrivals, first, diagnostics = [], [], [], []
def on_sample(data):
    now = time.monotonic()
    stamp = decode_joint_state(data).stamp_ns
    stamps.append(stamp)
    arrivals.append(now)
    t = stamp * 1e-9
    level = 2500.0 if int(t / 0.5) % 2 else 0.0           # switches twice a second
    dither = 5.0 if len(stamps) % 2 else -5.0
    cmd.publish(encode_float64_multi_array([max(0.0, level + dither)] * n_det))
    if not first:
        first.append(now)
def on_diagnostics(msg):
    for status in msg.status:
        if 'sim_node' in status.name:
            diagnostics.append({'level': int.from_bytes(status.level, 'little')
                                if isinstance(status.level, bytes) else int(status.level),
                                'message': status.message,
                                'values': {v.key: v.value for v in status.values}})
node.create_subscription(JointState, 'displacement', on_sample, depth, raw=True)
node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
executor = EventsExecutor()
executor.add_node(node)
try:
    while rclpy.ok() and not (first and time.monotonic() > first[0] + seconds):
        executor.spin_once(timeout_sec=0.1)
except BaseException:
    pass
finally:
    with open(out_path, 'w') as stream:
        json.dump({'stamps': stamps, 'arrivals': arrivals, 'diagnostics': diagnostics}, stream)
"""


def _percentile(values, q):
    values = sorted(values)
    if not values:
        return None
    index = min(len(values) - 1, max(0, int(round(q / 100.0 * (len(values) - 1)))))
    return values[index]


def analyse(data, dt):
    """Return samples received and lost, the arrival lag (ms) and the RTF of one run."""
    stamps, arrivals = data['stamps'], data['arrivals']
    if len(stamps) < 2:
        return {'samples_received': len(stamps), 'samples_lost': None}
    step = round(dt * 1e9)
    lost = sum(max(0, (b - a) // step - 1) for a, b in zip(stamps, stamps[1:]))
    start = min(a - s * 1e-9 for s, a in zip(stamps, arrivals))
    lag = [(a - s * 1e-9 - start) * 1e3 for s, a in zip(stamps, arrivals)]
    offsets = [a - s * 1e-9 for s, a in zip(stamps, arrivals)]
    ahead, window = [], collections.deque()   # a sliding minimum over the next 1000
    for i in range(len(offsets) - 1, -1, -1):
        while window and offsets[window[-1]] >= offsets[i]:
            window.pop()
        window.append(i)
        if window[0] > i + 999:
            window.popleft()
        ahead.append(offsets[i] - offsets[window[0]])
    own = [x * 1e3 for x in ahead]
    wall = arrivals[-1] - arrivals[0]
    result = {'own_lag_ms_p50': _percentile(own, 50), 'own_lag_ms_p99': _percentile(own, 99),
              'own_lag_ms_max': max(own), 'samples_received': len(stamps),
              'samples_lost': int(lost),
              'lag_ms_p50': _percentile(lag, 50), 'lag_ms_p99': _percentile(lag, 99),
              'lag_ms_max': max(lag), 'rtf': (stamps[-1] - stamps[0]) * 1e-9 / wall}
    if data['diagnostics']:
        last = data['diagnostics'][-1]
        result['diagnostics_level'] = last['level']
        result['diagnostics_message'] = last['message']
        values = last['values']
        for key in ('slipped_s', 'late_ticks', 'max_lag_ms', 'stepper'):
            if key in values:
                result[key] = values[key]
    return result


def run_once(extra, seconds, depth, folder, label, repo=REPO, controller_priority=0):
    """Run node (from checkout ``repo``), controller and busy process once; the figures."""
    out = os.path.join(folder, f'controller_{label}.json')
    log_dir = os.path.join(folder, f'log_{label}')
    params = ['-p', f'log.path:={log_dir}', '-p', 'info_period:=0.0']
    for item in filter(None, (extra or '').split(',')):
        params += ['-p', item]
    busy = spawn(BUSY)
    node = subprocess.Popen([sys.executable, '-m', 'det_sim_ros.cli.sim_node', '--ros-args',
                             *params], cwd=folder, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True,
                            env=tree_env(repo))
    controller = spawn(SWITCHING_CONTROLLER, '1', out, str(seconds), str(depth))
    if controller_priority:   # as `chrt -f N` would (its threads, started later, inherit it)
        os.sched_setscheduler(controller.pid, os.SCHED_FIFO,
                              os.sched_param(controller_priority))
    try:
        controller.wait(timeout=seconds + 60)
    except subprocess.TimeoutExpired:
        stop(controller)
    finally:
        stop(node)
        busy.kill()
        busy.wait()
    node_output = node.stdout.read()
    with open(out) as stream:
        data = json.load(stream)
    result = analyse(data, 1e-3)
    result['node_warnings'] = [line.strip()[:200] for line in node_output.splitlines()
                               if 'WARN' in line or 'ERROR' in line][:12]
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--seconds', type=float, default=30.0)
    parser.add_argument('--pairs', type=int, default=1)
    parser.add_argument('--a', default='', help="the node's extra parameters, NAME:=VALUE,...")
    parser.add_argument('--b', default=None, help='a second configuration, paired with --a')
    parser.add_argument('--a-repo', default=REPO, help='the checkout configuration a runs')
    parser.add_argument('--b-repo', default=REPO, help='the checkout configuration b runs')
    parser.add_argument('--controller-depth', type=int, default=10)
    parser.add_argument('--controller-priority', type=int, default=0,
                        help="the controller process's SCHED_FIFO priority (0 = ordinary)")
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--json')
    parser.add_argument('--quick', action='store_true', help='one run of 0.5 s (a smoke run)')
    args = parser.parse_args(argv)
    if args.quick:
        args.seconds, args.pairs = 0.5, 1
    configs = {'a': args.a}
    if args.b is not None or os.path.abspath(args.a_repo) != os.path.abspath(args.b_repo):
        configs['b'] = args.b or ''
    repos = {'a': os.path.abspath(args.a_repo), 'b': os.path.abspath(args.b_repo)}
    rng = random.Random(args.seed)
    results = {name: [] for name in configs}
    report = {'cpus': os.cpu_count(), 'load_avg_at_start': os.getloadavg(),
              'configs': configs, 'repos': repos, 'seconds': args.seconds}
    with tempfile.TemporaryDirectory() as folder:
        for pair in range(args.pairs):
            order = list(configs)
            rng.shuffle(order)
            for name in order:
                result = run_once(configs[name], args.seconds, args.controller_depth, folder,
                                  f'{name}{pair}', repos[name], args.controller_priority)
                results[name].append(result)
                print(json.dumps({name: configs[name], 'repo': repos[name], **result}),
                      flush=True)
                time.sleep(0.0 if args.quick else 1.0)
    report['results'] = results
    report['load_avg_at_end'] = os.getloadavg()
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(report, stream, indent=2)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
