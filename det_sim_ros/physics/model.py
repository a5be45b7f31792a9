"""
The DET-buckled-beam model, derived from energies and virtual works (paper Sections 2-3).

Generalized coordinates: the Ritz coefficients q of each beam pair ("cell", w = sum q_j S_j),
the Maxwell strain eps_E of each DET (if creep) and the DET charge q_p (if the source is an RC
circuit). With y_c(q) the end shortening of cell c and lambda = (l - y_c)/l0 (eq 66):

    T    = 1/2 qdot' Mb qdot + 1/2 ydot' MI ydot,          ydot = J qdot, J = dy/dq
    U_s  = sum_cells EI int w''^2 (1 + w'^2) dx             (eq 51, both beams)
    U_DE = V Y/6 (lambda^2 + lambda^-2 - 2) + q_p^2 / (2 C0 lambda^2)     (eq 53)
    dW   = -(qdot' D + V (E_M eps_E + eta_v dlz/dt) dlz/dq) dq           (eqs 54-55, 67)
           + V (eta_M (dlz/dt - deps_E/dt) - E_M eps_E) d eps_E + circuit (eqs 56-57)

Lagrange's equations (35) then give, with lz = 1/lambda and dlz/dq = J / (l0 lambda^2):

    (Mb + J' MI J) qddot + J' MI (qdot' H_y qdot) + D qdot + dU_s/dq
        - (J / l0) [V Y/3 (lambda - lambda^-3) - q_p^2 / (C0 lambda^3)]
        + V (E_M eps_E + eta_v dlz/dt) dlz/dq = 0
    deps_E/dt = dlz/dt - (E_M / eta_M) eps_E
    dq_p/dt   = v / Rs - (1/Rs + 1/Rp) v_p,    v_p = q_p / (C0 lambda^2),  i_DE = (v - v_p) / Rs

For one cell and the paper's one-term shape this is the paper's eq 71 with its errata corrected
(listed in docs/model.md, verified here by the tests):

1. the inertia term is a m (q^2 qddot + q qdot^2), not a m (q^2 qddot + 2 q qdot^2): the printed
   form forgets dT/dq and injects the spurious power -a m q qdot^3 (eq 75 likewise);
2. eq 70's kinetic energy carries qdot^2, not qdot;
3. eq 57's V_e has R_p qdot_p, not R_p q_p;
4. eq 62's condition is w(l/2) = q, not w'(l/2) = q;
5. eq 78's pre-strain energy is a constant already contained in U_DE.

The 'consistent' fidelity uses the fourth-order end shortening y = int (w'^2/2 + w'^4/8) dx that
matches eq 51's energy (eq 65 drops it). The 'exact' fidelity keeps the inextensible kinematics
untruncated: with sin(theta) = w', y = int (1 - cos theta) dx and the bending energy
EI int w''^2 / (1 - w'^2) dx (curvature theta' = w''/cos theta), which converge to the
elastica. Reductions: no creep drops eps_E; the ideal source
(Rs -> 0) makes q_p = C0 lambda^2 v algebraic and drops the stiff charge state; a dropped state
is neither stored nor computed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .shapes import make_basis
from ..core import kernel
from ..scenes.scene import Scene

__all__ = ['Model', 'ModelArrays', 'ModelDomainError', 'build_model', 'CELL_OUTPUTS',
           'GLOBAL_OUTPUTS']

CELL_OUTPUTS = ('q', 'q_dot', 'y', 'lambda', 'q_p', 'v_p', 'i_DE', 'C', 'eps_E')
GLOBAL_OUTPUTS = ('H', 'P_in', 'P_diss')
_STATUS_TEXT = {
    kernel.BAD_STRETCH: 'DET stretch lambda = (l - y)/l0 <= 0: the beam ends met (l - y <= 0)',
    kernel.NON_FINITE: 'non-finite state, rate or output (NaN or inf)',
    kernel.BAD_SLOPE: "beam slope |w'| reached 1 (theta = 90 deg): outside the 'exact' "
                        "kinematics (w' = sin theta); use fidelity 'consistent' for such motions",
    kernel.STEP_UNDERFLOW: 'the BDF step size underflowed (below 1e-10 of the control period): '
                           'the state changes faster than the stepper can follow',
    kernel.NO_PROGRESS: 'the BDF stepper made no progress (100000 steps in one control period)',
    kernel.SINGULAR: 'the BDF iteration matrix I - h/alpha J is singular',
}


class ModelDomainError(ArithmeticError):
    """The state left the model's domain; the message names the quantity."""

    def __init__(self, status: int, where: str = ''):
        self.status = status
        text = _STATUS_TEXT.get(status, f'status {status}')
        super().__init__(text + (f' {where}' if where else ''))


