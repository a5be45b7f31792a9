"""
Compiled kernels: the right-hand side, outputs and the one stepping core.

Everything that runs per step lives here and is compiled once with numba (``cache=True``), so a
step costs well under a microsecond instead of the tens of microseconds of interpreted Python.
The physics is written once, in :func:`rhs`; ``model.py`` builds the arrays it reads and
documents the equations. With ``NUMBA_DISABLE_JIT=1`` the same code runs as plain Python.

The model arrays ``A`` (built by :func:`det_sim_ros.model.build_model`) are a tuple:

    flags  int64[6]   n_q, n_c (= n_p), creep, rc source, power monitor, n_state
    cell_q int64[n_c+1]  offsets of each cell's Ritz coordinates in q
    cell_g int64[n_c+1]  offsets of each cell's quadrature nodes
    B1, B2 (n_nodes, r_max)  S_j'(x_g), S_j''(x_g) of the cell owning node g
    W      (n_nodes,)  quadrature weights (m)
    Mb, K, D (n_q, r_max)  beam mass, linear bending stiffness, beam damping (both beams of a
                       cell), block diagonal by cell: row j holds its cell's block row, column
                       k is relative to the cell's first coordinate
    mi_val (n_nz,)     nonzero entries of the interface mass matrix MI (n_c x n_c) that acts on
                       the end shortenings y_c (a cell's interface mass, or a plate shared by
                       several cells) ...
    cellp  (n_c, 6)    l, EI, kappa (1: the consistent w'^4/8 end-shortening term, 2: exact
                       kinematics 1 - cos(theta), curvature^2 = w''^2/(1 - w'^2)), and for
                       one-term cells the same integrals in closed form: c2 = 1/2 int S'^2,
                       c4 = 1/8 int S'^4, e4 = EI int S''^2 S'^2 (quadrature skipped)
    detp   (n_c, 15)   l0, V*Y, C0, V, E_M, eta_M, eta_v, Rs, Rp of the DET spanning cell c,
                       then 1/l0, 1/C0, 1/Rs, 1/Rp, Rp/(Rs+Rp), E_M/eta_M (the rhs multiplies
                       instead of dividing: 81 -> 67 ns per rhs, measured)
    ref    (n_q,)      S_j at the reference point of its cell (published deflection)
    mi_idx int64[n_nz, 2]  ... at (row cell, column cell)
    grp_q  int64[n_g+1]    coordinate offsets of the groups of cells MI couples (contiguous);
                       the mass matrix is block diagonal by group, so N independent actuators
                       cost O(N), not O(N^3)
    cell_grp int64[n_c]    group of each cell
    P      (n_s, n_c)  structure outputs as linear maps of the end shortenings (plate_y, ...)
    (empty) float64[0] only for fidelity 'exact': marks the tuple type (see _kinematics)

Status codes returned by kernels: 0 ok, 1 stretch lambda <= 0 (l - y <= 0), 2 non-finite state,
3 beam slope |w'| >= 1 (only the 'exact' kinematics, where w' = sin(theta), have that limit).
"""

import math

import numpy as np
from numba import njit

OK, BAD_STRETCH, NON_FINITE, BAD_SLOPE = 0, 1, 2, 3
N_CELL_OUTPUTS = 9   # q_ref, qdot_ref, y, lambda, q_p, v_p, i_DE, C, eps_E
N_GLOBAL_OUTPUTS = 3  # H, P_in, P_diss (after the structure outputs)
N_ARRAYS_EXACT = 18   # len(A) of a scene with exact kinematics (see _kinematics)
_JIT = dict(cache=True, nogil=True, error_model='numpy')  # numpy: no zero-division branches
# Helpers called in the step loop are inlined at numba-IR level: a real call would incref and
# decref every array of the model tuple, which cost more than the physics (measured 4x).
_INLINE = dict(_JIT, inline='always')


@njit(**_INLINE)
def _kinematics(x, A, ws, Us4, exact):
    """
    End shortening y_c, its gradient J, qd' H_y qd per cell, and the bending energy beyond
    EI int w''^2 (Us4), from q = x[:n_q], qd = x[n_q:2 n_q]. Written into the scratch ``ws``
    at fixed offsets (y: 0, h: n_c, J: 2 n_c) rather than into slices: a slice is a new array
    whose reference count numba updates atomically, which cost ~20 % of the rhs (measured).
    ``exact`` is a compile-time constant: len(A), and a scene with exact
    kinematics carries one extra (empty) array in A, so numba compiles its own kernels for it
    and the paper/consistent kernels do not contain the exact branch at all. Compiling both
    branches into the common rhs made it 2x slower (measured), even when never taken.

    exact: sin(theta) = w', y = int 1 - cos(theta), bending beyond EI int w''^2 is
    EI int w''^2 w'^2 / (1 - w'^2) (curvature^2 = w''^2 / (1 - w'^2)); |w'| >= 1 gives NaN.
    """
    flags, cell_q, cell_g, B1, B2, W = A[0], A[1], A[2], A[3], A[4], A[5]
    cellp = A[10]
    nc = flags[1]
    nq = flags[0]
    for c in range(nc):
        o = cell_q[c]
        r = cell_q[c + 1] - o
        EI = cellp[c, 1]
        kap = cellp[c, 2]
        if r == 1 and not exact:  # one term: polynomials in q, ~5x cheaper than quadrature
            c2, c4 = cellp[c, 3], kap * cellp[c, 4]
            qc = x[o]
            q2 = qc * qc
            ws[c] = c2 * q2 + c4 * q2 * q2
            ws[2 * nc + o] = 2.0 * c2 * qc + 4.0 * c4 * q2 * qc
            ws[nc + c] = (2.0 * c2 + 12.0 * c4 * q2) * x[nq + o] * x[nq + o]
            if Us4 is not None:
                Us4[c] = cellp[c, 5] * q2 * q2
            continue
        yc = 0.0
        hc = 0.0
        u4 = 0.0
        for j in range(r):
            ws[2 * nc + o + j] = 0.0
        for g in range(cell_g[c], cell_g[c + 1]):
            wp = 0.0
            wd = 0.0
            for j in range(r):
                wp += B1[g, j] * x[o + j]
                wd += B1[g, j] * x[nq + o + j]
            wg = W[g]
            wp2 = wp * wp
            if exact:
                cos2 = 1.0 - wp2
                cos = math.sqrt(cos2)
                yc += wg * (1.0 - cos)
                hc += wg * wd * wd / (cos2 * cos)
                gy = wg * wp / cos
            else:
                yc += wg * (0.5 * wp2 + 0.125 * kap * wp2 * wp2)
                hc += wg * (1.0 + 1.5 * kap * wp2) * wd * wd
                gy = wg * (wp + 0.5 * kap * wp2 * wp)
            for j in range(r):
                ws[2 * nc + o + j] += gy * B1[g, j]
            if Us4 is not None:
                wpp = 0.0
                for j in range(r):
                    wpp += B2[g, j] * x[o + j]
                u4 += EI * wg * wpp * wpp * (wp2 / (1.0 - wp2) if exact else wp2)
        ws[c] = yc
        ws[nc + c] = hc
        if Us4 is not None:
            Us4[c] = u4

