"""
Fingerprints of the simulator's behaviour, to show that a change leaves results bit for bit.

SHA-256 of the states, outputs and step counts on nine scene kinds, of a fixed run's MCAP log
(its messages, its metadata but the wall-clock start, the file's bytes up to that), and of its
re-simulation. A change that should not alter results must leave every hash as it was:

    python bench/behaviour_hashes.py > before.json          # before the change
    python bench/behaviour_hashes.py | diff before.json -   # after it: no output

``--quick`` is accepted for bench/'s smoke test (test/test_bench_scripts.py); the script is already
quick (seconds). Uses only the public entry points (``load_scene``, ``Simulator``, ``simulate``,
``Recorder``, ``LogReader``, ``resimulate``), so the same script runs on both sides of a refactor.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
import warnings

import numpy as np

warnings.simplefilter('ignore', DeprecationWarning)   # the flat module aliases warn once

try:
    from det_sim_ros.io.replay import resimulate, simulate_to_log
    from det_sim_ros.scenes.scene import load_scene
    from det_sim_ros.sim.simulator import simulate, Simulator
    try:
        from det_sim_ros.io.log import LogReader, Recorder
    except ImportError:   # the log before its subpackage (io/mcap_log.py)
        from det_sim_ros.io.mcap_log import LogReader, Recorder
except ImportError:   # a package with the flat module layout (no layer subpackages)
    from det_sim_ros.mcap_log import LogReader, Recorder
    from det_sim_ros.replay import resimulate, simulate_to_log
    from det_sim_ros.scene import load_scene
    from det_sim_ros.simulator import simulate, Simulator

# The stepper and structure kinds run at the paper's level, set explicitly (the shipped scenes
# default to 'exact'), so their hashes compare across a change of the shipped default;
# 'default' is the shipped default scene as it is, and 'default_paper' the same scene at the
# paper's level.
PAPER = {'scene.fidelity': 'paper'}
# the polynomial Ritz family, named where the scene has the key (the shipped scenes pick the
# family per beam): 'exact_n3' stays the same model on both sides of a change of that choice
try:
    from det_sim_ros.scenes.keys import SCENE_SPEC
    POLYNOMIAL = {'scene.shapes': 'polynomial'} if 'shapes' in SCENE_SPEC else {}
except ImportError:
    POLYNOMIAL = {}
SCENES = {
    'default': ('default', {}),
    'default_paper': ('default', PAPER),
    'ideal_dp5': ('default', {**PAPER, 'scene.source': 'ideal', 'integrator.method': 'dp5'}),
    'rk4': ('default', {**PAPER, 'scene.source': 'ideal', 'integrator.method': 'rk4'}),
    'no_creep_no_monitor': ('default', {**PAPER, 'scene.creep': False,
                                        'scene.monitor_power': False}),
    'consistent_n3': ('default', {'scene.fidelity': 'consistent', 'scene.n_ritz': 3}),
    'exact_n3': ('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 3, **POLYNOMIAL}),
    'plate': ('plate', PAPER),
    'array20': ('array', {**PAPER, 'structure.copies': 20}),
    'substeps12': ('default', {**PAPER, 'integrator.substeps': 12}),
    # the BDF stepper (what 'auto' picks for the simply supported beam) and an amplified
    # supply (the amplifier's periods), named so that a change of 'auto' keeps them
    'bdf_simply_supported': ('default', {'scene.beam': 'simply_supported',
                                         'integrator.method': 'bdf'}),
    'linearized_amplifier': ('amplifier_lab', {'integrator.method': 'etdrk4_linearized'}),
}


def _digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def _profile(n_inputs: int, n_periods: int) -> np.ndarray:
    """0 V, 3 kV from 0.2 s to 0.6 s, 1.5 kV after; copies staggered by a period each."""
    k = np.arange(n_periods)[:, None] - np.arange(n_inputs)[None, :]
    return np.where((k >= 200) & (k < 600), 3000.0, np.where(k >= 600, 1500.0, 0.0))


def scene_hashes() -> dict:
    result = {}
    for name, (source, overrides) in SCENES.items():
        scene = load_scene(source, overrides)
        sim = Simulator(scene)
        run = simulate(sim, _profile(sim.model.n_inputs, 800), 0.8)
        outputs = np.column_stack([run[n] for n in sim.output_names])
        result[name] = {'x': _digest(run.x), 'outputs': _digest(outputs),
                        'steps': int(sim.steps_taken)}
    return result


def log_hashes() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, 'fixed.mcap')
        scene = load_scene('default', PAPER)
        sim = Simulator(scene)
        volts = _profile(1, 400)
        commands = {k: volts[k] for k in range(400) if k == 0 or volts[k, 0] != volts[k - 1, 0]}
        with Recorder(path, scene, metadata={'method': sim.method.name}) as recorder:
            simulate_to_log(recorder, sim, commands, 400)
        reader = LogReader(path)
        h = hashlib.sha256()
        for message in reader.messages():
            h.update(f'{message.topic}|{message.log_time}|'.encode() + bytes(message.data))
        info = {k: v for k, v in reader.info.items() if k != 'wall_start_ns'}
        data = open(path, 'rb').read()
        resim = resimulate(path)
        return {'messages': h.hexdigest()[:16],
                'metadata': hashlib.sha256(json.dumps(info, sort_keys=True).encode())
                .hexdigest()[:16],
                'file_head': hashlib.sha256(data[:data.find(b'wall_start_ns')]
                                            ).hexdigest()[:16],
                'resim': {'max_deviation': resim.max_deviation, 'compared': resim.compared,
                          'steps': resim.steps, 'commands': resim.commands}}


if __name__ == '__main__':
    if sys.argv[1:] not in ([], ['--quick']):
        raise SystemExit('usage: python bench/behaviour_hashes.py [--quick]')
    json.dump({'scenes': scene_hashes(), 'log': log_hashes()}, sys.stdout, indent=1,
              sort_keys=True)
    print()
