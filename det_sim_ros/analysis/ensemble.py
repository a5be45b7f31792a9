"""
An ensemble of perturbed runs, and what all of them share: what a test can assert on.

Where a run's path is not robust (det_sim_ros.analysis.predictability), a single run is one
draw: a controller test asserting on its snap count or settling time passes or fails by the
last digits of a parameter. An ensemble runs the same input, or the same controller in closed
loop (each copy gets its own controller's answers), against copies of the plant perturbed at
the measure's stated size, and :meth:`Ensemble.shared` states what every copy agrees on: the
final branch, the range of snap counts, of the time on each branch, of settling times. Assert
on those.

Copy 0 is the scene itself; copy i > 0 has the perturbed parameter at ``value * (1 + r z_i)``
and the tolerance at ``tolerance * (1 - (1 - f) u_i)``, with r and f the
:class:`~det_sim_ros.analysis.predictability.Perturbation`'s sizes, z_i standard normal and
u_i uniform in [0, 1) from a seeded generator: the same seed gives the same copies.

:func:`ensemble` runs one offline; the pytest plugin's ``det_sim.ensemble`` runs one in
lockstep against your controller nodes (det_sim_ros.ros.testing).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from .predictability import Perturbation
from .response import SimRun, step_metrics
from .scenarios import snap_times
from ..scenes.scene import load_scene, Scene
from ..sim.simulator import simulate, Simulator

__all__ = ['ensemble_overrides', 'ensemble', 'Ensemble', 'SharedOutcome']


def ensemble_overrides(scene: Scene, copies: int, perturbation: Perturbation | None = None,
                       seed: int = 0) -> list[dict]:
    """
    Return each copy's scene overrides (copy 0: none), as the module's docstring draws them.

    Every copy steps by the method the scene resolves ('auto' picks by tolerance: a copy of a
    tighter one must not change method).

    :raises ValueError: fewer than 2 copies.
    """
    if not isinstance(copies, int) or copies < 2:
        raise ValueError(f'copies: an ensemble needs at least 2 (got {copies!r})')
    perturbation = perturbation or Perturbation()
    rng = np.random.default_rng(seed)
    z = rng.standard_normal(copies)
    u = rng.uniform(0.0, 1.0, copies)
    method = Simulator(scene).method.name
    overrides = [{}]
    for i in range(1, copies):
        copy = Perturbation(perturbation.parameter, perturbation.relative * float(z[i]),
                            1.0 - (1.0 - perturbation.tolerance_factor) * float(u[i]))
        overrides.append(copy.overrides(scene, method))
    return overrides


@dataclasses.dataclass(frozen=True)
class SharedOutcome:
    """
    What every copy of an ensemble agrees on (ranges are (lowest, highest) over the copies).

    ``final_branch``: 'buckled+' or 'buckled-' when every copy ends on it, None when they
    differ (``final_branches`` counts them); ``snaps``: sign changes of q from ``start``;
    ``time_on_plus``: the fraction of samples from ``start`` with q > 0; ``settling``: settling
    times (s after the step; None without a target), NaN in it when a copy never settles.
    """

    copies: int
    final_branch: str | None
    final_branches: dict
    snaps: tuple
    time_on_plus: tuple
    settling: tuple | None
    steady_state_error: tuple | None

    def __str__(self) -> str:
        branch = self.final_branch or ' / '.join(f'{n} {b}' for b, n in
                                                 sorted(self.final_branches.items()))
        text = (f'{self.copies} copies: final branch {branch}; snaps {self.snaps[0]}-'
                f'{self.snaps[1]}; time on q > 0 {100 * self.time_on_plus[0]:.1f}-'
                f'{100 * self.time_on_plus[1]:.1f} %')
        if self.settling is not None:
            text += f'; settling {self.settling[0]:.3f}-{self.settling[1]:.3f} s'
        return text


class Ensemble:
    """
    Runs of one input or controller against perturbed copies of a plant, and their statistics.

    :param runs: one run per copy, each with ``t`` (s) and ``q``, ``dy`` (m) arrays of
        (samples, DETs) (:class:`~det_sim_ros.analysis.response.SimRun`).
    :param overrides: each copy's scene overrides (what it changed), for the record.
    """

    def __init__(self, runs, overrides=None):
        self.runs = list(runs)
        self.overrides = list(overrides) if overrides is not None else [{}] * len(self.runs)

    def __len__(self) -> int:
        return len(self.runs)

    def snap_counts(self, start: float = 0.0, det: int = 0) -> np.ndarray:
        """Return each copy's number of snaps (sign changes of q) from ``start`` (s)."""
        return np.array([len(snap_times(run.t, run.q[:, det], start)) for run in self.runs])

    def time_on_plus(self, start: float = 0.0, det: int = 0) -> np.ndarray:
        """Return each copy's fraction of samples from ``start`` with q > 0."""
        return np.array([float(np.mean(run.q[run.t >= start - 1e-9, det] > 0.0))
                         for run in self.runs])

    def final_branches(self, det: int = 0) -> list:
        """Return each copy's branch at its last sample: 'buckled+' (q > 0) or 'buckled-'."""
        return ['buckled+' if run.q[-1, det] > 0.0 else 'buckled-' for run in self.runs]

    def envelope(self, name: str = 'dy', det: int = 0) -> tuple:
        """Return the lowest and highest value of a signal over the copies, per sample."""
        stacked = np.stack([getattr(run, name)[:, det] for run in self.runs])
        return stacked.min(axis=0), stacked.max(axis=0)

    def step_metrics(self, target: float, t_step: float, name: str = 'dy', det: int = 0,
                     band: float = 0.05) -> list:
        """Return each copy's step-response figures (:func:`~.response.step_metrics`)."""
        return [step_metrics(run.t, getattr(run, name)[:, det], target, t_step, band)
                for run in self.runs]

    def shared(self, start: float = 0.0, target: float | None = None,
               t_step: float | None = None, name: str = 'dy', det: int = 0,
               band: float = 0.05) -> SharedOutcome:
        """
        Return what every copy agrees on (:class:`SharedOutcome`).

        With ``target`` (and ``t_step``, default ``start``) also the settling times and
        steady-state errors of a set-point step of ``name``.
        """
        snaps = self.snap_counts(start, det)
        plus = self.time_on_plus(start, det)
        finals = self.final_branches(det)
        counts = {branch: finals.count(branch) for branch in sorted(set(finals))}
        settling = error = None
        if target is not None:
            figures = self.step_metrics(target, start if t_step is None else t_step, name,
                                        det, band)
            times = np.array([m.settling_time for m in figures])
            errors = [m.steady_state_error for m in figures]
            never = np.isnan(times)
            settling = (float('nan') if never.all() else float(np.min(times[~never])),
                        float('nan') if never.any() else float(np.max(times)))
            error = (min(errors), max(errors))
        return SharedOutcome(len(self.runs), finals[0] if len(counts) == 1 else None, counts,
                             (int(snaps.min()), int(snaps.max())),
                             (float(plus.min()), float(plus.max())), settling, error)


