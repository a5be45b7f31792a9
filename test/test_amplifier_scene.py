"""
The scene's amplifier section: defaults off, per-DET overrides, one-line refusals.

The refusals come before any preparation; the keys are among the node's read-only scene
parameters.
"""

from det_sim_ros.ros.params import scene_parameters
from det_sim_ros.scenes.amplifier import Amplifier
from det_sim_ros.scenes.scene import load_scene, scene_to_dict, SceneError
import pytest

KNOBS = ('slew_rate', 'current_limit', 'bandwidth', 'dac_bits', 'delay', 'offset')


def _refusal(overrides, source='default'):
    with pytest.raises(SceneError) as caught:
        load_scene(source, overrides)
    message = str(caught.value)
    assert '\n' not in message
    return message


def test_every_knob_is_off_by_default_and_absent_from_the_stored_scene():
    scene = load_scene('default')
    assert scene.cell_amplifiers() == (Amplifier(),)
    assert not scene.amplified
    assert 'amplifier' not in scene_to_dict(scene)   # logs of ideal scenes keep their bytes


def test_the_section_applies_to_every_det_and_dets_override_it():
    scene = load_scene('plate', {'amplifier.slew_rate': 1.0e6, 'amplifier.delay': 0.002,
                                 'dets.right.slew_rate': 2.0e6, 'dets.right.dac_bits': 12})
    left, right = scene.cell_amplifiers()
    assert (left.slew_rate, left.delay, left.dac_bits) == (1.0e6, 0.002, 0)
    assert (right.slew_rate, right.delay, right.dac_bits) == (2.0e6, 0.002, 12)
    assert scene.cell_physics()[1].Rs == 2.0e3          # physics overrides unaffected
    again = load_scene(scene_to_dict(scene))
    assert again.cell_amplifiers() == scene.cell_amplifiers()


@pytest.mark.parametrize('key', ['slew_rate', 'current_limit', 'bandwidth', 'delay',
                                 'dac_bits'])
def test_a_negative_knob_is_refused_in_one_line(key):
    assert f"'amplifier.{key}'" in _refusal({f'amplifier.{key}': -1})
    assert f"'dets.det0.{key}'" in _refusal({f'dets.det0.{key}': -1})


def test_a_delay_that_is_not_whole_periods_is_refused():
    message = _refusal({'amplifier.delay': 0.0025})
    assert 'whole number of control periods' in message and '2.5 periods' in message
    assert load_scene('default', {'amplifier.delay': 0.003}).cell_amplifiers()[0] \
        .delay_periods(1e-3) == 3


def test_a_current_limit_below_the_leakage_current_is_refused():
    # default scene: v_max / Rp = 3000 V / 1e10 Ohm = 3e-7 A
    assert 'leakage current' in _refusal({'amplifier.current_limit': 3.0e-7})
    load_scene('default', {'amplifier.current_limit': 3.1e-7})


def test_circuit_knobs_need_the_rc_circuit_and_unknown_keys_are_named():
    assert "scene.source 'rc'" in _refusal({'amplifier.bandwidth': 1.0e3,
                                            'scene.source': 'ideal'})
    load_scene('default', {'amplifier.dac_bits': 12, 'scene.source': 'ideal'})
    assert "'gain'" in _refusal({'amplifier.gain': 2.0})


def test_the_knobs_are_scene_parameters_of_the_node_also_when_off():
    for overrides in ({}, {'amplifier.offset': 5.0}):
        names = dict(scene_parameters(load_scene('default', overrides)))
        assert all(f'amplifier.{key}' in names for key in KNOBS)
    assert dict(scene_parameters(load_scene('default')))['amplifier.dac_bits'] == 0


@pytest.mark.parametrize('name', ['amplifier_lab', 'amplifier_dcdc'])
def test_the_presets_are_the_default_scene_with_an_amplifier(name):
    scene = load_scene(name)
    default = load_scene('default')
    assert scene.physics == default.physics and scene.structure == default.structure
    amp, = scene.cell_amplifiers()
    assert amp.acts_in_circuit and amp.acts_on_command and amp.current_limit > 0.0


def test_the_bench_rig_is_the_laser_sensor_and_the_lab_amplifier_on_the_default():
    rig, default = load_scene('bench_rig'), load_scene('default')
    assert rig.physics == default.physics and rig.fidelity == default.fidelity
    assert rig.amplifier == load_scene('amplifier_lab').amplifier
    assert rig.sensors == load_scene('sensor_laser').sensors != default.sensors
