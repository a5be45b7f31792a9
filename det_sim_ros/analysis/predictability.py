"""
Is a run's path a result? A twin perturbed at a stated size, and how far it has drifted.

Under fast switching (a PWM, a bang-bang controller) a bistable beam can amplify a difference
in the last digits of a parameter or of the integration until the two paths snap differently:
the run is then deterministic but not robust, and a test asserting on its path passes or fails
by rounding. The measure here answers, per sample, how far a twin of the run has moved from it.

The twin is the same scene with a perturbation of a stated size (:class:`Perturbation`; by
default the interface mass 1 ppm heavier and the integrator's tolerance 10 % tighter: a
parameter's seventh digit and a change of the integration error, both below anything a user can
measure or would call a different setting), driven by the same commands. Its distance from the
run (:class:`Stroke`) is the larger of the distance in Δy over the rest shortening y0 (the rise
of a snap through) and the distance in q over the gap between the two rest states. A path is
not robust where that distance is beyond ``ROBUST_LIMIT`` of the stroke; a stretch
(:class:`Stretches`) ends once the twin has stayed back within half of it for HOLD_S.

Why a twin (an identical-twin experiment, Lorenz 1965; "breeding", Toth & Kalnay 1993) and not
the tangent-linear equation or a finite-time Lyapunov exponent (Benettin et al. 1980): the
question is a finite one (has a small difference grown to 5 % of the stroke, i.e. to a snap
made or missed), which a linearisation answers wrongly across a snap, where growth saturates;
it costs one more run of the same compiled stepper and no Jacobian; and its perturbation
persists (a parameter, a tolerance), so it needs no renormalisation: in a contracting stretch
the twin stays a parameter's sensitivity away instead of decaying to round-off, and a later
sensitive stretch starts from the stated size, not from 1e-16 (the finite-size Lyapunov view,
Aurell et al. 1997). docs/predictability.md has the choice, its cost and what it measured.

:func:`predictability` runs a scene and its twin offline; :class:`TwinMonitor` steps a twin
beside a :class:`~det_sim_ros.sim.simulator.Simulator` one period at a time (sim_node's
``predictability`` parameters).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from ..physics.model import ModelDomainError
from ..physics.statics import rest_state
from ..scenes.keys import PHYSICS_SPEC
from ..scenes.scene import load_scene, Scene, SceneError
from ..sim.integrators import integration_tolerance
from ..sim.simulator import simulate, Simulator

__all__ = ['PathNotRobustWarning', 'ROBUST_LIMIT', 'HOLD_S', 'Perturbation', 'Stroke',
           'Stretches', 'hold_samples', 'Predictability', 'predictability', 'TwinMonitor',
           'NO_STROKE', 'MANY_DETS']

ROBUST_LIMIT = 0.05   # fraction of the stroke: a twin further away means a different path
# s: how long a twin must stay back within half the limit for a stretch to end (~9 periods of
# the beam's lowest mode: paths apart ring out of phase and cross each other meanwhile)
HOLD_S = 0.1
MANY_DETS = 8   # from this many DETs on, one sample's distance is taken with numpy
NO_STROKE = 'the beams are straight at rest (no snap through): no stroke to measure against'


class PathNotRobustWarning(UserWarning):
    """A run whose path is not robust was used as one (the pytest plugin warns with it)."""


@dataclasses.dataclass(frozen=True)
class Perturbation:
    """
    What the twin changes: one physics parameter by a relative amount, and the tolerance.

    :param parameter: a ``physics`` key of the scene (default the interface mass ``m``).
    :param relative: the parameter becomes ``value * (1 + relative)`` (default 1e-6: 1 ppm).
        A parameter's uncertainty can go here (e.g. the relative half-width of its interval from
        ``det_sim fit``): the measure then says whether that uncertainty decides the path.
    :param tolerance_factor: the twin's integrator tolerance relative to the run's (default
        0.9; 1 leaves it; no effect with a fixed step count).
    """

    parameter: str = 'm'
    relative: float = 1e-6
    tolerance_factor: float = 0.9

    def __post_init__(self):
        if not (isinstance(self.relative, (int, float)) and math.isfinite(self.relative)
                and self.relative > -1.0):
            raise ValueError(f'perturbation relative: a finite number > -1 (got '
                             f'{self.relative!r})')
        if not (isinstance(self.tolerance_factor, (int, float))
                and math.isfinite(self.tolerance_factor) and self.tolerance_factor > 0.0):
            raise ValueError(f'perturbation tolerance_factor: a finite number > 0 (got '
                             f'{self.tolerance_factor!r})')
        if self.relative == 0.0 and self.tolerance_factor == 1.0:
            raise ValueError('perturbation: relative 0 and tolerance_factor 1 make the twin '
                             'the run itself')

    def overrides(self, scene: Scene, method: str | None = None) -> dict:
        """
        Return the twin's scene overrides: the perturbed parameter and tolerance.

        ``method``: the stepper the run resolved ('auto' picks by tolerance, and a twin of a
        tighter one must not step by another method): pinned in the twin's scene.
        """
        if self.parameter not in PHYSICS_SPEC:
            raise SceneError(f'perturbation parameter {self.parameter!r}: not a physics key '
                             f'(one of {", ".join(PHYSICS_SPEC)})')
        value = getattr(scene.physics, self.parameter)
        perturbed = type(value)(value * (1.0 + self.relative))
        if self.relative != 0.0 and perturbed == value:
            raise SceneError(f'perturbation parameter {self.parameter!r}: {self.relative:g} of '
                             f'{value!r} changes nothing (an integer, or below its precision)')
        changes = {f'physics.{self.parameter}': perturbed}
        if self.tolerance_factor != 1.0:
            changes['integrator.tolerance'] = (integration_tolerance(scene)
                                               * self.tolerance_factor)
        if method is not None:
            changes['integrator.method'] = method
        return changes

    def twin_scene(self, scene: Scene, method: str | None = None) -> Scene:
        """Return the twin's scene: ``scene`` with the parameter and tolerance perturbed."""
        return scene.replace(**self.overrides(scene, method))

    def describe(self) -> str:
        """Say what the twin changes, in a phrase ('m x (1 + 1e-06), tolerance x 0.9')."""
        parts = []
        if self.relative != 0.0:
            parts.append(f'{self.parameter} x (1 {"+" if self.relative > 0 else "-"} '
                         f'{abs(self.relative):g})')
        if self.tolerance_factor != 1.0:
            parts.append(f'tolerance x {self.tolerance_factor:g}')
        return ', '.join(parts)


