"""
Linear models of any scene at an equilibrium (for controller design), no ROS.

The equilibrium at constant DET voltages V (one per DET, V) on a branch ('buckled+',
'buckled-' or 'straight', the 0 V equilibria of det_sim_ros.physics.statics):

- qdot = 0; the creep strain at its equilibrium (eps_E = 0: it relaxes to the DET's rate,
  which is zero at rest); the charge at its RC equilibrium q_p = C(q) V Rp/(Rs + Rp);
- q from the static force balance: Newton's method on the model's acceleration (the velocity
  rate of dx/dt, zero exactly where the generalized force is) with the charge following q, by
  continuation in V from the branch's 0 V state (steps halved where Newton fails; a branch that
  ends, e.g. at snap-through, is reported with the voltage where it was last found).

At that point dx/dt = f(x, u) is linearized: dx' = A dx + B du, dz = C dx + D du with the
outputs z = [dy_i, q_i] per DET i: the published displacement Delta-y_i = y0_i - y_i (m) and
deflection q_i (reference-point deflection, m); u in V. A and B come from complex-step
differentiation of det_sim_ros.physics.reference.rhs (exact to round-off, no step-size trade-off),
C from the kinematics (dy/dq) and the reference rows; D = 0. The power monitor's energy states are
left out (they integrate power and feed nothing back).

``LinearModel.to_statespace()`` gives a python-control ``StateSpace`` (optional dependency:
``pip install control``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import reference
from .model import build_model, Model
from ..scenes.scene import Scene

__all__ = ['LinearModel', 'LinearizationError', 'BRANCHES', 'equilibrium_state', 'linearize',
           'complex_step_jacobian']

BRANCHES = ('buckled+', 'buckled-', 'straight')
_STEP = 1e-100        # complex step: any tiny step is exact (no subtraction)
_NEWTON_ITERS = 40


class LinearizationError(ValueError):
    """No equilibrium where one was asked for (message: one line, says why)."""


@dataclasses.dataclass
class LinearModel:
    """dx' = A dx + B du, dz = C dx + D du about (x0, u0); SI units (m, V, s)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    x0: np.ndarray
    u0: np.ndarray
    z0: np.ndarray            # outputs at the equilibrium
    state_names: tuple
    input_names: tuple
    output_names: tuple
    branch: str
    model: Model

    def poles(self) -> np.ndarray:
        """Return the eigenvalues of A (1/s), sorted by real part, slowest first (closest to 0)."""
        poles = np.linalg.eigvals(self.A)
        return poles[np.lexsort((poles.imag, -poles.real))]

    @staticmethod
    def natural_frequency(poles) -> np.ndarray:
        """Return the natural frequencies |p| (rad/s)."""
        return np.abs(poles)

    @staticmethod
    def damping(poles) -> np.ndarray:
        """
        Return the damping ratio zeta = -Re p / |p|.

        1 for a real stable pole, < 0 for an unstable one.
        """
        poles = np.asarray(poles)
        wn = np.abs(poles)
        return np.where(wn > 0, -poles.real / np.where(wn > 0, wn, 1.0), -1.0)

    def dc_gain(self) -> np.ndarray:
        """Return G(0) = D - C A^-1 B (outputs x inputs; m/V); inf where A is singular."""
        try:
            return self.D - self.C @ np.linalg.solve(self.A, self.B)
        except np.linalg.LinAlgError:
            return np.full(self.D.shape, math.inf)

    def frequency_response(self, omega) -> np.ndarray:
        """Return G(j omega) for each omega (rad/s): array (n_omega, outputs, inputs)."""
        n = self.A.shape[0]
        eye = np.eye(n)
        return np.array([self.C @ np.linalg.solve(1j * w * eye - self.A, self.B) + self.D
                         for w in np.atleast_1d(omega)])

    def to_statespace(self):
        """Return the model as a python-control ``StateSpace`` (needs ``pip install control``)."""
        try:
            import control
        except ImportError:
            raise ImportError('python-control is not installed: pip install control '
                              "(or the 'test' extra)") from None
        return control.ss(self.A, self.B, self.C, self.D, states=list(self.state_names),
                          inputs=list(self.input_names), outputs=list(self.output_names))


def complex_step_jacobian(func, x, h: float = _STEP) -> np.ndarray:
    """Return d func / dx (columns per x entry) by complex steps: Im f(x + i h e_j) / h."""
    x = np.asarray(x, dtype=float)
    cols = []
    for j in range(x.size):
        xc = x.astype(complex)
        xc[j] += 1j * h
        cols.append(np.imag(func(xc)) / h)
    return np.column_stack(cols)


def _linear_scene(scene: Scene) -> Scene:
    return scene.replace(**{'scene.monitor_power': False}) if scene.monitor_power else scene


def _branch_coords(scene: Scene, branch: str) -> np.ndarray:
    """
    Return the Ritz coordinates of every cell's 0 V equilibrium on the branch.

    Cells in DET order.
    """
    from .statics import equilibria
    coords = []
    for c, name in enumerate(scene.det_names):
        found = {e.kind: e for e in equilibria(scene.cell_scene(c), 0.0)}
        if branch not in found:
            raise LinearizationError(
                f"no '{branch}' equilibrium at 0 V on {name} (eps_b = {scene.eps_b:g}: "
                f"equilibria {', '.join(found) or 'none'}); choose another --branch")
        coords.append(np.array(found[branch].coords, dtype=float))
    return np.concatenate(coords)