def check(status: int, where: str = '') -> None:
    """Raise :class:`ModelDomainError` for a non-zero kernel status."""
    if status != kernel.OK:
        raise ModelDomainError(status, where)


KINEMATICS = {'paper': 0, 'consistent': 1, 'exact': 2}


@dataclasses.dataclass(frozen=True, eq=False)
class ModelArrays:
    """
    Everything the compiled kernel reads, by name.

    core/_csrc/binding/model_type.c reads these fields one attribute at a time; no positional
    tuple. SI units. Built by :func:`build_model`.

    The state is q (n_q Ritz coordinates, cell by cell), qdot (n_q), eps_E (n_cells, if
    ``creep``), q_p (n_cells, if ``rc_source``), the amplifiers' output voltages v_a (n_cells,
    if ``amp_state``), then W_in, W_diss (if ``power_monitor``).
    Beam matrices are stored as block rows by cell: row j holds its cell's block row, column k
    is relative to the cell's first coordinate.
    """

    n_q: int
    n_cells: int
    n_state: int
    r_max: int                 # most Ritz terms of a cell
    creep: int
    rc_source: int
    power_monitor: int
    cell_q: np.ndarray         # int64 (n_cells+1): offsets of each cell's coordinates in q
    cell_g: np.ndarray         # int64 (n_cells+1): offsets of each cell's quadrature nodes
    cell_group: np.ndarray     # int64 (n_cells): coupled group of each cell
    group_q: np.ndarray        # int64 (n_groups+1): coordinate offsets of the groups
    kinematics: np.ndarray     # int64 (n_cells): 0 paper, 1 consistent, 2 exact (KINEMATICS)
    B1: np.ndarray             # (n_nodes, r_max): S_j'(x_g) of the cell owning node g
    B2: np.ndarray             # (n_nodes, r_max): S_j''(x_g)
    W: np.ndarray              # (n_nodes,): quadrature weights, m
    Mb: np.ndarray             # (n_q, r_max): beam mass, both beams, kg (m^-2 per Ritz unit)
    K: np.ndarray              # (n_q, r_max): linear bending stiffness
    D: np.ndarray              # (n_q, r_max): Kelvin-Voigt beam damping
    ref: np.ndarray            # (n_q,): S_j at the cell's reference point (published q)
    mi_val: np.ndarray         # nonzero entries of the interface mass MI (n_cells x n_cells), kg
    mi_row: np.ndarray         # int64: their row cells
    mi_col: np.ndarray         # int64: their column cells
    P: np.ndarray              # (n_structure, n_cells): structure outputs = P @ y
    # per cell (beam pair)
    length: np.ndarray         # beam length l, m
    EI: np.ndarray             # bending stiffness, N m^2
    c2: np.ndarray             # one-term closed forms: 1/2 int S'^2,
    c4: np.ndarray             # 1/8 int S'^4,
    e4: np.ndarray             # EI int S''^2 S'^2 (quadrature skipped for one-term cells)
    # per DET (eqs 53-57, 66-67)
    l0: np.ndarray             # DET length at rest, m
    VY: np.ndarray             # volume * Young's modulus, N m
    C0: np.ndarray             # capacitance at lambda = 1, F
    volume: np.ndarray         # m^3
    E_M: np.ndarray            # Maxwell creep modulus, Pa
    eta_M: np.ndarray          # Maxwell viscosity, Pa s
    eta_v: np.ndarray          # Kelvin-Voigt viscosity, Pa s
    Rs: np.ndarray             # series resistance, Ohm
    Rp: np.ndarray             # leakage resistance, Ohm
    # the amplifier in the supply circuit (core/_csrc/physics/amplifier.c), read when ``amplifier``
    amplifier: int = 0         # 1: a bandwidth, slew rate or current limit shapes the supply
    amp_state: int = 0         # 1: the outputs v_a are states (a bandwidth or slew rate)
    amp_tau: np.ndarray = None   # output time constant 1/(2 pi bandwidth), s (0: ideal)
    amp_slew: np.ndarray = None  # slew-rate limit, V/s (0: none)
    amp_imax: np.ndarray = None  # current limit, A (0: none)

    @property
    def n_groups(self) -> int:
        """Return the number of independent coupled groups of cells (the copies of an array)."""
        return len(self.group_q) - 1

    def cell_slice(self, c: int) -> slice:
        """Return the coordinates of cell ``c`` in q."""
        return slice(int(self.cell_q[c]), int(self.cell_q[c + 1]))


