"""
Scene values checked against their keys' entries (det_sim_ros/scenes/keys.py).

Every ranged scene key refuses a value just above its maximum, naming the key; a number that
YAML 1.1 reads as text ('4.0e9') in a mapping is refused with the fix, and the same text as an
override is the number.
"""

from det_sim_ros.scenes.scene import load_scene, SceneError
import numpy as np
import pytest

# the paper's one-term model: the level is not the subject here
PAPER = {'scene.fidelity': 'paper'}


def _ranged_scene_keys():
    from det_sim_ros.scenes import keys
    sections = dict(keys.SECTIONS, structure=keys.STRUCTURE_SPEC, **{'': keys.TOP_SPEC})
    for section, spec in sections.items():
        for key, entry in spec.items():
            if entry[0] in ('int', 'float') and np.isfinite(entry[3]):
                yield (f'{section}.{key}' if section else key), entry


RANGED_SCENE_KEYS = dict(_ranged_scene_keys())


@pytest.mark.parametrize('key', sorted(RANGED_SCENE_KEYS))
def test_a_scene_value_just_above_its_maximum_is_refused(key):
    kind, upper = RANGED_SCENE_KEYS[key][0], RANGED_SCENE_KEYS[key][3]
    above = upper + 1 if kind == 'int' else upper * (1.0 + 1e-9) + 1e-12
    base = {'structure.type': 'array'} if key.startswith('structure.') else {}
    with pytest.raises(SceneError, match=f"{key}'.*out of range"):
        load_scene('default', {**PAPER, **base, key: above})


@pytest.mark.parametrize('text', ['4.0e9', '4e9'])
def test_yaml_11_exponent_text_in_a_mapping_is_refused_with_the_fix(text):
    """
    Check that YAML 1.1 exponent text in a mapping is refused with the fix.

    A mapping (as a parsed YAML 1.1 file gives it) holding '4.0e9' as text: refused, with the
    advice to write the exponent's sign; the same text as an override is a number.
    """
    from det_sim_ros.scenes.scene import scene_to_dict
    data = scene_to_dict(load_scene('default', PAPER))
    data['physics']['E_b'] = text
    with pytest.raises(SceneError, match=r"physics.E_b'.*YAML 1.1.*4.0e\+9"):
        load_scene(data)
    assert load_scene('default', {**PAPER, 'physics.E_b': text}).physics.E_b == 4.0e9
