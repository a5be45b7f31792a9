"""
What a new user meets: seconds from `sim_node`'s start to its first sample, after `pip install .`.

A fresh venv, `pip install .`, then `sim_node` started as a process; seconds from the process
start to the first `displacement` sample at a subscriber in this process (reliable QoS, own ROS
domain, localhost only). The first start after the install is reported separately from the
following ones; nothing should differ, because nothing is compiled at run time. With --colcon
the same after `colcon build` of a workspace holding this repository (colcon-core and colcon-ros
from PyPI, installed into the fresh venv).

Discovery is part of that time and is not the node's: Fast DDS learns of an already running
participant only when that one re-announces itself (every 3 s by default), so a subscriber
created together with the node makes the node wait up to ~3 s. ``--probe-announce-ms 100``
gives this process's subscriber a 100 ms announcement period (a Fast DDS XML profile for this
process only), which leaves mostly the node's own start-up in the figure.

Run from the repository with a venv that has rclpy: python bench/first_sample.py [--starts 3]

``--tree DIR`` (repeatable) skips the install and starts ``python -m det_sim_ros.cli.sim_node``
from each source tree DIR (its kernel built in place, its modules compiled to bytecode first as
pip does at an install), the trees taking turns start by start, and prints each tree's median
and maximum: two versions side by side in one run (the trees run through bench/checkouts.py).
``--quick``: one start from this tree, no install, a 100 ms announcement period (a smoke run).
"""

import argparse
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time

from checkouts import THIS_TREE, tree_env

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))   # what `pip install .` takes
PROBE_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="probe" is_default_profile="true">
    <rtps><builtin><discovery_config>
      <leaseAnnouncement><sec>0</sec><nanosec>{ns}</nanosec></leaseAnnouncement>
    </discovery_config></builtin></rtps>
  </participant>
</profiles>
"""


def _env():
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(120, 200)))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('PYTHONPATH', None)
    return env


def time_to_first_sample(command, env, timeout=120.0, cwd=None):
    """Start ``command``; seconds until this process receives its first displacement sample."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState
    os.environ['ROS_DOMAIN_ID'] = env['ROS_DOMAIN_ID']
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    context = Context()
    rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('first_sample_probe', context=context)
    got = []
    node.create_subscription(JointState, 'displacement', lambda m: got.append(time.perf_counter()),
                             10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    log = tempfile.TemporaryFile()
    t0 = time.perf_counter()
    proc = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=cwd)
    try:
        while not got and time.perf_counter() - t0 < timeout and proc.poll() is None:
            executor.spin_once(timeout_sec=0.01)
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    log.seek(0)
    text = log.read().decode(errors='replace')
    if not got:
        raise RuntimeError(f'no sample within {timeout} s; node said:\n{text}')
    prepared = [line for line in text.splitlines() if 'prepared in' in line]
    return got[0] - t0, (prepared[0].split('] ', 1)[-1] if prepared else '')


