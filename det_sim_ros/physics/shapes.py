"""
Ritz shape functions of the buckled beams and the integrals the energies need.

Each beam pair is described by w(x, t) = sum_j q_j(t) S_j(x) on 0 <= x <= l. The 'paper' fidelity
uses the paper's one-term shapes, S_s (eq 63, clamped at x = 0 and pinned at x = l although the
paper calls it 'simply supported') and S_f (eq 64, clamped at both ends). The 'consistent' fidelity
keeps the paper's shape as the first function and adds admissible polynomials for the same end
conditions, xi^(j+1) (1 - xi) and xi^(j+1) (1 - xi)^2, made orthogonal to the previous ones in the
bending-energy inner product so that the stiffness matrix stays well conditioned up to 12 terms.

Integrals are evaluated with Gauss-Legendre quadrature that is exact for every integrand the model
has (polynomials of degree <= 4 deg(S) - 4), so they equal the closed forms of eqs 72/73 to
round-off; nothing here is typed in from the paper.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from numpy.polynomial import polynomial as P

__all__ = ['RitzBasis', 'make_basis', 'ritz_coefficients', 'REFERENCE_POINT']

# Where the generalized coordinate q of the paper's one-term model is the deflection: the paper's
# S_s(2l/3) = 1 (eq 61) and S_f(l/2) = 1 (eq 62, read with w(l/2) = q, erratum 4).
REFERENCE_POINT = {'simply_supported': 2.0 / 3.0, 'fixed': 0.5}
_PAPER_SHAPE = {
    # coefficients in xi = x / l, lowest power first
    'simply_supported': np.array([0.0, 0.0, 27.0 / 4.0, -27.0 / 4.0]),
    'fixed': np.array([0.0, 0.0, 16.0, -32.0, 16.0]),
}
_END_FACTOR = {'simply_supported': np.array([1.0, -1.0]),            # (1 - xi)
               'fixed': np.array([1.0, -2.0, 1.0])}                  # (1 - xi)^2


@dataclasses.dataclass(frozen=True)
class RitzBasis:
    """Shape functions S_j(xi) (coefficient rows in xi = x/l) of one beam of length l."""

    beam: str
    length: float
    coefficients: tuple  # one numpy coefficient array per shape function

    @property
    def n_ritz(self) -> int:
        """Return the number of shape functions."""
        return len(self.coefficients)

    @property
    def degree(self) -> int:
        """Return the highest polynomial degree among the shape functions."""
        return max(len(c) - 1 for c in self.coefficients)

    def values(self, x, derivative: int = 0) -> np.ndarray:
        """
        Return the matrix [S_j^(derivative)(x_k)] with x in metres.

        Rows are points, columns are S_j.
        """
        xi = np.asarray(x, dtype=float) / self.length
        scale = self.length ** -derivative
        columns = [P.polyval(xi, P.polyder(c, derivative)) * scale if derivative else
                   P.polyval(xi, c) for c in self.coefficients]
        return np.stack(columns, axis=-1)

    def quadrature(self, nonpolynomial: bool = False):
        """
        Return Gauss-Legendre nodes x (m) and weights (m) for the energy integrands.

        They are exact for every polynomial energy integrand; with ``nonpolynomial`` (the
        'exact' fidelity: sqrt(1 - w'^2), 1/(1 - w'^2), singular at |w'| = 1) twice as many
        plus 8. The 'step' runs reach |w'| = 0.77-0.99 (fixed eps_b 0.15 to simply supported
        0.20), where the bending force is resolved to ~1e-5 only, but Delta-y over those runs
        moves by at most 1.4e-7 of the stroke against a rule with 24 or 40 more nodes
        (test/test_exact_quadrature.py), and by up to 5.8e-6 with two to six fewer: the count
        the integrands need at the tolerance 1e-6, not fewer.
        """
        n_nodes = 2 * self.degree - 1   # exact up to degree 4 deg - 3 >= 4 deg - 4
        if nonpolynomial:
            n_nodes = 2 * n_nodes + 8
        xi, w = _gauss_legendre(n_nodes)
        x = 0.5 * self.length * (xi + 1.0)
        return x, 0.5 * self.length * w

    def reference_row(self) -> np.ndarray:
        """Return S_j at the reference point: q_ref = row @ q is the published deflection."""
        return self.values(np.array([REFERENCE_POINT[self.beam] * self.length]))[0]


@functools.lru_cache(maxsize=None)
def _gauss_legendre(n_nodes: int):
    """
    Return numpy's Gauss-Legendre rule on [-1, 1], computed once per size.

    An array scene builds one model per distinct copy, and leggauss is not free
    (docs/development.md). Read-only: shared.
    """
    xi, w = np.polynomial.legendre.leggauss(n_nodes)
    xi.flags.writeable = False
    w.flags.writeable = False
    return xi, w


def make_basis(beam: str, length: float, fidelity: str = 'paper', n_ritz: int = 1) -> RitzBasis:
    """Build the Ritz basis of one beam of the pair (see module docstring)."""
    first = _PAPER_SHAPE[beam]
    coefficients = [first]
    for j in range(2, n_ritz + 1):
        # xi^(j+1) * end factor, then orthogonalized against the previous shapes in <S'', S''>
        raw = P.polymul(np.r_[np.zeros(j + 1), 1.0], _END_FACTOR[beam])
        coefficients.append(raw)
    if n_ritz > 1:
        coefficients = _orthogonalize(coefficients, length)
    del fidelity  # the basis is the same; fidelity changes the kinematics (see model.py)
    return RitzBasis(beam, float(length), tuple(coefficients))


def _orthogonalize(coefficients, length):
    """
    Orthogonalize by Gram-Schmidt in the bending inner product <f, g> = int f'' g'' dx.

    S_1 is kept unchanged.
    """
    basis = RitzBasis('fixed', length, tuple(coefficients))
    x, w = basis.quadrature()
    out = []
    for c in coefficients:
        c = np.array(c, dtype=float)
        for o in out:
            s2c = P.polyval(x / length, P.polyder(c, 2))
            s2o = P.polyval(x / length, P.polyder(o, 2))
            c = P.polysub(c, np.dot(w, s2c * s2o) / np.dot(w, s2o * s2o) * o)
        if out:  # scale to unit reference-free size: max |S| on a grid equals 1
            grid = np.linspace(0.0, 1.0, 201)
            c = c / np.max(np.abs(P.polyval(grid, c)))
        out.append(c)
    return out


def ritz_coefficients(basis: RitzBasis, rho: float, area: float, inertia: float,
                      modulus: float, viscosity: float) -> dict:
    """
    Return the paper's one-term integrals for the beam pair (eqs 70-73), from the shape function.

    Returns M = 2 int rho (I S'^2 + A S^2), c1 = 2 EI int S''^2, c2 = 1/2 int S'^2,
    c3 = 4 EI int (S'' S')^2, d = 2 eta I int S''^2, a = 4 c2^2, b = 2 c2, and c4 = 1/8 int S'^4
    (the end-shortening term eq 65 drops). Only defined for a one-term basis.
    """
    if basis.n_ritz != 1:
        raise ValueError('ritz_coefficients is the one-term (paper) summary; n_ritz must be 1')
    x, w = basis.quadrature()
    s0, s1, s2 = (basis.values(x, k)[:, 0] for k in range(3))
    c2 = 0.5 * np.dot(w, s1 ** 2)
    return {
        'M': 2.0 * rho * np.dot(w, inertia * s1 ** 2 + area * s0 ** 2),
        'c1': 2.0 * modulus * inertia * np.dot(w, s2 ** 2),
        'c2': c2,
        'c3': 4.0 * modulus * inertia * np.dot(w, (s2 * s1) ** 2),
        'c4': 0.125 * np.dot(w, s1 ** 4),
        'd': 2.0 * viscosity * inertia * np.dot(w, s2 ** 2),
        'a': 4.0 * c2 ** 2,
        'b': 2.0 * c2,
    }
