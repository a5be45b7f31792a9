"""
Scene files that name only what they change, on top of the defaults or of a ``base:`` scene.

A partial file loads as the shipped defaults (or its base) with its keys laid over them; bad
keys, bad values, a missing base and a base cycle are refused with one line; full files load
exactly as before; a log recorded from an inheriting scene holds the resolved scene and
re-simulates bit for bit.
"""

import textwrap

from det_sim_ros.io.log import logged_scene, LogReader, Recorder
from det_sim_ros.io.replay import resimulate, simulate_to_log
from det_sim_ros.scenes.scene import find_config, load_scene, scene_to_dict, SceneError
from det_sim_ros.sim.simulator import Simulator
import pytest
import yaml


def _write(folder, name, body):
    path = folder / name
    path.write_text(textwrap.dedent(body))
    return path


def _refusal(source):
    with pytest.raises(SceneError) as caught:
        load_scene(source)
    message = str(caught.value)
    assert '\n' not in message
    return message


def test_a_file_that_names_two_keys_is_the_defaults_with_those_two(tmp_path):
    path = _write(tmp_path, 'soft.yaml', """\
        sim_node:
          ros__parameters:
            scene:
              beam: simply_supported
              eps_b: 0.15
        """)
    expected = load_scene('default', {'scene.beam': 'simply_supported', 'scene.eps_b': 0.15})
    assert load_scene(str(path)) == expected


def test_the_fidelity_is_inherited_and_paper_is_one_term(tmp_path):
    """Check a file without a level gets the default's; one that picks 'paper' gets one term."""
    default = load_scene('default')
    plain = load_scene(str(_write(tmp_path, 'plain.yaml', 'scene: {eps_b: 0.15}\n')))
    assert (plain.fidelity, plain.ritz_level) == (default.fidelity, default.ritz_level) == (
        'exact', ('buckling_modes', 3))
    paper = load_scene(str(_write(tmp_path, 'paper.yaml', 'scene: {fidelity: paper}\n')))
    assert (paper.fidelity, paper.n_ritz, paper.ritz_level) == ('paper', 1, ('polynomial', 1))
    assert load_scene('default', {'scene.fidelity': 'paper', 'scene.n_ritz': 7}).n_ritz == 1
    exact = load_scene(str(_write(tmp_path, 'exact.yaml', 'scene: {n_ritz: 3}\n')))
    assert (exact.fidelity, exact.n_ritz) == ('exact', 3)


def test_a_bare_mapping_file_and_overrides_inherit_too(tmp_path):
    path = _write(tmp_path, 'fast.yaml', """\
        physics: {Rs: 1.0e+3}
        rate_hz: 500.0
        """)
    scene = load_scene(str(path), {'scene.creep': False})
    assert (scene.physics.Rs, scene.rate_hz, scene.creep) == (1.0e3, 500.0, False)
    assert scene.physics.Y == load_scene('default').physics.Y


def test_a_base_by_name_merges_sections_key_by_key(tmp_path):
    path = _write(tmp_path, 'wide_plate.yaml', """\
        base: plate
        structure: {plate_width: 0.08}
        dets:
          left: {Rs: 1.0e+3}
        """)
    scene = load_scene(str(path))
    plate = load_scene('plate')
    assert scene.structure['plate_width'] == 0.08
    assert scene.structure['plate_mass'] == plate.structure['plate_mass']
    assert scene.det_names == ('left', 'right')
    assert scene.dets == {'left': {'Rs': 1.0e3}, 'right': dict(plate.dets['right'])}


def test_a_base_path_is_relative_to_the_file_and_bases_chain(tmp_path):
    (tmp_path / 'lab').mkdir()
    _write(tmp_path, 'lab/common.yaml', 'scene: {beam: simply_supported}\n')
    _write(tmp_path, 'lab/thick.yaml', 'base: common.yaml\nphysics: {t_b: 3.0e-4}\n')
    path = _write(tmp_path, 'run.yaml', 'base: lab/thick.yaml\nscene: {eps_b: 0.25}\n')
    scene = load_scene(str(path))
    assert (scene.beam, scene.physics.t_b, scene.eps_b) == ('simply_supported', 3.0e-4, 0.25)


