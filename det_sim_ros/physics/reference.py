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

__all__ = ['kinematics', 'rhs', 'stiff_rates', 'outputs', 'phi', 'step', 'mechanical_jacobian',
           'step_linearized']

EXACT = 2


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
    return i_eps, i_qp, i_qp + a.n_cells * a.rc_source


def _numbers(v):
    """Return v as a float array, or complex if it is complex."""
    v = np.asarray(v)
    return v if np.iscomplexobj(v) else v.astype(float)


def rhs(a, x, u, quasi_static: bool = False):
    """
    Return (dx/dt, P_in, P_diss) at (x, u).

    Lagrange's equations of model.py,
    (Mb + J' MI J) qdd = -K q - D qd - dU4/dq - J' MI (qd' H_y qd) + J/l0 [dU_DE/dlambda]
    - V (E_M eps + eta_v dlz/dt) dlz/dq, with the creep and circuit equations.
    ``quasi_static``: the charge slots hold z = q_p - C(q) v_inf and receive dz/dt, and the
    supplied-energy slot receives the rate of W_in - u q_p, u v_p / Rp (see :func:`step`).
    """
    x, u = _numbers(x), _numbers(u)
    kind = np.result_type(x, u, float)
    nq, nc = a.n_q, a.n_cells
    i_eps, i_qp, i_w = _index(a)
    q, qd = x[:nq], x[nq:2 * nq]
    kin = kinematics(a, x)
    K, D, Mb = _blocks(a, a.K), _blocks(a, a.D), _blocks(a, a.Mb)
    MI = _interface_mass(a)
    Jc = np.zeros((nc, nq), kind)            # row c: dy_c/dq
    for c in range(nc):
        s = a.cell_slice(c)
        Jc[c, s] = kin.J[s]
    M = Mb + Jc.T @ MI @ Jc
    F = -K @ q - D @ qd - kin.dU4 - Jc.T @ (MI @ kin.h)
    p_diss = qd @ D @ qd
    lam = (a.length - kin.y) / a.l0
    ydot = Jc @ qd
    lzd = ydot / (a.l0 * lam ** 2)           # d(1/lambda)/dt
    eps = x[i_eps:i_eps + nc] if a.creep else np.zeros(nc)
    dx = np.zeros(x.shape, kind)
    if a.rc_source:
        qp = x[i_qp:i_qp + nc] + (_charge_offset(a, x, u) if quasi_static else 0.0)
        vp = qp / (a.C0 * lam ** 2)
        dU_dlam = a.VY / 3.0 * (lam - lam ** -3) - qp ** 2 / (a.C0 * lam ** 3)
        i_de = (u - vp) / a.Rs
        dqp = u / a.Rs - (1.0 / a.Rs + 1.0 / a.Rp) * vp
        if quasi_static:   # dz/dt = dq_p/dt - d(C v_inf)/dt, dlambda/dt = -ydot/l0
            dqp = dqp + 2.0 * a.C0 * lam * ydot / a.l0 * u * a.Rp / (a.Rs + a.Rp)
        dx[i_qp:i_qp + nc] = dqp
        p_diss += (u - vp) @ i_de
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
    p_in = u @ i_de
    p_diss += np.sum(vp ** 2 / a.Rp + a.volume * a.eta_v * lzd ** 2)
    dx[:nq] = qd
    dx[nq:2 * nq] = np.linalg.solve(M, F)
    if a.power_monitor:   # quasi-static: the rate of W_in - u q_p (see step)
        dx[i_w:i_w + 2] = (u @ (vp / a.Rp) if quasi_static and a.rc_source else p_in), p_diss
    return dx, p_in, p_diss


def stiff_rates(a, x) -> np.ndarray:
    """
    Return the diagonal stiff part (1/s).

    -1/(C (Rs || Rp)) at the charge states, 0 elsewhere.
    """
    L = np.zeros(a.n_state)
    if a.rc_source:
        i_qp = _index(a)[1]
        lam = (a.length - kinematics(a, x).y) / a.l0
        L[i_qp:i_qp + a.n_cells] = -(1.0 / a.Rs + 1.0 / a.Rp) / (a.C0 * lam ** 2)
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


