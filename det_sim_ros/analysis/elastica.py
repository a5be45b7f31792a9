"""
Exact reference solutions for one buckled beam: the Euler critical load and the elastica.

The beams of the model are inextensible strips of length l, clamped at x = 0 and either pinned
('simply_supported': the paper's S_s of eq 63 satisfies w(0) = w'(0) = w(l) = 0, i.e. it is
clamped-pinned) or clamped ('fixed') at x = l, loaded by an end force along the chord. With s the
arc length, theta the slope angle, p = P l^2 / EI the compressive chord force and v = V l^2 / EI
the transverse end reaction (nonzero only for the clamped-pinned beam), the exact elastica is

    theta'' + p sin(theta) - v cos(theta) = 0,   x' = cos(theta),   w' = sin(theta)   (' = d/ds)

with theta(0) = x(0) = w(0) = 0, w(l) = 0, x(l) = l - y (prescribed end shortening y) and
theta'(l) = 0 (pin: no moment) or theta(l) = 0 (clamp). It is solved here as a two-point boundary
value problem by shooting from the clamp (DOP853 at rtol 1e-12, the unknowns theta'(0), p, v
found by scipy's hybrid Powell method to residuals < 1e-10, continued in y from the Euler mode),
and for
the clamped-clamped beam also in closed form by elliptic integrals (four quarter waves of the
Euler elastica: p = 16 K(k)^2, y/l = 2 (1 - E(k)/K(k)), w(l/2)/l = k/K(k)), which the tests use to
check the BVP solve.

Deflections are those of a material point: ``q_ref`` is w at arc length s = x_ref (x_ref = 2l/3 for
'simply_supported' and l/2 for 'fixed', :data:`det_sim_ros.physics.shapes.REFERENCE_POINT`), the
point whose deflection the simulator publishes as q; ``q_max`` is the largest |w|. The Ritz model
uses the same Lagrangian coordinate (its end shortening int (w'^2/2 + w'^4/8) dx is the expansion
of int (1 - cos theta) ds with w' = sin theta), so both are compared at the same material point.
Everything is dimensionless: load P l^2/EI, lengths / l. numpy and scipy only.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, root
from scipy.special import ellipe, ellipk

from ..physics.shapes import REFERENCE_POINT

__all__ = ['euler_load', 'euler_mode', 'ElasticaPath', 'elastica', 'elastica_fixed_closed_form',
           'initial_slope']

BEAMS = ('simply_supported', 'fixed')
_RTOL = 1e-12


def euler_load(beam: str) -> float:
    """
    Return the Euler critical load P_cr l^2 / EI of one beam.

    It is mu^2 with tan mu = mu (clamped-pinned, 20.1907...) or 4 pi^2 (clamped-clamped).
    """
    if beam == 'simply_supported':
        mu = brentq(lambda m: math.sin(m) - m * math.cos(m), 4.0, 4.6, xtol=1e-15, rtol=1e-15)
        return mu * mu
    if beam == 'fixed':
        return 4.0 * math.pi ** 2
    raise ValueError(f'unknown beam {beam!r}')


def euler_mode(beam: str):
    """
    Return the Euler buckling mode phi(s) (s = x/l) and its first three derivatives.

    They are callables returning arrays (unnormalized).
    """
    if beam == 'simply_supported':
        m = math.sqrt(euler_load(beam))
        # w = A sin + B cos + C s + D with w(0) = w'(0) = w(1) = w''(1) = 0
        return (lambda s: np.sin(m * s) - m * np.cos(m * s) - m * s + m,
                lambda s: m * np.cos(m * s) + m * m * np.sin(m * s) - m,
                lambda s: -m * m * np.sin(m * s) + m ** 3 * np.cos(m * s),
                lambda s: -m ** 3 * np.cos(m * s) - m ** 4 * np.sin(m * s))
    if beam == 'fixed':
        t = 2.0 * math.pi
        return (lambda s: 1.0 - np.cos(t * s), lambda s: t * np.sin(t * s),
                lambda s: t * t * np.cos(t * s), lambda s: -t ** 3 * np.sin(t * s))
    raise ValueError(f'unknown beam {beam!r}')


def initial_slope(beam: str) -> float:
    """
    Return d(P/P_cr)/d(y/l) at y = 0 on the exact elastica.

    This is Koiter's symmetric-bifurcation coefficient: with the energy 1/2 EI int theta'^2 ds and
    y = int (1 - cos theta) ds expanded to fourth order about the Euler mode phi (no second-order
    field by symmetry), P/P_cr = 1 + 8 (u4 - P_cr y4) / (P_cr g^2) y/l,
    u4 = 1/2 int phi''^2 phi'^2, y4 = 1/8 int phi'^4, g = int phi'^2. Equals 1/2 for the
    clamped-clamped beam.
    """
    _, d1, d2, _ = euler_mode(beam)
    s, w = np.polynomial.legendre.leggauss(200)
    s, w = 0.5 * (s + 1.0), 0.5 * w
    p = euler_load(beam)
    g = w @ d1(s) ** 2
    u4 = 0.5 * w @ (d2(s) ** 2 * d1(s) ** 2)
    y4 = 0.125 * w @ d1(s) ** 4
    return 8.0 * (u4 - p * y4) / (p * g * g)


@dataclasses.dataclass(frozen=True)
class ElasticaPath:
    """
    The elastica at the end shortenings ``y`` (y/l).

    Fields: ``load`` P l^2/EI, ``shear`` the transverse end reaction V l^2/EI, ``q_ref`` and
    ``q_max`` the reference-point and maximum deflection (w/l), and ``theta_max`` the largest
    slope angle (rad).
    """

    beam: str
    y: np.ndarray
    load: np.ndarray
    shear: np.ndarray
    q_ref: np.ndarray
    q_max: np.ndarray
    theta_max: np.ndarray


def _shoot(beam, u):
    """Integrate the elastica from the clamp with theta'(0), p, v = u; returns the solution."""
    k0, p, v = u

    def f(s, z):
        th = z[0]
        return [z[1], -p * math.sin(th) + v * math.cos(th), math.cos(th), math.sin(th)]
    return solve_ivp(f, (0.0, 1.0), [0.0, k0, 0.0, 0.0], method='DOP853', rtol=_RTOL,
                     atol=_RTOL * 1e-2, dense_output=True)


