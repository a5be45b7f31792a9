#!/usr/bin/env python3
"""
Benchmark fleets of sim_nodes: nodes per host, lockstep loops per host, QoS across hosts.

A script, not a test. Run each part under the bench lock (bench/README.md).

capacity  N default-scene nodes in real time at 1 kHz on this host (det_sim_ros.ros.fleet), one
          listener process subscribed (reliable, depth 1000) to every node's displacement:
          per node samples lost and sim seconds per wall second over the window; the nodes'
          CPU (s per wall s, all N together); the nodes' own real-time factor (their INFO
          lines, every 5 s). A host "holds" N when every node lost 0 samples and kept real
          time (>= 0.995).
lockstep  N lockstep nodes, each answered by its own controller process
          (bench/peer_processes.py's CONTROLLER): aggregate simulated seconds per wall second
          (sum over nodes).
hosts     One node at 1 kHz in real time (lockstep_* cases: lockstep, sim s per wall s) on
          namespace host h0 (test/netns_hosts.py), its controller (CONTROLLER: answers every
          displacement sample) on host h1, unicast discovery over UDP: command-to-effect
          latency p50/p99 (controller publishes a command -> it receives the first sample that
          shows it) and samples lost at the controller; the h1 link direct (veth) or through
          the TAP relay with delay / loss, default QoS (reliable depth 10) or qos_keep_all,
          with or without config/dds_lossy.xml.

Usage (root for hosts):
    flock bench/.lock python bench/fleet.py capacity --nodes 1,2,4 --seconds 15
    flock bench/.lock python bench/fleet.py lockstep --nodes 1,2,4,8 --seconds 10
    flock bench/.lock python bench/fleet.py hosts --cases direct,lossy_keep_all_profile
Add --json FILE to append the numbers (one JSON object per line). ``--quick`` (no part: capacity
and lockstep) runs one node for 0.5 s after 0.5 s of settling (a smoke run).
"""

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time


HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(1, os.path.join(ROOT, 'test'))   # netns_hosts: the tests' namespace hosts
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 101))

from det_sim_ros.ros.fleet import Fleet, FleetNode  # noqa: E402
from peer_processes import command_latency, CONTROLLER  # noqa: E402

DT_NS = 1_000_000          # the default scene's period (1 kHz)
STARTUP_LIMIT = 120.0      # s: bounds a start that hangs (never part of a measurement)
SETTLE = 2.0               # s after every node runs before the window opens

# Subscribes to /n<i>/displacement for i < N (reliable, depth 1000, raw bytes) and records each
# sample's stamp and arrival time (CLOCK_MONOTONIC); writes them as JSON at SIGINT.
LISTENER = """
import json, sys, time, rclpy
from rclpy.experimental import EventsExecutor
from sensor_msgs.msg import JointState
from det_sim_ros.io.contract import decode_joint_state
n, out_path = int(sys.argv[1]), sys.argv[2]
rclpy.init()
node = rclpy.create_node('bench_listener')
got = {i: [] for i in range(n)}
for i in range(n):
    node.create_subscription(
        JointState, f'/n{i}/displacement',
        lambda data, i=i: got[i].append((decode_joint_state(data).stamp_ns, time.monotonic())),
        1000, raw=True)
executor = EventsExecutor()
executor.add_node(node)
try:
    while rclpy.ok():
        executor.spin_once(timeout_sec=0.1)
except BaseException:
    pass
finally:
    with open(out_path, 'w') as stream:
        json.dump(got, stream)
"""


def child_env(**extra):
    return dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), PYTHONSAFEPATH='1', **extra)