def step(a, method, x, u, h: float) -> np.ndarray:
    """
    Return one step of size h of a :class:`det_sim_ros.sim.integrators.Method`.

    The step goes from x with u held:

        X_i = exp(c_i h L) x + h sum_j a_ij(hL) N(X_j),   x+ = exp(h L) x + h sum_j b_j(hL) N(X_j)

    with N(X) = f(X) - L X, L the stiff diagonal at x (zero for explicit methods), every a_ij,
    b_j a sum of weight * phi_k(c_arg h L); exponential methods on an RC scene work in the
    quasi-static charge coordinates (see :func:`rhs`).
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    if method.linearized:   # the dense linear part taken at x
        return step_linearized(a, method, x, u, h, mechanical_jacobian(a, x, u))[0]
    s = method.n_stages
    L = stiff_rates(a, x) if method.exponential else np.zeros(a.n_state)
    quasi = bool(method.exponential and a.rc_source)
    i_qp = _index(a)[1]
    charge = slice(i_qp, i_qp + a.n_cells)
    x = x.copy()
    i_w = _index(a)[2]
    if quasi:   # the stages integrate z and, with the power monitor, xi = W_in - u q_p
        if a.power_monitor:
            x[i_w] -= u @ x[charge]
        x[charge] -= _charge_offset(a, x, u)

    def weight(term):
        _, _, k, c_arg, w = term
        if k < 0:
            return np.full(a.n_state, w)
        return w * np.array([phi(int(k), c_arg * h * rate) for rate in L])

    N = []
    for i in range(s + 1):
        ci = method.c[i] if i < s else 1.0
        X = np.exp(ci * h * L) * x
        for term in method.terms:
            if term[0] == i:
                X = X + h * weight(term) * N[int(term[1])]
        if i == s:
            break
        N.append(rhs(a, X, u, quasi)[0] - L * X)
    if quasi:
        X[charge] += _charge_offset(a, X, u)
        if a.power_monitor:
            X[i_w] += u @ X[charge]
    return X


def _to_quasi(a, x, u):
    """Return x in the quasi-static charge coordinates (see :func:`step`)."""
    x = x.copy()
    i_qp, i_w = _index(a)[1:]
    charge = slice(i_qp, i_qp + a.n_cells)
    if a.power_monitor:
        x[i_w] -= u @ x[charge]
    x[charge] -= _charge_offset(a, x, u)
    return x


def _from_quasi(a, X, u):
    i_qp, i_w = _index(a)[1:]
    charge = slice(i_qp, i_qp + a.n_cells)
    X = X.copy()
    X[charge] += _charge_offset(a, X, u)
    if a.power_monitor:
        X[i_w] += u @ X[charge]
    return X


def mechanical_jacobian(a, x, u) -> np.ndarray:
    """
    Return d(dq/dt, dqd/dt)/d(q, qd) at (x, u), by complex steps (exact to round-off).

    In the coordinates the exponential stages integrate (quasi-static charge on RC scenes):
    the dense linear part of a linearized method.
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    nd = 2 * a.n_q
    z = _to_quasi(a, x, u) if a.rc_source else x
    J = np.empty((nd, nd))
    step = 1e-30
    for j in range(nd):
        zc = z.astype(complex)
        zc[j] += 1j * step
        J[:, j] = rhs(a, zc, u, bool(a.rc_source))[0][:nd].imag / step
    return J


def step_linearized(a, method, x, u, h: float, A):
    """
    Return (x+, error vector) of one step of an exponential method with a dense linear part.

    As :func:`step` with x' = A x + L x + N(x): A (2 n_q x 2 n_q) on q, qd, the stiff diagonal L
    on the charge; the weights of q, qd are matrices weight * phi_k(c_arg h A) (from the
    augmented matrix exponential). The error vector over q, qd is the embedded estimate
    h b_{s-1}(hA) (N_{s-1} - N(x+)) / (6 b_{s-1}(0)) * 6 e_{s-1}, the kernel's.
    """
    from .matrix_phi import augmented_phis
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    s, nd, k_max = method.n_stages, 2 * a.n_q, max(t[2] for t in method.terms)
    A = np.asarray(A, dtype=float)
    L = stiff_rates(a, x)
    quasi = bool(a.rc_source)
    x = _to_quasi(a, x, u) if quasi else x.copy()
    phis = {c: augmented_phis(c * h * A, int(k_max)) for c in {t[3] for t in method.terms}}

    def remainder(X):
        f = rhs(a, X, u, quasi)[0] - L * X
        f[:nd] -= A @ X[:nd]
        return f

    def weights(term):
        _, _, k, c_arg, w = term
        diag = np.full(a.n_state, w) if k < 0 else w * np.array(
            [phi(int(k), c_arg * h * rate) for rate in L])
        block = w * np.eye(nd) if k < 0 else w * phis[c_arg][int(k)]
        return diag, block

    N = []
    for i in range(s + 1):
        ci = method.c[i] if i < s else 1.0
        X = np.exp(ci * h * L) * x
        X[:nd] = (phis[ci][0] if ci else np.eye(nd)) @ x[:nd]
        for term in method.terms:
            if term[0] == i:
                diag, block = weights(term)
                Nj = N[int(term[1])]
                X[nd:] += h * diag[nd:] * Nj[nd:]
                X[:nd] += h * block @ Nj[:nd]
        if i == s:
            break
        N.append(remainder(X))
    e = method.embedded
    last = [t for t in method.terms if t[0] == s and t[1] == s - 1]
    b_last = sum(weights(t)[1] for t in last)
    b0 = sum(t[4] * (1.0 if t[2] < 0 else 1.0 / np.prod(np.arange(1, t[2] + 1))) for t in last)
    error = h * e[s - 1] / b0 * b_last @ (N[s - 1][:nd] - remainder(X)[:nd])
    return (_from_quasi(a, X, u) if quasi else X), error
