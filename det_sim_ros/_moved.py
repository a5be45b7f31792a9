"""
Alias the flat module paths of earlier releases to the modules' homes in the layer subpackages.

The flat paths (``det_sim_ros.scene``, ``det_sim_ros.sim_node``, ...) are aliases. Importing an
old path gives the new module itself (the same objects, so ``isinstance`` and monkeypatching
keep working) and warns once with a DeprecationWarning that names the new path. ``python -m`` on
an old path runs the new module.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

MOVED = {
    'kernel': 'core.kernel',
    'scene': 'scenes.scene',
    'shapes': 'physics.shapes',
    'model': 'physics.model',
    'statics': 'physics.statics',
    'geometry': 'physics.geometry',
    'reference': 'physics.reference',
    'linearize': 'physics.linearize',
    'integrators': 'sim.integrators',
    'simulator': 'sim.simulator',
    'elastica': 'analysis.elastica',
    'fidelity': 'analysis.fidelity',
    'scenarios': 'analysis.scenarios',
    'benchmark': 'analysis.benchmark',
    'contract': 'io.contract',
    'mcap_log': 'io.mcap_log',
    'replay': 'ros.play',          # play, and io.replay's names re-exported
    'logplot': 'io.logplot',
    'sim_node': 'ros.node',
    'markers': 'ros.markers',
    'fleet': 'ros.fleet',
    'netns': 'ros.netns',
    'testing': 'ros.testing',
}
_ROOT = __name__.rpartition('.')[0]
_RUN_AS_MAIN = {'sim_node': 'cli.sim_node', 'replay': 'cli.replay'}


class _MovedPath(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``det_sim_ros.<old>`` and loads it as the module it moved to."""

    def find_spec(self, fullname, path=None, target=None):
        root, _, old = fullname.rpartition('.')
        if root != _ROOT or old not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        new = f'{_ROOT}.{MOVED[spec.name.rpartition(".")[2]]}'
        warnings.warn(f'{spec.name} has moved to {new}; import it from there',
                      DeprecationWarning, stacklevel=2)
        module = importlib.import_module(new)
        spec.loader_state = module.__spec__   # the import system overwrites it: restored below
        return module

    def exec_module(self, module):
        """Give the module back its own spec (the import system set the alias's)."""
        module.__spec__ = module.__spec__.loader_state

    def get_code(self, fullname):
        """
        Return the code that ``python -m det_sim_ros.<old>`` runs.

        It runs the new module as the main program.
        """
        old = fullname.rpartition('.')[2]
        target = f'{_ROOT}.{_RUN_AS_MAIN.get(old, MOVED[old])}'
        return compile(f'import runpy\nrunpy.run_module({target!r}, run_name="__main__", '
                       'alter_sys=True)\n', f'<{fullname}>', 'exec')

    def is_package(self, fullname):
        return False


def install() -> None:
    """Put the alias finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedPath) for f in sys.meta_path):
        sys.meta_path.append(_MovedPath())
