"""
The numpy reference of the linearized exponential methods (``etdrk4_linearized``).

A dense linear part over the beams' Ritz coordinates and rates next to the stiff diagonal of
:func:`det_sim_ros.physics.reference.stiff_rates`; the kernel's ``linear_part.c`` and
``stages.c`` (``core/_csrc/stepping``) are held to these functions by test/test_linearized.py.
Without an amplifier: the kernel's amplified circuit under a linearized method is held to the plain
method at a tight tolerance instead.
"""

from __future__ import annotations

import numpy as np

from .matrix_phi import augmented_phis
from .reference import _charge_offset, _index, phi, rhs, stiff_rates

__all__ = ['mechanical_jacobian', 'step_linearized']


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
