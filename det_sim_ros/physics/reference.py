"""
The DET-beam physics and one step of every method in plain numpy.

This is the readable reference that the compiled kernel (det_sim_ros/core/_csrc) is held to, to
round-off, by test/test_kernel.py.

Nothing here is fast or used by the simulator. It is written to be checked by eye against
model.py's derivation: every beam integral by quadrature (the kernel uses closed forms for
one-term cells), the mass matrix assembled and solved whole (the kernel solves it block by
block), and phi_k from an augmented matrix exponential (the kernel uses series and recurrences).

State layout and units: see :class:`det_sim_ros.physics.model.ModelArrays`.

:func:`kinematics` and :func:`rhs` also take complex x and u (every operation is analytic), so
complex-step differentiation gives their Jacobians to round-off (det_sim_ros.physics.linearize).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.linalg import expm

__all__ = ['kinematics', 'rhs', 'stiff_rates', 'outputs', 'phi', 'step', 'amplifier_laws',
           'LIMIT_MARGIN']

EXACT = 2
LIMIT_MARGIN = 1e-6   # the current-limit law starts at |i| = I (1 - LIMIT_MARGIN)
SLEW_MARGIN = 1e-9    # a gap within S tau_a (1 + SLEW_MARGIN) is followed, not slewed


@dataclasses.dataclass
class Kinematics:
    """
    The kinematics of every cell at one state.

    Per cell: end shortening y, qd' H_y qd (h) and the bending energy beyond EI int w''^2 (U4);
    per coordinate: J = dy/dq and the gradient of U4.
    """

    y: np.ndarray
    h: np.ndarray
    J: np.ndarray
    U4: np.ndarray
    dU4: np.ndarray


def kinematics(a, x) -> Kinematics:
    """
    Return the kinematics of every cell at the state x.

    See model.py: y, curvature, eqs 51, 65.
    """
    nq = a.n_q
    q, qd = x[:nq], x[nq:2 * nq]
    kind = np.result_type(x, float)            # complex for complex-step differentiation
    y, h, U4 = (np.zeros(a.n_cells, kind) for _ in range(3))
    J, dU4 = np.zeros(nq, kind), np.zeros(nq, kind)
    for c in range(a.n_cells):
        s = a.cell_slice(c)
        r = s.stop - s.start
        g = slice(a.cell_g[c], a.cell_g[c + 1])
        B1, B2, W = a.B1[g, :r], a.B2[g, :r], a.W[g]
        wp, wd, wpp = B1 @ q[s], B1 @ qd[s], B2 @ q[s]
        EI = a.EI[c]
        if a.kinematics[c] == EXACT:   # w' = sin(theta): y = int 1 - cos(theta)
            cos = np.sqrt(1.0 - wp ** 2)
            y[c] = W @ (1.0 - cos)
            dy_dwp = wp / cos
            h[c] = W @ (wd ** 2 / cos ** 3)           # d/dt (dy/dwp) wd = wd^2 / cos^3
            g_bend = wp ** 2 / (1.0 - wp ** 2)        # curvature^2 = w''^2 / (1 - w'^2)
            dg_bend = 2.0 * wp / (1.0 - wp ** 2) ** 2
        else:                                        # y = int w'^2/2 (+ w'^4/8, consistent)
            kappa = 1.0 if a.kinematics[c] == 1 else 0.0
            y[c] = W @ (0.5 * wp ** 2 + 0.125 * kappa * wp ** 4)
            dy_dwp = wp + 0.5 * kappa * wp ** 3
            h[c] = W @ ((1.0 + 1.5 * kappa * wp ** 2) * wd ** 2)
            g_bend, dg_bend = wp ** 2, 2.0 * wp       # eq 51: EI int w''^2 (1 + w'^2)
        J[s] = B1.T @ (W * dy_dwp)
        U4[c] = EI * W @ (wpp ** 2 * g_bend)
        dU4[s] = EI * (B2.T @ (W * 2.0 * wpp * g_bend) + B1.T @ (W * wpp ** 2 * dg_bend))
    return Kinematics(y, h, J, U4, dU4)


def _blocks(a, M):
    """Return the full n_q x n_q matrix of a block-row-by-cell array (Mb, K, D)."""
    full = np.zeros((a.n_q, a.n_q))
    for c in range(a.n_cells):
        s = a.cell_slice(c)
        full[s, s] = M[s, :s.stop - s.start]
    return full


def _interface_mass(a):
    """Return MI (n_cells x n_cells): the interface/plate mass acting on the end shortenings."""
    MI = np.zeros((a.n_cells, a.n_cells))
    MI[a.mi_row, a.mi_col] = a.mi_val
    return MI


def _charge_offset(a, x, u):
    """
    Return C(q) v_inf per DET: the charge the circuit relaxes to for frozen q.

    The quasi-static coordinates z = q_p - C v_inf are used by the exponential methods on RC
    scenes.
    """
    lam = (a.length - kinematics(a, x).y) / a.l0
    return a.C0 * lam ** 2 * u * a.Rp / (a.Rs + a.Rp)


def _index(a):
    i_eps = 2 * a.n_q
    i_qp = i_eps + a.n_cells * a.creep
    return i_eps, i_qp, i_qp + a.n_cells * (a.rc_source + a.amp_state)


def _source_voltage(a, x, u):
    """Return the voltage behind Rs per DET: the amplifier's v_a where it lags, else u."""
    if not a.amp_state:
        return u
    i_va = _index(a)[1] + a.n_cells
    lags = (a.amp_tau > 0.0) | (a.amp_slew > 0.0)
    return np.where(lags, x[i_va:i_va + a.n_cells], u)