def _open_loop_run(scene, volts, t_end) -> SimRun:
    sim = Simulator(scene)
    result = simulate(sim, volts, t_end)
    q = np.column_stack([result.outputs[sim.output_names[i]] for i in sim.model.channel('q')])
    y = np.column_stack([result.outputs[sim.output_names[i]] for i in sim.model.channel('y')])
    dy = _rest_shortenings(sim) - y
    nan = np.full_like(q, np.nan)
    return SimRun(list(sim.model.input_names), result.t, result.u, q, dy, nan, nan)


def _rest_shortenings(sim) -> np.ndarray:
    from ..physics.statics import rest_shortenings
    return np.asarray(rest_shortenings(sim.scene))


def _closed_loop_run(scene, make_controller, t_end) -> SimRun:
    sim = Simulator(scene)
    act = make_controller()
    y0 = _rest_shortenings(sim)
    q_at, y_at = sim.model.channel('q'), sim.model.channel('y')
    n = int(round(t_end / sim.dt))
    out = np.array(list(sim.outputs().values()))
    t = np.arange(n + 1) * sim.dt
    volts = np.empty((n + 1, sim.model.n_inputs))
    q = np.empty((n + 1, len(q_at)))
    dy = np.empty_like(q)
    for k in range(n + 1):
        q[k], dy[k] = out[q_at], y0 - out[y_at]
        if k == n:
            break
        # sample k -> command -> period k + 1, as in sim_node
        command = np.broadcast_to(np.asarray(act(t[k], dy[k].copy(), q[k].copy()), float),
                                  (sim.model.n_inputs,))
        check = sim.set_input(command.tolist())
        if not check.accepted:
            raise ValueError(f'the controller at t = {t[k]:.6g} s: {check.reason}')
        volts[k] = sim.u
        out = sim.step()
    volts[n] = sim.u
    nan = np.full_like(q, np.nan)
    return SimRun(list(sim.model.input_names), t, volts, q, dy, nan, nan)


def ensemble(scene, t_end: float, volts: Callable | np.ndarray | None = None,
             controller: Callable | None = None, copies: int = 20,
             perturbation: Perturbation | None = None, seed: int = 0) -> Ensemble:
    """
    Run an input or a controller against ``copies`` perturbed copies of ``scene``, offline.

    What the copies share is the scene's level's answer: under fast switching a coarse level's
    statistics can differ from the converged beam's (docs/lockstep.md, "When a single run is
    enough", names a level that holds them).

    :param volts: an open-loop input, as :func:`~det_sim_ros.sim.simulator.simulate` takes it.
    :param controller: or a closed loop: a function of no arguments that returns a fresh
        controller (its state its own, one per copy): ``act(t, dy, q) -> volts``, called with
        sample k's time (s), Δy and q (m, one per DET); its answer is held over period k + 1,
        as sim_node holds a command.
    :param perturbation: the sizes the copies are drawn at (default the measure's).
    """
    if (volts is None) == (controller is None):
        raise ValueError('give one of volts (open loop) or controller (closed loop)')
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    overrides = ensemble_overrides(scene, copies, perturbation, seed)
    runs = []
    for change in overrides:
        copy = scene.replace(**change) if change else scene
        runs.append(_open_loop_run(copy, volts, t_end) if controller is None
                    else _closed_loop_run(copy, controller, t_end))
    return Ensemble(runs, overrides)