def _residual(beam, y, u):
    z = _shoot(beam, u).y[:, -1]
    end = z[1] if beam == 'simply_supported' else z[0]    # pin: theta' = 0, clamp: theta = 0
    a = math.sqrt(y)                    # residuals scaled to O(1) near the bifurcation
    return np.array([z[3] / a, end / a, (z[2] - (1.0 - y)) / y])


def _max_deflection(sol):
    s = np.linspace(0.0, 1.0, 2001)
    z = sol.sol(s)
    k = int(np.argmax(np.abs(z[3])))
    if 0 < k < len(s) - 1 and z[0][k - 1] * z[0][k + 1] < 0.0:
        s_k = brentq(lambda t: sol.sol(t)[0], s[k - 1], s[k + 1], xtol=1e-15)
        return abs(float(sol.sol(s_k)[3]))
    return abs(float(z[3][k]))


@functools.lru_cache(maxsize=16)
def _solve(beam: str, ys: tuple) -> ElasticaPath:
    p_cr = euler_load(beam)
    _, d1, d2, d3 = euler_mode(beam)
    s = np.linspace(0.0, 1.0, 2001)
    y_prev = min(1e-4, ys[0]) if ys else 1e-4
    a = math.sqrt(2.0 * y_prev / np.trapezoid(d1(s) ** 2, s))
    p0 = p_cr * (1.0 + initial_slope(beam) * y_prev)
    u = np.array([a * d2(0.0), p0, a * (d3(0.0) + p0 * d1(0.0))])
    hist = []                             # (y, u) of the solved points, for extrapolation
    rows = []
    # continuation grid: the requested points plus enough intermediate ones (doubling from
    # 1e-4, then steps <= 0.02) that every shooting solve starts close to its solution
    grid = [y_prev]
    for y in ys:
        while grid[-1] < y:
            grid.append(min(y, 2.0 * grid[-1], grid[-1] + 0.02))
    wanted = set(ys)
    for y in grid:
        guess = u.copy()
        if hist:                          # theta'(0), v ~ sqrt(y); p linear in y
            y1, u1 = hist[-1]
            guess[0], guess[2] = u1[0] * math.sqrt(y / y1), u1[2] * math.sqrt(y / y1)
            if len(hist) > 1:
                y0, u0 = hist[-2]
                guess[1] = u1[1] + (u1[1] - u0[1]) * (y - y1) / (y1 - y0)
            else:
                guess[1] = p_cr + (u1[1] - p_cr) * y / y1
        sol = root(lambda w: _residual(beam, y, w), guess, method='hybr', tol=1e-14)
        res = _residual(beam, y, sol.x)
        if np.max(np.abs(res)) > 1e-10:
            raise RuntimeError(f'elastica shooting failed at y/l = {y}: residual {res}')
        u = sol.x
        hist.append((y, u))
        if y not in wanted:
            continue
        ivp = _shoot(beam, u)
        w_ref = float(ivp.sol(REFERENCE_POINT[beam])[3])
        sign = -1.0 if w_ref < 0.0 else 1.0
        rows.append((y, u[1], sign * u[2], sign * w_ref, _max_deflection(ivp),
                     float(np.max(np.abs(ivp.sol(s)[0])))))
    rows = np.array(rows) if ys else np.zeros((0, 6))
    return ElasticaPath(beam, *(rows[:, k].copy() for k in range(6)))


def elastica(beam: str, y) -> ElasticaPath:
    """
    Return the exact elastica of one beam at end shortening(s) ``y`` = y/l.

    ``y`` is increasing, 0 < y < 0.5, on the first (Euler) branch. Solved by continuation from
    the Euler mode; cached.
    """
    if beam not in BEAMS:
        raise ValueError(f'unknown beam {beam!r}')
    ys = tuple(float(v) for v in np.atleast_1d(y))
    if any(b <= a for a, b in zip(ys, ys[1:])) or (ys and ys[0] <= 0.0):
        raise ValueError('y/l must be positive and strictly increasing')
    return _solve(beam, ys)


def elastica_fixed_closed_form(y) -> tuple:
    """
    Return the clamped-clamped elastica in closed form at y/l (arrays).

    The result is (P l^2/EI, w(l/2)/l, theta_max).

    Four quarter waves of the Euler elastica with modulus k = sin(theta_max/2):
    p = 16 K^2, y/l = 2 (1 - E/K), w(l/2)/l = k/K (scipy's ellipk/ellipe take m = k^2).
    """
    ys = np.atleast_1d(np.asarray(y, dtype=float))
    out = []
    for yv in ys:
        m = brentq(lambda mm: 2.0 * (1.0 - ellipe(mm) / ellipk(mm)) - yv, 1e-16, 0.99,
                   xtol=1e-16, rtol=1e-15)
        K = ellipk(m)
        out.append((16.0 * K * K, math.sqrt(m) / K, 2.0 * math.asin(math.sqrt(m))))
    out = np.array(out)
    return out[:, 0], out[:, 1], out[:, 2]