@dataclasses.dataclass
class Model:
    """
    A built model: f(t, x, u), named states and outputs, and the compiled kernel.

    Create it with :func:`build_model`; ``arrays`` holds the named arrays the kernel was built
    from, ``kernel`` the compiled model (det_sim_ros.core.kernel.Model).
    """

    scene: Scene
    arrays: ModelArrays
    state_names: tuple
    output_names: tuple
    n_inputs: int
    bases: tuple
    input_names: tuple = ('det0',)      # DET names, in voltage-command order
    structure_output_names: tuple = ()  # e.g. ('plate_y', 'plate_phi')
    kernel: object = None

    def __post_init__(self):
        if self.kernel is None:
            self.kernel = kernel.Model(self.arrays)

    @property
    def structure_map(self) -> np.ndarray:
        """
        Return P (n_structure_outputs x n_cells), the map to the structure outputs.

        Structure outputs = P @ y (the cells' end shortenings).
        """
        return self.arrays.P

    def channel(self, base: str) -> list:
        """
        Return the indices in ``output_names`` of a per-DET output, in DET order.

        ``base`` names the output: 'q', 'y', 'q_p', ...
        """
        if self.n_inputs == 1:
            return [self.output_names.index(base)]
        return [self.output_names.index(f'{base}[{d}]') for d in self.input_names]

    @property
    def n_states(self) -> int:
        """Return the length of x, including the two energy-monitor states when enabled."""
        return len(self.state_names)

    def released_state(self) -> np.ndarray:
        """
        Return the 'released' initial state.

        Each cell's beam in the paper's shape with q = q0 at the reference point (the Ritz
        coordinates of :meth:`RitzBasis.released_coordinates`), everything else 0.
        :func:`det_sim_ros.physics.statics.initial_state` gives the scene's own (rest or
        released).
        """
        x = np.zeros(self.n_states)
        cell_q = self.arrays.cell_q
        for c, physics in enumerate(self.scene.cell_physics()):
            x[cell_q[c]:cell_q[c + 1]] = self.bases[c].released_coordinates(physics.q0)
        return x

    def f(self, t, x, u, params=None) -> np.ndarray:  # noqa: ARG002 - nlsys signature
        """Return dx/dt at (x, u); python-control's ``updfcn(t, x, u, params)`` signature."""
        del t, params
        dx = np.empty(self.n_states)
        x = np.ascontiguousarray(x, dtype=float)
        if not np.all(np.isfinite(x)):
            check(kernel.NON_FINITE)
        check(self.kernel.rhs(x, self._u(u), dx)[0])
        return dx

    def output_vector(self, x, u) -> np.ndarray:
        """Return the outputs as one vector in ``output_names`` order."""
        out = np.empty(len(self.output_names))
        check(self.kernel.outputs(np.ascontiguousarray(x, dtype=float), self._u(u), out))
        return out

    def outputs(self, x, u) -> dict:
        """Return the named outputs at one state (see ``output_names``)."""
        return dict(zip(self.output_names, self.output_vector(x, u)))

    def apply_input_jump(self, x, u_old, u_new) -> None:
        """
        Book an instantaneous recharge of an ideal source in the power monitor.

        In place; see ds_book_input_jump in _csrc/physics/physics.c. Nothing to book for an RC
        source, without the monitor, or without a change.
        """
        if self.scene.source != 'ideal' or not self.scene.monitor_power:
            return
        u_old, u_new = self._u(u_old), self._u(u_new)
        if np.array_equal(u_old, u_new):
            return
        self.kernel.book_input_jump(x, u_old, u_new)

    def fastest_beam_rate(self) -> float:
        """
        Return the fastest rate (1/s) of the beams' linear modes.

        The largest undamped frequency of (K, Mb) or Kelvin-Voigt decay rate of (D, Mb) over the
        cells. With many Ritz terms the
        decay rate ~ omega^2 eta_b / E_b of the highest mode (4e5...1e6 1/s at n_r = 6...7)
        bounds the explicit stages' step size, not the tolerance.
        """
        a = self.arrays
        cell_q, Mb, K, D = a.cell_q, a.Mb, a.K, a.D
        rate = 0.0
        for c in range(len(cell_q) - 1):
            s, r = slice(cell_q[c], cell_q[c + 1]), cell_q[c + 1] - cell_q[c]
            # symmetric-definite pencils (K, Mb), (D, Mb) by Cholesky Mb = L L': the eigenvalues
            # of L^-1 K L^-T (numpy only: importing scipy.linalg slows a node's start;
            # docs/development.md)
            L_inv = np.linalg.inv(np.linalg.cholesky(Mb[s, :r]))
            omega2 = np.linalg.eigvalsh(L_inv @ K[s, :r] @ L_inv.T)
            decay = np.linalg.eigvalsh(L_inv @ D[s, :r] @ L_inv.T)
            rate = max(rate, float(np.sqrt(max(omega2.max(), 0.0))), float(decay.max()))
        return rate

    def stiff_rates(self, x) -> np.ndarray:
        """
        Return the diagonal of the stiff linear part (1/s).

        -1/(C Rs||Rp) at the charge states.
        """
        L = np.empty(self.n_states)
        check(self.kernel.stiff_rates(np.ascontiguousarray(x, dtype=float), L))
        return L

    def _u(self, u):
        u = np.atleast_1d(np.asarray(u, dtype=float))
        if u.shape != (self.n_inputs,):
            raise ValueError(f'expected {self.n_inputs} input voltage(s), got shape {u.shape}')
        return u