class Stroke:
    """
    The scale a twin's distance is measured on, per DET; the distance of two output vectors.

    Δy over the rest shortening y0 (Δy when the beam passes straight: a snap's rise) and q over
    twice the rest deflection (the gap between the two buckled rest states; Δy alone cannot
    tell the branches apart, y being even in q).

    :raises SceneError: with :data:`NO_STROKE` when a beam is straight at rest.
    """

    def __init__(self, model):
        x_rest = rest_state(model)
        out = np.empty(len(model.output_names))
        from ..core import kernel
        status = model.kernel.outputs(x_rest, np.zeros(model.n_inputs), out)
        if status != kernel.OK:
            raise ModelDomainError(status, 'in the rest state')
        self.y_index = np.array(model.channel('y'))
        self.q_index = np.array(model.channel('q'))
        self.y0 = out[self.y_index]                  # m, rest shortening per DET
        self.q_gap = 2.0 * np.abs(out[self.q_index])   # m, between the two rest states
        if np.any(self.y0 <= 0.0) or np.any(self.q_gap <= 0.0):
            raise SceneError(NO_STROKE)
        self._per_det = [(int(iy), int(iq), 1.0 / y0, 1.0 / gap) for iy, iq, y0, gap in
                         zip(self.y_index, self.q_index, self.y0.tolist(), self.q_gap.tolist())]

    def distance(self, out, twin_out) -> float:
        """Return the twin's distance from the run at one sample, a fraction of the stroke."""
        if len(self._per_det) > MANY_DETS:
            return float(self.distances(out[None, :], twin_out[None, :])[0])
        # (per DET in plain floats: numpy's per-call cost on a few values is several times the
        # arithmetic, and a node pays this every period)
        largest = 0.0
        for iy, iq, per_y, per_q in self._per_det:
            d_y = abs(out[iy] - twin_out[iy]) * per_y
            d_q = abs(out[iq] - twin_out[iq]) * per_q
            if d_y != d_y or d_q != d_q:
                return math.nan
            largest = max(largest, d_y, d_q)
        return float(largest)

    def distances(self, outs, twin_outs) -> np.ndarray:
        """Return the distance at every sample of two (samples x outputs) arrays."""
        y, q = self.y_index, self.q_index
        # (times the reciprocals, as distance() does: the same bits per sample)
        per_y, per_q = 1.0 / self.y0, 1.0 / self.q_gap
        return np.maximum(np.max(np.abs(outs[:, y] - twin_outs[:, y]) * per_y, axis=1),
                          np.max(np.abs(outs[:, q] - twin_outs[:, q]) * per_q, axis=1))