def _run(cmd, **kw):
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, **kw)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--starts', type=int, default=3)
    parser.add_argument('--colcon', action='store_true', help='also colcon build')
    parser.add_argument('--probe-announce-ms', type=int, default=0,
                        help="this process's participant re-announces itself this often "
                             '(0: the Fast DDS default, 3 s)')
    parser.add_argument('--tree', action='append', default=[],
                        help='a source tree to start sim_node from, without an install '
                             '(repeatable: the trees take turns)')
    parser.add_argument('--quick', action='store_true',
                        help='one start from this tree, no install, 100 ms announcements')
    args = parser.parse_args(argv)
    if args.quick:
        args.starts, args.tree = 1, args.tree or [THIS_TREE]
        args.probe_announce_ms = args.probe_announce_ms or 100
    env = _env()
    env.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)   # the node keeps the defaults
    if args.probe_announce_ms:
        profile = os.path.join(tempfile.mkdtemp(prefix='det_sim_dds_'), 'probe.xml')
        with open(profile, 'w') as stream:
            stream.write(PROBE_PROFILE.format(ns=args.probe_announce_ms * 1_000_000))
        os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = profile   # before rclpy is imported
    if args.tree:
        return _compare_trees(args.tree, args.starts, env)
    tmp = tempfile.mkdtemp(prefix='det_sim_first_')
    try:
        venv = os.path.join(tmp, 'venv')
        _run([sys.executable, '-m', 'venv', venv])
        pip = os.path.join(venv, 'bin', 'pip')
        t_install = _run([pip, 'install', '--quiet', '--disable-pip-version-check', REPO],
                         env=env, stderr=subprocess.DEVNULL)
        print(f'fresh venv, pip install . : {t_install:.1f} s (dependencies and the C kernel)')
        node = os.path.join(venv, 'lib', 'det_sim_ros', 'sim_node')   # what ros2 run starts
        for k in range(args.starts):
            seconds, line = time_to_first_sample([node], env)
            label = 'first start after install' if k == 0 else f'start {k + 1}'
            print(f'{label}: first displacement sample after {seconds:.2f} s   [{line}]')
        if args.colcon:
            _run([pip, 'install', '--quiet', '--disable-pip-version-check', 'colcon-core',
                  'colcon-ros', 'colcon-package-selection'], env=env, stderr=subprocess.DEVNULL)
            ws = os.path.join(tmp, 'ws')
            os.makedirs(os.path.join(ws, 'src'))
            shutil.copytree(REPO, os.path.join(ws, 'src', 'det_sim_ros'),
                            ignore=shutil.ignore_patterns('.git', 'build', 'install', 'log',
                                                          '*.so', '__pycache__', '.venv'))
            colcon_env = dict(env, PATH=os.path.join(venv, 'bin') + os.pathsep + env['PATH'])
            t_build = _run([os.path.join(venv, 'bin', 'colcon'), 'build', '--packages-select',
                            'det_sim_ros'], cwd=ws, env=colcon_env, stderr=subprocess.DEVNULL)
            print(f'colcon build --packages-select det_sim_ros: {t_build:.1f} s')
            install = os.path.join(ws, 'install', 'det_sim_ros')
            site = subprocess.run([os.path.join(venv, 'bin', 'python'), '-c',
                                   'import sysconfig; print(sysconfig.get_python_version())'],
                                  capture_output=True, text=True, check=True).stdout.strip()
            ros_env = dict(colcon_env, AMENT_PREFIX_PATH=install, PYTHONPATH=os.path.join(
                install, 'lib', f'python{site}', 'site-packages'))
            for k in range(args.starts):
                seconds, line = time_to_first_sample(
                    [os.path.join(venv, 'bin', 'python'),
                     os.path.join(install, 'lib', 'det_sim_ros', 'sim_node')], ros_env)
                print(f'colcon install, start {k + 1}: first displacement sample after '
                      f'{seconds:.2f} s   [{line}]')
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


def _compare_trees(trees, starts, env) -> int:
    """Start sim_node from each tree in turn ``starts`` times; print each one's median, max."""
    import compileall
    import statistics
    # as an installed package is (pip compiles its modules): without bytecode every start
    # compiles the package's modules anew, ~80 ms here (and PYTHONDONTWRITEBYTECODE=1 keeps it so)
    for tree in trees:
        compileall.compile_dir(os.path.join(tree, 'det_sim_ros'), quiet=1)
    seconds = {tree: [] for tree in trees}
    for k in range(starts):
        for tree in trees:
            took, _ = time_to_first_sample(
                [sys.executable, '-m', 'det_sim_ros.cli.sim_node', '--ros-args',
                 '-p', 'log.enabled:=false'], tree_env(tree, env), cwd=tree)   # -m: the tree first
            seconds[tree].append(took)
            print(f'{tree} start {k + 1}: first displacement sample after {took:.2f} s',
                  flush=True)
    for tree, values in seconds.items():
        print(f'{tree}: {len(values)} starts, median {statistics.median(values):.2f} s, '
              f'max {max(values):.2f} s (process start to the first sample at a subscriber)')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
