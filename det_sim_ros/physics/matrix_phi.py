"""
The phi functions of a small dense matrix in numpy: the reference of the kernel's matrix_phi.c.

phi_k(Z) = sum_m Z^m / (m + k)!, k = 0..k_max (phi_0 = exp), by scaling and squaring: a diagonal
balancing D by powers of two (exact in binary), Y = D^-1 Z D / 2^s with a 1-norm of at most
1/2, a Taylor polynomial of phi_{k_max}(Y) by Horner, the downward recurrence
phi_{k-1} = Y phi_k + I / (k-1)!, then s doublings

    phi_k(2Y) = 2^-k (phi_0(Y) phi_k(Y) + sum_{j=1..k} phi_j(Y) / (k-j)!),

the one before the last giving phi_k(Z / 2) as well. The same operations as the C code; the
tests hold the two together, and both to the exponential of the augmented block matrix.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ['balance', 'matrix_phis', 'augmented_phis']

TAYLOR_DEGREE = 13   # |Y| <= 1/2: the first term left out is < 1e-15 of the sum
PHI_NORM = 0.5


def balance(Z: np.ndarray) -> np.ndarray:
    """Return powers of two d that give the rows and columns of D^-1 Z D similar 1-norms."""
    n = Z.shape[0]
    d = np.ones(n)
    absz = np.abs(Z)
    for _ in range(40):
        changed = False
        for i in range(n):
            off = np.arange(n) != i
            col = float(np.sum(absz[off, i] * d[i] / d[off]))
            row = float(np.sum(absz[i, off] * d[off] / d[i]))
            if col == 0.0 or row == 0.0:
                continue
            f, total = 1.0, col + row
            while col < 0.5 * row:
                col, row, f = col * 2.0, row * 0.5, f * 2.0
            while col >= 2.0 * row:
                col, row, f = col * 0.5, row * 2.0, f * 0.5
            if col + row < 0.95 * total:
                d[i] *= f
                changed = True
        if not changed:
            break
    return d


def _doubling_count(norm: float) -> int:
    s = 1   # at least one: phi_k(Z / 2) comes from the chain
    while s < 1000 and norm > PHI_NORM * 2.0 ** s:
        s += 1
    return s


def _taylor(Y: np.ndarray, k_max: int) -> list:
    n = Y.shape[0]
    eye = np.eye(n)
    top = eye / math.factorial(TAYLOR_DEGREE + k_max)
    for m in range(TAYLOR_DEGREE - 1, -1, -1):
        top = Y @ top + eye / math.factorial(m + k_max)
    P = [None] * (k_max + 1)
    P[k_max] = top
    for k in range(k_max, 0, -1):
        P[k - 1] = Y @ P[k] + eye / math.factorial(k - 1)
    return P


def _double(P: list) -> list:
    out = []
    for k in range(len(P)):
        acc = P[0] @ P[k]
        for j in range(k, 0, -1):
            acc = acc + P[j] / math.factorial(k - j)
        out.append(acc * 2.0 ** -k)
    return out


def matrix_phis(Z, scale: float, k_max: int):
    """Return (phi_k(scale Z) for k <= k_max, phi_k(scale Z / 2) for k <= k_max) as arrays."""
    Z = np.asarray(Z, dtype=float)
    d = balance(Z)
    B = scale * Z * d[None, :] / d[:, None]
    s = _doubling_count(float(np.abs(B).sum(axis=0).max()))
    P = _taylor(np.ldexp(B, -s), k_max)
    half = P
    for i in range(s):
        if i == s - 1:
            half = P
        P = _double(P)
    back = d[:, None] / d[None, :]
    return np.array([p * back for p in P]), np.array([p * back for p in half])


def augmented_phis(Z, k_max: int) -> np.ndarray:
    """
    Return phi_k(Z), k <= k_max, from the exponential of the augmented block matrix.

    exp([[Z, I, 0..], [0, 0, I..], ..]) holds phi_k(Z) in its first block row (Higham,
    Functions of Matrices, thm 10.34 form): an independent check (scipy's expm).
    """
    from scipy.linalg import expm   # tests and benchmarks only
    Z = np.asarray(Z, dtype=float)
    n = Z.shape[0]
    M = np.zeros(((k_max + 1) * n,) * 2)
    M[:n, :n] = Z
    for k in range(k_max):
        M[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] = np.eye(n)
    E = expm(M)
    return np.array([E[:n, k * n:(k + 1) * n] for k in range(k_max + 1)])
