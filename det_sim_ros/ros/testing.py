"""
pytest plugin for deterministic controller tests against sim_node.

It is registered as ``det_sim`` through the ``pytest11`` entry point, so installing
det_sim_ros makes the fixture available.

The fixture ``det_sim`` makes :class:`LockstepSim` objects: sim_node in-process, in lockstep
(``mode: lockstep``), in a ROS context of its own with localhost-only discovery, on the
domain ``ROS_DOMAIN_ID`` names when it is set (as the package's own tests do), else on one
picked from the pid (never the default domain 0). Your controller nodes are created in
``sim.context`` and spun with sim_node in one executor; every period waits for their answer,
so a run gives the same numbers whatever the host load::

    def test_pi(det_sim):
        sim = det_sim('default')
        controller = MyController(context=sim.context)   # any rclpy node
        run = sim.run(until=1.0, nodes=[controller])
        assert run.step_metrics('dy', target=2e-3, t_step=0.6).settling_time <= 0.5

:class:`SimRun` holds the run as arrays, one row per sample (t = k dt) and one column per DET:
``t`` (s), ``voltage`` (V held during the period that ended at t), ``q`` (m), ``dy`` (m),
``charge`` (C), ``current`` (A).
"""

from __future__ import annotations

import os
import time
from typing import Iterable, Sequence
import warnings

import numpy as np

from ..analysis.ensemble import Ensemble, ensemble_overrides
from ..analysis.predictability import PathNotRobustWarning
from ..analysis.response import SimRun, StepMetrics
from ..scenes.outputs import main_topic

__all__ = ['LockstepSim', 'SimRun', 'StepMetrics', 'det_sim', 'pick_domain_id',
           'lockstep_ensemble', 'Ensemble']

WALL_TIMEOUT = 600.0   # s: a safety net against a controller that never answers
MAX_DOMAIN_ID = 232    # the largest ROS domain id (ports must fit below 65536)


def pick_domain_id(environ=None, pid=None) -> int:
    """
    Return the ROS domain id for a test.

    The user's ``ROS_DOMAIN_ID`` when set (a number in 0..232; anything else is refused with
    one line), else 1 + pid % 101, which avoids the default domain 0 so that a running ROS
    system is not disturbed. ``environ`` and ``pid`` default to this process's.
    """
    environ = os.environ if environ is None else environ
    text = environ.get('ROS_DOMAIN_ID', '').strip()
    if text:
        if not text.isdigit() or int(text) > MAX_DOMAIN_ID:
            raise ValueError(f'ROS_DOMAIN_ID={text!r}: expected a number in 0..{MAX_DOMAIN_ID}')
        return int(text)
    return 1 + (os.getpid() if pid is None else pid) % 101


def _import_type_support_quietly() -> None:
    """
    Import rclpy's message type support with lark-parser's DeprecationWarning ignored.

    A process's first node imports rosidl_generator_py, whose IDL parser imports lark-parser
    (0.12, which the ROS packages require), which imports the deprecated sre_parse and
    sre_constants: a warning about a third party's imports that a strict run (``-W
    error::DeprecationWarning``) would fail the user's first test with.
    """
    import warnings
    with warnings.catch_warnings():
        warnings.filterwarnings('ignore', category=DeprecationWarning, module='lark')
        try:
            import rosidl_generator_py  # noqa: F401
        except ImportError:   # pragma: no cover - rclpy's own import then fails with the reason
            pass


