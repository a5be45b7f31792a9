"""
One-line answers that read plainly: a ROS rule without ``:=``, dimensionless keys, zero at rest.

rcl refuses ``-p mode=free_run`` with an error about lexeme types: sim_node and ``det_sim replay
play`` answer first, naming ``:=``. A dimensionless scene key's message has no unit ('-'). The
node's INFO line shows the rest state's round-off (-4e-8 mm) as 0.000, never -0.000.
"""

from det_sim_ros.cli.det_sim import main as det_sim
from det_sim_ros.cli.ros_args import ros_rule_error
from det_sim_ros.cli.sim_node import main as sim_node
from det_sim_ros.ros.diagnostics import status_line
from det_sim_ros.scenes.scene import load_scene, SceneError
import numpy as np
import pytest


@pytest.mark.parametrize('rule, line', [
    (['-p', 'mode=free_run'],
     "-p mode=free_run: a parameter is -p NAME:=VALUE, with ':=' (-p mode:=free_run)"),
    (['--param', 'log.enabled'],
     "--param log.enabled: a parameter is --param NAME:=VALUE, with ':='"),
    (['-r', '__ns=/arm1'], "-r __ns=/arm1: a remap is -r FROM:=TO, with ':=' (-r __ns:=/arm1)"),
    (['-p'], '-p needs a rule after it: a parameter is -p NAME:=VALUE'),
])
def test_sim_node_names_the_colon_equals_a_rule_lacks(capsys, rule, line):
    """Check one line and exit code 1, before rcl starts (the ros mark's guard would refuse)."""
    assert sim_node(['sim_node', '--ros-args', '-p', 'real_time:=false', *rule]) == 1
    captured = capsys.readouterr()
    assert captured.err == f'sim_node: {line}\n' and not captured.out


def test_det_sim_replay_play_names_it_too(tmp_path, capsys):
    """Check the player's ROS arguments: one line, exit code 2 (bad input), before the log."""
    argv = ['replay', 'play', str(tmp_path / 'run.mcap'), '--ros-args', '-p',
            'use_sim_time=true']
    assert det_sim(argv) == 2
    assert capsys.readouterr().err == (
        "det_sim: error: -p use_sim_time=true: a parameter is -p NAME:=VALUE, with ':=' "
        '(-p use_sim_time:=true)\n')


@pytest.mark.parametrize('argv', [
    ['--ros-args', '-p', 'mode:=free_run', '-r', '__ns:=/arm1', '--params-file', 'a.yaml'],
    ['--ros-args', '--log-level', 'debug', '--', '-p', 'not=ros'],   # after --: not rcl's
    ['-p', 'x=1'],                     # outside --ros-args: sim_node refuses it as stray
    [],
])
def test_well_formed_rules_pass(argv):
    assert ros_rule_error(argv) == ''


@pytest.mark.parametrize('key, value, message', [
    ('scene.eps_b', 'abc', "scene key 'scene.eps_b': must be a number, not a string (got 'abc')"),
    ('scene.eps_b', 5.0, "scene key 'scene.eps_b': out of range (-1, 2] (got 5.0)"),
    ('scene.n_ritz', 99, "scene key 'scene.n_ritz': out of range [0, 12] (got 99)"),
    ('physics.Rs', 'abc', "scene key 'physics.Rs': must be a number in Ohm, not a string "
     "(got 'abc')"),
])
def test_a_dimensionless_key_says_no_unit(key, value, message):
    with pytest.raises(SceneError) as caught:
        load_scene('default', {key: value})
    assert str(caught.value) == message


@pytest.mark.parametrize('dy_mm, shown', [
    ([-4e-8], 'dy=0.000 mm'),                          # the rest state's round-off
    ([-4e-8, -1.25], 'dy=[0.000, -1.250] mm'),         # a real negative value keeps its sign
    ([-4e-8, -1e-9, -3e-7, -2e-8, -5e-10], 'dy=0.000..0.000 mm'),   # more than four DETs
])
def test_the_info_line_never_shows_minus_zero(dy_mm, shown):
    dy = np.array(dy_mm)
    line = status_line(t=1.0, volts=np.zeros(len(dy)), q_mm=-np.abs(dy) * 1e-3, dy_mm=dy,
                       rtf=1.0, window_s=1.0, state='running')
    assert shown in line and '-0.000' not in line, line
