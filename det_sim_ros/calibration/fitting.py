"""
:func:`fit`: scene parameters from measured logs, by weighted least squares from several starts.

The optimizer is scipy's ``least_squares`` (trust-region reflective, with the parameters'
bounds) on the fit coordinates (log scale for positive parameters), with forward-difference
sensitivities evaluated in parallel. The beam is bistable: parameters far off can put a run on
the other branch, where the residual is large and the local search may stall. So the fit first
scores a few candidate starts around the given one (one run each), runs the local search from
the given start and the best-scoring others, and keeps the lowest cost.

That search runs at a cheap coarse level of the scene (:mod:`.levels`); the scene's own level
then corrects the coarse optimum (:func:`_polish`): one run there, a coarse fit to that run
(which tells how far the coarse level's optimum sits from the scene's), and a Gauss-Newton step
with the scene's sensitivities that checks the result, or a local search from it when the step
would still move it.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from typing import Callable, Mapping, Sequence

import numpy as np

from .intervals import MAX_DIRECTION_SE, RCOND, uncertainty
from .levels import fit_levels
from .measurement import CalibrationError, Measurement, read_csv
from .parameters import fit_parameters, from_z, to_z
from .problem import Evaluator, make_evaluator, Problem

__all__ = ['fit', 'FitResult', 'StartOutcome', 'PassOutcome', 'load_measurements']

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
# the polish stops when a Gauss-Newton step at the scene's level would lower the cost by less
# than this times the residual variance: the step moves the estimates by less than
# sqrt(2 x 0.05) = 0.32 standard errors (in the direction they are best determined, less)
POLISH_DECREASE = 0.05
# Gauss-Newton steps at the scene's level after the space-mapping step before a local search
# takes over (each is one batch of a run and one per parameter)
POLISH_STEPS = 2
# Runs per fitted parameter, for the time said up front (bench/fit_speed.py, 3 and 5 parameters
# of a 10 s log: 59 and 75 at the coarse level's search, 8-10 at the scene's level's polish)
SEARCH_RUNS_PER_PARAMETER = 70
POLISH_RUNS_PER_PARAMETER = 10


@dataclasses.dataclass
class StartOutcome:
    """One local search: its start values, final cost (½|r|²), evaluations and scipy status."""

    start: list
    cost: float
    evaluations: int
    status: int
    message: str


@dataclasses.dataclass
class PassOutcome:
    """
    One pass of a fit at one model level: its role, level, what it did and what it cost.

    ``role``: 'coarse' (the search from several starts) or 'scene' (the scene's own level: the
    polish after a coarse pass, else the whole search); ``level``: fidelity, Ritz terms and
    integrator tolerance (:meth:`~.levels.Level.describe`); ``values``: name -> value at the
    pass's optimum; ``start``: name -> value where it began (the given start; the polish's: the
    space-mapping step's result from the coarse optimum, or the coarse optimum itself when no
    step could be made).
    """

    role: str
    level: str
    work: str
    simulate_calls: int
    wall_time: float
    parallel: str
    values: dict
    start: dict = dataclasses.field(default_factory=dict)


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
    passes: list = dataclasses.field(default_factory=list)

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
        self._known = (None, None, None)
        self.iterations = 0

    def know(self, z, f, jacobian) -> None:
        """Keep a residual and Jacobian already evaluated at z (the search starts there)."""
        self._known = (np.array(z), f, jacobian)

    def residual(self, z) -> np.ndarray:
        point, f, _ = self._known
        if point is None or not np.array_equal(point, z):
            f = self.evaluator.evaluate([np.array(z)], self.window)[0]
        self._last = (np.array(z), f)
        return f

    def jacobian(self, z) -> np.ndarray:
        point, f0 = self._last
        if point is None or not np.array_equal(point, z):
            f0 = self.residual(z)
        self.iterations += 1
        self.report(self.iterations, z, f0)
        known, _, jacobian = self._known
        if known is not None and np.array_equal(known, z):
            return jacobian
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
    residuals = evaluator.evaluate(points, window)
    costs = [0.5 * float(f @ f) for f in residuals]
    misfits = [_misfit(f) for f in residuals]
    say(f'tried {len(points)} starting points: misfit {min(misfits):.3g} .. {max(misfits):.3g} x '
        'noise (a start on the wrong side of the snap-through is far off)')
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


def _misfit(f) -> float:
    """Return the weighted residual's RMS: the misfit in units of the noise (1 = at the noise)."""
    return math.sqrt(float(f @ f) / max(len(f), 1))


