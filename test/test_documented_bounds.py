"""
Test every finite scene-key and node-parameter bound against a table written by hand.

The bounds users are told (docs/parameters.md, the scene keys' and parameters' reference), copied
here by hand rather than read from det_sim_ros.scenes.keys or det_sim_ros.ros.params: a bound
removed from the code (and so from the generated page and from the tests that walk the code's
own tables) still fails here. A new finite bound must be added to the table (the last test).
"""

import math

from det_sim_ros.ros.params import check_node_value, NODE_PARAMS
from det_sim_ros.scenes import keys
from det_sim_ros.scenes.scene import load_scene, SceneError
from det_sim_ros.scenes.sensors import SEED_SPEC, SENSOR_SPEC
import pytest

# key: (lowest allowed, whether it is allowed itself, highest allowed)
SCENE_BOUNDS = {
    'scene.eps_b': (-1.0, False, 2.0),
    'scene.n_ritz': (0, True, 12),                # 0 = auto
    'physics.n': (1, True, 10000),
    'integrator.tolerance': (0.0, True, 0.1),     # 0 = auto
    'integrator.substeps': (0, True, 100000),
    'structure.copies': (1, True, 100000),
    'structure.spread': (0.0, True, 0.3),
    'structure.seed': (0, True, 2 ** 31 - 1),
    'amplifier.dac_bits': (0, True, 32),
    'amplifier.delay': (0.0, True, 3600.0),
    'rate_hz': (0.0, False, 1.0e6),
    'sensors.seed': (0, True, 2 ** 63 - 1),
    'sensors.displacement.delay_samples': (0, True, 100000),
    'sensors.displacement.dropout': (0.0, True, 1.0),
}
# node parameter: (lowest, highest), both allowed
NODE_BOUNDS = {
    'lockstep.sources': (1, 10000),
    'lockstep.timeout': (0.0, 3600.0),
    'real_time_factor': (0.001, 1000.0),
    'steps_per_tick': (1, 100000),
    'threads': (1, 256),
    'max_catchup_steps': (1, 1000000),
    'max_lag': (0.0, 3600.0),
    'realtime_priority': (0, 98),
    'diagnostics_period': (0.01, 3600.0),
    'log.split_mb': (0.0, 1.0e6),
    'log.max_mb': (0.0, 1.0e9),
    'log.max_files': (0, 1000000),
    'info_period': (0.0, 3600.0),
    'markers.rate_hz': (0.0, 1.0e4),
    'live.port': (0, 65535),
    'live.rate_hz': (0.0, 1.0e6),
    'wait_for_subscribers': (0, 10000),
    'predictability.relative': (-0.5, 0.5),
    'predictability.tolerance_factor': (0.01, 100.0),
    'predictability.limit': (1.0e-6, 10.0),
}
PAPER = {'scene.fidelity': 'paper'}


def _scene(key, value):
    """Load the default scene with ``key`` at ``value`` (an array for the structure's keys)."""
    base = {'structure.type': 'array'} if key.startswith('structure.') else {}
    return load_scene('default', {**PAPER, **base, key: value})


def _beyond(value, direction):
    """Return a value just beyond ``value`` (direction +1: above, -1: below)."""
    if isinstance(value, int):
        return value + direction
    return value + direction * (abs(value) * 1e-9 + 1e-12)


@pytest.mark.parametrize('key', sorted(SCENE_BOUNDS))
def test_a_scene_value_beyond_its_documented_range_is_refused(key):
    low, low_allowed, high = SCENE_BOUNDS[key]
    with pytest.raises(SceneError, match=f"{key}'.*out of range"):
        _scene(key, _beyond(high, +1))
    with pytest.raises(SceneError, match=f"{key}'.*out of range"):
        _scene(key, low if not low_allowed else _beyond(low, -1))


@pytest.mark.parametrize('name', sorted(NODE_BOUNDS))
def test_a_node_parameter_beyond_its_documented_range_is_refused(name):
    low, high = NODE_BOUNDS[name]
    for value in (low, high):
        assert check_node_value(name, value) == value
    for value in (_beyond(high, +1), _beyond(low, -1)):
        with pytest.raises(SceneError, match=f'{name}: out of range'):
            check_node_value(name, value)


def _finite_scene_bounds():
    sections = dict(keys.SECTIONS, structure=keys.STRUCTURE_SPEC, amplifier=keys.AMPLIFIER_SPEC,
                    **{'sensors.displacement': SENSOR_SPEC, '': keys.TOP_SPEC})
    found = {'sensors.seed'} if math.isfinite(SEED_SPEC[3]) else set()
    for section, spec in sections.items():
        for key, entry in spec.items():
            if entry[0] in ('int', 'float') and math.isfinite(entry[3]):
                found.add(f'{section}.{key}' if section else key)
    return found


def test_every_finite_bound_in_the_code_is_in_the_hand_written_tables():
    assert _finite_scene_bounds() <= set(SCENE_BOUNDS)
    ranged = {name for name, (default, _, _, bounds) in NODE_PARAMS.items()
              if bounds is not None and not isinstance(default, (str, bool))}
    assert ranged <= set(NODE_BOUNDS), ranged - set(NODE_BOUNDS)
