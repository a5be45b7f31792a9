"""
Where the package meets mcap and rclpy, checked on every module's imports and attribute access.

mcap is imported by the log subpackage (det_sim_ros.io.log) only: no other module reads or
writes MCAP records. A private name of mcap or rclpy (an import path with a part that starts
with '_') is imported by no module but the one facade listed for it, for the reason given, so
an upgrade of either library has one place to look. Outside rclpy's facade no module reaches an
rclpy object's C handle (``.handle``) or a private attribute of rclpy's classes (the names
read from the installed rclpy's own source), by ``x._name`` or ``getattr(x, '_name')``.
"""

import ast
import os

import det_sim_ros
import rclpy

PACKAGE_DIR = os.path.dirname(det_sim_ros.__file__)
LOG_PACKAGE = 'det_sim_ros.io.log'
# library -> {module allowed to import its private names: why}
FACADES = {
    'mcap': {},
    'rclpy': {'det_sim_ros.ros.rclpy_facade': 'RCLError (rclpy._rclpy_pybind11): rclpy gives the '
              'error of a failed rcl call no public name; taking a raw message outside an '
              'executor: rclpy has no public call for it'},
}
RCLPY_FACADE = 'det_sim_ros.ros.rclpy_facade'


def _modules(package_dir=PACKAGE_DIR):
    """Yield (module name, its parsed tree) for every module of the package."""
    for folder, _, files in os.walk(package_dir):
        for name in files:
            if not name.endswith('.py'):
                continue
            path = os.path.join(folder, name)
            rel = os.path.relpath(path, os.path.dirname(package_dir))[:-3].replace(os.sep, '.')
            yield rel.removesuffix('.__init__'), ast.parse(open(path, encoding='utf-8').read(),
                                                           path)


def _imports():
    """Yield (module, imported absolute name, line) for every import in the package."""
    for module, tree in _modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    yield module, alias.name, node.lineno
            elif isinstance(node, ast.ImportFrom) and not node.level:
                for alias in node.names:
                    yield module, f'{node.module}.{alias.name}', node.lineno


def test_mcap_only_in_the_log_subpackage():
    outside = [f'{module}:{line} imports {name}' for module, name, line in _imports()
               if name.split('.')[0] == 'mcap'
               and not (module == LOG_PACKAGE or module.startswith(LOG_PACKAGE + '.'))]
    assert not outside, outside


def test_private_names_of_mcap_and_rclpy_only_in_their_facade():
    found = [(module, name, line) for module, name, line in _imports()
             if name.split('.')[0] in FACADES
             and any(part.startswith('_') for part in name.split('.')[1:])]
    stray = [f'{module}:{line} imports {name}' for module, name, line in found
             if module not in FACADES[name.split('.')[0]]]
    assert not stray, stray
    used = {(name.split('.')[0], module) for module, name, _ in found}
    listed = {(library, module) for library, modules in FACADES.items() for module in modules}
    assert used == listed, f'facades listed but importing no private name: {listed - used}'


def _rclpy_private_names() -> set:
    """
    Return the private attribute names of rclpy's classes, read from rclpy's own source.

    Every ``def _name`` in a class and every ``self._name`` its methods use (``self.__name`` as
    Python mangles it, ``_Class__name``).
    """
    names = set()
    for _, tree in _modules(os.path.dirname(rclpy.__file__)):
        for cls in (n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)):
            for node in ast.walk(cls):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    name = node.name
                elif (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                      and node.value.id == 'self'):
                    name = node.attr
                else:
                    continue
                if name.startswith('__') and not name.endswith('__'):
                    names.add(f'_{cls.name}{name}')
                elif name.startswith('_') and not name.startswith('__'):
                    names.add(name)
    return names


RCLPY_PRIVATE = _rclpy_private_names()


def _rclpy_bases(tree) -> set:
    """Return the names the module binds to rclpy classes (``from rclpy.node import Node``)."""
    return {alias.asname or alias.name for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and (node.module or '').split('.')[0] == 'rclpy'
            for alias in node.names}


def rclpy_reach(tree) -> list:
    """
    Return (line, what) for every place ``tree`` reaches past rclpy's public API.

    ``.handle`` on anything (rclpy's C handles); an rclpy private attribute name read on any
    object but ``self``, or on ``self`` in a subclass of an rclpy class (its own attributes
    must not be rclpy's either); ``getattr``/``setattr``/``hasattr`` with such a name.
    """
    found = []
    rclpy_classes = _rclpy_bases(tree)

    def visit(node, in_rclpy_subclass):
        if isinstance(node, ast.ClassDef):
            in_rclpy_subclass = any(isinstance(base, ast.Name) and base.id in rclpy_classes
                                    for base in node.bases)
        if isinstance(node, ast.Attribute):
            on_self = isinstance(node.value, ast.Name) and node.value.id in ('self', 'cls')
            if node.attr == 'handle':
                found.append((node.lineno, '.handle'))
            elif node.attr in RCLPY_PRIVATE and (in_rclpy_subclass or not on_self):
                found.append((node.lineno, f'.{node.attr}'))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ('getattr', 'setattr', 'hasattr') and len(node.args) > 1
              and isinstance(node.args[1], ast.Constant) and node.args[1].value in RCLPY_PRIVATE):
            found.append((node.lineno, f'{node.func.id}(..., {node.args[1].value!r})'))
        for child in ast.iter_child_nodes(node):
            visit(child, in_rclpy_subclass)
    visit(tree, False)
    return found


def test_rclpy_handles_and_private_attributes_only_in_the_facade():
    stray = [f'{module}:{line} reaches {what}' for module, tree in _modules()
             if module != RCLPY_FACADE for line, what in rclpy_reach(tree)]
    assert not stray, stray


def test_the_facade_is_where_the_reach_is():
    """The facade's own uses are seen by the scan (the scan is not blind to them)."""
    facade = dict(_modules())[RCLPY_FACADE]
    assert [what for _, what in rclpy_reach(facade)] == ['.handle']


# the uses of rclpy's insides this package had before they moved to the public API or the facade
OLD_USES = {
    'overrides read by getattr': (
        "def load(node):\n    return dict(getattr(node, '_parameter_overrides', {}))",
        ["getattr(..., '_parameter_overrides')"]),
    'overrides written': (
        "def declare(node):\n    given = node._parameter_overrides\n    given['a'] = 1",
        ['._parameter_overrides']),
    'publish through the C handle': (
        'class T:\n    def __init__(self, pub):\n        self.f = pub.handle.publish_raw',
        ['.handle']),
    'take through the C handle': (
        'def drain(sub):\n    return sub.handle.take_message(sub.msg_type, True)',
        ['.handle']),
    "an rclpy Node subclass using the Node's insides": (
        'from rclpy.node import Node\nclass N(Node):\n    def f(self):\n'
        '        return self._parameter_overrides',
        ['._parameter_overrides']),
}


def test_the_scan_finds_the_old_uses_of_rclpy_insides():
    for what, (source, expected) in OLD_USES.items():
        assert [found for _, found in rclpy_reach(ast.parse(source))] == expected, what
    # a subclass of the package's own keeps its own private names (not rclpy's business)
    own = 'class N:\n    def f(self):\n        return self._parameter_overrides'
    assert rclpy_reach(ast.parse(own)) == []