def _reporter(parameters, say, label: str):
    def report(iteration, z, f):
        shown = ', '.join(f'{p.name}={v:.5g}' for p, v in zip(parameters, from_z(parameters, z)))
        say(f'{label}, step {iteration}: misfit {_misfit(f):.3g} x noise ({shown})')
    return report


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
        coarse: bool = True, progress: Callable[[str], None] | None = None) -> FitResult:
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
    :param coarse: search at the coarse level and polish at the scene's (:mod:`.levels`); False:
        search at the scene's level alone.
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
    levels = fit_levels(base) if coarse else fit_levels(base)[-1:]
    problems = [Problem(level.scene, measurements, parameters, sigma) for level in levels]
    z0 = to_z(parameters, [p.start for p in parameters])
    search = _Pass(levels[0], problems[0], parallel, say)
    search.z_start = z0
    search.time_a_run(z0)
    try:
        say(f'searching at {search.level.describe()}: '
            f'{search.expected(SEARCH_RUNS_PER_PARAMETER)}')
        best, outcomes = _searches(problems[0], search.evaluator, z0, starts, candidates, seed,
                                   max_evaluations, say)
        search.done(f'{len(outcomes)} local search(es) from {max(candidates, starts)} '
                    'candidate starts', best.x)
        passes = [search]
        if len(levels) > 1:
            polish = _Pass(levels[1], problems[1], parallel, say)
            passes.append(polish)
            try:
                best = _polish(polish, search, best, max_evaluations)
                return _result(polish, z0, best, outcomes, passes, samples, began)
            finally:
                polish.close()
        return _result(search, z0, best, outcomes, passes, samples, began)
    finally:
        search.close()


class _Pass:
    """A fit's work at one level: its problem, its evaluator (picked by a run's cost), a tally."""

    def __init__(self, level, problem, parallel: str, say):
        self.level, self.problem, self.parallel, self.say = level, problem, parallel, say
        self.evaluator = None
        self.extra_runs = 0   # runs outside the evaluator: the timed one
        self.run_seconds = 0.0   # wall time of that run
        self.work = ''
        self.z = None
        self.z_start = None
        self._began = time.monotonic()
        self._wall = None

    def time_a_run(self, z, simulate: bool = False):
        """Run at z once and pick the evaluator by its cost; return the runs or the residual."""
        timed = time.monotonic()
        value = _runs_or_none(self.problem, z) if simulate else self.problem.residual(z)
        self.run_seconds = time.monotonic() - timed
        self.evaluator = make_evaluator(self.problem, self.parallel, self.run_seconds)
        self.extra_runs += 1
        return value

    def expected(self, runs_per_parameter: int) -> str:
        """Say roughly how long the pass will take, from its first run's wall time."""
        runs = runs_per_parameter * len(self.problem.parameters)
        return (f'one run takes {self.run_seconds:.2g} s; expect about {runs} runs, '
                f'~{runs * self.run_seconds:.0f} s (fewer on two threads)')

    def done(self, work: str, z=None) -> None:
        """Note what the pass did and where it ended (z); stop its clock."""
        self.work = work
        self.z = self.z if z is None else np.array(z, dtype=float)
        self._wall = time.monotonic() - self._began

    def outcome(self) -> PassOutcome:
        """Return the pass's :class:`PassOutcome`."""
        wall = self._wall if self._wall is not None else time.monotonic() - self._began
        parameters = self.problem.parameters

        def named(z):
            return {} if z is None else {p.name: v for p, v in zip(parameters,
                                                                   from_z(parameters, z))}
        return PassOutcome(self.level.role, self.level.describe(), self.work,
                           self.evaluator.calls + self.extra_runs, wall, self.evaluator.kind,
                           named(self.z), named(self.z_start))

    def close(self) -> None:
        """Stop the evaluator's workers."""
        if self.evaluator is not None:
            self.evaluator.close()


