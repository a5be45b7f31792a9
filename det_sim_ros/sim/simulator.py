"""
The simulator: state, the sim-time grid t = k dt, and inputs held between commands.

:class:`Simulator` advances exactly one control period dt per :meth:`Simulator.step` with the input
held constant (zero-order hold), in fixed internal steps of the chosen method. With
``integrator.substeps: 0`` and a method that has an embedded error estimate (the default) their
number adapts from period to period to the scene's tolerance (ds_stages_period in
_csrc/stepping/period.c); else it is fixed; the BDF stepper has its own step control (the
method's kind: det_sim_ros.sim.integrators.StepperKind). Independent coupled groups (the
copies of an array) each keep their own count.
Time is always ``k * dt`` (never accumulated), and the same inputs give bit-identical outputs: the
step count depends only on the state and the inputs. A state that leaves the model's domain puts
the simulator in a fault: the last good state is kept, ``fault`` names the cause, and
:meth:`Simulator.reset` recovers. No NaN ever leaves it.

:func:`simulate` is the offline entry point: a voltage profile in, named output arrays out.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from .amplifier import CommandStage
from .integrators import (BDF_MIN_COORDINATES, BDF_MIN_TOLERANCE, get_method,
                          integration_tolerance, make_stepper, Method, step_control,
                          transient_settings)
from ..core import kernel
from ..physics.model import build_model, Model, ModelDomainError
from ..physics.statics import initial_state
from ..scenes.scene import load_scene, Scene, SceneError

__all__ = ['Simulator', 'InputCheck', 'simulate', 'SimulationResult', 'POWER_RESIDUAL_LIMIT',
           'inputs_within']

# |power-balance residual| beyond which a run is no longer vouched for: the stress suite keeps
# it below this (test/test_integrators.py: Rs >= 1 kOhm, every pre-strain), so a larger value
# means the integration error has left the tolerance (e.g. voltages far beyond the calibrated
# 3 kV)
POWER_RESIDUAL_LIMIT = 1e-3
# ... or this many times the integrator's tolerance, if larger: the residual is the integration
# error of the energy states, and it grows with the tolerance (docs/fidelity.md has the ratios:
# a loose tolerance leaves the charge transients after input jumps unresolved, whose
# dissipation the energy states then miss; the mechanics stay within the tolerance)
POWER_RESIDUAL_PER_TOLERANCE = 50.0


@dataclasses.dataclass(frozen=True)
class InputCheck:
    """What :meth:`Simulator.set_input` did with a command."""

    accepted: bool
    clamped: bool
    reason: str = ''


_ACCEPTED = InputCheck(True, False)
_FLOAT_ONLY = {float}


def inputs_within(values: list, v_max: float) -> bool:
    """
    Check that every value of a non-empty list of floats is in [0, v_max], none NaN.

    The answer of ``all(0.0 <= v <= v_max for v in values)`` in three C loops instead of a
    generator, a few times cheaper (docs/development.md). A NaN makes the sum NaN; without one,
    min and max are exact.
    """
    total = sum(values)
    return total == total and min(values) >= 0.0 and max(values) <= v_max


class Simulator:
    """
    Fixed-rate simulation of one scene (fixed internal steps within each control period).

    :param scene: a :class:`Scene`, a scene file/name, or a built :class:`Model`.
    :param method: stepper name (default: the scene's ``integrator.method``; 'auto' picks
        'etdrk4' when the scene has a stiff charge state, 'etdrk4_linearized' when its beams
        also have more than one Ritz term (stiff beam modes), and 'dp5' otherwise: the
        cheapest per accuracy in ``det_sim bench`` and bench/stiff_speed.py).
    :param substeps: internal steps per control period (default: the scene's; 0 = adaptive
        from the scene's tolerance when the method has an embedded estimate, else a fixed count
        from the tolerance).
    :param threads: threads that step the independent coupled groups of a scene (the copies
        of an array; 1 for a single or plate scene). Results do not depend on it.
    """

    def __init__(self, scene=None, method: str | None = None, substeps: int | None = None,
                 threads: int = 1):
        if isinstance(scene, Model):
            self.model = scene
        else:
            if not isinstance(scene, Scene):
                scene = load_scene('default' if scene is None else scene)
            self.model = build_model(scene)
        self.scene = self.model.scene
        self.method = self._pick_method(method or self.scene.method)
        substeps = self.scene.substeps if substeps is None else substeps
        if substeps < 0:
            raise ValueError(f'substeps must be >= 0 (got {substeps})')
        self.dt = self.scene.dt
        # the tolerance the step control works to (the scene's, or its level's when 'auto')
        self.tolerance = integration_tolerance(self.scene)
        # the power-balance residual beyond which a run is not vouched for (trust_issue)
        self.power_residual_limit = max(POWER_RESIDUAL_LIMIT,
                                        POWER_RESIDUAL_PER_TOLERANCE * self.tolerance)
        self.control = step_control(self.method, self.model, substeps)
        self.adaptive = self.control.adaptive
        self.transient = transient_settings(self.method, self.scene)
        # the compiled stepper keeps its scratch and step counts between periods
        self.stepper = make_stepper(self.model, self.method, self.control, self.dt,
                                    self.transient)
        self.stepper.threads = threads
        # the amplifier's DAC, delay and offset (None when off: the command goes straight in)
        self.command_stage = CommandStage.for_scene(self.scene)
        self.output_names = self.model.output_names
        self._out = np.empty(len(self.output_names))
        self.x0 = initial_state(self.model)   # the scene's initial state (reset returns here)
        self.reset()

    def _pick_method(self, name: str) -> Method:
        a = self.model.arrays
        if name == 'auto':
            if self.scene.source != 'rc':
                return get_method('dp5')
            # beams with more than one Ritz coordinate have stiff, heavily damped modes; from
            # BDF_MIN_COORDINATES on, BDF steps them for less than the linearized stages' phi
            # upkeep (at loose tolerances)
            modes = np.diff(a.cell_q)   # coordinates per beam: its n_ritz
            tolerance = integration_tolerance(self.scene)
            bdf = get_method('bdf')
            if (not bdf.kind.refusal(self.model) and np.max(modes) >= BDF_MIN_COORDINATES
                    and tolerance >= BDF_MIN_TOLERANCE):
                return bdf
            return get_method('etdrk4_linearized' if np.any(modes > 1) else 'etdrk4')
        try:
            method = get_method(name)
        except ValueError as exc:   # a scene value: one line naming the key and the choices
            raise SceneError(f"scene key 'integrator.method': {exc}") from None
        refusal = method.kind.refusal(self.model)
        if refusal:
            raise SceneError(f"scene key 'integrator.method': {name!r} {refusal}")
        return method

    # -- state ----------------------------------------------------------------------------
    def reset(self, x0=None) -> None:
        """Go back to t = 0, the scene's initial state (or ``x0``), 0 V input, no fault."""
        self.k = 0
        self.stepper.reset_control()   # the step count starts over: runs repeat exactly
        self.x = self.x0.copy() if x0 is None else np.array(x0, dtype=float)
        if self.x.shape != (self.model.n_states,):
            raise ValueError(f'x0 must have {self.model.n_states} entries')
        self.u = np.zeros(self.model.n_inputs)
        self._u_prev = self.u.copy()    # input of the last period: a jump starts a transient
        if self.command_stage is not None:
            self.command_stage.reset()
        self.fault = ''
        status = self.model.kernel.outputs(self.x, self.applied_input, self._out)
        if status != kernel.OK:
            raise ModelDomainError(status, 'in the initial state')
        self.initial_energy = float(self._out[self.output_names.index('H')])

    @property
    def applied_input(self) -> np.ndarray:
        """
        Return the voltages the supply circuit receives, V.

        The held command ``u``; with the amplifier's DAC, delay or offset on, what they made of
        the commands (that of the last period run).
        """
        return self.u if self.command_stage is None else self._u_prev

    @property
    def t(self) -> float:
        """Return the simulated time k * dt, s."""
        return self.k * self.dt

    @property
    def substeps(self) -> int:
        """
        Return the internal steps the next control period starts with.

        Fixed unless ``adaptive``; the largest over the coupled groups.
        """
        return self.stepper.substeps

    @property
    def h(self) -> float:
        """Return the internal step size of the next control period, s."""
        return self.dt / self.substeps

    @property
    def steps_taken(self) -> int:
        """
        Return the internal steps taken since construction.

        All periods, repeated ones included; summed over the coupled groups.
        """
        return int(self.stepper.steps_taken)

    @property
    def substeps_setting(self) -> int:
        """
        Return the step count as a setting: 0 = adaptive, else the fixed count.

        Logs record this, so a re-simulation uses the same stepping and reproduces the run
        exactly.
        """
        return 0 if self.adaptive else self.substeps

    def describe_stepper(self) -> str:
        """
        Describe the stepping in one phrase, for logs and diagnostics.

        'etdrk4 x20' or 'etdrk4 adaptive (now x12)' (', 2 threads' when stepping on more than
        one).
        """
        threads = self.stepper.threads
        on = f', {threads} threads' if threads > 1 else ''
        return self.method.kind.describe(self.method, self.control, self.substeps) + on

    # -- input ----------------------------------------------------------------------------
    def set_input(self, volts) -> InputCheck:
        """
        Hold new DET voltages from now on (zero-order hold).

        Non-finite values and a wrong length are refused (the previous input stays); values
        outside [0, v_max] are clamped.
        """
        v_max = self.scene.physics.v_max
        values = list(volts) if type(volts) in (list, tuple) else None
        if values is not None and len(values) == len(self.u) \
                and set(map(type, values)) == _FLOAT_ONLY and inputs_within(values, v_max):
            # the common case, a list of valid floats (the node's commands): no numpy round
            # trip (the general path below costs several times more; docs/development.md)
            if values != self.u.tolist():
                new = np.array(values)
                if self.command_stage is None:   # else booked when the amplifier applies it
                    self.model.apply_input_jump(self.x, self.u, new)
                self.u = new
            return _ACCEPTED
        try:
            v = np.array(volts, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            return InputCheck(False, False, f'not a vector of numbers: {volts!r}')
        if v.shape != (self.model.n_inputs,):
            return InputCheck(False, False, f'expected {self.model.n_inputs} voltage(s), '
                                            f'got {v.size}')
        if not np.all(np.isfinite(v)):
            return InputCheck(False, False, f'non-finite voltage {v.tolist()}')
        clamped = np.clip(v, 0.0, v_max)
        if self.command_stage is None:
            self.model.apply_input_jump(self.x, self.u, clamped)
        self.u = clamped
        if np.any(clamped != v):
            return InputCheck(True, True, f'voltage {v.tolist()} clamped to [0, {v_max:g}] V')
        return _ACCEPTED

    # -- stepping ---------------------------------------------------------------------------
    def step(self) -> np.ndarray:
        """
        Advance one control period and return the outputs (a view, in ``output_names`` order).

        :raises ModelDomainError: the state left the domain; the simulator is then faulted at
            the last good state until :meth:`reset`.
        """
        if self.fault:
            raise ModelDomainError(kernel.NON_FINITE, f'(faulted: {self.fault})')
        u = self.u
        if self.command_stage is not None:
            u = self.command_stage.apply(u)
            if self.scene.source == 'ideal':   # (an RC source books nothing)
                self.model.apply_input_jump(self.x, self._u_prev, u)
        # in place: on failure the kernel leaves x at the period's start (the last good state)
        status = self.stepper.period(self.x, self._u_prev, u, self._out)
        if status != kernel.OK:
            error = ModelDomainError(status, f'at t = {self.t + self.dt:.6g} s')
            self.fault = str(error)
            # leave the outputs buffer at the last good state so nothing faulty can be read
            self.model.kernel.outputs(self.x, self.applied_input, self._out)
            raise error
        self._u_prev = u
        self.k += 1
        return self._out

    def outputs(self) -> dict:
        """Return the named outputs at the current state and input."""
        status = self.model.kernel.outputs(self.x, self.applied_input, self._out)
        if status != kernel.OK:
            raise ModelDomainError(status)
        return dict(zip(self.output_names, self._out.tolist()))

    def trust_issue(self) -> str:
        """
        Return '' while the run can be vouched for, else why not (one line).

        A run is not vouched for with the power-balance residual beyond
        :attr:`power_residual_limit` (only with ``monitor_power``).
        """
        if self.fault:
            return ''
        residual = self.power_residual()
        limit = self.power_residual_limit
        if math.isfinite(residual) and abs(residual) > limit:
            return (f'power-balance residual {residual:.3g} beyond {limit:g} '
                    f'(normally ~20 x the tolerance {self.tolerance:g}): the integration error '
                    f'has left its tolerance and the '
                    f'outputs cannot be vouched for (inputs now {self.u.tolist()} V; the '
                    'stepper is calibrated up to 3 kV); ~/reset starts over')
        return ''

    def power_residual(self) -> float:
        """
        Return the energy-balance residual H(t) - H(0) - (W_in - W_diss), relative.

        Relative to the energy scale max(H(0), W_in, 1 uJ); NaN when the scene does not monitor
        power.
        """
        if not self.scene.monitor_power:
            return math.nan
        out = self.outputs()
        w_in, w_diss = self.x[-2], self.x[-1]
        scale = max(abs(self.initial_energy), abs(w_in), 1e-6)
        return (out['H'] - self.initial_energy - (w_in - w_diss)) / scale


@dataclasses.dataclass
class SimulationResult:
    """Sampled outputs of an offline run: ``t`` (s), ``u`` (V), ``x`` and each named output."""

    t: np.ndarray
    u: np.ndarray
    x: np.ndarray
    outputs: dict

    def __getitem__(self, name):
        return self.outputs[name]


def simulate(scene, voltage: Callable[[float], float] | np.ndarray, t_end: float,
             method: str | None = None, substeps: int | None = None) -> SimulationResult:
    """
    Run a scene offline and return the outputs at every control sample t = k dt.

    :param voltage: a function v(t) (sampled at the start of each period and held), or an array
        of per-period voltages (shape (n_periods,) or (n_periods, n_inputs)).
    :param t_end: end time, s (rounded to whole control periods).
    """
    sim = scene if isinstance(scene, Simulator) else Simulator(scene, method, substeps)
    n = int(round(t_end / sim.dt))
    n_in = sim.model.n_inputs
    if callable(voltage):
        samples = [voltage((sim.k + k) * sim.dt) for k in range(n)]
        # one conversion for the whole record, not a broadcast per sample (docs/development.md)
        try:
            volts = np.broadcast_to(np.asarray(samples, dtype=float).reshape(n, -1), (n, n_in))
        except ValueError:   # ragged: scalars and vectors mixed
            volts = np.array([np.broadcast_to(v, (n_in,)) for v in samples], dtype=float)
        volts = volts.reshape(n, n_in)
    else:
        volts = np.asarray(voltage, dtype=float).reshape(n, -1) if n else np.zeros((0, n_in))
        if volts.shape[1] != n_in:
            raise ValueError(f'expected {n_in} voltage(s) per sample, got {volts.shape[1]}')
    bad = ~np.all(np.isfinite(volts), axis=1)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise ValueError(f'voltage sample {k}: non-finite voltage {volts[k].tolist()}')
    if sim.fault:
        raise ModelDomainError(kernel.NON_FINITE, f'(faulted: {sim.fault})')
    U = np.ascontiguousarray(np.clip(volts, 0.0, sim.scene.physics.v_max))
    t = (sim.k + np.arange(n + 1)) * sim.dt
    Y = np.empty((n + 1, len(sim.output_names)))
    X = np.empty((n + 1, sim.model.n_states))
    Y[0] = list(sim.outputs().values())
    # the whole run in one compiled call (same periods as n calls of Simulator.step); it writes
    # X[0] and leaves x at X[done], the last good state
    x = sim.x.copy()
    if sim.command_stage is None:
        applied, u_held = U, sim.u
    else:   # the amplifier's DAC, delay and offset: the inputs the circuit receives
        applied, u_held = np.ascontiguousarray(sim.command_stage.run(U)), sim._u_prev
    status, done = sim.stepper.run(x, u_held, sim._u_prev, applied, X, Y)
    sim.x = x
    if done:
        sim.u, sim._u_prev = U[done - 1].copy(), applied[done - 1].copy()
        sim.k += done
    if status != kernel.OK:
        error = ModelDomainError(status, f'at t = {sim.t + sim.dt:.6g} s')
        sim.fault = str(error)
        raise error
    U_out = np.vstack([U, U[-1:] if n else sim.u[None, :]])
    return SimulationResult(t, U_out, X, {name: Y[:, i]
                                          for i, name in enumerate(sim.output_names)})
