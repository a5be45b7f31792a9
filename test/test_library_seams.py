"""
Where the package meets mcap and rclpy, checked on every module's imports.

mcap is imported by the log subpackage (det_sim_ros.io.log) only: no other module reads or
writes MCAP records. A private name of mcap or rclpy (an import path with a part that starts
with '_') is imported by no module but the one facade listed for it, for the reason given, so
an upgrade of either library has one place to look.
"""

import ast
import os

import det_sim_ros

PACKAGE_DIR = os.path.dirname(det_sim_ros.__file__)
LOG_PACKAGE = 'det_sim_ros.io.log'
# library -> {module allowed to import its private names: why}
FACADES = {
    'mcap': {},
    'rclpy': {'det_sim_ros.ros.node': 'RCLError (rclpy._rclpy_pybind11), the error a context '
                                      'shut down mid-call raises: rclpy gives it no public name'},
}


def _imports():
    """Yield (module, imported absolute name, line) for every import in the package."""
    for folder, _, files in os.walk(PACKAGE_DIR):
        for name in files:
            if not name.endswith('.py'):
                continue
            path = os.path.join(folder, name)
            rel = os.path.relpath(path, os.path.dirname(PACKAGE_DIR))[:-3].replace(os.sep, '.')
            module = rel.removesuffix('.__init__')
            tree = ast.parse(open(path, encoding='utf-8').read(), path)
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