class LockstepSim:
    """
    sim_node in lockstep with the controller nodes you give it, in one process and executor.

    :param scene: scene file name or path (``scene_file``).
    :param overrides: scene keys, e.g. ``{'physics.Rs': 1.0e3, 'structure.copies': 4}``.
    :param params: other node parameters (``lockstep.sources``, ``lockstep.timeout``,
        ``log.path`` to record the run, ...).
    :param domain_id: the ROS domain (default: :func:`pick_domain_id`, ``ROS_DOMAIN_ID`` if set).
    :param executor: 'events' (sim_node's own) or 'single' (SingleThreadedExecutor).
    """

    def __init__(self, scene: str = 'default', overrides: dict | None = None,
                 params: dict | None = None, domain_id: int | None = None,
                 executor: str = 'events'):
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        _import_type_support_quietly()    # before the first node, yours or sim_node
        import rclpy
        from rclpy.context import Context
        self.domain_id = pick_domain_id() if domain_id is None else domain_id
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain_id)
        self._scene, self._overrides = scene, dict(overrides or {})
        self._params = dict(params or {})
        self._executor_kind = executor
        self.node = None
        self.executor = None
        self._rows: list = []
        self._nodes: list = []
        self._warned = False

    # -- set-up ----------------------------------------------------------------------------
    def start(self, nodes: Iterable = (), wait: bool = True) -> 'LockstepSim':
        """
        Create sim_node (paused), spin it with ``nodes`` and let the lockstep run.

        Before the lockstep runs it waits until the controllers' command publishers are matched
        (``lockstep.sources`` of them; ``wait=False``: it does not wait).
        """
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter
        from .node import make_executor, SimNode
        if self.node is None:
            # (its domain is this process's own: no discovery wait for a duplicate name)
            params = {'log.enabled': 'log.path' in self._params, 'info_period': 0.0,
                      'allow_duplicate_name': True, **self._params, 'mode': 'lockstep',
                      'start_paused': True, 'scene_file': self._scene, **self._overrides}
            self.node = SimNode(context=self.context, parameter_overrides=[
                Parameter(name, value=value) for name, value in params.items()])
            self.node.on_sample = self._record
            self._record(0, self.node.current_outputs())
            self.executor = (make_executor(self.context) if self._executor_kind == 'events'
                             else SingleThreadedExecutor(context=self.context))
            self.executor.add_node(self.node)
        for node in nodes:
            if node not in self._nodes:
                self._nodes.append(node)
                self.executor.add_node(node)
        if self.node.paused:
            sources = self.node.get_parameter('lockstep.sources').value
            subs = list(self.node.command_subscriptions.values())
            if wait:
                self.spin_until(lambda: sum(s.get_publisher_count() for s in subs) >= sources,
                                'the controller command publishers')
            self.node.set_paused(False)
        return self

    def _record(self, k, out):
        node = self.node
        contract = node.contract
        self._rows.append((k, node.simulator.u.copy(),
                           contract.values(out, 'deflection', 'position'),
                           contract.values(out, main_topic(), 'position'),   # dy
                           contract.values(out, 'charge', 'position'),
                           contract.values(out, 'current', 'position')))

    # -- running -----------------------------------------------------------------------------
    def spin_until(self, condition, what='condition') -> None:
        """Spin sim_node and the controllers until ``condition()``."""
        deadline = time.monotonic() + WALL_TIMEOUT
        while not condition():
            if time.monotonic() > deadline:
                raise TimeoutError(f'lockstep: timed out waiting for {what} (does the '
                                   'controller answer every sample?)')
            self.executor.spin_once(timeout_sec=0.01)

    def run(self, until: float, nodes: Sequence = ()) -> SimRun:
        """
        Run until the sample at sim time ``until`` (s); return the run so far.

        The lockstep starts first if needed.
        """
        self.start(nodes)
        simulator = self.node.simulator
        k_end = int(round(until / self.node.dt))
        self.spin_until(lambda: simulator.k >= k_end or simulator.fault, f'sim time {until} s')
        if simulator.fault:
            raise RuntimeError(f'sim_node fault: {simulator.fault}')
        run = self.result()
        if run.robust_until is not None and not self._warned:
            self._warned = True   # (once per sim: a later run() of it says nothing new)
            warnings.warn(PathNotRobustWarning(
                f'this lockstep run is not robust from t = {run.robust_until:.3f} s (a twin '
                "differing by a parameter's 7th digit took another path): assert on what "
                'det_sim.ensemble(...).shared() states, not on this run (docs/predictability.md)'),
                stacklevel=2)
        return run

    def result(self) -> SimRun:
        """Return the samples recorded so far (the t = 0 sample first)."""
        rows = self._rows
        dt = self.node.dt

        def column(i):
            return np.array([row[i] for row in rows], dtype=float)
        first = self.node.predictability.first_not_robust()
        return SimRun(list(self.node.det_names), column(0) * dt, column(1), column(2),
                      column(3), column(4), column(5), first)

    def close(self) -> None:
        """Destroy the nodes (the log, if any, is finished) and shut the context down."""
        import rclpy
        if self.executor is not None:
            self.executor.shutdown()
        for node in self._nodes:
            node.destroy_node()
        if self.node is not None:
            self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def lockstep_ensemble(make_controllers, until: float, scene: str = 'default',
                      overrides: dict | None = None, params: dict | None = None,
                      copies: int = 20, perturbation=None, seed: int = 0,
                      domain_id: int | None = None) -> Ensemble:
    """
    Run your controller in lockstep against ``copies`` perturbed copies of a plant.

    Each copy is its own sim_node (copy 0 the scene as given, copy i > 0 perturbed as
    :func:`~det_sim_ros.analysis.ensemble.ensemble_overrides` draws it) with fresh controller
    nodes: ``make_controllers(sim)`` returns them, created in ``sim.context``. Returns the
    :class:`~det_sim_ros.analysis.ensemble.Ensemble` of the runs to ``until`` (s); its
    ``shared()`` states what every copy agrees on.
    """
    from ..scenes.scene import load_scene
    base = load_scene(scene, overrides or {})
    runs, changes = [], ensemble_overrides(base, copies, perturbation, seed)
    for change in changes:
        sim = LockstepSim(scene, {**(overrides or {}), **change}, params, domain_id)
        try:
            with warnings.catch_warnings():   # (a copy not robust is what an ensemble is for)
                warnings.simplefilter('ignore', PathNotRobustWarning)
                runs.append(sim.run(until, nodes=list(make_controllers(sim))))
        finally:
            sim.close()
    return Ensemble(runs, changes)


def _fixture():
    import pytest

    @pytest.fixture
    def det_sim():
        """
        Make :class:`LockstepSim` objects, closed after the test.

        Call it as ``det_sim(scene, overrides, params)``; ``det_sim.ensemble(make_controllers,
        until, scene, ...)`` runs your controller against perturbed copies
        (:func:`lockstep_ensemble`).
        """
        made = []

        def make(scene='default', overrides=None, params=None, **kwargs):
            sim = LockstepSim(scene, overrides, params, **kwargs)
            made.append(sim)
            return sim
        make.ensemble = lockstep_ensemble
        yield make
        for sim in made:
            sim.close()
    return det_sim


try:
    det_sim = _fixture()
except ImportError:   # pragma: no cover - pytest absent: the classes still work
    pass
