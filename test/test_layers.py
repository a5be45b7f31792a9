"""
The package's layers, checked on every module's imports.

The imports are read from the source with ast (top-level and inside functions, nothing
imported): each layer imports only the layers below it, no module imports rclpy below the ros
layer, and no two modules import each other, directly or round a loop.
"""

import ast
import os
import subprocess
import sys

import det_sim_ros
import pytest

PACKAGE_DIR = os.path.dirname(det_sim_ros.__file__)
# rank of each layer: a module may import its own layer and any layer of a lower rank
LAYERS = {'core': 0, 'scenes': 0, 'physics': 1, 'sim': 2, 'analysis': 3, 'io': 3,
          'calibration': 3.5, 'ros': 4, 'cli': 5}
ROOT_MODULES = {'det_sim_ros'}   # the package's own plumbing
ROS_ONLY = ('rclpy',)


def _modules():
    for folder, _, files in os.walk(PACKAGE_DIR):
        for name in files:
            if name.endswith('.py'):
                path = os.path.join(folder, name)
                rel = os.path.relpath(path, os.path.dirname(PACKAGE_DIR))[:-3].replace(os.sep, '.')
                yield rel.removesuffix('.__init__'), path


def _imports(module, path):
    """Yield (imported absolute name, line) for every import statement in the file."""
    tree = ast.parse(open(path, encoding='utf-8').read(), path)
    package = module if path.endswith('__init__.py') else module.rpartition('.')[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')
                base = base[:len(base) - node.level + 1]
                stem = '.'.join(base + ([node.module] if node.module else []))
            else:
                stem = node.module
            for alias in node.names:   # a module, or a name in one (resolved by the caller)
                yield f'{stem}.{alias.name}', node.lineno


def _layer(module):
    parts = module.split('.')
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def _graph():
    modules = dict(_modules())
    edges = {}
    for module, path in modules.items():
        found = []
        for name, line in _imports(module, path):
            target = name
            while target and target not in modules:   # from pkg.mod import function
                target = target.rpartition('.')[0]
            found.append((name, target or None, line))
        edges[module] = found
    return modules, edges


def test_every_module_sits_in_a_layer():
    modules, _ = _graph()
    stray = sorted(m for m in modules if _layer(m) is None and m not in ROOT_MODULES)
    assert not stray, f'modules outside the layer subpackages: {stray}'


def test_imports_point_down_only():
    _, edges = _graph()
    wrong = []
    for module, found in edges.items():
        mine = _layer(module)
        for name, target, line in found:
            if mine is None or target is None or not target.startswith('det_sim_ros'):
                continue
            theirs = _layer(target)
            if theirs is None:
                if target not in ('det_sim_ros',):   # __version__ from the root
                    wrong.append(f'{module}:{line} imports {target} (outside the layers)')
            elif theirs != mine and LAYERS[theirs] >= LAYERS[mine]:
                wrong.append(f'{module}:{line} ({mine}) imports {target} ({theirs})')
    assert not wrong, 'imports that do not point down:\n' + '\n'.join(wrong)


def test_rclpy_only_in_the_ros_layer_and_above():
    _, edges = _graph()
    wrong = [f'{module}:{line} imports {name}'
             for module, found in edges.items()
             if _layer(module) not in ('ros', 'cli')
             for name, _, line in found if name.split('.')[0] in ROS_ONLY]
    assert not wrong, 'rclpy below the ros layer:\n' + '\n'.join(wrong)


def test_no_import_cycles():
    _, edges = _graph()
    graph = {m: {t for _, t, _ in found if t and t != m and t.startswith('det_sim_ros.')
                 and t not in ROOT_MODULES}
             for m, found in edges.items()}
    state, cycles = {}, []

    def visit(node, trail):
        state[node] = 'open'
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 'open':
                cycles.append(' -> '.join(trail[trail.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, trail + [nxt])
        state[node] = 'done'

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not cycles, 'import cycles:\n' + '\n'.join(cycles)


def test_the_layer_check_sees_a_planted_upward_import(tmp_path):
    """
    Check that the layer check sees a planted upward import.

    The checks above read what they claim to: an upward import in a copy of a module is found
    by the same functions.
    """
    path = os.path.join(PACKAGE_DIR, 'physics', 'shapes.py')
    planted = tmp_path / 'shapes.py'
    planted.write_text(open(path, encoding='utf-8').read()
                       + '\n\ndef _f():\n    from ..ros import node  # noqa\n')
    found = [t for t, _ in _imports('det_sim_ros.physics.shapes', str(planted))]
    assert 'det_sim_ros.ros.node' in found


@pytest.mark.ros
def test_importing_the_package_has_no_side_effects():
    """Check that ``import det_sim_ros`` is cheap and inert: no signal handlers, rclpy, numpy."""
    code = ('import signal, sys\n'
            'before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}\n'
            'import det_sim_ros\n'
            'after = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}\n'
            'assert before == after, (before, after)\n'
            'heavy = [m for m in ("rclpy", "numpy", "det_sim_ros.core._ckernel") '
            'if m in sys.modules]\n'
            'assert not heavy, heavy\n')
    subprocess.run([sys.executable, '-c', code], check=True)
