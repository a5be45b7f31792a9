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
    cycles = _cycles(graph)
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


# The C kernel's layers (folders of det_sim_ros/core/_csrc): physics and wire (the node's
# message bytes) at the ground, stepping on physics, the Python binding on all three. A unit is
# a .c file with the header of the same name (group.h, model.h: records without a .c file).
# The sources are read in the repository beside this file: an installed package holds only the
# compiled kernel.
C_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'det_sim_ros',
                     'core', '_csrc')
C_LAYERS = {'physics': 0, 'wire': 0, 'stepping': 1, 'binding': 2}


def _c_files():
    for folder, _, files in os.walk(C_DIR):
        for name in sorted(files):
            if name.endswith(('.c', '.h')):
                yield os.path.relpath(os.path.join(folder, name), C_DIR).replace(os.sep, '/')


def _c_includes(rel):
    """Yield (included path as written, line) for every quoted #include of a kernel file."""
    with open(os.path.join(C_DIR, rel), encoding='utf-8') as f:
        for line_no, line in enumerate(f, 1):
            parts = line.split()
            if len(parts) >= 2 and parts[0] == '#include' and parts[1].startswith('"'):
                yield parts[1].strip('"'), line_no


def _c_unit(rel):
    return rel.rsplit('.', 1)[0]


def _c_graph(files):
    """Map each unit to the units it includes, from {path: [(included, line)]}."""
    graph = {}
    for rel, found in files.items():
        graph.setdefault(_c_unit(rel), set()).update(
            _c_unit(target) for target, _ in found if _c_unit(target) != _c_unit(rel))
    return graph


def _cycles(graph):
    """Return the cycles of a graph {node: set of nodes it points to}, each as 'a -> b -> a'."""
    state, cycles = {}, []

    def visit(node, trail):
        state[node] = 'open'
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 'open':
                cycles.append(' -> '.join(trail[trail.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, trail + [nxt])
        state[node] = 'done'

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    return cycles


def test_every_kernel_file_sits_in_a_layer():
    files = list(_c_files())
    assert files, f'no kernel sources under {C_DIR}'
    stray = [rel for rel in files if rel.split('/')[0] not in C_LAYERS or rel.count('/') != 1]
    assert not stray, f'kernel files outside the layer folders: {stray}'


def _c_upward(files):
    """List the includes in {path: [(included, line)]} not of a header of a lower layer."""
    wrong = []
    for rel, found in files.items():
        home = rel.split('/')[0]
        for target, line in found:
            layer = target.split('/')[0]
            if target not in files or not target.endswith('.h') or layer not in C_LAYERS:
                wrong.append(f'{rel}:{line} includes "{target}" (not a layer/header.h)')
            elif layer != home and C_LAYERS[layer] >= C_LAYERS[home]:
                wrong.append(f'{rel}:{line} includes {target} (not below {home})')
    return wrong


def test_kernel_includes_point_down_only():
    """
    Check that every quoted include names an existing header of its own or a lower layer.

    "physics/model.h", never a bare "model.h": the folder in the include is the layer it
    comes from, so this check (and a reader) sees the arrow.
    """
    wrong = _c_upward({rel: list(_c_includes(rel)) for rel in _c_files()})
    assert not wrong, 'kernel includes that do not point down:\n' + '\n'.join(wrong)


def test_no_kernel_unit_includes_one_that_includes_it():
    graph = _c_graph({rel: list(_c_includes(rel)) for rel in _c_files()})
    cycles = _cycles(graph)
    assert not cycles, 'kernel include cycles:\n' + '\n'.join(cycles)


def test_the_kernel_checks_see_a_planted_upward_include():
    """Check that the include checks read what they claim: a planted include is found."""
    files = {rel: list(_c_includes(rel)) for rel in _c_files()}
    assert not _c_upward(files) and not _cycles(_c_graph(files))
    files['physics/physics.c'] = files['physics/physics.c'] + [('stepping/stages.h', 0)]
    assert _c_upward(files) == ['physics/physics.c:0 includes stepping/stages.h '
                                '(not below physics)']
    assert 'physics/physics -> stepping/stages -> physics/physics' in _cycles(_c_graph(files))
