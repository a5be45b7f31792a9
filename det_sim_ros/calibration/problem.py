"""
The fit's residual: each measurement's commands replayed through :func:`simulate`.

For parameter values θ the scene is the base scene with θ laid over it, at each measurement's
own control rate; the run starts in the scene's initial state (the rest state at 0 V, as
sim_node starts) and holds each command for its period. The residual is measured minus
simulated at every measured sample, divided by its channel's noise level, all measurements and
channels in one vector. Finite-difference sensitivities (one run per parameter) are evaluated
serially, on threads (the compiled run releases the GIL) or in processes.
"""

from __future__ import annotations

import concurrent.futures
import copy
import os

import numpy as np

from .measurement import CalibrationError, CHANNELS, noise_level
from .parameters import from_z

__all__ = ['Problem', 'Evaluator', 'make_evaluator', 'FAULT_RESIDUAL', 'FD_STEP',
           'PARALLEL_MIN_CALL']

# weighted residual of every sample when the model leaves its domain (a rejected trial step)
FAULT_RESIDUAL = 1e3
# forward-difference step in the fit coordinates: 0.1 % of a log-scale value (1 % bends the
# beam's phase enough over a ring-down to bias the stiffness and mass columns)
FD_STEP = 1e-3
# 'auto' evaluates on threads when one run of the logs takes at least this long, s
PARALLEL_MIN_CALL = 0.5


class Problem:
    """
    The weighted residual of measurements as a function of the fit coordinates z.

    :param sigma: channel -> noise level (SI units) for every measurement; the others are
        estimated from the data (:func:`~.measurement.noise_level`).
    """

    def __init__(self, scene, measurements, parameters, sigma=None):
        self.scene = scene
        self.measurements = list(measurements)
        self.parameters = list(parameters)
        self.blocks = []   # (measurement, channel, grid indices, measured (flat), weights)
        for m_index, measurement in enumerate(self.measurements):
            if measurement.volts.shape[1] != scene.n_dets:
                raise CalibrationError(f'{measurement.source}: {measurement.volts.shape[1]} '
                                       f'voltage(s) per command, the scene has {scene.n_dets} '
                                       'DET(s)')
            for name, channel in measurement.channels.items():
                given = (sigma or {}).get(name)
                level = noise_level(channel) if given is None else \
                    np.full(channel.values.shape[1], float(given))
                if not np.all(level > 0.0):
                    raise CalibrationError(f'{name}: the noise level must be above 0')
                channel.sigma = level
                self.blocks.append((m_index, name, channel.index, channel.values,
                                    1.0 / level))
        self.size = sum(block[3].size for block in self.blocks)

    def scene_at(self, values, dt: float | None = None):
        """Return the base scene with parameter values laid over it (at rate 1/dt if given)."""
        changes = {p.key: float(v) for p, v in zip(self.parameters, values)}
        if dt is not None and abs(dt - self.scene.dt) > 1e-12 * dt:
            changes['rate_hz'] = 1.0 / dt
        return self.scene.replace(**changes)

    def simulate(self, z) -> list:
        """
        Return per measurement: channel -> simulated values (grid points, DETs).

        :raises ModelDomainError: the run left the model's domain.
        """
        from ..io.contract import rest_shortenings
        from ..sim.simulator import simulate, Simulator
        values = from_z(self.parameters, z)
        runs = []
        for measurement in self.measurements:
            scene = self.scene_at(values, measurement.dt)
            sim = Simulator(scene)
            result = simulate(sim, measurement.volts, measurement.periods * sim.dt)
            channels = {}
            for name in measurement.channels:
                output, relative = CHANNELS[name]
                columns = np.column_stack([result.outputs[sim.output_names[i]]
                                           for i in sim.model.channel(output)])
                if relative:   # published relative to the rest state at 0 V
                    columns = np.asarray(rest_shortenings(scene)) - columns
                channels[name] = columns
            runs.append(channels)
        return runs

    def residual(self, z, window: int = 1) -> np.ndarray:
        """
        Return the weighted residual, (measured - simulated) / sigma, as one vector.

        ``window`` > 1: of the moving averages over that many samples, which remove the
        beam's ringing (a fit to them has one basin where the ringing's phase has many).
        """
        from ..physics.model import ModelDomainError
        try:
            runs = self.simulate(z)
        except ModelDomainError:
            return np.full(self.residual_size(window), FAULT_RESIDUAL)
        return self.residual_of(runs, window)

    def residual_size(self, window: int = 1) -> int:
        """Return the length of :meth:`residual`'s vector."""
        return sum(max(len(block[3]) - window + 1, 0) * block[3].shape[1]
                   for block in self.blocks)

    def residual_of(self, runs, window: int = 1) -> np.ndarray:
        """Return the weighted residual of simulated runs (:meth:`simulate`)."""
        parts = [_smoothed((measured - runs[m][name][index]) * weights, window).ravel()
                 for m, name, index, measured, weights in self.blocks]
        return np.concatenate(parts) if parts else np.zeros(0)

    def rms(self, runs) -> dict:
        """Return (source, channel) -> RMS of measured - simulated (SI units), all DETs."""
        return {(self.measurements[m].source, name):
                float(np.sqrt(np.mean((measured - runs[m][name][index]) ** 2)))
                for m, name, index, measured, _ in self.blocks}

    def matching(self, runs, scene, parameters=None) -> 'Problem':
        """
        Return the problem of matching simulated runs (:meth:`simulate`) at another scene.

        The same samples and weights, with ``runs`` in place of the measured values, varying
        ``parameters`` (default: all of this problem's; the others keep the scene's values): its
        optimum is the parameters at which ``scene`` behaves most like the runs.
        """
        other = copy.copy(self)
        other.scene = scene
        other.parameters = list(self.parameters if parameters is None else parameters)
        other.blocks = [(m, name, index, runs[m][name][index], weights)
                        for m, name, index, _, weights in self.blocks]
        return other

    def jacobian(self, z, f0, evaluator, step: float = FD_STEP, window: int = 1) -> np.ndarray:
        """Return the forward-difference Jacobian of :meth:`residual` (backward at a bound)."""
        points, steps = self._shifted(z, step)
        columns = evaluator.evaluate(points, window)
        return np.column_stack([(f - f0) / h for f, h in zip(columns, steps)])

    def linearize(self, z, evaluator, step: float = FD_STEP, window: int = 1) -> tuple:
        """Return (:meth:`residual`, :meth:`jacobian`) at z, their runs evaluated as one batch."""
        points, steps = self._shifted(z, step)
        f0, *columns = evaluator.evaluate([np.array(z, dtype=float), *points], window)
        return f0, np.column_stack([(f - f0) / h for f, h in zip(columns, steps)])

    def _shifted(self, z, step: float) -> tuple:
        """Return the points z + h e_j and the steps h (backward where forward is outside)."""
        upper = [p.to_z(p.upper) for p in self.parameters]
        points, steps = [], []
        for j in range(len(z)):
            h = step if z[j] + step <= upper[j] else -step
            point = np.array(z, dtype=float)
            point[j] += h
            points.append(point)
            steps.append(h)
        return points, steps


