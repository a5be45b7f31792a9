"""
Test launch/sim.launch.py without the launch packages (they are not on PyPI).

Parsed, it imports launch and launch_ros only (the stand-ins below replace all it uses) and
names one node by literal package, executable and name; run against the stand-ins, it declares
the arguments scene, ns, mode and log_path, starts that one sim_node, and every parameter it
sets is a node parameter (det_sim_ros.ros.params.NODE_PARAMS) or scene_file whose launch
default the node accepts. setup.py installs the file to share/det_sim_ros/launch and the
executable where ``ros2 launch`` looks for it (lib/det_sim_ros).
"""

import ast
import os
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


STAND_IN_MODULES = {'launch', 'launch.actions', 'launch.substitutions', 'launch_ros',
                    'launch_ros.actions', 'launch_ros.parameter_descriptions'}


def _parsed():
    with open(LAUNCH_FILE, encoding='utf-8') as stream:
        return ast.parse(stream.read(), LAUNCH_FILE)


def test_the_parsed_file_imports_launch_only_and_names_one_node_of_this_package():
    tree = _parsed()
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert imported <= STAND_IN_MODULES
    assert not [node for node in ast.walk(tree) if isinstance(node, ast.Import)]
    nodes = [call for call in ast.walk(tree) if isinstance(call, ast.Call)
             and isinstance(call.func, ast.Name) and call.func.id == 'Node']
    assert len(nodes) == 1
    literal = {k.arg: k.value.value for k in nodes[0].keywords
               if isinstance(k.value, ast.Constant)}
    assert literal['package'] == 'det_sim_ros'
    assert literal['executable'] == 'sim_node' and literal['name'] == 'sim_node'


def test_the_executable_is_installed_where_ros2_launch_looks(monkeypatch):
    """``ros2 launch`` runs <prefix>/lib/<package>/<executable>; setup.py puts it there."""
    import setuptools
    captured = {}
    monkeypatch.setattr(setuptools, 'setup', lambda **kwargs: captured.update(kwargs))
    monkeypatch.chdir(ROOT)
    runpy.run_path(os.path.join(ROOT, 'setup.py'))
    installed = dict(captured['data_files'])[os.path.join('lib', 'det_sim_ros')]
    (script,) = [path for path in installed if os.path.basename(path) == 'sim_node']
    with open(os.path.join(ROOT, script), encoding='utf-8') as stream:
        assert 'det_sim_ros.cli.sim_node' in stream.read()   # the node's entry point
    assert 'sim_node = det_sim_ros.cli.sim_node:main' in \
        captured['entry_points']['console_scripts']


def test_the_launch_defaults_are_values_the_node_accepts(description):
    from det_sim_ros.ros.params import node_parameter_values
    from det_sim_ros.scenes.scene import load_scene
    classes, launch = description
    (entities,) = launch.args
    defaults = {e.args[0]: e.kwargs['default_value'] for e in entities
                if isinstance(e, classes['DeclareLaunchArgument'])}
    (node,) = [e for e in entities if isinstance(e, classes['Node'])]
    (parameters,) = node.kwargs['parameters']
    given = {name: defaults[value.args[0].args[0]] for name, value in parameters.items()}
    scene = load_scene(given.pop('scene_file'))
    values = node_parameter_values(scene.node, given)   # raises for one it refuses
    assert values['log.path'] == defaults['log_path']


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