@njit(**_INLINE)
def _kinematics_any(x, A, ws, Us4):
    """:func:`_kinematics` with the scene's kinematics (known from the tuple's type)."""
    _kinematics(x, A, ws, Us4, len(A) == N_ARRAYS_EXACT)


@njit(**_INLINE)
def _quartic_force(x, A, ws, iF, exact):
    """
    Subtract from F the gradient of the bending energy beyond EI int w''^2 dx: EI int w''^2 g
    with g = w'^2 (eq 51) or, ``exact`` (a call-site constant), g = w'^2 / (1 - w'^2).
    """
    flags, cell_q, cell_g, B1, B2, W = A[0], A[1], A[2], A[3], A[4], A[5]
    cellp = A[10]
    for c in range(flags[1]):
        o = cell_q[c]
        r = cell_q[c + 1] - o
        if r == 1 and not exact:
            ws[iF + o] -= 4.0 * cellp[c, 5] * x[o] ** 3
            continue
        EI2 = 2.0 * cellp[c, 1]
        for g in range(cell_g[c], cell_g[c + 1]):
            wp = 0.0
            wpp = 0.0
            for j in range(r):
                wp += B1[g, j] * x[o + j]
                wpp += B2[g, j] * x[o + j]
            if exact:
                cos2 = 1.0 - wp * wp
                s1 = EI2 * W[g] * wpp * wpp * wp / (cos2 * cos2)
                s2 = EI2 * W[g] * wpp * wp * wp / cos2
            else:
                s1 = EI2 * W[g] * wpp * wpp * wp
                s2 = EI2 * W[g] * wpp * wp * wp
            for j in range(r):
                ws[iF + o + j] -= s1 * B1[g, j] + s2 * B2[g, j]

