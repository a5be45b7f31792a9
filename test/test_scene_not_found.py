"""
An unknown scene name is one line that lists the scenes found and the folders searched.

The same line reaches the user of load_scene, of ``det_sim --scene`` and of sim_node's
``scene_file``.
"""

import os
import re

from det_sim_ros.cli import main as det_sim
from det_sim_ros.ros.node import main as sim_node
from det_sim_ros.scenes.scene import find_config, load_scene, SceneError
import pytest

# the folder the shipped scenes are found in: the install's share folder, or the source tree's
SHIPPED = os.path.dirname(find_config('default'))


def _check_line(line):
    """Check one line: the name, the scenes found (no fleet file) and their folder."""
    assert "'plates' not found" in line, line
    listed = re.search(r'scenes: ([\w, ]+) \(looked in ', line)
    assert listed is not None, line
    names = set(listed.group(1).split(', '))
    assert {'array', 'default', 'plate'} <= names and 'fleet' not in names, line
    looked_in = line.split('looked in ')[1].split(',')
    assert os.path.realpath(SHIPPED) in {os.path.realpath(p.strip(' ()')) for p in looked_in}


def test_load_scene_lists_the_scenes_and_where_it_looked():
    with pytest.raises(SceneError) as caught:
        load_scene('plates')
    assert '\n' not in str(caught.value)
    _check_line(str(caught.value))


def test_det_sim_says_it_in_one_line(tmp_path, capsys):
    assert det_sim(['step', '--scene', 'plates', '--out', str(tmp_path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    _check_line(lines[0])


@pytest.mark.ros
def test_sim_node_says_it_in_one_fatal_line(capfd):
    code = sim_node(['sim_node', '--ros-args', '-p', 'scene_file:=plates',
                     '-p', 'log.enabled:=false'])
    out, err = capfd.readouterr()
    lines = [line for line in (out + err).splitlines() if line.strip()]
    assert code == 1 and len(lines) == 1 and 'cannot start' in lines[0], lines
    _check_line(lines[0])


def test_a_scene_file_that_is_not_text_is_one_line(tmp_path):
    """Check that a binary scene file is refused with a SceneError naming the file."""
    path = tmp_path / 'random.yaml'
    path.write_bytes(bytes(range(128, 256)) * 4)
    with pytest.raises(SceneError, match='not UTF-8 text'):
        load_scene(str(path))
