"""
det_sim_ros: dielectric elastomer transducers coupled with buckled beams, simulated for ROS 2.

The package is layered; each layer imports only the layers below it (test/test_layers.py
checks every module's imports):

    cli        one ``det_sim`` command with its verbs, and the ``sim_node`` entry point
    ros        the node, its pacing and diagnostics, markers, fleets, the pytest plugin
    calibration  scene parameters fitted to measured logs (no ROS)
    io         the topic contract and its CDR bytes, MCAP recording, reading and replay
    analysis   elastica, fidelity studies, the paper's scenarios, benchmarks
    sim        the sim-time grid, inputs held per period, the integration methods' tables
    physics    energies -> model, statics, linearization, the numpy reference
    scenes     scene files (YAML): loading and validation
    core       the compiled kernel (C) behind its one facade, core.kernel

docs/architecture.md has the layers' rules, how a sample travels and where to change what.

Importing the package has no side effects. The common entry points are here, imported on
first use:
:func:`load_scene`, :class:`Simulator`, :func:`simulate`, :func:`linearize`, :func:`fit`.
"""

__version__ = '0.1.0'

_PUBLIC = {
    'load_scene': 'det_sim_ros.scenes.scene',
    'Scene': 'det_sim_ros.scenes.scene',
    'SceneError': 'det_sim_ros.scenes.scene',
    'Simulator': 'det_sim_ros.sim.simulator',
    'simulate': 'det_sim_ros.sim.simulator',
    'linearize': 'det_sim_ros.physics.linearize',
    'fit': 'det_sim_ros.calibration.fitting',
}

__all__ = ['__version__', *_PUBLIC]


def __getattr__(name):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    import importlib
    return getattr(importlib.import_module(module), name)