def _static_x(a, q, u):
    """
    Return the static state of the coordinates q.

    qdot = 0, eps_E = 0 and the charge at its RC equilibrium.
    """
    x = np.zeros(a.n_state, dtype=np.result_type(q, float))
    x[:a.n_q] = q
    if a.rc_source:
        i_qp = 2 * a.n_q + a.n_cells * a.creep
        x[i_qp:i_qp + a.n_cells] = reference._charge_offset(a, x, u)
    return x


def _acceleration(a, q, u):
    """
    Return qddot at the static state of q.

    It is zero exactly at an equilibrium (M is positive definite).
    """
    return reference.rhs(a, _static_x(a, q, u), u)[0][a.n_q:2 * a.n_q]


def _newton(a, q, u, scale):
    for _ in range(_NEWTON_ITERS):
        with np.errstate(invalid='ignore'):    # an iterate past |w'| = 1 is an answer: None
            g = _acceleration(a, q, u)
        if not np.all(np.isfinite(g)):
            return None
        J = complex_step_jacobian(lambda c: _acceleration(a, c, u), q)
        try:
            dq = np.linalg.solve(J, -g)
        except np.linalg.LinAlgError:
            return None
        q = q + dq
        if np.max(np.abs(dq)) <= 1e-13 * scale:
            return q
    return None


def equilibrium_state(scene: Scene, voltage, branch: str = 'buckled+',
                      model: Model | None = None) -> np.ndarray:
    """
    Return the equilibrium state at DET voltages ``voltage`` on ``branch``.

    ``voltage`` is a number for all DETs or one per DET, V; ``branch`` as in the module
    docstring. The state has the layout of ``model`` (default: the scene's model without the
    power monitor).
    """
    if branch not in BRANCHES:
        raise LinearizationError(f"unknown branch {branch!r}; choose from {', '.join(BRANCHES)}")
    model = model or build_model(_linear_scene(scene))
    a = model.arrays
    u = _voltages(model, voltage)
    q = _branch_coords(scene, branch)
    scale = max(np.max(np.abs(q)), 1e-6 * scene.beam_length)
    sign = {'buckled+': 1.0, 'buckled-': -1.0}.get(branch, 0.0)

    def on_branch(coords):
        """Check that a buckled branch keeps its side (Newton past its end finds the straight)."""
        if coords is None or not sign:
            return coords is not None
        q_ref = np.array([a.ref[a.cell_slice(c)] @ coords[a.cell_slice(c)]
                          for c in range(a.n_cells)])
        return bool(np.all(sign * q_ref > 1e-6 * scene.beam_length))

    done, step = 0.0, 1.0
    while done < 1.0:
        trial = min(1.0, done + step)
        solved = _newton(a, q, trial * u, scale)
        if not on_branch(solved):
            step *= 0.5
            if step < 1e-4:
                raise LinearizationError(
                    f"the '{branch}' branch ends near {_v(done * u)} V (last equilibrium on it; "
                    f'none at {_v(trial * u)} V): below {_v(u)} V the actuator leaves it')
            continue
        q, done = solved, trial
        step = min(2.0 * step, 0.25)
    return _static_x(a, q, u)


def _v(u):
    return '/'.join(f'{v:.6g}' for v in np.atleast_1d(u))


def _voltages(model: Model, voltage) -> np.ndarray:
    v = np.atleast_1d(np.asarray(voltage, dtype=float)).reshape(-1)
    n = model.n_inputs
    if v.size == 1:
        v = np.full(n, v[0])
    if v.size != n:
        raise LinearizationError(f'expected 1 or {n} voltages ({", ".join(model.input_names)})'
                                 f', got {v.size}' if n > 1 else
                                 f'expected 1 voltage ({model.input_names[0]}), got {v.size}')
    v_max = model.scene.physics.v_max
    if not np.all(np.isfinite(v)) or np.any(v < 0.0) or np.any(v > v_max):
        raise LinearizationError(f'voltage {v.tolist()} outside [0, {v_max:g}] V')
    return v


def linearize(scene: Scene, voltage=0.0, branch: str = 'buckled+') -> LinearModel:
    """
    Return A, B, C, D of ``scene`` at its equilibrium at ``voltage`` on ``branch``.

    The module docstring describes the equilibrium, the inputs and the outputs.
    """
    from .statics import rest_shortening
    model = build_model(_linear_scene(scene))
    a = model.arrays
    x0 = equilibrium_state(scene, voltage, branch, model)
    u0 = _voltages(model, voltage)
    A = complex_step_jacobian(lambda x: reference.rhs(a, x, u0)[0], x0)
    B = complex_step_jacobian(lambda u: reference.rhs(a, x0, u)[0], u0)
    kin = reference.kinematics(a, x0)
    nc, n = a.n_cells, a.n_state
    C = np.zeros((2 * nc, n))
    for c in range(nc):
        s = a.cell_slice(c)
        C[c, s] = -kin.J[s]            # d(y0 - y)/dq
        C[nc + c, s] = a.ref[s]         # q = S(x_ref) . coords
    D = np.zeros((2 * nc, model.n_inputs))
    y0 = np.array([rest_shortening(scene.cell_scene(c)) for c in range(nc)])  # as the node
    q_ref = np.array([a.ref[a.cell_slice(c)] @ x0[a.cell_slice(c)] for c in range(nc)])
    z0 = np.concatenate([y0 - kin.y, q_ref])
    names = model.input_names
    outputs = tuple(f'dy[{d}]' for d in names) + tuple(f'q[{d}]' for d in names)
    return LinearModel(A, B, C, D, x0, u0, z0, tuple(model.state_names), tuple(names),
                       outputs, branch, model)
