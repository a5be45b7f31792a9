"""
Fingerprints of whole MCAP log files, to show that a change to the log writer keeps every byte.

bench/behaviour_hashes.py hashes a log's messages and the file up to the wall-clock start; this
hashes every byte of every file (the wall clock pinned, flushes by log time only) of logs
written in many configurations: each compression, a small and the default chunk size, with
and without the writer thread and the record packer, with a sample layout that changes, a
topic that drops out and a new file mid-run; a split run; a simulated run; ``recover`` of it.
Run it before and after a change (seconds):

    python bench/log_bytes.py > before.json
    python bench/log_bytes.py | diff before.json -   # no output: the same bytes

``--quick`` is accepted for bench/'s smoke test; the script is already quick.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
import time

from det_sim_ros.io.contract import encode_float64_multi_array, encode_joint_state, TOPIC_TYPES
from det_sim_ros.io.replay import simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator

try:
    from det_sim_ros.io.log import Recorder, recover
except ImportError:   # the log before its subpackage (io/mcap_log.py)
    from det_sim_ros.io.mcap_log import Recorder, recover

FIXED = {'flush_period_s': 1e9, 'clock': lambda: 0.0}   # flushes by log time only


def _digest(path) -> str:
    with open(path, 'rb') as stream:
        return hashlib.sha256(stream.read()).hexdigest()[:16]


def _mixed_run(recorder) -> None:
    """Record samples whose layout changes, a topic that drops out, commands, a new file."""
    for k in range(3000):
        if k % 97 == 0:
            recorder.record('voltage_command', encode_float64_multi_array([float(k)]),
                            k * 1000 - 500, TOPIC_TYPES['voltage_command'])
        names = ['det0'] if k % 500 else ['det0', 'det1']
        data = [encode_joint_state(names, [float(k)] * len(names), stamp_ns=k)] * 2
        topics = ('deflection', 'charge') if k % 700 else ('deflection',)
        recorder.record_sample(k * 1000, topics, data[:len(topics)], TOPIC_TYPES)
        if k == 1500:
            recorder.new_file()


def log_bytes(folder: str) -> dict:
    result = {}
    for compression in ('zstd', 'lz4', 'none'):
        for chunk_size in (4096, 1024 * 1024):
            for background in (False, True):
                for packing in (True, False):
                    path = os.path.join(folder, f'{compression}{chunk_size}{background}'
                                                f'{packing}.mcap')
                    with Recorder(path, 'a: 1\n', chunk_size=chunk_size, packing=packing,
                                  compression=compression, background=background,
                                  metadata={'x': 'y'}, **FIXED) as recorder:
                        _mixed_run(recorder)
                    key = f'{compression}/{chunk_size}/thread {background}/packing {packing}'
                    result[key] = [_digest(p) for p in recorder.paths]
    path = os.path.join(folder, 'split.mcap')
    with Recorder(path, None, split_mb=0.05, chunk_size=8192, **FIXED) as recorder:
        for k in range(5000):
            recorder.record_sample(k * 1000, ('deflection',),
                                   [encode_joint_state(['d'], [k * 1.0], stamp_ns=k)],
                                   TOPIC_TYPES)
    result['split'] = [_digest(p) for p in recorder.paths]
    scene = load_scene('default', {'scene.fidelity': 'paper'})
    sim = Simulator(scene)
    path = os.path.join(folder, 'run.mcap')
    with Recorder(path, scene, metadata={'method': sim.method.name}, **FIXED) as recorder:
        simulate_to_log(recorder, sim, {0: [0.0], 200: [3000.0]}, 400)
    result['simulated run'] = _digest(path)
    for compression in ('zstd', 'lz4'):
        target = os.path.join(folder, f'recovered_{compression}.mcap')
        recover(path, target, compression)
        result[f'recover {compression}'] = _digest(target)
    return result


if __name__ == '__main__':
    if sys.argv[1:] not in ([], ['--quick']):
        raise SystemExit('usage: python bench/log_bytes.py [--quick]')
    time.time_ns = lambda: 1234567890   # the wall start in each file's metadata
    with tempfile.TemporaryDirectory() as tmp:
        json.dump(log_bytes(tmp), sys.stdout, indent=1, sort_keys=True)
    print()
