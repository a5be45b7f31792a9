"""
Test the node's parameter table, its ROS-free helpers, and the choice of pacing object.

The node's parameter table and its ROS-free helpers (det_sim_ros.ros.params), and the choice
of the pacing object from the mode parameters (det_sim_ros.ros.pacing).
"""

import math

from det_sim_ros.ros.pacing import (FreeRunPacing, LockstepPacing, make_pacing,
                                    RealTimePacing)
from det_sim_ros.ros.params import (node_parameter_values, NODE_PARAMS, Param,
                                    runtime_refusal, unknown_parameters)
from det_sim_ros.scenes.scene import SceneError
import pytest


def test_entries_are_named_and_unpack_as_four_tuples():
    for name, param in NODE_PARAMS.items():
        assert isinstance(param, Param), name
        default, description, read_only, bounds = param
        assert (default, description, read_only, bounds) == (
            param.default, param.description, param.read_only, param.bounds)
        assert description and 'issue' not in description.lower(), name


def test_a_p_override_wins_over_the_scene_file_which_wins_over_the_default():
    values = node_parameter_values(
        {'max_lag': 0.1, 'log': {'max_files': 7}, 'steps_per_tick': 2},
        {'max_lag': 0.2, 'node.steps_per_tick': 4, 'real_time_factor': 2})
    assert list(values) == list(NODE_PARAMS)
    assert values['max_lag'] == 0.2                      # -p name:=value
    assert values['steps_per_tick'] == 4                 # -p node.name:=value
    assert values['log.max_files'] == 7                  # the scene's node: section, nested
    assert values['real_time_factor'] == 2.0 and isinstance(values['real_time_factor'], float)
    assert values['info_period'] == NODE_PARAMS['info_period'].default


@pytest.mark.parametrize('scene_node, overrides, message', [
    ({'bogus': 1}, {}, "scene key 'node.bogus': unknown"),
    ({}, {'node.bogus': 1}, "scene key 'node.bogus': unknown"),
    ({'max_lag': 'x'}, {}, 'scene key node.max_lag: must be a number'),
    ({}, {'max_lag': -1.0}, r'parameter max_lag: out of range \[0, 3600\]'),
    ({}, {'log.compression': 'gzip'}, 'parameter log.compression: one of zstd, lz4, none'),
])
def test_unknown_keys_and_unfit_values_are_refused(scene_node, overrides, message):
    with pytest.raises(SceneError, match=message):
        node_parameter_values(scene_node, overrides)


@pytest.mark.parametrize('given, sentence', [
    ('modee', "unknown parameter 'modee' (ignored); did you mean 'mode'?"),
    ('lockstep.timout', "unknown parameter 'lockstep.timout' (ignored); did you mean "
                        "'lockstep.timeout'?"),
    ('log.enable', "unknown parameter 'log.enable' (ignored); did you mean 'log.enabled'?"),
    ('log.maxfiles', "unknown parameter 'log.maxfiles' (ignored); did you mean 'log.max_files'?"),
    ('realtime', "unknown parameter 'realtime' (ignored); did you mean 'real_time'?"),
    ('zzz', "unknown parameter 'zzz' (ignored) (sim_node --help lists them)"),
])
def test_an_unknown_name_is_answered_with_the_closest_known_one(given, sentence):
    known = [*NODE_PARAMS, 'physics.Y', 'scene_file', 'use_sim_time']
    assert unknown_parameters([given, 'mode', 'physics.Y'], known) == [sentence]


@pytest.mark.parametrize('name, value, reason', [
    ('real_time_factor', 2.5, ''),
    ('real_time_factor', 0.0, 'real_time_factor must be > 0 (got 0.0)'),
    ('real_time_factor', math.inf, 'real_time_factor must be > 0 (got inf)'),
    ('steps_per_tick', 0, 'steps_per_tick must be >= 1 (got 0)'),
    ('max_catchup_steps', 3, ''),
    ('lockstep.sources', 0, 'lockstep.sources must be >= 1 (got 0)'),
    ('lockstep.timeout', 0.0, ''),
    ('lockstep.timeout', -0.5, 'lockstep.timeout must be >= 0 s (got -0.5)'),
    ('max_lag', math.nan, 'max_lag must be >= 0 s (got nan)'),
    ('info_period', -1.0, ''),          # read-only: rclpy refuses it before this check
])
def test_runtime_changes_are_checked(name, value, reason):
    assert runtime_refusal(name, value) == reason


def _values(**given):
    values = {name: param.default for name, param in NODE_PARAMS.items()}
    values.update({name.replace('__', '.'): value for name, value in given.items()})
    return values.__getitem__


@pytest.mark.parametrize('given, kind', [
    ({}, RealTimePacing),
    ({'real_time': False}, FreeRunPacing),
    ({'mode': 'free_run'}, FreeRunPacing),
    ({'mode': 'lockstep', 'real_time': True}, LockstepPacing),   # mode wins over its alias
    ({'mode': 'real_time', 'real_time': False}, RealTimePacing),
])
def test_the_pacing_is_chosen_once_from_mode_or_its_alias(given, kind):
    pacing = make_pacing(_values(**given))
    assert type(pacing) is kind and pacing.node is None


def test_an_unknown_mode_is_refused():
    with pytest.raises(SceneError, match="parameter 'mode': one of real_time, free_run, "
                                         "lockstep \\(got 'fast'\\)"):
        make_pacing(_values(mode='fast'))


def test_each_pacing_reads_its_own_parameters():
    get = _values(real_time_factor=4.0, max_lag=0.2, steps_per_tick=3,
                  lockstep__sources=2, lockstep__timeout=0.5)
    real_time = RealTimePacing(get)
    assert (real_time.real_time_factor, real_time.max_lag, real_time.label()) == (
        4.0, 0.2, 'real-time x4')
    assert FreeRunPacing(get).steps_per_tick == 3
    lockstep = LockstepPacing(get)
    assert (lockstep.sources, lockstep.timeout, lockstep.label()) == (2, 0.5, 'lockstep')
    assert not real_time.publishes_clock and lockstep.publishes_clock
