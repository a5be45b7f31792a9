"""
:func:`fit`: scene parameters from measured logs, by weighted least squares from several starts.

The optimizer is scipy's ``least_squares`` (trust-region reflective, with the parameters'
bounds) on the fit coordinates (log scale for positive parameters), with forward-difference
sensitivities evaluated in parallel. The beam is bistable: parameters far off can put a run on
the other branch, where the residual is large and the local search may stall. So the fit first
scores a few candidate starts around the given one (one run each), runs the local search from
the given start and the best-scoring others, and keeps the lowest cost.
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Callable, Mapping, Sequence

import numpy as np

from .intervals import uncertainty
from .measurement import CalibrationError, Measurement, read_csv
from .parameters import fit_parameters, from_z, to_z
from .problem import make_evaluator, Problem

__all__ = ['fit', 'FitResult', 'StartOutcome', 'load_measurements']

# candidate starts: the given one and others spread by up to this factor (log scale) or
# fraction (linear scale) around it
START_SPREAD_LOG = 2.5
START_SPREAD_LINEAR = 0.25
# residual evaluations of each start before the best one alone goes on
PROBE_EVALUATIONS = 6
# the first searches fit moving averages over this time, s: about four periods of the beam's
# 85 Hz mode, whose ringing they remove
SMOOTHING = 0.05
# relative decrease of the cost below which a search stops (cost ~ N/2 at the noise level: a
# change far below one unit of chi^2)
FTOL = 1e-6


@dataclasses.dataclass
class StartOutcome:
    """One local search: its start values, final cost (½|r|²), evaluations and scipy status."""

    start: list
    cost: float
    evaluations: int
    status: int
    message: str


@dataclasses.dataclass
class FitResult:
    """
    A fit's outcome: the fitted scene, each parameter's estimate and the residuals.

    ``rms_before``/``rms_after``: (source, channel) -> RMS of measured - simulated at the start
    and at the optimum (SI units); ``noise``: (source, channel) -> the noise level used as the
    weight; ``traces``: per measurement, what the plot draws.
    """

    scene: object
    start_scene: object
    parameters: list
    estimates: list
    correlation: np.ndarray
    singular_values: np.ndarray
    residual_variance: float
    dof: int
    rms_before: dict
    rms_after: dict
    noise: dict
    converged: bool
    message: str
    starts: list
    simulate_calls: int
    wall_time: float
    samples: int
    traces: list
    parallel: str = 'serial'

    @property
    def values(self) -> dict:
        """Return parameter name -> fitted value."""
        return {e.name: e.value for e in self.estimates}

    @property
    def flagged(self) -> list:
        """Return the names of the parameters the log does not identify."""
        return [e.name for e in self.estimates if e.flags]

    def report(self) -> str:
        """Return the text report, as ``det_sim fit`` prints it."""
        from .report import report_text
        return report_text(self)

    def write(self, path: str, plot: bool = True) -> list:
        """Write the scene YAML at ``path``, the report and the PNG beside it; return the paths."""
        from .report import write_outputs
        return write_outputs(self, path, plot)


def load_measurements(logs, mapping: Mapping | None = None) -> list:
    """Return a :class:`Measurement` per log: MCAP files or directories, CSV files, or as given."""
    from .logs import parse_mapping, read_log
    mapping = parse_mapping(mapping) if mapping else None   # a bad one fails before any read
    if isinstance(logs, (str, os.PathLike, Measurement)):
        logs = [logs]
    measurements = []
    for log in logs:
        if isinstance(log, Measurement):
            measurements.append(log)
            continue
        path = os.fspath(log)
        if not os.path.exists(path):
            raise CalibrationError(f'{path}: no such file or directory')
        if path.lower().endswith('.csv'):
            measurements.append(read_csv(path))
        else:
            measurements.append(read_log(path, mapping))
    if not measurements:
        raise CalibrationError('no log to fit')
    return measurements


def _base_scene(scene, measurements):
    from ..scenes.scene import load_scene, Scene
    if isinstance(scene, Scene):
        return scene
    if scene is not None:
        return load_scene(scene)
    logged = [m.scene for m in measurements if m.scene is not None]
    return logged[0] if logged else load_scene('default')


class _Objective:
    """The residual and Jacobian for least_squares (the residual at the last point kept)."""

    def __init__(self, problem, evaluator, report, window: int = 1):
        self.problem, self.evaluator, self.report = problem, evaluator, report
        self.window = window
        self._last = (None, None)
        self.iterations = 0

    def residual(self, z) -> np.ndarray:
        f = self.evaluator.evaluate([np.array(z)], self.window)[0]
        self._last = (np.array(z), f)
        return f

    def jacobian(self, z) -> np.ndarray:
        point, f0 = self._last
        if point is None or not np.array_equal(point, z):
            f0 = self.residual(z)
        self.iterations += 1
        self.report(self.iterations, z, 0.5 * float(f0 @ f0))
        return self.problem.jacobian(np.array(z), f0, self.evaluator, window=self.window)


def _candidates(parameters, z0, count: int, seed: int) -> list:
    """Return ``count`` starts: the given one, all parameters up and down by the spread, random."""
    rng = np.random.default_rng(seed)
    lower = np.array([p.to_z(p.lower) for p in parameters])
    upper = np.array([p.to_z(p.upper) for p in parameters])
    spread = np.array([np.log(START_SPREAD_LOG) if p.log else START_SPREAD_LINEAR
                       for p in parameters])
    points = [z0, np.clip(z0 + spread, lower, upper), np.clip(z0 - spread, lower, upper)]
    while len(points) < count:
        points.append(np.clip(z0 + rng.uniform(-spread, spread), lower, upper))
    return points[:max(count, 1)]


def _local_search(objective, z, parameters, max_evaluations: int):
    from scipy.optimize import least_squares
    lower = [p.to_z(p.lower) for p in parameters]
    upper = [p.to_z(p.upper) for p in parameters]
    return least_squares(objective.residual, z, jac=objective.jacobian, bounds=(lower, upper),
                         method='trf', x_scale='jac', xtol=1e-8, ftol=FTOL, gtol=1e-8,
                         max_nfev=max_evaluations)


def _searches(problem, evaluator, z0, starts: int, candidates: int, seed: int,
              max_evaluations: int, say) -> tuple:
    """
    Run the local searches; return (the final scipy result, [StartOutcome]).

    First on the moving averages over :data:`SMOOTHING` s (the ringing's phase makes the full
    residual's landscape many narrow basins; the averages have one wide one): each start runs
    :data:`PROBE_EVALUATIONS` evaluations, the lowest goes on to convergence (a start on the
    beam's other branch stays far above and is dropped). Then on the full residual from there.
    """
    parameters = problem.parameters
    window = max(1, int(round(SMOOTHING / min(m.dt for m in problem.measurements))))
    points = _candidates(parameters, z0, max(candidates, starts), seed)
    costs = [0.5 * float(f @ f) for f in evaluator.evaluate(points, window)]
    say(f'scored {len(points)} candidate starts: costs {min(costs):.4g} .. {max(costs):.4g}')
    order = [0] + [i for i in np.argsort(costs) if i != 0][:max(starts - 1, 0)]
    probe = PROBE_EVALUATIONS if len(order) > 1 else max_evaluations
    results, outcomes = [], []
    for n, i in enumerate(order, start=1):
        label = f'start {n}/{len(order)} (averaged)'
        result = _local_search(_Objective(problem, evaluator,
                                          _reporter(parameters, say, label), window),
                               points[i], parameters, probe)
        outcomes.append(StartOutcome(from_z(parameters, points[i]), float(result.cost),
                                     int(result.nfev), int(result.status), str(result.message)))
        results.append(result)
    best = min(results, key=lambda r: r.cost)
    if best.status == 0 and probe < max_evaluations:   # the probe's budget ran out: go on
        best = _local_search(_Objective(problem, evaluator,
                                        _reporter(parameters, say, 'best (averaged)'), window),
                             best.x, parameters, max_evaluations)
    final = _local_search(_Objective(problem, evaluator, _reporter(parameters, say, 'full')),
                          best.x, parameters, max_evaluations)
    return final, outcomes


def _reporter(parameters, say, label: str):
    def report(iteration, z, cost):
        shown = ', '.join(f'{p.name}={v:.5g}' for p, v in zip(parameters, from_z(parameters, z)))
        say(f'{label}, iteration {iteration}: cost {cost:.6g} ({shown})')
    return report


def _runs(problem, z):
    from ..physics.model import ModelDomainError
    try:
        return problem.simulate(z)
    except ModelDomainError:
        return None


def _traces(problem, before, after) -> list:
    traces = []
    for m, measurement in enumerate(problem.measurements):
        channels = {name: (channel.index, channel.values,
                           None if before is None else before[m][name],
                           None if after is None else after[m][name])
                    for name, channel in measurement.channels.items()}
        traces.append({'source': measurement.source, 't': measurement.t,
                       'volts': measurement.volts, 'channels': channels})
    return traces


def fit(logs, params: Sequence[str] | str, scene=None, *, mapping: Mapping | None = None,
        start: Mapping[str, float] | None = None, bounds: Mapping[str, tuple] | None = None,
        sigma: Mapping[str, float] | None = None, starts: int = 3, candidates: int = 6,
        max_evaluations: int = 60, parallel: str = 'auto', seed: int = 0,
        progress: Callable[[str], None] | None = None) -> FitResult:
    """
    Fit scene parameters to measured logs and return a :class:`FitResult`.

    :param logs: a log or a list: sim_node MCAP logs (file or directory), rig MCAP logs (with
        ``mapping``), CSV files (t, v, dy / charge / current), or :class:`Measurement` objects.
    :param params: parameter names, 'E_M,eta_M' or ['E_M', 'physics.eta_M'].
    :param scene: the base scene (a Scene, a file or a name; default: the scene the first
        sim_node log recorded, else 'default').
    :param mapping: a rig log's channels, ``{'voltage': '/rig/cmd.data', 'dy': ...}``
        (det_sim_ros.calibration.logs).
    :param start, bounds: name -> start value, name -> (lower, upper) (None: the default).
    :param sigma: channel -> noise level in SI units (default: estimated from the data).
    :param starts: local searches (the given start and the best-scoring other candidates).
    :param candidates: candidate starts scored (one run each), the given one included.
    :param max_evaluations: residual evaluations per local search before it gives up.
    :param parallel: 'auto', 'threads', 'processes' or 'serial' (the sensitivities' runs;
        'auto': threads when a run takes 0.5 s or more, see :func:`~.problem.make_evaluator`).
    :param progress: called with a line of text per iteration.
    :raises CalibrationError: bad input (one line).
    """
    began = time.monotonic()
    say = progress or (lambda text: None)
    try:
        import scipy.optimize  # noqa: F401 - the search and the intervals need it
    except ImportError:
        raise CalibrationError("det_sim_ros.fit needs scipy: pip install 'scipy>=1.11'") \
            from None
    measurements = load_measurements(logs, mapping)
    base = _base_scene(scene, measurements)
    names = params.split(',') if isinstance(params, str) else list(params)
    parameters = fit_parameters([n for n in names if n.strip()], base, start, bounds)
    samples = sum(m.samples for m in measurements)
    if samples <= len(parameters):
        raise CalibrationError(f'{samples} measured sample(s) for {len(parameters)} '
                               'parameter(s): a fit needs more samples than parameters')
    problem = Problem(base, measurements, parameters, sigma)
    z0 = to_z(parameters, [p.start for p in parameters])
    timed = time.monotonic()
    problem.residual(z0)   # the cost of a run decides whether threads pay
    evaluator = make_evaluator(problem, parallel, time.monotonic() - timed)
    try:
        best, outcomes = _searches(problem, evaluator, z0, starts, candidates, seed,
                                   max_evaluations, say)
    finally:
        evaluator.close()
    return _result(problem, z0, best, outcomes, evaluator, samples, time.monotonic() - began)


def _result(problem, z0, best, outcomes, evaluator, samples: int, wall: float) -> FitResult:
    parameters = problem.parameters
    stats = uncertainty(best.jac, best.fun, parameters, best.x)
    z_fit = [p.to_z(e.value) for p, e in zip(parameters, stats.estimates)]
    before, after = _runs(problem, z0), _runs(problem, z_fit)
    nan = {key: float('nan') for key in ((problem.measurements[m].source, name)
                                         for m, name, *_ in problem.blocks)}
    noise = {(problem.measurements[m].source, name):
             problem.measurements[m].channels[name].sigma for m, name, *_ in problem.blocks}
    converged = best.status > 0
    message = ('converged: ' if converged else 'did not converge: ') + str(best.message)
    return FitResult(
        scene=problem.scene_at([e.value for e in stats.estimates]), start_scene=problem.scene,
        parameters=parameters, estimates=stats.estimates, correlation=stats.correlation,
        singular_values=stats.singular_values, residual_variance=stats.residual_variance,
        dof=stats.dof, rms_before=nan if before is None else problem.rms(before),
        rms_after=nan if after is None else problem.rms(after), noise=noise,
        converged=converged, message=message, starts=outcomes,
        simulate_calls=evaluator.calls + 3, wall_time=wall, samples=samples,
        traces=_traces(problem, before, after), parallel=evaluator.kind)