@njit(**_INLINE)
def _solve_spd(Mt, F, out):
    """Solve Mt out = F for a small symmetric positive definite Mt (Cholesky, in place)."""
    n = F.shape[0]
    if n == 1:
        out[0] = F[0] / Mt[0, 0]
        return
    for j in range(n):
        s = Mt[j, j]
        for k in range(j):
            s -= Mt[j, k] * Mt[j, k]
        d = math.sqrt(s)
        Mt[j, j] = d
        for i in range(j + 1, n):
            s = Mt[i, j]
            for k in range(j):
                s -= Mt[i, k] * Mt[j, k]
            Mt[i, j] = s / d
    for i in range(n):
        s = F[i]
        for k in range(i):
            s -= Mt[i, k] * out[k]
        out[i] = s / Mt[i, i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s -= Mt[k, i] * out[k]
        out[i] = s / Mt[i, i]


@njit(**_JIT)
def mass_block_size(A):
    """Columns of the mass-matrix scratch: the largest group's coordinate count."""
    grp_q = A[14]
    size = 1
    for g in range(grp_q.shape[0] - 1):
        size = max(size, grp_q[g + 1] - grp_q[g])
    return size


@njit(**_JIT)
def workspace_size(A):
    """Scratch floats :func:`rhs` needs: y, h (n_c each), J, F (n_q each)."""
    nq, nc = A[0][0], A[0][1]
    return 2 * nc + 2 * nq


@njit(**_INLINE)
def rhs(x, u, A, dx, pw, ws, Mt, quasi_static=False):
    """
    dx = f(x, u) for the DET-beam system; returns a status code (see module docstring).

    State layout: q (n_q), qdot (n_q), eps_E (n_p, if creep), q_p (n_p, if rc source), then the
    supplied and dissipated energy (2, if the power monitor is on). ``pw`` receives the
    supplied and dissipated power (W) whether or not the monitor integrates them. ``ws`` is a
    scratch buffer of :func:`workspace_size` floats and ``Mt`` an (n_q, mass_block_size) one for
    the mass matrix (allocated once by the caller: allocations and reshapes cost more than the physics).

    With ``quasi_static`` the charge slots hold z = q_p - C(q) v_inf (v_inf = v Rp/(Rs+Rp), the
    charge the circuit relaxes to for frozen q) and receive dz/dt; see :func:`advance`.
    """
    return _rhs_impl(x, u, A, dx, pw, ws, Mt, quasi_static, len(A) == N_ARRAYS_EXACT)


@njit(**_INLINE)
def _rhs_impl(x, u, A, dx, pw, ws, Mt, quasi_static, exact):
    """The body of :func:`rhs`; ``exact`` is a constant at both call sites."""
    flags, cell_q = A[0], A[1]
    Mb, K, D, mi_val, cellp, detp = A[6], A[7], A[8], A[9], A[10], A[11]
    mi_idx, grp_q, cell_grp = A[13], A[14], A[15]
    nq, nc, creep, rcsrc, power = flags[0], flags[1], flags[2], flags[3], flags[4]
    ie = 2 * nq
    ip = ie + nc * creep
    iw = ip + nc * rcsrc
    # (finiteness is checked once per step by the callers, not per stage: measured 30 % of rhs)
    iy, ih, iJ, iF = 0, nc, 2 * nc, 2 * nc + nq
    _kinematics(x, A, ws, None, exact)
    p_diss = 0.0
    for c in range(nc):   # cell blocks of K, D and Mb
        o = cell_q[c]
        r = cell_q[c + 1] - o
        col = o - grp_q[cell_grp[c]]     # column of the cell's first coordinate in Mt
        size = grp_q[cell_grp[c] + 1] - grp_q[cell_grp[c]]
        for i in range(o, o + r):
            s = 0.0
            dq = 0.0
            for k in range(r):
                s += K[i, k] * x[o + k]
                dq += D[i, k] * x[nq + o + k]
            ws[iF + i] = -s - dq
            p_diss += x[nq + i] * dq
        for i in range(o, o + r):
            for k in range(size):
                Mt[i, k] = 0.0
            for k in range(r):
                Mt[i, col + k] = Mb[i, k]
    _quartic_force(x, A, ws, iF, exact)
    # Interface mass on the end shortenings: T_I = 1/2 ydot' MI ydot with ydot_c = J_c . qdot.
    for e in range(mi_val.shape[0]):
        c = mi_idx[e, 0]
        c2 = mi_idx[e, 1]
        mi = mi_val[e]
        go = grp_q[cell_grp[c]]
        for j in range(cell_q[c], cell_q[c + 1]):
            ws[iF + j] -= mi * ws[iJ + j] * ws[ih + c2]
            for k in range(cell_q[c2], cell_q[c2 + 1]):
                Mt[j, k - go] += mi * ws[iJ + j] * ws[iJ + k]
    p_in = 0.0
    status = OK
    for i in range(nc):
        VY, C0, V = detp[i, 1], detp[i, 2], detp[i, 3]
        EM, etav = detp[i, 4], detp[i, 6]
        inv_l0, inv_C0, inv_Rs, inv_Rp = detp[i, 9], detp[i, 10], detp[i, 11], detp[i, 12]
        share, relax_M = detp[i, 13], detp[i, 14]   # Rp / (Rs + Rp), E_M / eta_M
        lam = (cellp[i, 0] - ws[iy + i]) * inv_l0
        if not lam > 0.0:   # NaN: exact kinematics past |w'| = 1 (states are finite here)
            status = BAD_STRETCH if lam == lam else BAD_SLOPE
            break
        inv_lam = 1.0 / lam
        inv_lam2 = inv_lam * inv_lam
        # dU_DE/dlambda without the sign of dlambda/dq = -J/l0 (eq 53, corrected eq 71)
        if rcsrc:
            qp = x[ip + i]
            if quasi_static:
                qp += C0 * lam * lam * u[i] * share
            vp = qp * inv_C0 * inv_lam2
            bracket = VY / 3.0 * (lam - inv_lam2 * inv_lam) - qp * vp * inv_lam
        else:
            vp = u[i]
            bracket = VY / 3.0 * (lam - inv_lam2 * inv_lam) - C0 * lam * vp * vp
        jqd = 0.0
        for j in range(cell_q[i], cell_q[i + 1]):
            jqd += ws[iJ + j] * x[nq + j]
        lzd = jqd * inv_l0 * inv_lam2          # d(lambda_z)/dt, lambda_z = 1/lambda
        eps = x[ie + i] if creep else 0.0
        visc = V * (EM * eps + etav * lzd)  # Maxwell spring + Kelvin-Voigt stress (eq 67)
        coef = (bracket - visc * inv_lam2) * inv_l0
        for j in range(cell_q[i], cell_q[i + 1]):
            ws[iF + j] += coef * ws[iJ + j]
        if creep:
            dx[ie + i] = lzd - relax_M * eps
        if rcsrc:
            i_de = (u[i] - vp) * inv_Rs
            dx[ip + i] = u[i] * inv_Rs - (inv_Rs + inv_Rp) * vp
            if quasi_static:  # minus d(C v_inf)/dt, dC/dt = 2 C0 lam dlam/dt
                dx[ip + i] += 2.0 * C0 * lam * jqd * inv_l0 * u[i] * share
            p_diss += (u[i] - vp) * i_de
        else:
            # q_p = C0 lam^2 v: i = dq_p/dt + v/Rp with dlambda/dt = -J.qdot / l0
            i_de = -2.0 * C0 * lam * jqd * inv_l0 * vp + vp * inv_Rp
        p_in += u[i] * i_de
        p_diss += vp * vp * inv_Rp + V * etav * lzd * lzd
        if creep:
            p_diss += V * EM * relax_M * eps * eps
    if nq == 1:
        dx[1] = ws[iF] / Mt[0, 0]
    else:
        qdd = dx[nq:2 * nq]
        F = ws[iF:iF + nq]
        for g in range(grp_q.shape[0] - 1):
            a, b = grp_q[g], grp_q[g + 1]
            _solve_spd(Mt[a:b, :b - a], F[a:b], qdd[a:b])
    for i in range(nq):
        dx[i] = x[nq + i]
    pw[0] = p_in
    pw[1] = p_diss
    if power:
        dx[iw] = p_in
        dx[iw + 1] = p_diss
    return status


@njit(**_INLINE)
def stiff_rates(x, A, L, ws, enabled=True):
    """
    Diagonal linear part for exponential steppers: dq_p/dt = -q_p/(C Rs || Rp) + ... ; all
    zero unless ``enabled`` (an exponential method on an RC scene). Returns a status code.

    ``ws``: scratch of :func:`workspace_size` floats (no allocation: this runs every step).
    No early return and no call under a branch: either made numba keep the reference counts
    of the model arrays it reads, 23 -> 105 ns per call (measured).
    """
    flags, detp, cellp = A[0], A[11], A[10]
    nq, nc, creep, rcsrc = flags[0], flags[1], flags[2], flags[3]
    for k in range(L.shape[0]):
        L[k] = 0.0
    status = OK
    _kinematics_any(x, A, ws, None)
    ip = 2 * nq + nc * creep
    for i in range(nc * rcsrc * enabled):
        lam = (cellp[i, 0] - ws[i]) / detp[i, 0]
        if not lam > 0.0:   # NaN: exact kinematics past |w'| = 1 (states are finite here)
            status = BAD_STRETCH if lam == lam else BAD_SLOPE
            break
        L[ip + i] = -(detp[i, 11] + detp[i, 12]) * detp[i, 10] / (lam * lam)
    return status


@njit(**_JIT)
def outputs(x, u, A, out):
    """
    Fill ``out`` with the named outputs (see model.OUTPUT_NAMES); returns a status code.

    Per cell: q_ref, qdot_ref, y, lambda, q_p, v_p, i_DE, C, eps_E; then the structure outputs
    (rows of P applied to y), H, P_in, P_diss.
    """
    nq, nc, nx = A[0][0], A[0][1], A[0][5]
    return _outputs(x, u, A, out, np.empty(nx), np.empty(2), np.empty(workspace_size(A)),
                    np.empty((nq, mass_block_size(A))), np.empty(nc), np.empty(nc))


@njit(**_JIT)
def _outputs(x, u, A, out, dx, pw, ws, Mt, Us4, ydot):
    """:func:`outputs` with caller-owned scratch (the per-period path: no allocation). Compiled
    once and called, not inlined: three inlined copies (outputs, run, period_and_output) made a
    cold start compile 106 s instead of ~60 (measured), for 0.2 us per period."""
    flags, cell_q = A[0], A[1]
    Mb, K, mi_val, cellp, detp, ref, mi_idx = A[6], A[7], A[9], A[10], A[11], A[12], A[13]
    nq, nc, creep, rcsrc = flags[0], flags[1], flags[2], flags[3]
    status = OK
    for k in range(x.shape[0]):
        if not math.isfinite(x[k]):
            status = NON_FINITE
    rhs_status = rhs(x, u, A, dx, pw, ws, Mt)
    if status == OK:
        status = rhs_status
    _kinematics_any(x, A, ws, Us4)   # the rhs's kinematics again, now with Us4, in ws
    energy = 0.0
    for c in range(nc):
        ydot[c] = 0.0
    for c in range(nc):
        o = cell_q[c]
        for i in range(o, cell_q[c + 1]):
            for k in range(cell_q[c + 1] - o):
                energy += (0.5 * x[nq + i] * Mb[i, k] * x[nq + o + k]
                           + 0.5 * x[i] * K[i, k] * x[o + k])
        energy += Us4[c]
        for j in range(cell_q[c], cell_q[c + 1]):
            ydot[c] += ws[2 * nc + j] * x[nq + j]
    for e in range(mi_val.shape[0]):
        energy += 0.5 * mi_val[e] * ydot[mi_idx[e, 0]] * ydot[mi_idx[e, 1]]
    ie = 2 * nq
    ip = ie + nc * creep
    for c in range(nc):
        l0, VY, C0, V, EM, Rs, Rp = (detp[c, 0], detp[c, 1], detp[c, 2], detp[c, 3],
                                     detp[c, 4], detp[c, 7], detp[c, 8])
        lam = (cellp[c, 0] - ws[c]) / l0
        lam2 = lam * lam
        cap = C0 * lam2
        if rcsrc:
            qp = x[ip + c]
            vp = qp / cap
            i_de = (u[c] - vp) / Rs
        else:
            vp = u[c]
            qp = cap * vp
            i_de = 2.0 * C0 * lam * (-ydot[c] / l0) * vp + vp / Rp
        eps = x[ie + c] if creep else 0.0
        energy += VY / 6.0 * (lam2 + 1.0 / lam2 - 2.0) + 0.5 * qp * qp / cap
        energy += 0.5 * V * EM * eps * eps
        qr = 0.0
        qdr = 0.0
        for j in range(cell_q[c], cell_q[c + 1]):
            qr += ref[j] * x[j]
            qdr += ref[j] * x[nq + j]
        k = c * N_CELL_OUTPUTS
        out[k] = qr
        out[k + 1] = qdr
        out[k + 2] = ws[c]
        out[k + 3] = lam
        out[k + 4] = qp
        out[k + 5] = vp
        out[k + 6] = i_de
        out[k + 7] = cap
        out[k + 8] = eps
    k = nc * N_CELL_OUTPUTS
    P = A[16]
    for r in range(P.shape[0]):
        value = 0.0
        for c in range(nc):
            value += P[r, c] * ws[c]
        out[k] = value
        k += 1
    out[k] = energy
    out[k + 1] = pw[0]
    out[k + 2] = pw[1]
    for k in range(out.shape[0]):
        if not math.isfinite(out[k]) and status == OK:
            status = NON_FINITE
    return status


@njit(**_JIT)
def _stretches(x, A):
    """DET stretches lambda_c = (l_c - y_c(q)) / l0_c at the state x, allocated: only for the
    rare input jumps (the per-stage rhs computes its own from the kinematics it needs)."""
    flags, detp, cellp = A[0], A[11], A[10]
    nq, nc = flags[0], flags[1]
    kin = np.empty(workspace_size(A))
    _kinematics_any(x, A, kin, None)
    lam = np.empty(nc)
    for i in range(nc):
        lam[i] = (cellp[i, 0] - kin[i]) / detp[i, 0]
    return lam


@njit(**_INLINE)
def _shift_charge(x, u, A, sign, ws):
    """q_p += sign * C(q) v_inf: to and from the quasi-static charge coordinates z. ``ws``: the
    rhs scratch (the kinematics land there; no allocation)."""
    flags, detp, cellp = A[0], A[11], A[10]
    nq, nc, creep = flags[0], flags[1], flags[2]
    _kinematics_any(x, A, ws, None)
    ip = 2 * nq + nc * creep
    for i in range(nc):
        lam = (cellp[i, 0] - ws[i]) / detp[i, 0]
        x[ip + i] += sign * detp[i, 2] * lam * lam * u[i] * detp[i, 13]


@njit(**_INLINE)
def phi(k, z):
    """phi_k(z) = sum_m z^m / (m + k)!, the exponential integrators' functions (phi_0 = e^z)."""
    if k == 0:
        return math.exp(z)
    if abs(z) < 0.5:
        # Taylor series: 18 terms reach round-off for |z| < 0.5 and k >= 1
        term = 1.0
        for m in range(1, k + 1):
            term /= m
        s = term
        for m in range(1, 18):
            term *= z / (m + k)
            s += term
        return s
    value = math.exp(z)
    fact = 1.0
    for m in range(k):
        if m > 0:
            fact *= m
        value = (value - 1.0 / fact) / z
    return value


@njit(**_INLINE)
def _phi_all(z, out):
    """out[k] = phi_k(z) for k = 0..len(out)-1, one exp per call."""
    n = out.shape[0]
    if abs(z) < 0.5:
        for k in range(n):
            out[k] = phi(k, z)
        return
    out[0] = math.exp(z)
    fact = 1.0
    for k in range(1, n):
        out[k] = (out[k - 1] - 1.0 / fact) / z
        fact *= k


@njit(**_JIT)
def advance(x, u, A, c, terms, h, n_steps):
    """Advance x in place by n_steps fixed steps of size h (see :func:`advance_core`)."""
    return advance_core(x, u, A, h, n_steps, 1.0,
                        prepare(A, c, terms, np.zeros(0), np.zeros(x.shape[0])))


@njit(**_JIT)
def prepare(A, c, terms, embedded, inv_scale):
    """
    Decode a method table and allocate the stepping scratch once (per Simulator, per
    :func:`advance` call): a tuple read by :func:`advance_core` and :func:`period_core`.

    ``embedded``: weights e_0..e_s of the error estimate h sum_j e_j N_j (e_s multiplies
    f(x_new), the first stage of the next step), empty for a method without one;
    ``inv_scale``: 1 / scale of each state in the error norm (0: not in the norm).
    """
    nx = A[0][5]
    s = c.shape[0]
    nt = terms.shape[0]
    tj = np.empty(nt, dtype=np.int64)   # stage whose N the term multiplies
    tk = np.empty(nt, dtype=np.int64)   # phi index (-1: constant weight)
    tw = np.empty(nt)
    # distinct phi arguments of the table, so each step needs one exp per argument and state
    arg_index = np.zeros(nt, dtype=np.int64)
    args_all = np.empty(nt + 1)
    n_args = 0
    k_max = 0
    for t in range(nt):
        tj[t] = int(terms[t, 1])
        tk[t] = int(terms[t, 2])
        tw[t] = terms[t, 4]
        found = -1
        for a in range(n_args):
            if args_all[a] == terms[t, 3]:
                found = a
        if found < 0:
            args_all[n_args] = terms[t, 3]
            found = n_args
            n_args += 1
        arg_index[t] = found
        k_max = max(k_max, tk[t])
    args = args_all[:n_args].copy()
    # terms are grouped by stage row (tables list them in order): row i uses t_start[i]..[i+1]
    t_start = np.zeros(s + 2, dtype=np.int64)
    for t in range(nt):
        t_start[int(terms[t, 0]) + 1] = t + 1
    for i in range(1, s + 2):
        t_start[i] = max(t_start[i], t_start[i - 1])
    # exp(c_i z) and exp(z) are phi_0 of a table argument when one is equal (-1: compute)
    ec_arg = np.full(s + 1, -1, dtype=np.int64)
    for i in range(s + 1):
        ci = c[i] if i < s else 1.0
        for a in range(n_args):
            if args[a] == ci:
                ec_arg[i] = a
    phis = np.empty((max(n_args, 1), k_max + 1))
    coef0 = np.empty(nt)   # L = 0 values: phi_k(0) = 1/k!
    for a in range(n_args):
        _phi_all(0.0, phis[a])
    exponential = False    # a table with any phi_k term is an exponential method
    for t in range(nt):
        coef0[t] = tw[t] * (1.0 if tk[t] < 0 else phis[arg_index[t], tk[t]])
        if tk[t] >= 0:
            exponential = True
    # The same table at L = 0, terms of equal (row, stage) merged and zeros dropped: what the
    # states without a stiff rate use (Krogstad's 16 terms are classical RK4's 7 there).
    w0 = np.zeros((s + 1, s))
    for t in range(nt):
        w0[int(terms[t, 0]), tj[t]] += coef0[t]
    m_start = np.zeros(s + 2, dtype=np.int64)
    m_j = np.empty(nt, dtype=np.int64)
    m_w = np.empty(nt)
    n_m = 0
    for i in range(s + 1):
        for j in range(s):
            if w0[i, j] != 0.0:
                m_j[n_m] = j
                m_w[n_m] = w0[i, j]
                n_m += 1
        m_start[i + 1] = n_m
    coef = np.empty((nt, nx))
    for t in range(nt):
        for m in range(nx):
            coef[t, m] = coef0[t]
    flags = A[0]
    nq, nc, creep, rcsrc = flags[0], flags[1], flags[2], flags[3]
    # states with a stiff rate (the charges of an RC scene under an exponential method) are
    # the contiguous slots [s0, s1); all others take the merged table
    s0 = 2 * nq + nc * creep
    s1 = s0 + (nc if exponential and rcsrc else 0)
    # the error estimate needs stage 0 at the step's start (c_0 = 0) for its FSAL term
    n_emb = embedded.shape[0] if (embedded.shape[0] == s + 1 and c[0] == 0.0) else 0
    ints = np.array([s0, s1, n_emb, int(exponential)], dtype=np.int64)
    ws = np.empty(workspace_size(A))
    Mt = np.empty((nq, mass_block_size(A)))
    # est[0]: largest error estimate of the steps since the caller reset it; est[1]: steps taken
    est = np.zeros(2)
    # N (stage rates), X (stage state, then the new state), L, pw, e_c (exp(c_i h L), row s:
    # exp(h L)), x_start, pend (partial error estimate), x0 (_fixed_period), x_keep (period_core)
    scratch = (np.empty((s, nx)), np.empty(nx), np.zeros(nx), np.empty(2), np.ones((s + 1, nx)),
               np.empty(nx), np.zeros(nx), np.empty(nx), np.empty(nx))
    out_scratch = (np.empty(nc), np.empty(nc))   # Us4 and ydot for _outputs
    # (index P_EST of this tuple is est)
    return (c, tj, tk, tw, arg_index, args, t_start, ec_arg, phis, coef, ws, Mt, scratch,
            m_start, m_j, m_w, ints, embedded[:n_emb].copy(), inv_scale.copy(), est,
            out_scratch)


@njit(**_JIT)
def advance_core(x, u, A, h, n_steps, growth, P):
    """
    Advance x in place by n_steps steps with the input u held (zero-order hold).

    One core for every method: an exponential Runge-Kutta scheme for x' = L x + N(x) with the
    diagonal L of :func:`stiff_rates` frozen per step,

        X_i = phi_0(c_i h L) x + h sum_j a_ij(hL) N(X_j),  x+ = phi_0(hL) x + h sum_i b_i(hL) N(X_i)

    where each a_ij, b_i is a sum of ``weight * phi_k(c_arg h L)`` (rows of ``terms``:
    stage i (n_stages for b), j, k, c_arg, weight; k = -1 is a constant weight). With L = 0
    (explicit methods, or no stiff state) it is the classical Runge-Kutta method of the table.
    Exponential methods integrate the charge in quasi-static coordinates z = q_p - C(q) v_inf:
    z is the small lag behind the charge the circuit relaxes to, so the part of the charge
    equation left to the explicit stages (the change of 1/(C Rs) along the step) acts on z
    instead of on the full charge, which makes the frozen-L splitting error tiny.
    Step k has size h * growth^k (growth = 1: fixed steps; > 1: the graded steps that follow a
    charge transient, see :func:`period_core`). ``P`` is :func:`prepare`'s tuple; with an
    embedded table the largest weighted error estimate of these steps is max'ed into P's
    ``est[0]`` (one extra rhs at the end for the last step's FSAL term). Returns a status
    code; on failure x holds the last good state.
    """
    c, tj, tk, tw, arg_index, args, t_start, ec_arg, phis, coef, ws, Mt, scratch = P[:13]
    m_start, m_j, m_w, ints, emb, inv_scale, est = P[13:20]
    N, X, L, pw, e_c, x_start, pend = scratch[:7]
    nx = x.shape[0]
    s = c.shape[0]
    n_args = args.shape[0]
    s0, s1, n_emb, exponential = ints[0], ints[1], ints[2], ints[3]
    nmech = 2 * A[0][0]
    qs = exponential == 1 and A[0][3] == 1
    for m in range(nx):
        if not math.isfinite(x[m]):
            return NON_FINITE
    x_start[:] = x
    if qs:
        _shift_charge(x, u, A, -1.0, ws)
    status = OK
    h_prev = 0.0
    # (the estimate is max'ed straight into est[0]: a loop-carried scalar maximum made numba
    # compile the whole step loop 60 % slower, measured)
    for _ in range(n_steps):
        status = stiff_rates(x, A, L, ws, exponential == 1)
        if status != OK:
            break
        for m in range(s0, s1):
            z = h * L[m]
            for a in range(n_args):
                _phi_all(args[a] * z, phis[a])
            for t in range(tj.shape[0]):
                if tk[t] >= 0:
                    coef[t, m] = tw[t] * phis[arg_index[t], tk[t]]
            for i in range(s + 1):
                a = ec_arg[i]
                ci = c[i] if i < s else 1.0
                e_c[i, m] = 1.0 if ci == 0.0 else (phis[a, 0] if a >= 0 else math.exp(ci * z))
        # rows 0..s-1 of the table build the stages, row s (the weights b) the new state in X
        for i in range(s + 1):
            for m in range(nx):
                X[m] = x[m]
            for t in range(m_start[i], m_start[i + 1]):
                j = m_j[t]
                w = h * m_w[t]
                for m in range(s0):
                    X[m] += w * N[j, m]
                for m in range(s1, nx):
                    X[m] += w * N[j, m]
            for m in range(s0, s1):
                X[m] = e_c[i, m] * x[m]
            for t in range(t_start[i], t_start[i + 1]):
                j = tj[t]
                for m in range(s0, s1):
                    X[m] += h * coef[t, m] * N[j, m]
            if i == s:
                break
            status = rhs(X, u, A, N[i], pw, ws, Mt, qs)
            if status != OK:
                break
            for m in range(s0, s1):
                N[i, m] -= L[m] * X[m]
            if i == 0 and h_prev > 0.0:   # FSAL: N_0 = f(x) completes the last step's estimate
                for m in range(nmech):
                    est[0] = max(est[0], abs(h_prev * (pend[m] + emb[s] * N[0, m])) * inv_scale[m])
        if status != OK:
            break
        for m in range(nx):
            if not math.isfinite(X[m]):
                status = NON_FINITE
        if status != OK:
            break
        for m in range(nx):
            x[m] = X[m]
        if n_emb > 0:
            for m in range(nmech):
                acc = 0.0
                for j in range(s):
                    acc += emb[j] * N[j, m]
                pend[m] = acc
            h_prev = h
        h *= growth
    if status == OK and h_prev > 0.0:   # the last step's FSAL term: one more rhs
        status = rhs(x, u, A, N[0], pw, ws, Mt, qs)
        for m in range(nmech):
            est[0] = max(est[0], abs(h_prev * (pend[m] + emb[s] * N[0, m])) * inv_scale[m])
    if status != OK:
        x[:] = x_start
        return status
    est[1] += n_steps
    if qs:
        _shift_charge(x, u, A, 1.0, ws)
    return OK


@njit(**_INLINE)
def _charge_transient(x, u_old, u_new, A, z_tol):
    """
    After an input jump, how long the charge transient stays above ``z_tol`` (C), and the
    shortest charge time constant (s): (T, tau_min); T = 0 when no transient matters.

    A jump du moves the charge the circuit relaxes to by dz = C du Rp/(Rs+Rp); the lag decays
    like dz exp(-t/tau) with tau = C (Rs || Rp). While the lag is large it changes the
    electrostatic force on the time scale tau, which the explicit mechanics stages cannot
    resolve with steps >> tau (measured: at 1 ms / 8 steps this alone made the 'step' error
    1.9e-3; with the transient resolved, 8.6e-6 = the ideal-source error of the same table).
    """
    detp = A[11]
    T = 0.0
    tau_min = np.inf
    jump = False
    for i in range(A[0][1]):
        jump = jump or u_new[i] != u_old[i]
    if not jump:   # the common case: no stretches needed (they cost an allocation)
        return T, tau_min
    stretch = _stretches(x, A)
    for i in range(A[0][1]):
        du = abs(u_new[i] - u_old[i])
        if du == 0.0:
            continue
        lam = stretch[i]
        Rs, Rp = detp[i, 7], detp[i, 8]
        cap = detp[i, 2] * lam * lam
        dz = cap * du * Rp / (Rs + Rp)
        if dz <= z_tol:
            continue
        tau = cap * Rs * Rp / (Rs + Rp)
        T = max(T, tau * math.log(dz / z_tol))
        tau_min = min(tau_min, tau)
    return T, tau_min


# period_core and _fixed_period are inlined into their callers: every real call of a function
# that unpacks the model and scratch tuples updates the reference counts of ~45 arrays (atomic
# operations): a real call of period_core cost 0.2-1 us per period (interleaved A/B).
@njit(**_INLINE)
def _fixed_period(x, u_old, u, A, h, n_sub, z_tol, fine, P):
    """
    One control period dt = n_sub h with the input u held, starting from an input u_old.

    With ``z_tol`` > 0 (exponential methods on an RC scene) a charge transient after an input
    jump is resolved first: graded steps from ``fine`` * tau (never coarser than h) until the
    lag has decayed below z_tol (see :func:`_charge_transient`), then steps of at most h to the
    end of the period. The period still ends exactly at dt; the split depends only on the
    state and the inputs, so runs stay deterministic. Returns a status code; on failure x
    holds the state at the period's start.
    """
    if z_tol > 0.0 and A[0][3] == 1:
        dt = h * n_sub
        T, tau = _charge_transient(x, u_old, u, A, z_tol)
        if T > 0.0:
            x0 = P[12][7]
            x0[:] = x
            T = min(T, dt)
            # The local error of a step is about lag(t) (h/tau)^5 and the lag decays like
            # exp(-t/tau), so the step may grow like exp(t / (5 tau)): geometric steps with
            # ratio exp(fine/5) from fine*tau (half the steps of uniform fine*tau steps).
            h0 = min(fine * tau, h)
            g = math.exp(h0 / (5.0 * tau))
            n_fine = int(math.ceil(math.log(1.0 + T * (g - 1.0) / h0) / math.log(g) - 1e-9))
            h0 = T * (g - 1.0) / (g ** n_fine - 1.0)
            if h0 * g ** (n_fine - 1) > h:   # never coarser than the regular step
                n_fine = int(math.ceil(T / h0 - 1e-9))
                h0 = T / n_fine
                g = 1.0
            status = advance_core(x, u, A, h0, n_fine, g, P)
            rest = dt - T
            if status == OK and rest > 1e-6 * dt:
                n_rest = int(math.ceil(rest / h - 1e-9))
                status = advance_core(x, u, A, rest / n_rest, n_rest, 1.0, P)
            if status != OK:
                x[:] = x0
            return status
    return advance_core(x, u, A, h, n_sub, 1.0, P)


P_EST = 19   # index of est (error estimate, steps taken) in prepare's tuple

# ctl, the step-count controller's state and settings (float64[5], see period_core)
CTL_N, CTL_TOL, CTL_N_MIN, CTL_N_MAX, CTL_EXPONENT = 0, 1, 2, 3, 4
CTL_SAFETY = 0.5   # aim the next period's estimate at half the local tolerance


@njit(**_INLINE)
def period_core(x, u_old, u, A, dt, z_tol, fine, P, ctl):
    """
    One control period dt with the input u held, in ``ctl[CTL_N]`` steps (plus the graded
    steps of a charge transient, see :func:`_fixed_period`).

    With a local tolerance ``ctl[CTL_TOL]`` > 0 the step count adapts from period to period
    (fixed steps inside each period): a period whose largest embedded error estimate exceeds
    the tolerance, or that left the domain, is repeated with more steps (up to CTL_N_MAX), and
    the next period starts from the count the estimate predicts (estimate ~ n^-CTL_EXPONENT),
    never below CTL_N_MIN nor below half the current count. Everything depends only on the
    state and the inputs, so runs stay deterministic. Returns a status code; on failure x
    holds the state at the period's start.
    """
    tol = ctl[CTL_TOL]
    if tol <= 0.0:
        n = int(ctl[CTL_N])
        return _fixed_period(x, u_old, u, A, dt / n, n, z_tol, fine, P)
    est = P[19]
    n_max = int(ctl[CTL_N_MAX])
    x_keep = P[12][8]
    x_keep[:] = x
    while True:
        n = int(ctl[CTL_N])
        est[0] = 0.0
        status = _fixed_period(x, u_old, u, A, dt / n, n, z_tol, fine, P)
        if n < n_max and (status != OK or est[0] > tol):
            grow = 4.0 if status != OK else 1.2 * (est[0] / tol) ** (1.0 / ctl[CTL_EXPONENT])
            ctl[CTL_N] = min(n_max, max(n + 1, int(math.ceil(n * grow))))
            x[:] = x_keep
            continue
        if status != OK:
            return status
        ratio = (est[0] / (CTL_SAFETY * tol)) ** (1.0 / ctl[CTL_EXPONENT])
        n_next = int(math.ceil(n * ratio - 1e-9))
        ctl[CTL_N] = min(n_max, max(ctl[CTL_N_MIN], (n + 1) // 2, n_next))
        return OK


@njit(**_JIT)
def book_input_jump(x, u_old, u_new, A):
    """
    Ideal source with the power monitor: book an instantaneous recharge (in place).

    A voltage step moves the charge C dv at once: the source supplies v_new C dv and the
    vanishing series resistance dissipates C dv^2 / 2 (the R -> 0 limit of the RC charging
    loss). Nothing to do for RC scenes or without the monitor.
    """
    flags, detp = A[0], A[11]
    if flags[3] or not flags[4]:   # RC source, or no monitor
        return
    jump = False
    for i in range(flags[1]):
        jump = jump or u_new[i] != u_old[i]
    if not jump:
        return
    stretch = _stretches(x, A)
    for i in range(flags[1]):
        cap = detp[i, 2] * stretch[i] * stretch[i]
        dv = u_new[i] - u_old[i]
        x[-2] += u_new[i] * cap * dv
        x[-1] += 0.5 * cap * dv * dv


@njit(**_INLINE)
def _period_outputs(x, u, A, out, P):
    """:func:`outputs` after a period, in the stepping scratch of ``P`` (stage buffers are free
    between periods)."""
    scratch = P[12]
    Us4, ydot = P[20]
    return _outputs(x, u, A, out, scratch[1], scratch[3], P[10], P[11], Us4, ydot)


@njit(**_JIT)
def run(x, u_held, u_last, U, A, dt, z_tol, fine, P, ctl, X, Y):
    """
    Many control periods in one call (offline runs): period k holds U[k]; X[k + 1] and Y[k + 1]
    receive the state and outputs after it. ``u_held`` is the input held now (already booked),
    ``u_last`` the one the last period ran with; ``P`` and ``ctl`` as for :func:`period_core`.
    Returns (status, periods completed); x is left at the last good state.
    """
    u_book = u_held.copy()
    u_prev = u_last.copy()
    for k in range(U.shape[0]):
        u = U[k]
        book_input_jump(x, u_book, u, A)
        u_book = u
        status = period_core(x, u_prev, u, A, dt, z_tol, fine, P, ctl)
        if status != OK:
            return status, k
        status = _period_outputs(x, u, A, Y[k + 1], P)
        if status != OK:
            return status, k
        X[k + 1] = x
        u_prev = u
    return OK, U.shape[0]


@njit(**_JIT)
def period_and_output(x, u_old, u, A, dt, z_tol, fine, P, ctl, out):
    """One control period in one call (:func:`period_core` with the scratch ``P`` of
    :func:`prepare`, kept by the caller between periods), then the outputs."""
    status = period_core(x, u_old, u, A, dt, z_tol, fine, P, ctl)
    if status != OK:
        return status
    return _period_outputs(x, u, A, out, P)
