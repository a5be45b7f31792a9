"""
Test launch/sim.launch.py without the launch packages (they are not on PyPI).

The file compiles; run against stand-ins of launch and launch_ros, it declares the arguments
scene, ns, mode and log_path, starts one sim_node of this package, and every parameter it sets
is a node parameter (det_sim_ros.ros.params.NODE_PARAMS) or scene_file. setup.py installs it
to share/det_sim_ros/launch.
"""

import os
import py_compile
import runpy
import sys
import types

from det_sim_ros.ros.params import NODE_PARAMS
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LAUNCH_FILE = os.path.join(ROOT, 'launch', 'sim.launch.py')


class _Recorded:
    """A stand-in for a launch class: keeps its arguments."""

    def __init__(self, *args, **kwargs):
        self.args = args
        self.kwargs = kwargs


def _stand_ins(monkeypatch):
    """Install launch and launch_ros stand-ins; return the class of each name."""
    names = {'launch': ['LaunchDescription'], 'launch.actions': ['DeclareLaunchArgument'],
             'launch.substitutions': ['LaunchConfiguration'],
             'launch_ros': [], 'launch_ros.actions': ['Node'],
             'launch_ros.parameter_descriptions': ['ParameterValue']}
    classes = {}
    for module_name, class_names in names.items():
        module = types.ModuleType(module_name)
        for name in class_names:
            classes[name] = type(name, (_Recorded,), {})
            setattr(module, name, classes[name])
        monkeypatch.setitem(sys.modules, module_name, module)
    return classes


@pytest.fixture
def description(monkeypatch):
    classes = _stand_ins(monkeypatch)
    namespace = runpy.run_path(LAUNCH_FILE)
    return classes, namespace['generate_launch_description']()


def test_the_launch_file_compiles(tmp_path):
    py_compile.compile(LAUNCH_FILE, cfile=str(tmp_path / 'sim.launch.pyc'), doraise=True)


def test_the_launch_arguments(description):
    classes, launch = description
    (entities,) = launch.args
    declared = {e.args[0]: e.kwargs for e in entities
                if isinstance(e, classes['DeclareLaunchArgument'])}
    assert set(declared) == {'scene', 'ns', 'mode', 'log_path'}
    assert declared['scene']['default_value'] == 'default'
    assert declared['mode']['default_value'] == NODE_PARAMS['mode'].default
    assert declared['log_path']['default_value'] == NODE_PARAMS['log.path'].default


def test_every_parameter_is_a_node_parameter(description):
    classes, launch = description
    (entities,) = launch.args
    (node,) = [e for e in entities if isinstance(e, classes['Node'])]
    assert node.kwargs['package'] == 'det_sim_ros' and node.kwargs['executable'] == 'sim_node'
    assert node.kwargs['namespace'].args == ('ns',)
    (parameters,) = node.kwargs['parameters']
    assert parameters and set(parameters) <= set(NODE_PARAMS) | {'scene_file'}
    for value in parameters.values():   # strings stay strings (not read as YAML)
        assert value.kwargs['value_type'] is str
        assert isinstance(value.args[0], classes['LaunchConfiguration'])
    arguments = {value.args[0].args[0] for value in parameters.values()}
    assert arguments == {'scene', 'mode', 'log_path'}


def test_setup_installs_the_launch_file(monkeypatch):
    import setuptools
    captured = {}
    monkeypatch.setattr(setuptools, 'setup', lambda **kwargs: captured.update(kwargs))
    monkeypatch.chdir(ROOT)
    runpy.run_path(os.path.join(ROOT, 'setup.py'))
    data_files = dict(captured['data_files'])
    assert data_files[os.path.join('share', 'det_sim_ros', 'launch')] == [
        os.path.join('launch', 'sim.launch.py')]