class Evaluator:
    """Evaluate :meth:`Problem.residual` at several points: serially, on threads or processes."""

    def __init__(self, problem: Problem, kind: str = 'serial', workers: int = 1):
        self.problem, self.kind, self.workers = problem, kind, max(1, workers)
        self.calls = 0
        self._pool = None
        if kind == 'threads' and self.workers > 1:
            self._pool = concurrent.futures.ThreadPoolExecutor(self.workers)
        elif kind == 'processes' and self.workers > 1:
            self._pool = concurrent.futures.ProcessPoolExecutor(
                self.workers, initializer=_install, initargs=(problem,))
        elif kind not in ('serial', 'threads', 'processes'):
            raise CalibrationError(f'unknown evaluator {kind!r}: serial, threads or processes')

    def evaluate(self, points, window: int = 1) -> list:
        """Return the residual at each point (in order; ``window``: :meth:`Problem.residual`)."""
        points = list(points)
        self.calls += len(points)
        if self._pool is None or len(points) == 1:
            return [self.problem.residual(z, window) for z in points]
        run = _residual_in_worker if self.kind == 'processes' else self.problem.residual
        return list(self._pool.map(run, points, [window] * len(points)))

    def runs(self, points) -> list:
        """Return :meth:`Problem.simulate` at each point (None where the run left the domain)."""
        points = list(points)
        self.calls += len(points)
        if self._pool is None or len(points) == 1:
            return [_runs_or_none(self.problem, z) for z in points]
        if self.kind == 'processes':
            return list(self._pool.map(_runs_in_worker, points))
        return list(self._pool.map(_runs_or_none, [self.problem] * len(points), points))

    def close(self) -> None:
        """Stop the workers."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


def make_evaluator(problem: Problem, parallel: str = 'auto',
                   call_seconds: float = 0.0) -> Evaluator:
    """
    Return the evaluator ``parallel`` names: 'serial', 'threads', 'processes' or 'auto'.

    'auto' is threads on every core when there is more than one and a run of the logs takes at
    least :data:`PARALLEL_MIN_CALL` (``call_seconds``, as measured), else serial: the compiled
    run releases the GIL, but each run's Python part (scene, model, rest state) does not, and
    on a shared 2-core host threads do not pay for the short runs of a 10 s log at
    ``fidelity: paper`` (docs/calibration.md, "Measured accuracy and speed"; bench/fit_speed.py).
    """
    cores = os.cpu_count() or 1
    if parallel == 'auto':
        parallel = 'threads' if cores > 1 and call_seconds >= PARALLEL_MIN_CALL else 'serial'
    return Evaluator(problem, parallel, 1 if parallel == 'serial' else cores)


_WORKER_PROBLEM = []


def _install(problem) -> None:
    _WORKER_PROBLEM[:] = [problem]


def _residual_in_worker(z, window) -> np.ndarray:
    return _WORKER_PROBLEM[0].residual(z, window)


def _runs_in_worker(z):
    return _runs_or_none(_WORKER_PROBLEM[0], z)


def _runs_or_none(problem, z):
    from ..physics.model import ModelDomainError
    try:
        return problem.simulate(z)
    except ModelDomainError:
        return None


def _smoothed(values: np.ndarray, window: int) -> np.ndarray:
    """Return the moving averages of each column over ``window`` samples (valid part only)."""
    if window <= 1:
        return values
    if len(values) < window:
        return values[:0]
    sums = np.cumsum(np.vstack([np.zeros((1, values.shape[1])), values]), axis=0)
    return (sums[window:] - sums[:-window]) / window