def _polish(polish: _Pass, search: _Pass, coarse, max_evaluations: int):
    """
    Return the scene level's optimum from the coarse level's one (a scipy OptimizeResult).

    The parameters that make the coarse level behave like the scene's level at z are about
    z + d, with an offset d that hardly changes over the small distance between the two
    levels' optima (the coarse level's model error, absorbed by the parameters). One run at the
    scene's level at the coarse optimum z_c and a coarse fit to it give d; the scene's optimum
    is then about z_c - d (a space-mapping step: one expensive run instead of a search). A
    Gauss-Newton step with the scene level's own sensitivities at that point checks it: when
    the step would lower the cost by less than :data:`POLISH_DECREASE` x the residual variance
    it is the answer; else up to :data:`POLISH_STEPS` such steps go on while they lower the
    cost, and then a local search at the scene's level.
    """
    from scipy.optimize import OptimizeResult
    problem, parameters = polish.problem, polish.problem.parameters
    lower = np.array([p.to_z(p.lower) for p in parameters])
    upper = np.array([p.to_z(p.upper) for p in parameters])
    z = np.array(coarse.x, dtype=float)
    runs = polish.time_a_run(z, simulate=True)
    polish.say(f'polishing at {polish.level.describe()}: '
               f'{polish.expected(POLISH_RUNS_PER_PARAMETER)}')
    coarse_runs = 0
    free = _determined(coarse, parameters)
    if runs is not None and free:
        coarse_scene = search.problem.scene_at(from_z(parameters, z))
        target = search.problem.matching(runs, coarse_scene, [parameters[j] for j in free])
        evaluator = Evaluator(target, search.evaluator.kind, search.evaluator.workers)
        try:
            mapped = _local_search(_Objective(target, evaluator, lambda *args: None),
                                   z[free], target.parameters, max_evaluations)
        finally:
            evaluator.close()
        coarse_runs = evaluator.calls
        polish.extra_runs += coarse_runs
        z[free] = np.clip(z[free] + (z[free] - mapped.x), lower[free], upper[free])
    polish.z_start = z.copy()
    f, jacobian = problem.linearize(z, polish.evaluator)
    for steps in range(POLISH_STEPS + 1):
        step, decrease, variance = _gauss_newton(f, jacobian)
        moves = math.sqrt(2.0 * max(decrease, 0.0) / variance) if variance > 0 else math.inf
        polish.say(f"at the scene's level: misfit {_misfit(f):.3g} x noise; one more step would "
                   f'move the estimates by about {moves:.2g} standard errors (done below '
                   f'{math.sqrt(2.0 * POLISH_DECREASE):.2g})')
        if decrease <= POLISH_DECREASE * variance:
            polish.done(f'a space-mapping step from the coarse optimum ({coarse_runs} of the runs '
                        f'at the coarse level) and {steps} Gauss-Newton step(s), checked by one',
                        z)
            message = (f"a Gauss-Newton step at the scene's level would lower the cost by "
                       f'{decrease:.3g}, below {POLISH_DECREASE:g} x the residual variance')
            return OptimizeResult(x=z, fun=f, jac=jacobian, cost=0.5 * float(f @ f), status=1,
                                  message=message, nfev=steps + 1)
        if steps == POLISH_STEPS:
            break
        trial = np.clip(z + step, lower, upper)
        f_trial, jacobian_trial = problem.linearize(trial, polish.evaluator)
        if f_trial @ f_trial >= f @ f:   # the linearisation does not hold: search from z
            break
        z, f, jacobian = trial, f_trial, jacobian_trial
    objective = _Objective(problem, polish.evaluator,
                           _reporter(parameters, polish.say, "scene's level"))
    objective.know(z, f, jacobian)
    result = _local_search(objective, z, parameters, max_evaluations)
    polish.done(f'a space-mapping step from the coarse optimum ({coarse_runs} of the runs at '
                f'the coarse level), Gauss-Newton steps, then a local search ({result.nfev} '
                'evaluations)', result.x)
    return result


