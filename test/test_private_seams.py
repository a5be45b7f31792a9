"""
No class method is called from outside its module by a private name.

A module that calls (or hands on) ``something._name`` where ``_name`` is a method of a class in
another module reaches into that class: the seam between the two should be public. Read from
the source with ast: a use counts when its private name is a method of some other module's
class and the using module neither defines nor assigns that name itself.
"""

import ast
import os
import sys

import det_sim_ros

PACKAGE_DIR = os.path.dirname(det_sim_ros.__file__)


def _trees():
    for folder, _, files in os.walk(PACKAGE_DIR):
        for name in files:
            if name.endswith('.py'):
                path = os.path.join(folder, name)
                with open(path, encoding='utf-8') as stream:
                    yield os.path.relpath(path, PACKAGE_DIR), ast.parse(stream.read(), path)


def _private(name: str) -> bool:
    return name.startswith('_') and not name.startswith('__')


def _private_calls():
    """Return (module, line, text) of private uses of another module's class methods."""
    methods, own, calls = {}, {}, []
    for module, tree in _trees():
        names = own.setdefault(module, set())
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                for item in node.body:
                    if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) \
                            and _private(item.name):
                        methods.setdefault(item.name, set()).add(module)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.Attribute) and _private(node.attr):   # called or passed
                calls.append((module, node.lineno, node.attr, ast.unparse(node)))
    return [(module, line, text) for module, line, name, text in calls
            if name in methods and name not in own[module] and module not in methods[name]]


def test_no_private_method_is_called_from_another_module():
    found = _private_calls()
    assert not found, 'private methods called from another module: ' + '; '.join(
        f'{module}:{line} {text}' for module, line, text in found)


def test_the_check_sees_a_private_call(tmp_path, monkeypatch):
    """A module calling another module's private method is found (the check can fail)."""
    package = tmp_path / 'pkg'
    package.mkdir()
    (package / 'a.py').write_text('class A:\n    def _step(self):\n        return 1\n')
    (package / 'b.py').write_text('def use(a):\n    return a._step()\n')
    monkeypatch.setattr(sys.modules[__name__], 'PACKAGE_DIR', str(package))
    assert [(m, text) for m, _, text in _private_calls()] == [('b.py', 'a._step')]