class Stretches:
    """
    The stretches of a run where the path is not robust, fed one distance per sample.

    A stretch starts at the first sample beyond ``limit`` and ends at the first of ``hold``
    samples in a row back within ``limit / 2``: two paths apart ring out of phase and cross
    each other, and a crossing is not a return (:data:`HOLD_S` of sim time).
    """

    def __init__(self, limit: float = ROBUST_LIMIT, hold: int = 100):
        if not (isinstance(limit, (int, float)) and math.isfinite(limit) and limit > 0.0):
            raise ValueError(f'limit: a fraction of the stroke > 0 (got {limit!r})')
        self.limit = limit
        self.hold = max(1, int(hold))
        self.reset()

    def reset(self) -> None:
        """Forget every stretch (a run that starts over)."""
        self.spans: list = []    # [start, end) sample indices; end None while open
        self.peak = 0.0          # the largest distance seen, a fraction of the stroke
        self._within = 0         # samples in a row back within limit / 2 in an open stretch

    @property
    def open(self) -> bool:  # noqa: A003 - a stretch is open (not ended)
        """Return True while the path is not robust (a stretch has started and not ended)."""
        return bool(self.spans) and self.spans[-1][1] is None

    @property
    def first(self) -> int | None:
        """Return the sample where the path first stopped being robust, None if never."""
        return self.spans[0][0] if self.spans else None

    def add(self, k: int, distance: float) -> str:
        """Take sample k's distance; return 'start', 'end' (at sample k) or '' (no change)."""
        if not distance <= self.peak:   # (a NaN is beyond any limit: nothing vouches for it)
            self.peak = distance if distance == distance else math.inf
        if self.open:
            if distance <= 0.5 * self.limit:
                self._within += 1
                if self._within >= self.hold:
                    self.spans[-1][1] = k - self.hold + 1
                    return 'end'
            else:
                self._within = 0
        elif not distance <= self.limit:
            self.spans.append([k, None])
            self._within = 0
            return 'start'
        return ''

    def scan(self, distances) -> 'Stretches':
        """Take a whole run's distances (sample 0 first); return self."""
        for k, distance in enumerate(np.asarray(distances, dtype=float).tolist()):
            self.add(k, distance)
        return self


def hold_samples(dt: float) -> int:
    """Return :data:`HOLD_S` in control periods of ``dt`` seconds."""
    return max(1, int(round(HOLD_S / dt)))


@dataclasses.dataclass
class Predictability:
    """
    How far a perturbed twin drifted from a run, per sample (see the module's docstring).

    ``distance[k]``: the twin's distance at t[k], a fraction of the stroke; ``stretches``:
    [(t_start, t_end)] where it was beyond ``limit`` (t_end None: to the end of the run);
    ``robust_until``: the time the path first stopped being robust, None if never.
    """

    t: np.ndarray
    distance: np.ndarray
    stretches: list
    robust_until: float | None
    limit: float
    perturbation: Perturbation
    run: object            # the run's SimulationResult
    twin: object           # the twin's

    @property
    def robust(self) -> bool:
        """Return True if the twin stayed within the limit over the whole run."""
        return self.robust_until is None

    def summary(self) -> str:
        """Say in one line whether the path is robust, and from when not."""
        peak = float(np.max(self.distance)) if self.distance.size else 0.0
        twin = f'a twin ({self.perturbation.describe()})'
        if self.robust:
            return (f'robust: {twin} stayed within {100 * peak:.2g} % of the stroke (limit '
                    f'{100 * self.limit:g} %)')
        spans = ', '.join(f'{a:.3f}-{"end" if b is None else f"{b:.3f}"} s'
                          for a, b in self.stretches)
        return (f'not robust from t = {self.robust_until:.3f} s: {twin} moved up to '
                f'{100 * peak:.3g} % of the stroke (limit {100 * self.limit:g} %); not robust '
                f'over {spans}. Assert on statistics over perturbed runs, not on this path')