def spawn(code, *args, env=None, wrap=()):
    return subprocess.Popen([*wrap, sys.executable, '-c', code, *args], env=env or child_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def stop(proc, timeout=30.0):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def cpu_seconds(pids):
    total = 0
    for pid in pids:
        try:
            with open(f'/proc/{pid}/stat') as stream:
                fields = stream.read().rsplit(')', 1)[1].split()
            total += int(fields[11]) + int(fields[12])     # utime + stime, ticks
        except OSError:
            pass
    return total / os.sysconf('SC_CLK_TCK')


def fleet_nodes(folder, n, mode, **params):
    params = {'info_period': 0.0, **params}
    return [FleetNode(f'/n{i}', 'default', mode, {}, params, None,
                      os.path.join(folder, f'n{i}.log'), os.path.join(folder, f'n{i}'))
            for i in range(n)]


def wait_ready(fleet):
    deadline = time.monotonic() + STARTUP_LIMIT
    while len(fleet.ready()) < len(fleet.nodes):
        bad = [p.returncode for p in fleet.procs if p.poll() is not None]
        if bad or time.monotonic() > deadline:
            raise RuntimeError(f'fleet did not start (exit codes {bad})')
        time.sleep(0.1)


def window_stats(samples, t0, t1):
    """Return samples lost and sim s per wall s of a topic's (stamp, arrival) list in [t0, t1]."""
    inside = [(s, r) for s, r in samples if t0 <= r <= t1]
    if len(inside) < 2:
        return {'received': len(inside), 'lost': None, 'rtf': 0.0}
    stamps = sorted(s for s, _ in inside)
    lost = sum((b - a) // DT_NS - 1 for a, b in zip(stamps, stamps[1:]))
    (s0, r0), (s1, r1) = inside[0], inside[-1]
    return {'received': len(inside), 'lost': int(lost), 'rtf': (s1 - s0) * 1e-9 / (r1 - r0)}


def node_rtf(log_file):
    """Return the real-time factors of a node's INFO lines (every 5 s) but the start-up one."""
    import re
    with open(log_file, encoding='utf-8', errors='replace') as stream:
        return [float(x) for x in re.findall(r'RTF=([0-9.]+)', stream.read())][1:]


def capacity(n, seconds):
    with tempfile.TemporaryDirectory() as folder:
        # the nodes' own view too: INFO lines with the real-time factor every 5 s
        fleet = Fleet(fleet_nodes(folder, n, 'real_time', info_period=5.0), env=child_env())
        out = os.path.join(folder, 'listener.json')
        listener = spawn(LISTENER, str(n), out)
        try:
            fleet.start()
            wait_ready(fleet)
            time.sleep(SETTLE)
            pids = [p.pid for p in fleet.procs]
            t0, c0 = time.monotonic(), cpu_seconds(pids)
            time.sleep(seconds)
            t1, c1 = time.monotonic(), cpu_seconds(pids)
        finally:
            stop(listener)
            fleet.signal(signal.SIGINT)
            codes = fleet.wait(30.0)
        with open(out) as stream:
            got = json.load(stream)
        own_rtf = [min(node_rtf(node.log_file), default=None) for node in fleet.nodes]
        per_node = [window_stats(got[str(i)], t0, t1) for i in range(n)]
        lost = [s['lost'] for s in per_node]
        rtf = [s['rtf'] for s in per_node]
        return {'part': 'capacity', 'nodes': n, 'window_s': round(t1 - t0, 2),
                'lost_per_node': lost, 'rtf_min': min(rtf), 'rtf_per_node': rtf,
                'nodes_cpu_s_per_s': (c1 - c0) / (t1 - t0),
                'node_info_rtf_min_per_node': own_rtf,
                'holds': all(x == 0 for x in lost) and min(rtf) >= 0.995,
                'exit_codes': codes, 'load_avg': os.getloadavg()}


def lockstep(n, seconds):
    with tempfile.TemporaryDirectory() as folder:
        fleet = Fleet(fleet_nodes(folder, n, 'lockstep', **{'lockstep.timeout': 1.0}),
                      env=child_env())
        outs = [os.path.join(folder, f'c{i}.json') for i in range(n)]
        controllers = []
        try:
            fleet.start()
            controllers = [spawn(CONTROLLER, '1', outs[i], '--ros-args', '-r', f'__ns:=/n{i}')
                           for i in range(n)]
            wait_ready(fleet)
            time.sleep(SETTLE)
            t0 = time.monotonic()
            time.sleep(seconds)
            t1 = time.monotonic()
        finally:
            for proc in controllers:
                stop(proc)
            fleet.signal(signal.SIGINT)
            codes = fleet.wait(30.0)
        rates = []
        for path in outs:
            with open(path) as stream:
                received = [(int(k), v) for k, v in json.load(stream)['received'].items()]
            rates.append(window_stats(sorted(received), t0, t1)['rtf'])
        return {'part': 'lockstep', 'nodes': n, 'window_s': round(t1 - t0, 2),
                'aggregate_sim_s_per_wall_s': sum(rates), 'per_node': rates,
                'exit_codes': codes, 'load_avg': os.getloadavg()}


# name: (h1 link: None = veth, else (delay s, loss), qos_keep_all, use config/dds_lossy.xml,
#        controller on the node's host, the node's mode)
CASES = {
    'one_host': (None, False, False, True, 'real_time'),
    'direct': (None, False, False, False, 'real_time'),
    'relay': ((0.0, 0.0), False, False, False, 'real_time'),
    'delay_1ms': ((0.001, 0.0), False, False, False, 'real_time'),
    'lossy_depth10': ((0.001, 0.01), False, False, False, 'real_time'),
    'lossy_depth10_profile': ((0.001, 0.01), False, True, False, 'real_time'),
    'lossy_keep_all': ((0.001, 0.01), True, False, False, 'real_time'),
    'lossy_keep_all_profile': ((0.001, 0.01), True, True, False, 'real_time'),
    # lockstep across hosts: sim seconds per wall second
    'lockstep_one_host': (None, False, False, True, 'lockstep'),
    'lockstep_direct': (None, False, False, False, 'lockstep'),
    'lockstep_delay_1ms': ((0.001, 0.0), False, False, False, 'lockstep'),
    'lockstep_lossy_keep_all_profile': ((0.001, 0.01), True, True, False, 'lockstep'),
}


def hosts(case, seconds):
    from netns_hosts import NetnsHosts
    link, keep_all, profile, same_host, mode = CASES[case]
    extra = ({'FASTRTPS_DEFAULT_PROFILES_FILE': os.path.join(ROOT, 'config', 'dds_lossy.xml')}
             if profile else {})
    with tempfile.TemporaryDirectory() as folder, \
            NetnsHosts(2, lossy={1: link} if link else None) as net:
        env = net.ros_env(child_env(**extra))
        fleet_file = os.path.join(folder, 'fleet.yaml')
        with open(fleet_file, 'w') as stream:
            json.dump({'log_dir': 'logs', 'nodes': [{
                'namespace': '/n0', 'mode': mode,
                'params': {'info_period': 0.0, 'qos_keep_all': keep_all,
                           # lockstep: an answer lost before discovery ended costs 1 s once
                           **({'lockstep.timeout': 1.0} if mode == 'lockstep' else {})}}]},
                      stream)
        with open(os.path.join(folder, 'fleet.out'), 'w') as out:
            fleet = net.popen(0, [sys.executable, '-m', 'det_sim_ros.cli', 'fleet', fleet_file],
                              env=env, stdout=out, stderr=subprocess.STDOUT, cwd=folder)
        result_file = os.path.join(folder, 'controller.json')
        controller = spawn(CONTROLLER, '1', result_file,
                           *(['keep_all'] if keep_all else []), '--ros-args', '-r', '__ns:=/n0',
                           env=env, wrap=net.command(0 if same_host else 1, []))
        net.procs.append(controller)
        try:
            deadline = time.monotonic() + STARTUP_LIMIT
            while 'running' not in open(os.path.join(folder, 'fleet.out')).read():
                if fleet.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(open(os.path.join(folder, 'fleet.out')).read())
                time.sleep(0.1)
            time.sleep(SETTLE + seconds)
        finally:
            stop(controller)
            stop(fleet)
        logs = os.path.join(folder, 'logs', 'n0')
        (log_path,) = [os.path.join(logs, f) for f in os.listdir(logs) if f.endswith('.mcap')]
        result = command_latency(log_path, result_file, DT_NS * 1e-9, '/n0/voltage_command')
        with open(result_file) as stream:
            received = sorted((int(k), v) for k, v in json.load(stream)['received'].items())
        end = received[-1][1]
        result['sim_s_per_wall_s_last_10s'] = window_stats(received, end - 10.0, end)['rtf']
        return {'part': 'hosts', 'case': case, 'mode': mode,
                'link_delay_s': link[0] if link else 0.0,
                'link_loss': link[1] if link else 0.0, 'relay': bool(link),
                'qos_keep_all': keep_all, 'profile': profile, 'seconds': SETTLE + seconds,
                **result, 'fleet_exit': fleet.returncode, 'load_avg': os.getloadavg()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('part', nargs='?', choices=('capacity', 'lockstep', 'hosts'))
    parser.add_argument('--nodes', default='1,2,4,8', help='node counts (capacity, lockstep)')
    parser.add_argument('--cases', default=','.join(CASES), help='hosts cases: '
                        + ', '.join(CASES))
    parser.add_argument('--seconds', type=float, default=15.0, help='measured window, s')
    parser.add_argument('--json', help='append each result as a JSON line to this file')
    parser.add_argument('--quick', action='store_true',
                        help='capacity and lockstep (or the part named), one node, 0.5 s')
    args = parser.parse_args()
    if args.quick:
        global SETTLE
        args.nodes, args.seconds, SETTLE = '1', 0.5, 0.5
    elif args.part is None:
        parser.error('name a part: capacity, lockstep or hosts')
    parts = [args.part] if args.part else ['capacity', 'lockstep']
    runs = [(part, point) for part in parts
            for point in (args.cases.split(',') if part == 'hosts'
                          else [int(n) for n in args.nodes.split(',')])]
    for part, point in runs:
        result = {'capacity': capacity, 'lockstep': lockstep, 'hosts': hosts}[part](
            point, args.seconds)
        result['cpus'] = os.cpu_count()
        line = json.dumps(result)
        print(line, flush=True)
        if args.json:
            with open(args.json, 'a') as stream:
                stream.write(line + '\n')


if __name__ == '__main__':
    main()
