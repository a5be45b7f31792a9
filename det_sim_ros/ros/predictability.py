"""
The node's predictability measure: a perturbed twin stepped beside the run, and what it says.

With ``predictability.mode`` 'on' (by default, 'auto': unless the scene is an array, whose
twin would double the physics of every copy) every period also steps a twin of the scene
(det_sim_ros.analysis.predictability: the ``predictability.parameter`` changed by
``predictability.relative``, the tolerance times ``predictability.tolerance_factor``) under the
same commands. Its distance from the run, a fraction of the stroke, goes on /diagnostics, on the
``predictability`` topic and into the log (PREDICTABILITY_RATE_HZ of sim time, and at every
stretch's start and end); a WARN line says once per stretch when the path stops being robust,
an INFO line when it is robust again. Off, the node steps nothing more (:class:`NoMeasure`).

The twin receives the commands the node received: in closed loop it measures the plant's
sensitivity along them, not the loop's (the plugin's ensemble runs the loop per copy).
"""

from __future__ import annotations

import math

from ..analysis.predictability import NO_STROKE, Perturbation, TwinMonitor
from ..io.contract import (encode_joint_state, JOINT_STATE, PREDICTABILITY_RATE_HZ,
                           PREDICTABILITY_TOPIC, stamp_ns)
from ..scenes.scene import SceneError

__all__ = ['attach_predictability', 'NodePredictability', 'NoMeasure']

CHANNEL = 'twin_distance'


class NoMeasure:
    """The measure off: nothing stepped, nothing reported."""

    enabled = False

    def follow(self, sim, out) -> None:
        """Do nothing (the measure is off)."""

    def log_to(self, recorder) -> None:
        """Do nothing (the measure is off)."""

    def first_not_robust(self) -> None:
        """Return None: nothing is known (the measure is off)."""

    def reset(self) -> None:
        """Do nothing (the measure is off)."""

    def values(self) -> dict:
        """Return the /diagnostics keys: the measure is off."""
        return {'predictability': 'off'}


class NodePredictability:
    """
    A :class:`~det_sim_ros.analysis.predictability.TwinMonitor` with the node's outputs.

    :param monitor: the twin beside the node's simulator.
    :param publish: publishes the ``predictability`` JointState bytes.
    :param logger: the node's logger.
    """

    enabled = True

    def __init__(self, monitor: TwinMonitor, publish, logger):
        self.monitor = monitor
        self._publish, self._logger = publish, logger
        self._recorder = None
        self._every = max(1, int(round(1.0 / (PREDICTABILITY_RATE_HZ * monitor.twin.dt))))
        self._fault_told = False

    def follow(self, sim, out) -> None:
        """Step the twin through the period ``sim`` has just run; report what changed."""
        monitor = self.monitor
        event = monitor.follow(sim, out)
        if monitor.fault:
            if not self._fault_told:
                self._fault_told = True
                self._logger.warning(f'predictability measure stopped: {monitor.fault} (the '
                                     'run goes on; ~/reset starts both over)')
            return
        if event:
            self._tell(event, sim.t)
        if event or not sim.k % self._every:
            data = encode_joint_state((CHANNEL,), (monitor.distance,),
                                      stamp_ns=stamp_ns(sim.k, sim.dt))
            self._publish(data)
            if self._recorder is not None:
                self._recorder.record(PREDICTABILITY_TOPIC, data, stamp_ns(sim.k, sim.dt),
                                      type_name=JOINT_STATE)

    def log_to(self, recorder) -> None:
        """Record the measure with ``recorder`` (the node's MCAP recorder, or None)."""
        self._recorder = recorder

    def first_not_robust(self) -> float | None:
        """Return the sim time (s) the path first stopped being robust, None if never."""
        first = self.monitor.stretches.first
        return None if first is None else first * self.monitor.twin.dt

    def _tell(self, event: str, t: float) -> None:
        monitor = self.monitor
        limit = 100 * monitor.limit
        if event == 'start':
            self._logger.warning(
                f'path not robust from t = {t:.3f} s: a twin differing only by '
                f'{monitor.perturbation.describe()} is {100 * monitor.distance:.1f} % of the '
                f'stroke away (limit {limit:g} %), so the samples from here depend on rounding; '
                'assert on what an ensemble of perturbed runs shares, not on this path '
                '(docs/predictability.md)')
        else:   # (said once the twin has stayed back for HOLD_S: the stretch ended before)
            back = monitor.stretches.spans[-1][1] * monitor.twin.dt
            self._logger.info(f'path robust again from t = {back:.3f} s (the twin back within '
                              f'{limit / 2:g} % of the stroke since)')

    def reset(self) -> None:
        """Start the twin over with the run (~/reset)."""
        self.monitor.reset()
        self._fault_told = False

    def values(self) -> dict:
        """Return the /diagnostics keys: the twin's distance now, and the stretches."""
        monitor = self.monitor
        stretches = monitor.stretches
        dt = monitor.twin.dt
        first = stretches.first
        distance = monitor.distance
        return {
            'predictability': monitor.fault or f'twin {monitor.perturbation.describe()}',
            'twin_distance': 'nan' if math.isnan(distance) else f'{distance:.4g}',
            'robust_now': str(not stretches.open and not monitor.fault).lower(),
            'not_robust_since_s': (f'{stretches.spans[-1][0] * dt:.3f}' if stretches.open
                                   else ''),
            'robust_until_s': '' if first is None else f'{first * dt:.3f}',
            'not_robust_stretches': str(len(stretches.spans)),
        }


def attach_predictability(node, get, qos):
    """
    Return the node's measure from its ``predictability.*`` parameters.

    :class:`NoMeasure` when off, or (with one INFO line saying why) for an array scene in mode
    'auto' and for a scene without a stroke to measure against.

    :param get: a parameter's value by name.
    :raises SceneError: an invalid perturbation (one line naming the parameter).
    """
    mode = get('predictability.mode')
    if mode == 'off':
        return NoMeasure()
    if mode == 'auto' and node.simulator.model.arrays.n_groups > 1:
        node.get_logger().info('predictability measure off for an array scene (a twin doubles '
                               'the physics of every copy): -p predictability.mode:=on to step '
                               'one (docs/predictability.md)')
        return NoMeasure()
    try:
        perturbation = Perturbation(get('predictability.parameter'),
                                    get('predictability.relative'),
                                    get('predictability.tolerance_factor'))
        monitor = TwinMonitor(node.simulator, perturbation, get('predictability.limit'))
    except ValueError as exc:   # (SceneError is one)
        if str(exc) == NO_STROKE:
            node.get_logger().info(f'predictability measure off: {NO_STROKE}')
            return NoMeasure()
        raise SceneError(f'parameters predictability.*: {exc}') from None
    from sensor_msgs.msg import JointState
    publisher = node.create_publisher(JointState, PREDICTABILITY_TOPIC, qos)
    return NodePredictability(monitor, publisher.publish, node.get_logger())
