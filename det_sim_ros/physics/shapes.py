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

A second family, ``buckling_modes``, takes the straight beam's own Euler buckling modes (the
eigenfunctions of EI w^(4) + P w" = 0 with the beam's end conditions) instead of polynomials:

- 'fixed' (clamped-clamped): the symmetric modes (1 - cos 2 pi k xi) / 2, k = 1..n_r. The
  beam is loaded only through its end shortening, which is even in every antisymmetric shape, so
  from a symmetric start (the released shape, the rest state) the antisymmetric coordinates of a
  complete basis stay zero: the polynomial family's n_r = 2m - 1 has m symmetric terms and the
  same solution as m symmetric terms alone. The clamped-clamped elastica is a whole period of an
  elliptic function, whose Fourier cosine series converges geometrically: three modes hold its
  rest shortening to 1e-6 where the polynomials' four symmetric terms (n_r 7) hold it to 5e-4.
- 'simply_supported' (clamped-pinned): the modes -1 + xi + cos(beta xi) - sin(beta xi) / beta,
  tan beta = beta. Its elastica is no whole period; on the 'switching' scenario this family
  converges no faster than the polynomials, which 'auto' keeps for this beam
  (det_sim_ros.scenes.levels, docs/fidelity.md).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from numpy.polynomial import polynomial as P

__all__ = ['RitzBasis', 'BucklingModeBasis', 'make_basis', 'ritz_coefficients', 'REFERENCE_POINT']

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
    family = 'polynomial'

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

    def released_coordinates(self, q0: float) -> np.ndarray:
        """
        Return the coordinates of the 'released' start: the paper's shape, q0 at the reference.

        S_1 is the paper's shape itself, so only the first coordinate is set.
        """
        coords = np.zeros(self.n_ritz)
        coords[0] = q0 / self.reference_row()[0]
        return coords


@dataclasses.dataclass(frozen=True)
class BucklingModeBasis:
    """
    The straight beam's Euler buckling modes as shape functions (see the module docstring).

    ``wavenumbers`` are the modes' beta in xi = x/l; each mode is scaled to max |S| = 1, the
    first with S > 0 at the reference point.
    """

    beam: str
    length: float
    wavenumbers: tuple
    scales: tuple
    family = 'buckling_modes'

    @property
    def n_ritz(self) -> int:
        """Return the number of shape functions."""
        return len(self.wavenumbers)

    def values(self, x, derivative: int = 0) -> np.ndarray:
        """Return the matrix [S_j^(derivative)(x_k)] with x in metres (rows points)."""
        xi = np.asarray(x, dtype=float)[..., None] / self.length
        b = np.asarray(self.wavenumbers)
        if self.beam == 'fixed':          # (1 - cos b xi) / 2, b = 2 pi k
            if derivative == 0:
                v = 0.5 * (1.0 - np.cos(b * xi))
            else:                         # d^m/dxi^m of -cos/2: -b^m cos(b xi + m pi/2) / 2
                v = -0.5 * b ** derivative * np.cos(b * xi + 0.5 * np.pi * derivative)
        else:                             # -1 + xi + cos(b xi) - sin(b xi) / b, tan b = b
            c, sn = np.cos(b * xi), np.sin(b * xi)
            v = {0: -1.0 + xi + c - sn / b, 1: 1.0 - b * sn - c,
                 2: -b * b * c + b * sn}[derivative]
        return v * np.asarray(self.scales) * self.length ** -derivative

    def quadrature(self, nonpolynomial: bool = False):
        """
        Return Gauss-Legendre nodes x (m) and weights (m) for the energy integrands.

        16 + 8 n_r nodes (the kernel takes at most 72): on the 'switching' scenario's fixed
        eps_b 0.20 run at n_r 3, 32 nodes move y by 1.3e-6 of the stroke against 24, and 48 or
        72 by less than 1e-10 against 40.
        """
        del nonpolynomial   # the modes are not polynomials: one rule for every fidelity
        xi, w = _gauss_legendre(min(72, 16 + 8 * self.n_ritz))
        return 0.5 * self.length * (xi + 1.0), 0.5 * self.length * w

    def reference_row(self) -> np.ndarray:
        """Return S_j at the reference point: q_ref = row @ q is the published deflection."""
        return self.values(np.array([REFERENCE_POINT[self.beam] * self.length]))[0]

    def released_coordinates(self, q0: float) -> np.ndarray:
        """
        Return the coordinates of the 'released' start: the paper's shape, q0 at the reference.

        The paper's shape is not in this family's span: its least-squares projection on the
        values and (scaled) curvatures on a fine grid, so that every family starts from the
        same beam.
        """
        paper = make_basis(self.beam, self.length)
        x = np.linspace(0.0, self.length, 801)
        scale = q0 / paper.reference_row()[0]
        weight = self.length ** 2 / 50.0          # curvature rows as heavy as the value rows
        lhs = np.vstack([self.values(x), weight * self.values(x, 2)])
        rhs = np.concatenate([paper.values(x)[:, 0], weight * paper.values(x, 2)[:, 0]]) * scale
        return np.linalg.lstsq(lhs, rhs, rcond=None)[0]


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


def make_basis(beam: str, length: float, fidelity: str = 'paper', n_ritz: int = 1,
               shapes: str = 'polynomial'):
    """Build the Ritz basis of one beam of the pair (see module docstring)."""
    if shapes == 'buckling_modes':
        return _buckling_modes(beam, float(length), n_ritz)
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


def _buckling_modes(beam: str, length: float, n_ritz: int) -> BucklingModeBasis:
    """Return the first n_ritz (for 'fixed': symmetric) buckling modes, scaled to max |S| = 1."""
    if beam == 'fixed':
        betas = tuple(2.0 * np.pi * k for k in range(1, n_ritz + 1))
    else:
        betas = tuple(_tan_root(k) for k in range(1, n_ritz + 1))
    unscaled = BucklingModeBasis(beam, length, betas, (1.0,) * n_ritz)
    grid = unscaled.values(np.linspace(0.0, length, 2001))
    scales = 1.0 / np.max(np.abs(grid), axis=0)
    scales[0] = np.copysign(scales[0], unscaled.reference_row()[0])
    return BucklingModeBasis(beam, length, betas, tuple(float(v) for v in scales))


def _tan_root(k: int) -> float:
    """Return the root of tan b = b in (k pi, (k + 1/2) pi), by bisection to round-off."""
    lo, hi = k * np.pi + 1e-9, (k + 0.5) * np.pi - 1e-9
    while hi - lo > 4.0 * np.finfo(float).eps * hi:
        mid = 0.5 * (lo + hi)
        if np.tan(mid) > mid:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


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