def _relax_voltage(a, x, u, laws):
    """Return what the charge relaxes towards per DET: v_src while linear, 0 at the limit."""
    if not a.amplifier:
        return u
    return np.where(np.array(laws[1]) == 'linear', _source_voltage(a, x, u), 0.0)


def amplifier_laws(a, x, u):
    """
    Return each DET's amplifier laws at (x, u) (charge slots holding q_p): (v_law, i_law).

    v_law: 'follow' (dv_a/dt = (u - v_a)/tau_a), 'up' / 'down' (dv_a/dt = +-S while
    |u - v_a| > S tau_a), 'hold' (no output lag, or a slew without bandwidth that arrived);
    i_law: 'linear' (i = (v_a - v_p)/Rs), '+limit' / '-limit' (i = +-I once |i_lin| reaches
    I (1 - LIMIT_MARGIN)).
    """
    nc, i_qp = a.n_cells, _index(a)[1]
    lam = (a.length - kinematics(a, x).y) / a.l0
    v_src = _source_voltage(a, x, u)
    share = (v_src - x[i_qp:i_qp + nc] / (a.C0 * lam ** 2)) / a.Rs / np.where(
        a.amp_imax > 0.0, a.amp_imax, 1.0)
    v_laws, i_laws = [], []
    for c in range(nc):
        gap, band = u[c] - v_src[c], a.amp_slew[c] * a.amp_tau[c]
        if not (a.amp_tau[c] > 0.0 or a.amp_slew[c] > 0.0):
            v_laws.append('hold')
        elif a.amp_slew[c] > 0.0 and abs(gap) > band * (1.0 + SLEW_MARGIN):
            v_laws.append('up' if gap > 0.0 else 'down')
        else:
            v_laws.append('follow' if a.amp_tau[c] > 0.0 else 'hold')
        limited = a.amp_imax[c] > 0.0 and abs(share[c]) >= 1.0 - LIMIT_MARGIN
        i_laws.append(('+limit' if share[c] > 0.0 else '-limit') if limited else 'linear')
    return v_laws, i_laws