def predictability(scene, volts: Callable[[float], float] | np.ndarray, t_end: float,
                   perturbation: Perturbation | None = None,
                   limit: float = ROBUST_LIMIT) -> Predictability:
    """
    Run ``scene`` and its perturbed twin offline; return how far the twin drifted, per sample.

    :param scene: a :class:`Scene`, a scene name or file.
    :param volts: as :func:`~det_sim_ros.sim.simulator.simulate` takes them: a function v(t)
        or per-period voltages.
    :param t_end: end time, s.
    :param perturbation: what the twin changes (default: :class:`Perturbation`'s defaults).
    :param limit: the distance beyond which the path is not robust, a fraction of the stroke.
    """
    perturbation = perturbation or Perturbation()
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    run_sim = Simulator(scene)
    stroke = Stroke(run_sim.model)
    twin_sim = Simulator(perturbation.twin_scene(scene, run_sim.method.name))
    run = simulate(run_sim, volts, t_end)
    try:
        twin = simulate(twin_sim, volts, t_end)
    except ModelDomainError as exc:
        raise ModelDomainError(exc.status, f'(the twin, {perturbation.describe()}: {exc})') \
            from None
    names = run_sim.output_names
    outs = np.column_stack([run.outputs[name] for name in names])
    twin_outs = np.column_stack([twin.outputs[name] for name in names])
    distance = stroke.distances(outs, twin_outs)
    spans = Stretches(limit, hold_samples(run_sim.dt)).scan(distance).spans
    t = run.t
    stretches = [(float(t[a]), None if b is None else float(t[b])) for a, b in spans]
    return Predictability(t, distance, stretches, stretches[0][0] if stretches else None,
                          limit, perturbation, run, twin)


class TwinMonitor:
    """
    A perturbed twin stepped beside a simulator, one period at a time, and its distance.

    Call :meth:`follow` after each period of the run with its outputs: the twin takes the
    command the run held in that period (the same one, clamped alike; the amplifier and sensor
    stages are the twin's own copies) and steps. A twin that faults stops the measure
    (``fault`` says why); the run goes on. :meth:`reset` starts both over.

    :param sim: the run's simulator (its scene and state at t = 0).
    """

    def __init__(self, sim: Simulator, perturbation: Perturbation | None = None,
                 limit: float = ROBUST_LIMIT):
        self.perturbation = perturbation or Perturbation()
        self.stroke = Stroke(sim.model)
        self.twin = Simulator(self.perturbation.twin_scene(sim.scene, sim.method.name),
                              threads=sim.stepper.threads)
        self.stretches = Stretches(limit, hold_samples(sim.dt))
        self.distance = 0.0
        self.fault = ''
        self._held = None    # the run's command array the twin holds (identity: no compare)

    @property
    def limit(self) -> float:
        """Return the distance beyond which the path is not robust, a fraction of the stroke."""
        return self.stretches.limit

    def follow(self, sim: Simulator, out) -> str:
        """
        Step the twin through the period ``sim`` has just run; return 'start', 'end' or ''.

        ``out``: the run's outputs of that period.
        """
        if self.fault:
            return ''
        twin = self.twin
        if sim.u is not self._held:   # (set_input replaces u when it changes)
            self._held = sim.u
            twin.set_input(sim.u.tolist())
        try:
            twin_out = twin.step()
        except ModelDomainError as exc:
            self.fault = f'the twin ({self.perturbation.describe()}) faulted: {exc}'
            self.distance = math.nan
            return ''
        self.distance = distance = self.stroke.distance(out, twin_out)
        return self.stretches.add(sim.k, distance)

    def reset(self) -> None:
        """Start the twin over from its initial state (after the run's reset)."""
        self.twin.reset()
        self.stretches.reset()
        self.distance = 0.0
        self.fault = ''
        self._held = None