def test_an_empty_section_changes_nothing(tmp_path):
    path = _write(tmp_path, 'same.yaml', 'scene:\nphysics:\n')
    assert load_scene(str(path)) == load_scene('default')


@pytest.mark.parametrize('body, fragment', [
    ('scene: {beam: fixed, colour: red}\n', "unknown scene key scene.'colour'"),
    ('physics: {Rs: -5.0}\n', "'physics.Rs': out of range"),
    ('integrator: {tolerance: fine}\n', "'integrator.tolerance'"),
    ('base: no_such_scene\n', "base 'no_such_scene' not found"),
    ('base: ../nowhere.yaml\n', "base '../nowhere.yaml' not found"),
    ('base: 5\n', "'base' must be a scene name or a path"),
])
def test_bad_keys_values_and_bases_are_one_line(tmp_path, body, fragment):
    message = _refusal(str(_write(tmp_path, 'bad.yaml', body)))
    assert fragment in message, message


def test_a_base_cycle_is_one_line(tmp_path):
    _write(tmp_path, 'a.yaml', 'base: b.yaml\n')
    _write(tmp_path, 'b.yaml', 'base: a.yaml\nscene: {eps_b: 0.1}\n')
    assert 'base cycle a.yaml -> b.yaml -> a.yaml' in _refusal(str(tmp_path / 'a.yaml'))
    _write(tmp_path, 'self.yaml', 'base: self.yaml\n')
    assert 'base cycle self.yaml -> self.yaml' in _refusal(str(tmp_path / 'self.yaml'))


def test_a_mapping_without_base_must_be_complete():
    """A mapping (the scene a log stores) takes no defaults: a missing key is refused."""
    data = scene_to_dict(load_scene('default'))
    del data['scene']['fidelity']
    assert "scene key scene.'fidelity': missing" in _refusal(data)
    assert load_scene({'base': 'default', 'scene': {'eps_b': 0.1}}).eps_b == 0.1


@pytest.mark.parametrize('name', ['default', 'plate', 'array'])
def test_full_files_load_as_their_own_content(name):
    """The shipped scenes are complete: laid over the defaults they are what they hold."""
    with open(find_config(name), encoding='utf-8') as stream:
        content = yaml.safe_load(stream)
    assert load_scene(name) == load_scene(content)


def test_a_log_of_an_inheriting_scene_holds_the_resolved_scene(tmp_path):
    path = _write(tmp_path, 'soft.yaml', 'scene: {beam: simply_supported, eps_b: 0.15}\n')
    scene = load_scene(str(path))
    sim = Simulator(scene)
    log = str(tmp_path / 'run.mcap')
    recorder = Recorder(log, scene, metadata={'method': sim.method.name,
                                              'substeps': sim.substeps_setting})
    simulate_to_log(recorder, sim, lambda k: [2000.0] if k == 5 else None, 200)
    recorder.close()
    stored = yaml.safe_load(LogReader(log).scene_yaml)['sim_node']['ros__parameters']
    assert 'base' not in stored and {'scene', 'physics', 'integrator', 'rate_hz'} <= set(stored)
    assert load_scene(stored) == logged_scene(scene)   # its tolerance as resolved
    result = resimulate(log)
    assert result.steps == 200 and result.ok(tolerance=0.0), result.table()


@pytest.mark.ros
def test_the_node_logs_the_resolved_scene_of_an_inheriting_file(tmp_path, harness):
    path = _write(tmp_path, 'soft.yaml', 'scene: {beam: simply_supported, eps_b: 0.15}\n')
    h = harness(scene_file=str(path), **{'log.path': str(tmp_path / 'logs'),
                                         'scene.fidelity': None})
    assert h.node.scene == load_scene(str(path))
    # the default's level, inherited (auto: 7 polynomial terms on a simply supported beam)
    assert h.node.scene.fidelity_label == 'exact n_r=7'
    recorder = h.node.recorder
    h.command([2000.0])
    h.spin_until_sim_time(h.node.simulator.t + 0.05)
    h.close()
    stored = yaml.safe_load(LogReader(recorder.paths[0]).scene_yaml)
    assert load_scene(stored) == logged_scene(load_scene(str(path)))
    result = resimulate(recorder.paths[0])
    assert result.commands == 1 and result.ok(tolerance=0.0), result.table()