def _amplified_supply(a, x, u, vp, laws):
    """
    Return (current, v_out, v_src, dv_src/dt) per DET under the amplifier's ``laws``.

    The current through Rs, the amplifier's terminal voltage (v_a, or v_p + Rs i at the
    limit), the voltage behind Rs and its rate.
    """
    v_laws, i_laws = laws
    v_src = _source_voltage(a, x, u)
    rate = np.array([{'follow': (u[c] - v_src[c]) / a.amp_tau[c] if a.amp_tau[c] else 0.0,
                      'up': a.amp_slew[c], 'down': -a.amp_slew[c], 'hold': 0.0}[law]
                     for c, law in enumerate(v_laws)])
    limit = np.array([{'+limit': 1.0, '-limit': -1.0, 'linear': 0.0}[law] for law in i_laws])
    current = np.where(limit != 0.0, limit * a.amp_imax, (v_src - vp) / a.Rs)
    v_out = np.where(limit != 0.0, vp + a.Rs * current, v_src)
    return current, v_out, v_src, rate


def _numbers(v):
    """Return v as a float array, or complex if it is complex."""
    v = np.asarray(v)
    return v if np.iscomplexobj(v) else v.astype(float)


def _beams(a, x, kin, kind):
    """
    Return the beams' part of Lagrange's equations: (Jc, M, F, qd' D qd).

    Jc (row c: dy_c/dq), the mass matrix Mb + Jc' MI Jc, the forces without the DETs'
    -K q - D qd - dU4/dq - Jc' MI (qd' H_y qd), and the beams' damping power.
    """
    nq, nc = a.n_q, a.n_cells
    q, qd = x[:nq], x[nq:2 * nq]
    K, D, Mb = _blocks(a, a.K), _blocks(a, a.D), _blocks(a, a.Mb)
    MI = _interface_mass(a)
    Jc = np.zeros((nc, nq), kind)
    for c in range(nc):
        s = a.cell_slice(c)
        Jc[c, s] = kin.J[s]
    F = -K @ q - D @ qd - kin.dU4 - Jc.T @ (MI @ kin.h)
    return Jc, Mb + Jc.T @ MI @ Jc, F, qd @ D @ qd


def _rc_circuit(a, u, lam, ydot, vp, quasi_static, dx):
    """Set dq_p/dt of the RC circuit fed by u in dx; return (i, Rs i^2, u v_p / Rp)."""
    i_qp, nc = _index(a)[1], a.n_cells
    dqp = u / a.Rs - (1.0 / a.Rs + 1.0 / a.Rp) * vp
    if quasi_static:   # dz/dt = dq_p/dt - d(C v_inf)/dt, dlambda/dt = -ydot/l0
        dqp = dqp + 2.0 * a.C0 * lam * ydot / a.l0 * u * a.Rp / (a.Rs + a.Rp)
    dx[i_qp:i_qp + nc] = dqp
    i_de = (u - vp) / a.Rs
    return i_de, (u - vp) @ i_de, u @ (vp / a.Rp)


def _amplified_circuit(a, x, u, laws, det, quasi_static, dx):
    """
    Set the amplified circuit's rates in dx; return (i, v_out, Rs i^2, quasi-static energy rate).

    ``det`` holds lambda, dy/dt, q_p, v_p and the voltage the charge relaxes towards per DET;
    the energy rate is that of W_in - v_relax q_p (see :func:`rhs`).
    """
    lam, ydot, qp, vp, v_rel = det
    nc, i_qp = a.n_cells, _index(a)[1]
    i_de, v_out, _, v_rate = _amplified_supply(a, x, u, vp, laws)
    rel_rate = np.where(np.array(laws[1]) == 'linear', v_rate, 0.0)
    dqp = i_de - vp / a.Rp
    if quasi_static:   # dz/dt = dq_p/dt - d(C v_rel Rp/(Rs+Rp))/dt
        dqp = dqp + (2.0 * a.C0 * lam * ydot / a.l0 * v_rel
                     - a.C0 * lam ** 2 * rel_rate) * a.Rp / (a.Rs + a.Rp)
    dx[i_qp:i_qp + nc] = dqp
    if a.amp_state:
        dx[i_qp + nc:i_qp + 2 * nc] = v_rate
    p_relative = (v_out - v_rel) @ i_de + v_rel @ (vp / a.Rp) - rel_rate @ qp
    return i_de, v_out, (v_out - vp) @ i_de, p_relative