def build_model(scene: Scene) -> Model:
    """
    Assemble the model arrays from a scene (Ritz integrals computed once, here).

    Every cell (one DET and its beam pair, Section 3) brings its own Ritz basis and physics;
    the structure decides how the cells' end shortenings y_c meet inertia (MI, the kinetic
    energy 1/2 ydot' MI ydot) and which structure outputs exist:

    - 'single', 'array': each cell carries its own interface mass m (MI = diag(m_c)); an array
      is N independent copies stepped together;
    - 'plate': two cells at x = -w/2 (first DET) and +w/2 (second) under one rigid plate of mass
      M and inertia J. With the plate's height Y = (y_1 + y_2)/2 and small rotation
      phi = (y_1 - y_2)/w, T = 1/2 M Ydot^2 + 1/2 J phidot^2 gives
      MI = M/4 [[1, 1], [1, 1]] + J/w^2 [[1, -1], [-1, 1]] (the plate replaces the cells' m).
      Outputs plate_y = Y (end shortening at the centre) and plate_phi = phi (rad, positive when
      the second cell's side rises more, i.e. its Delta-y = y0 - y is larger).
    """
    physics = scene.cell_physics()
    shapes, n_ritz = scene.ritz_level
    cells = [make_basis(scene.beam, ph.l0 * (1.0 + scene.eps_b), scene.fidelity, n_ritz, shapes)
             for ph in physics]
    kind = scene.structure['type']
    if kind == 'plate':
        w = scene.structure['plate_width']
        M, Jp = scene.structure['plate_mass'], scene.structure['plate_inertia']
        MI = M / 4.0 * np.ones((2, 2)) + Jp / w ** 2 * np.array([[1.0, -1.0], [-1.0, 1.0]])
        P = np.array([[0.5, 0.5], [1.0 / w, -1.0 / w]])
        structure_names = ('plate_y', 'plate_phi')
    else:
        MI = np.diag([ph.m for ph in physics])
        P = np.zeros((0, len(cells)))
        structure_names = ()
    return _assemble(scene, cells, MI, physics, P, structure_names)


