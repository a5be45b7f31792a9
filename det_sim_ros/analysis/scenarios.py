"""
Named reference scenarios (described in docs/model.md) and the benchmark error metric.

'step': 0 V for 0 <= t < 1.5 s, v_max for 1.5 <= t < 3 s, 0 V until 4.5 s, sampled every 1 ms;
Delta-y = y0 - y with y0 the end shortening at the end of the 0 V phase, eps_y = Delta-y / l_y,
l_y = l - y0 (eqs 83-84). The reference solution restarts a tight solve_ivp run at every input
switch (zero-order hold, no interpolation of inputs).

'switching': what a controller does. Released at q0 at 0 V; from 0.5 s a square wave between
v_max and 0 V (v_max first) to 2.5 s, at 2 Hz (or faster). Scored by the snaps (sign changes
of q after 0.5 s: how many, and when) and max |y - y_ref| over 0.5-2.5 s divided by the
reference's travel there (max y_ref - min y_ref).

'pwm': a bang-bang controller. Released at q0 at 0 V; from 0.5 s a 10 Hz PWM at v_max with duty
30 %, 50 %, 70 %, 50 % for 0.5 s each, to 2.5 s. Its path can depend on rounding: score it
through det_sim_ros.analysis.predictability first (robust stretches as 'switching', the rest
as statistics over an ensemble of perturbed runs).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from ..physics.model import build_model
from ..physics.statics import initial_state
from ..scenes.scene import load_scene

__all__ = ['STEP_SWITCH_TIMES', 'step_voltage', 'step_scene', 'delta_y', 'reference_solution',
           'step_error', 'SWITCHING_START', 'SWITCHING_END', 'switching_voltage',
           'switching_scene', 'snap_times', 'switching_error', 'PWM_HZ', 'PWM_DUTIES',
           'pwm_voltage']

STEP_SWITCH_TIMES = (1.5, 3.0)   # s
STEP_END = 4.5                   # s
SWITCHING_START = 0.5            # s: the square wave starts here, the score from here
SWITCHING_END = 2.5              # s
PWM_HZ = 10.0                    # Hz: the 'pwm' carrier
PWM_DUTIES = (0.3, 0.5, 0.7, 0.5)   # the duty of each 0.5 s block from SWITCHING_START on
PWM_BLOCK = 0.5                  # s


def step_voltage(v_max: float):
    """Return the 'step' profile v(t) (V) as a function, exact at the switching instants."""
    def voltage(t):
        return v_max if STEP_SWITCH_TIMES[0] <= t + 1e-12 < STEP_SWITCH_TIMES[1] else 0.0
    return voltage


def step_scene(beam: str = 'fixed', eps_b: float = 0.20, **overrides):
    """
    Return the default scene for the 'step' scenario (1 kHz sampling, released from q0).

    At the paper's fidelity (its one-term model) unless ``overrides`` name another.
    """
    return load_scene('default', {'scene.beam': beam, 'scene.eps_b': eps_b, 'rate_hz': 1000.0,
                                  'scene.initial_state': 'released', 'scene.fidelity': 'paper',
                                  **overrides})


def switching_voltage(v_max: float, hz: float = 2.0):
    """
    Return the 'switching' profile v(t) (V) as a function.

    0 V to SWITCHING_START, then a square wave at ``hz`` between v_max and 0 V, v_max first,
    exact at its edges on the 1 ms grid.
    """
    half = 0.5 / hz

    def voltage(t):
        if t + 1e-12 < SWITCHING_START:
            return 0.0
        return v_max if int((t + 1e-12 - SWITCHING_START) / half) % 2 == 0 else 0.0
    return voltage


def pwm_voltage(v_max: float, hz: float = PWM_HZ, duties=PWM_DUTIES, block: float = PWM_BLOCK):
    """
    Return the 'pwm' profile v(t) (V) as a function.

    0 V to SWITCHING_START, then a PWM at ``hz`` between v_max (first in each carrier period)
    and 0 V, its duty ``duties[i]`` in the i-th ``block`` of seconds (the last duty held after
    the last block). Exact at its edges on the 1 ms grid.
    """
    def voltage(t):
        since = t + 1e-12 - SWITCHING_START
        if since < 0.0:
            return 0.0
        duty = duties[min(int(since / block), len(duties) - 1)]
        return v_max if (since * hz) % 1.0 < duty else 0.0
    return voltage


def switching_scene(beam: str = 'fixed', eps_b: float = 0.20, **overrides):
    """
    Return the default scene for the 'switching' scenario: released from q0, 1 kHz.

    At the default scene's own level (the package's default) unless ``overrides`` name another.
    """
    return load_scene('default', {'scene.beam': beam, 'scene.eps_b': eps_b, 'rate_hz': 1000.0,
                                  'scene.initial_state': 'released', **overrides})


def snap_times(t, q, start: float = SWITCHING_START) -> np.ndarray:
    """Return the times (s) of the sample after each sign change of q at or after ``start``."""
    t, q = np.asarray(t), np.asarray(q)
    keep = t >= start - 1e-9
    t, sign = t[keep], np.sign(q[keep])
    nonzero = sign != 0
    t, sign = t[nonzero], sign[nonzero]
    return t[1:][sign[1:] != sign[:-1]]


def switching_error(t, y, y_ref, start: float = SWITCHING_START) -> float:
    """Return max |y - y_ref| from ``start`` on over the travel of y_ref there (max - min)."""
    keep = np.asarray(t) >= start - 1e-9
    y, y_ref = np.asarray(y)[keep], np.asarray(y_ref)[keep]
    return float(np.max(np.abs(y - y_ref)) / (np.max(y_ref) - np.min(y_ref)))


def delta_y(t, y, l_beam):
    """Delta-y = y0 - y and eps_y = Delta-y / (l - y0), y0 = y at the end of the 0 V phase."""
    t = np.asarray(t)
    i0 = int(np.searchsorted(t, STEP_SWITCH_TIMES[0] - 1e-9))
    y0 = y[i0]
    dy = y0 - y
    return dy, dy / (l_beam - y0)


def reference_solution(scene, t_end: float = STEP_END, voltage=None, method: str = 'Radau',
                       rtol: float = 1e-12):
    """
    Return the 'step' run solved by solve_ivp at a tight tolerance, restarted at every 1 ms sample.

    Returns (t, X) at the control samples. Restarting at every sample both holds the input
    exactly and gives the sampled values without dense-output interpolation error.
    """
    model = build_model(scene)
    voltage = voltage or step_voltage(scene.physics.v_max)
    dt = scene.dt
    n = int(round(t_end / dt))
    x = initial_state(model)
    scale = _state_scale(model)
    X = np.empty((n + 1, model.n_states))
    X[0] = x
    for k in range(n):
        u = np.atleast_1d(voltage(k * dt))
        sol = solve_ivp(lambda t, z: model.f(t, z, u), (k * dt, (k + 1) * dt), x, method=method,
                        rtol=rtol, atol=rtol * scale)
        if not sol.success:
            raise RuntimeError(f'reference solve failed at t = {k * dt}: {sol.message}')
        x = sol.y[:, -1]
        X[k + 1] = x
    return np.arange(n + 1) * dt, X


def _state_scale(model):
    """Typical magnitude of each state, for absolute tolerances (q ~ 1 cm, q_p ~ C0 v_max)."""
    p = model.scene.physics
    scale = []
    for name in model.state_names:
        if name.startswith('q_dot'):
            scale.append(1.0)
        elif name.startswith('q_p'):
            scale.append(p.C0 * p.v_max)
        elif name.startswith('q['):
            scale.append(0.01)
        elif name.startswith('eps_E'):
            scale.append(0.01)
        else:
            scale.append(1e-3)   # energies, J
    return np.array(scale)


def step_error(model, t, X, X_ref):
    """
    Return the benchmark error of a run: the relative Delta-y error and the charge error.

    The Delta-y error is max |Delta-y - Delta-y_ref| / max |Delta-y_ref|; the charge error is the
    max charge error relative to C0 v_max (0 for scenes without a charge state).
    """
    l_beam = model.scene.beam_length
    u = np.zeros(model.n_inputs)

    def y_of(states):
        return np.array([model.outputs(s, u)['y'] for s in states])
    dy, _ = delta_y(t, y_of(X), l_beam)
    dy_ref, _ = delta_y(t, y_of(X_ref), l_beam)
    err_y = np.max(np.abs(dy - dy_ref)) / np.max(np.abs(dy_ref))
    qp_idx = [i for i, n in enumerate(model.state_names) if n.startswith('q_p')]
    p = model.scene.physics
    err_q = (np.max(np.abs(X[:, qp_idx] - X_ref[:, qp_idx])) / (p.C0 * p.v_max)
             if qp_idx else 0.0)
    return float(err_y), float(err_q)