def rhs(a, x, u, quasi_static: bool = False, laws=None):
    """
    Return (dx/dt, P_in, P_diss) at (x, u).

    Lagrange's equations of model.py,
    (Mb + J' MI J) qdd = -K q - D qd - dU4/dq - J' MI (qd' H_y qd) + J/l0 [dU_DE/dlambda]
    - V (E_M eps + eta_v dlz/dt) dlz/dq, with the creep and circuit equations.
    ``quasi_static``: the charge slots hold z = q_p - C(q) v_inf and receive dz/dt, and the
    supplied-energy slot receives the rate of W_in - u q_p, u v_p / Rp (see :func:`step`).
    With an amplifier (``a.amplifier``) its ``laws`` (default: :func:`amplifier_laws` at x as
    given) set the current and v_a's rate; z and the supplied-energy slot count against the
    voltage the charge relaxes towards (v_a while linear, 0 at the limit); the supplied power is
    v_out i at the amplifier's terminal.
    """
    x, u = _numbers(x), _numbers(u)
    kind = np.result_type(x, u, float)
    nq, nc = a.n_q, a.n_cells
    i_eps, i_qp, i_w = _index(a)
    qd = x[nq:2 * nq]
    kin = kinematics(a, x)
    Jc, M, F, p_diss = _beams(a, x, kin, kind)
    lam = (a.length - kin.y) / a.l0
    ydot = Jc @ qd
    lzd = ydot / (a.l0 * lam ** 2)           # d(1/lambda)/dt
    eps = x[i_eps:i_eps + nc] if a.creep else np.zeros(nc)
    dx = np.zeros(x.shape, kind)
    v_out = u
    if a.amplifier and laws is None:   # as the slots hold them (the kernel's Model.rhs)
        laws = amplifier_laws(a, np.real(x), np.real(u))
    if a.rc_source:
        v_rel = _relax_voltage(a, x, u, laws)
        qp = x[i_qp:i_qp + nc] + (_charge_offset(a, x, v_rel) if quasi_static else 0.0)
        vp = qp / (a.C0 * lam ** 2)
        dU_dlam = a.VY / 3.0 * (lam - lam ** -3) - qp ** 2 / (a.C0 * lam ** 3)
    if a.amplifier:
        i_de, v_out, p_rs, p_relative = _amplified_circuit(
            a, x, u, laws, (lam, ydot, qp, vp, v_rel), quasi_static, dx)
        p_diss += p_rs
    elif a.rc_source:
        i_de, p_rs, p_relative = _rc_circuit(a, u, lam, ydot, vp, quasi_static, dx)
        p_diss += p_rs
    else:
        vp = u
        dU_dlam = a.VY / 3.0 * (lam - lam ** -3) - a.C0 * lam * vp ** 2
        i_de = -2.0 * a.C0 * lam * ydot / a.l0 * vp + vp / a.Rp
    visc = a.volume * (a.E_M * eps + a.eta_v * lzd)
    F += Jc.T @ ((dU_dlam - visc / lam ** 2) / a.l0)
    if a.creep:
        relax = np.where(a.eta_M > 0.0, a.E_M / np.where(a.eta_M > 0.0, a.eta_M, 1.0), 0.0)
        dx[i_eps:i_eps + nc] = lzd - relax * eps
        p_diss += np.sum(a.volume * a.E_M * relax * eps ** 2)
    p_in = v_out @ i_de
    p_diss += np.sum(vp ** 2 / a.Rp + a.volume * a.eta_v * lzd ** 2)
    dx[:nq] = qd
    dx[nq:2 * nq] = np.linalg.solve(M, F)
    if a.power_monitor:   # quasi-static: the rate of W_in - v q_p (see step)
        dx[i_w:i_w + 2] = (p_relative if quasi_static and a.rc_source else p_in), p_diss
    return dx, p_in, p_diss