def _groups(MI):
    """Return the connected groups of cells under MI (cells of a group must be contiguous)."""
    n = MI.shape[0]
    group = np.arange(n)
    for i in range(n):           # union of coupled cells; coupling is local in practice
        for j in np.nonzero(MI[i])[0]:
            a, b = group[i], group[j]
            if a != b:
                group[group == max(a, b)] = min(a, b)
    labels, cell_grp = np.unique(group, return_inverse=True)
    if np.any(np.diff(cell_grp) < 0) or np.any(np.diff(cell_grp) > 1):
        raise ValueError('cells coupled by the structure must be listed next to each other')
    return cell_grp.astype(np.int64), len(labels)


def _cell_arrays(scene, cells, det_physics):
    """
    Return the per-cell blocks (see ModelArrays).

    Quadrature rows B1, B2, W by cell_g, the mass, stiffness and damping blocks by cell_q, the
    reference rows, and the cells' beam and DET constants (name -> one value per cell).
    """
    nc = len(cells)
    r = [b.n_ritz for b in cells]
    nq = int(sum(r))
    r_max = max(r)
    cell_q = np.concatenate([[0], np.cumsum(r)]).astype(np.int64)
    nodes = [b.quadrature(nonpolynomial=scene.fidelity == 'exact') for b in cells]
    cell_g = np.concatenate([[0], np.cumsum([len(x) for x, _ in nodes])]).astype(np.int64)
    B1 = np.zeros((cell_g[-1], r_max))
    B2 = np.zeros_like(B1)
    W = np.zeros(cell_g[-1])
    Mb = np.zeros((nq, r_max))     # block rows by cell (see ModelArrays)
    K = np.zeros((nq, r_max))
    D = np.zeros((nq, r_max))
    ref = np.zeros(nq)
    cell = {key: np.zeros(nc) for key in ('length', 'EI', 'c2', 'c4', 'e4')}
    det = {key: np.zeros(nc) for key in ('l0', 'VY', 'C0', 'volume', 'E_M', 'eta_M', 'eta_v',
                                         'Rs', 'Rp')}
    for c, (basis, (x, w), ph) in enumerate(zip(cells, nodes, det_physics)):
        g = slice(cell_g[c], cell_g[c + 1])
        s = slice(cell_q[c], cell_q[c + 1])
        S0, S1, S2 = (basis.values(x, k) for k in range(3))
        B1[g, :basis.n_ritz] = S1
        B2[g, :basis.n_ritz] = S2
        W[g] = w
        EI = ph.E_b * ph.I
        # both beams: factor 2 on every beam integral (eqs 49, 51, 55 with B1 = B2)
        Mb[s, :basis.n_ritz] = 2.0 * ph.rho_b * (ph.I * S1.T @ (w[:, None] * S1)
                                                 + ph.area * S0.T @ (w[:, None] * S0))
        K[s, :basis.n_ritz] = 2.0 * EI * S2.T @ (w[:, None] * S2)
        D[s, :basis.n_ritz] = 2.0 * ph.eta_b * ph.I * S2.T @ (w[:, None] * S2)
        ref[s] = basis.reference_row()
        values = {'length': basis.length, 'EI': EI,
                  'c2': 0.5 * w @ S1[:, 0] ** 2,                 # closed forms:
                  'c4': 0.125 * w @ S1[:, 0] ** 4,               # used when
                  'e4': EI * w @ (S2[:, 0] * S1[:, 0]) ** 2}     # n_ritz == 1
        values.update(l0=ph.l0, VY=ph.volume * ph.Y, C0=ph.C0, volume=ph.volume, E_M=ph.E_M,
                      eta_M=ph.eta_M, eta_v=ph.eta_v, Rs=ph.Rs, Rp=ph.Rp)
        for key, value in values.items():
            (cell if key in cell else det)[key][c] = value
    return {'nq': nq, 'r_max': r_max, 'cell_q': cell_q, 'cell_g': cell_g, 'B1': B1, 'B2': B2,
            'W': W, 'Mb': Mb, 'K': K, 'D': D, 'ref': ref, 'cell': cell, 'det': det}