def _determined(coarse, parameters) -> list:
    """
    Return the indices of the parameters the coarse optimum determines (a finite interval).

    One the log cannot identify moves the matching fit's optimum anywhere along its flat
    direction; the polish keeps it at its coarse value.
    """
    stats = uncertainty(coarse.jac, coarse.fun, parameters, coarse.x)
    return [j for j, e in enumerate(stats.estimates) if math.isfinite(e.se)]


def _gauss_newton(f, jacobian) -> tuple:
    """
    Return (the Gauss-Newton step, the cost decrease it predicts, the residual variance).

    Over the directions the log determines: a direction whose standard error exceeds
    :data:`~.intervals.MAX_DIRECTION_SE` (the data cannot fix it within a factor e; the
    intervals hold its parameters) may ask for a step far outside the bounds and the
    linearisation, and is left out, as the intervals leave it out.
    """
    dof = max(len(f) - jacobian.shape[1], 1)
    variance = float(f @ f) / dof
    u, singular, vt = np.linalg.svd(jacobian, full_matrices=False)
    top = singular[0] if singular.size and singular[0] > 0 else 1.0
    kept = (singular > RCOND * top) & (singular * MAX_DIRECTION_SE > math.sqrt(variance))
    projected = u[:, kept].T @ f
    step = -vt[kept].T @ (projected / singular[kept])
    return step, 0.5 * float(projected @ projected), variance


def _runs_or_none(problem, z):
    from ..physics.model import ModelDomainError
    try:
        return problem.simulate(z)
    except ModelDomainError:
        return None


def _result(last: _Pass, z0, best, outcomes, passes, samples: int, began: float) -> FitResult:
    """Return the FitResult: intervals at the optimum, runs at the start and at the optimum."""
    problem = last.problem
    parameters = problem.parameters
    stats = uncertainty(best.jac, best.fun, parameters, best.x)
    z_fit = [p.to_z(e.value) for p, e in zip(parameters, stats.estimates)]
    before, after = last.evaluator.runs([z0, z_fit])
    nan = {key: float('nan') for key in ((problem.measurements[m].source, name)
                                         for m, name, *_ in problem.blocks)}
    noise = {(problem.measurements[m].source, name):
             problem.measurements[m].channels[name].sigma for m, name, *_ in problem.blocks}
    converged = best.status > 0
    message = ('converged: ' if converged else 'did not converge: ') + str(best.message)
    last.done(last.work)   # its wall time includes the runs at the start and the optimum
    outcomes_of_passes = [p.outcome() for p in passes]
    return FitResult(
        scene=problem.scene_at([e.value for e in stats.estimates]), start_scene=problem.scene,
        parameters=parameters, estimates=stats.estimates, correlation=stats.correlation,
        singular_values=stats.singular_values, residual_variance=stats.residual_variance,
        dof=stats.dof, rms_before=nan if before is None else problem.rms(before),
        rms_after=nan if after is None else problem.rms(after), noise=noise,
        converged=converged, message=message, starts=outcomes,
        simulate_calls=sum(p.simulate_calls for p in outcomes_of_passes),
        wall_time=time.monotonic() - began,
        samples=samples, traces=_traces(problem, before, after), parallel=last.evaluator.kind,
        passes=outcomes_of_passes)