def stiff_rates(a, x, laws=None) -> np.ndarray:
    """
    Return the diagonal stiff part (1/s).

    -1/(C (Rs || Rp)) at the charge states, 0 elsewhere; with an amplifier, each law's own:
    -1/(C Rp) at the current limit, -1/tau_a at a following v_a (``laws``: see
    :func:`amplifier_laws`).
    """
    L = np.zeros(a.n_state)
    if a.rc_source:
        i_qp, nc = _index(a)[1], a.n_cells
        lam = (a.length - kinematics(a, x).y) / a.l0
        g = np.full(nc, 1.0 / a.Rs + 1.0 / a.Rp)
        if a.amplifier:
            v_laws, i_laws = laws
            g = np.where(np.array(i_laws) == 'linear', g, 1.0 / a.Rp)
            if a.amp_state:
                L[i_qp + nc:i_qp + 2 * nc] = [-1.0 / a.amp_tau[c] if law == 'follow' else 0.0
                                              for c, law in enumerate(v_laws)]
        L[i_qp:i_qp + nc] = -g / (a.C0 * lam ** 2)
    return L


def outputs(a, x, u) -> np.ndarray:
    """
    Return the outputs in det_sim_ros.physics.model output order.

    Per cell q_ref, qdot_ref, y, lambda, q_p, v_p, i_DE, C, eps_E; the structure outputs P y;
    the energy H, P_in, P_diss.
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    nq, nc = a.n_q, a.n_cells
    i_eps, i_qp, _ = _index(a)
    q, qd = x[:nq], x[nq:2 * nq]
    kin = kinematics(a, x)
    _, p_in, p_diss = rhs(a, x, u)
    lam = (a.length - kin.y) / a.l0
    cap = a.C0 * lam ** 2
    ydot = np.array([kin.J[a.cell_slice(c)] @ qd[a.cell_slice(c)] for c in range(nc)])
    if a.rc_source:
        qp = x[i_qp:i_qp + nc]
        vp = qp / cap
        i_de = (u - vp) / a.Rs
        if a.amplifier:
            i_de = _amplified_supply(a, x, u, vp, amplifier_laws(a, x, u))[0]
    else:
        vp = u
        qp = cap * vp
        i_de = -2.0 * a.C0 * lam * ydot / a.l0 * vp + vp / a.Rp
    eps = x[i_eps:i_eps + nc] if a.creep else np.zeros(nc)
    MI = _interface_mass(a)
    energy = (0.5 * qd @ _blocks(a, a.Mb) @ qd + 0.5 * q @ _blocks(a, a.K) @ q + kin.U4.sum()
              + 0.5 * ydot @ MI @ ydot
              + np.sum(a.VY / 6.0 * (lam ** 2 + lam ** -2 - 2.0) + 0.5 * qp ** 2 / cap
                       + 0.5 * a.volume * a.E_M * eps ** 2))
    q_ref = [a.ref[a.cell_slice(c)] @ q[a.cell_slice(c)] for c in range(nc)]
    qd_ref = [a.ref[a.cell_slice(c)] @ qd[a.cell_slice(c)] for c in range(nc)]
    cells = np.column_stack([q_ref, qd_ref, kin.y, lam, qp, vp, i_de, cap, eps]).reshape(-1)
    return np.concatenate([cells, a.P @ kin.y, [energy, p_in, p_diss]])


def phi(k: int, z: float) -> float:
    """
    Return phi_k(z) = sum_m z^m / (m + k)!.

    It is the first row of exp of the (k+1) x (k+1) matrix with z at (0, 0) and ones above the
    diagonal (Higham, Functions of Matrices, thm 10.34 form).
    """
    A = np.diag(np.ones(k), 1)
    A[0, 0] = z
    return float(expm(A)[0, k])


def _couplings(a, L, laws) -> list:
    """
    Return the charge's couplings to a following amplifier output: (i_z, i_va, M) per DET.

    In the quasi-static coordinates z' = L_z z + c v_a + ..., v_a' = L_a v_a + ... with
    c = C Rp/(Rs+Rp) / tau_a = -1/(Rs L_z tau_a) while v_a follows and the current is linear:
    the stages integrate the block M = [[L_z, c], [0, L_a]] exactly.
    """
    i_qp, nc = _index(a)[1], a.n_cells
    rs = np.broadcast_to(a.Rs, (nc,))
    v_laws, i_laws = laws
    return [(i_qp + c, i_qp + nc + c,
             np.array([[L[i_qp + c], -1.0 / (rs[c] * L[i_qp + c] * a.amp_tau[c])],
                       [0.0, L[i_qp + nc + c]]]))
            for c in range(nc) if v_laws[c] == 'follow' and i_laws[c] == 'linear']


def _corner(M, scale: float, k: int) -> float:
    """Return the corner (0, 1) of phi_k(scale M) for a 2 x 2 block M."""
    from .matrix_phi import augmented_phis   # scipy: tests only
    return float(augmented_phis(scale * M, k)[k][0, 1])


def _stages(a, method, x, u, h: float, L, laws, quasi: bool) -> np.ndarray:
    """Return the new state of :func:`step` from x in the coordinates the stages integrate."""
    s = method.n_stages
    couplings = _couplings(a, L, laws) if quasi and a.amp_state else []

    def weight(term):
        _, _, k, c_arg, w = term
        if k < 0:
            return np.full(a.n_state, w), [0.0] * len(couplings)
        return (w * np.array([phi(int(k), c_arg * h * rate) for rate in L]),
                [w * _corner(M, c_arg * h, int(k)) for _, _, M in couplings])

    def linear(X):   # the linear part times X: L X and each coupling's c v_a
        out = L * X
        for iz, iv, M in couplings:
            out[iz] += M[0, 1] * X[iv]
        return out

    N = []
    for i in range(s + 1):
        ci = method.c[i] if i < s else 1.0
        X = np.exp(ci * h * L) * x
        for iz, iv, M in couplings:   # the corner of exp(c_i h M)
            X[iz] += _corner(M, ci * h, 0) * x[iv] if ci else 0.0
        for term in method.terms:
            if term[0] == i:
                diag, corners = weight(term)
                Nj = N[int(term[1])]
                X = X + h * diag * Nj
                for (iz, iv, _), corner in zip(couplings, corners):
                    X[iz] += h * corner * Nj[iv]
        if i == s:
            break
        N.append(rhs(a, X, u, quasi, laws)[0] - linear(X))
    return X


def step(a, method, x, u, h: float) -> np.ndarray:
    """
    Return one step of size h of a :class:`det_sim_ros.sim.integrators.Method`.

    The step goes from x with u held:

        X_i = exp(c_i h L) x + h sum_j a_ij(hL) N(X_j),   x+ = exp(h L) x + h sum_j b_j(hL) N(X_j)

    with N(X) = f(X) - L X, L the stiff diagonal at x (zero for explicit methods), every a_ij,
    b_j a sum of weight * phi_k(c_arg h L); exponential methods on an RC scene work in the
    quasi-static charge coordinates (see :func:`rhs`), where a following amplifier output
    couples into L (see :func:`_couplings`).
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    if method.kind.name != 'stages':
        raise ValueError(f"{method.name}: only a table's stages step here; the kind "
                         f'{method.kind.name!r} steps in reference_linearized.step_linearized '
                         '(a dense linear part) or reference_bdf (BDF)')
    laws = amplifier_laws(a, x, u) if a.amplifier else None   # held for the step
    L = stiff_rates(a, x, laws) if method.exponential else np.zeros(a.n_state)
    quasi = bool(method.exponential and a.rc_source)
    i_qp = _index(a)[1]
    charge = slice(i_qp, i_qp + a.n_cells)
    x = x.copy()
    i_w = _index(a)[2]
    if quasi:   # the stages integrate z and, with the power monitor, xi = W_in - v q_p
        v = _relax_voltage(a, x, u, laws)
        if a.power_monitor:
            x[i_w] -= v @ x[charge]
        x[charge] -= _charge_offset(a, x, v)
    X = _stages(a, method, x, u, h, L, laws, quasi)
    if quasi:
        v = _relax_voltage(a, X, u, laws)
        X[charge] += _charge_offset(a, X, v)
        if a.power_monitor:
            X[i_w] += v @ X[charge]
    return X