def _state_names(scene, nq, nc):
    """
    Return the state names.

    q[j], q_dot[j], then eps_E[i] (creep), q_p[i] (RC source), W_in, W_diss (power).
    """
    names = [f'q[{j}]' for j in range(nq)] + [f'q_dot[{j}]' for j in range(nq)]
    if scene.creep:
        names += [f'eps_E[{i}]' for i in range(nc)]
    if scene.source == 'rc':
        names += [f'q_p[{i}]' for i in range(nc)]
    if _amplifier_fields(scene)['amp_state']:
        names += [f'v_a[{i}]' for i in range(nc)]
    if scene.monitor_power:
        names += ['W_in', 'W_diss']
    return names


def _amplifier_fields(scene) -> dict:
    """Return the ModelArrays fields of the amplifiers' circuit side (all off: none)."""
    amps = scene.cell_amplifiers()
    if scene.source != 'rc' or not any(amp.acts_in_circuit for amp in amps):
        return {'amplifier': 0, 'amp_state': 0}
    column = lambda values: np.ascontiguousarray(values, dtype=float)  # noqa: E731
    return {'amplifier': 1, 'amp_state': int(any(amp.has_output_state for amp in amps)),
            'amp_tau': column([amp.time_constant for amp in amps]),
            'amp_slew': column([amp.slew_rate for amp in amps]),
            'amp_imax': column([amp.current_limit for amp in amps])}


def _assemble(scene, cells, MI, det_physics, P, structure_names):
    """
    Return the :class:`Model` of ``cells`` (one Ritz basis per cell).

    The cells are coupled by the structure's inverse-mass map MI, with the structure outputs
    P @ y.
    """
    nc = len(cells)
    blocks = _cell_arrays(scene, cells, det_physics)
    nq, cell_q = blocks['nq'], blocks['cell_q']
    MI = np.asarray(MI, dtype=float)
    mi_idx = np.argwhere(MI != 0.0)            # row-major: entries of a group are contiguous
    cell_grp, n_groups = _groups(MI)
    grp_q = np.zeros(n_groups + 1, dtype=np.int64)
    for c in range(nc):
        grp_q[cell_grp[c] + 1] = cell_q[c + 1]
    creep, rc, power = int(scene.creep), int(scene.source == 'rc'), int(scene.monitor_power)
    names = _state_names(scene, nq, nc)
    ints = lambda v: np.ascontiguousarray(v, dtype=np.int64)  # noqa: E731
    arrays = ModelArrays(
        n_q=nq, n_cells=nc, n_state=len(names), r_max=blocks['r_max'], creep=creep, rc_source=rc,
        power_monitor=power, cell_q=ints(cell_q), cell_g=ints(blocks['cell_g']),
        cell_group=ints(cell_grp), group_q=ints(grp_q),
        kinematics=ints(np.full(nc, KINEMATICS[scene.fidelity])),
        **{key: blocks[key] for key in ('B1', 'B2', 'W', 'Mb', 'K', 'D', 'ref')},
        mi_val=np.ascontiguousarray(MI[MI != 0.0], dtype=float),
        mi_row=ints(mi_idx[:, 0]), mi_col=ints(mi_idx[:, 1]),
        P=np.ascontiguousarray(P, dtype=float), **blocks['cell'], **blocks['det'],
        **_amplifier_fields(scene))
    det_names = scene.det_names
    if nc == 1:
        out_names = CELL_OUTPUTS
    else:
        out_names = tuple(f'{n}[{d}]' for d in det_names for n in CELL_OUTPUTS)
    return Model(scene, arrays, tuple(names),
                 out_names + tuple(structure_names) + GLOBAL_OUTPUTS, nc, tuple(cells),
                 tuple(det_names), tuple(structure_names))
