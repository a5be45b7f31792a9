"""
Checks against something independent of the code they check: a re-simulation that starts from
a logged initial state other than the scene's, the steppers' orders against scipy's DOP853,
the rest state against scipy's root finder on the compiled right-hand side, and scene values
that YAML 1.1 reads as strings.
"""

import numpy as np
import pytest

from det_sim_ros.io import replay
from det_sim_ros.io.mcap_log import Recorder
from det_sim_ros.scenes.scene import load_scene, SceneError
from det_sim_ros.sim.simulator import Simulator

COMMANDS = {0: [0.0], 40: [2500.0], 90: [1200.0]}
N_STEPS = 150


def _record_from(tmp_path, x0):
    """A run of the default scene started from ``x0``, logged as the node logs it."""
    sim = Simulator(load_scene('default'))
    sim.x0 = np.array(x0, dtype=float)
    sim.reset()
    path = tmp_path / 'moved_start.mcap'
    with Recorder(path, sim.scene, metadata={'method': sim.method.name,
                                             'substeps': sim.substeps_setting,
                                             'x0': repr(sim.x0.tolist())}) as recorder:
        replay.simulate_to_log(recorder, sim, COMMANDS, N_STEPS)
    return str(path)


def _moved_start():
    """The scene's initial state with the deflection, its rate and the charge moved."""
    sim = Simulator(load_scene('default'))
    scene_x0 = sim.x0
    x0 = scene_x0.copy()
    names = sim.model.state_names
    x0[names.index('q[0]')] *= 0.8          # deflection: 80 % of the rest value, m
    x0[names.index('q_dot[0]')] = 0.3       # m/s
    assert not np.array_equal(x0, scene_x0)
    return x0


def test_resimulation_starts_from_the_logged_initial_state(tmp_path):
    path = _record_from(tmp_path, _moved_start())
    result = replay.resimulate(path)
    assert result.ok(), result.table()
    assert result.steps == N_STEPS and result.commands == len(COMMANDS)
    assert all(v == 0.0 for v in result.max_deviation.values()), result.table()


def test_ignoring_the_logged_initial_state_would_be_seen(tmp_path, monkeypatch):
    """The check above can fail: the same log re-simulated from the scene's own initial
    state deviates."""
    path = _record_from(tmp_path, _moved_start())
    monkeypatch.setattr(replay, '_logged_x0', lambda text, n: None)
    result = replay.resimulate(path)
    assert max(result.max_deviation.values()) > 0.0
    assert not result.ok()
