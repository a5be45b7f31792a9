"""
A run as arrays, and the step-response figures of a sampled signal.

Rise time, overshoot, settling time and final error. Shared by the lockstep plugin's runs
(det_sim_ros.ros.testing) and offline ensembles (det_sim_ros.analysis.ensemble).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ['StepMetrics', 'step_metrics', 'SimRun']


@dataclasses.dataclass(frozen=True)
class StepMetrics:
    """Step-response figures of one signal (times in s after the step, ``nan`` if never)."""

    rise_time: float           # from 10 % to 90 % of the step
    overshoot: float           # max beyond the target, relative to the step size (0.05 = 5 %)
    settling_time: float       # last entry into the band target +- band * |step|
    steady_state_error: float  # target - final value (same unit as the signal)


def step_metrics(t, x, target: float, t_step: float = 0.0, band: float = 0.05) -> StepMetrics:
    """
    Return the figures of the response ``x(t)`` to a set-point step to ``target`` at ``t_step``.

    Rise time (10-90 %), overshoot, settling time (into ``band`` of the step size) and
    steady-state error, all from the first sample at or after ``t_step``.
    """
    t, x = np.asarray(t, dtype=float), np.asarray(x, dtype=float)
    after = t >= t_step - 1e-12
    t, x = t[after] - t_step, x[after]
    if x.size == 0:
        raise ValueError(f'no samples after t_step = {t_step} s')
    start = x[0]
    size = target - start
    if size == 0.0:
        raise ValueError('the step has size 0 (the signal starts at the target)')
    progress = (x - start) / size

    def first(condition):
        hits = np.nonzero(condition)[0]
        return float(t[hits[0]]) if hits.size else float('nan')
    rise = first(progress >= 0.9) - first(progress >= 0.1)
    overshoot = max(0.0, float(progress.max()) - 1.0)
    outside = np.nonzero(np.abs(x - target) > band * abs(size))[0]
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] + 1 < x.size:
        settling = float(t[outside[-1] + 1])
    else:
        settling = float('nan')
    return StepMetrics(rise, overshoot, settling, float(target - x[-1]))


@dataclasses.dataclass
class SimRun:
    """
    A run as arrays (rows: samples t = k dt; columns: DETs in command order).

    ``robust_until``: where the node's predictability measure found the path stop being robust
    (s; None if it never did, or the measure was off: docs/predictability.md).
    """

    det_names: list
    t: np.ndarray
    voltage: np.ndarray
    q: np.ndarray
    dy: np.ndarray
    charge: np.ndarray
    current: np.ndarray
    robust_until: float | None = None

    def signal(self, name: str, det: int | str = 0) -> np.ndarray:
        """Return one column: ``name`` in voltage, q, dy, charge, current; ``det``: index, name."""
        column = self.det_names.index(det) if isinstance(det, str) else det
        return getattr(self, name)[:, column]

    def at(self, t: float, name: str, det: int | str = 0) -> float:
        """Return the value of a signal at the sample nearest sim time t."""
        return float(self.signal(name, det)[int(np.argmin(np.abs(self.t - t)))])

    def step_metrics(self, name: str = 'dy', target: float = 0.0, t_step: float = 0.0,
                     det: int | str = 0, band: float = 0.05) -> StepMetrics:
        """
        Return the step-response figures of a set-point step to ``target`` at ``t_step``.

        Rise time (10-90 %), overshoot, settling time (into ``band`` of the step size) and
        steady-state error of the response.
        """
        return step_metrics(self.t, self.signal(name, det), target, t_step, band)
