"""
Statics of the DET-buckled-beam actuator (paper Section 4, Fig. 5): equilibria, their stability,
the critical pre-strain and the equilibrium branches versus pre-strain.

Everything is derived from the dynamic model (:func:`det_sim_ros.physics.model.build_model`), so there is
one source of truth for the physics. For a scene with an ideal voltage source, no creep and no
power monitor the state is x = [q, q_dot] and, at q_dot = 0, the model's energy output is

    H(q) = U_s(q) + U_DE,m(q) + 1/2 C(q) v_p^2,

so the voltage-controlled potential of eq 79 (the Legendre transform of the charge-controlled
energy, eq 78; the constant U_DE,pre of eq 78 is already part of U_DE,m) is

    U_pot(q, v_p) = H(q) - C(q) v_p^2 = U_s + U_DE,m - 1/2 C(q) v_p^2,

with the steady-state polymer voltage v_p = v R_p / (R_p + R_s) (eq 81; v_p = v for the 'ideal'
source). Equilibria are the roots of the generalized force -dU_pot/dq; for one Ritz coordinate the
model's acceleration at q_dot = 0 is that force divided by a positive mass, so its roots and sign
changes are used directly (no finite-difference error in the equilibrium positions). Stability is
the sign of d^2 U_pot/dq^2 (one coordinate) or of the smallest Hessian eigenvalue (several Ritz
coordinates, fidelity 'consistent'), by central differences of U_pot.

Deflections ``q`` are the model's reference deflection (output 'q': the paper's q, w at x = 2l/3
for 'simply_supported' and at x = l/2 for 'fixed'); for one Ritz coordinate this is the coordinate
itself. Units: m, V, J, N/m.
"""

from __future__ import annotations

import collections
import dataclasses
import math
from typing import Sequence

import numpy as np

from ..core import kernel
from .model import build_model, check, ModelDomainError
from ..scenes.scene import Scene, SceneError


def brentq(f, a, b, args=(), xtol=2e-12, rtol=8.9e-16, maxiter=100):
    """
    A root of f in [a, b] (f(a), f(b) of opposite signs) by Brent's method (Brent 1973,
    'Algorithms for minimization without derivatives', ch. 4): inverse quadratic or secant steps
    kept inside the bracket, bisection when they would not shrink it fast enough; stops when the
    bracket is below xtol + rtol |x|. The same algorithm and stopping rule as scipy.optimize's
    brentq (test_statics checks equal roots), written here so that a node's start does not
    import scipy.optimize (0.4-0.9 s).
    """
    x_pre, x_cur = float(a), float(b)
    f_pre, f_cur = f(x_pre, *args), f(x_cur, *args)
    if f_pre == 0.0:
        return x_pre
    if f_cur == 0.0:
        return x_cur
    if (f_pre > 0.0) == (f_cur > 0.0):
        raise ValueError('brentq: f(a) and f(b) must have opposite signs')
    x_blk = f_blk = s_pre = s_cur = 0.0
    for _ in range(maxiter):
        if f_pre != 0.0 and f_cur != 0.0 and (f_pre > 0.0) != (f_cur > 0.0):
            x_blk, f_blk = x_pre, f_pre          # the bracket's other end
            s_pre = s_cur = x_cur - x_pre
        if abs(f_blk) < abs(f_cur):              # keep the best point in x_cur
            x_pre, x_cur, x_blk = x_cur, x_blk, x_cur
            f_pre, f_cur, f_blk = f_cur, f_blk, f_cur
        delta = (xtol + rtol * abs(x_cur)) / 2.0
        s_bis = (x_blk - x_cur) / 2.0
        if f_cur == 0.0 or abs(s_bis) < delta:
            return x_cur
        if abs(s_pre) > delta and abs(f_cur) < abs(f_pre):
            if x_pre == x_blk:                   # secant
                s_try = -f_cur * (x_cur - x_pre) / (f_cur - f_pre)
            else:                                # inverse quadratic interpolation
                d_pre = (f_pre - f_cur) / (x_pre - x_cur)
                d_blk = (f_blk - f_cur) / (x_blk - x_cur)
                s_try = -f_cur * (f_blk * d_blk - f_pre * d_pre) / (
                    d_blk * d_pre * (f_blk - f_pre))
            if 2.0 * abs(s_try) < min(abs(s_pre), 3.0 * abs(s_bis) - delta):
                s_pre, s_cur = s_cur, s_try      # the interpolation step is good
            else:
                s_pre = s_cur = s_bis
        else:
            s_pre = s_cur = s_bis
        x_pre, f_pre = x_cur, f_cur
        x_cur += s_cur if abs(s_cur) > delta else (delta if s_bis > 0.0 else -delta)
        f_cur = f(x_cur, *args)
    raise RuntimeError(f'brentq: no convergence in {maxiter} iterations')

__all__ = ['Equilibrium', 'BranchPoint', 'potential', 'potential_coords', 'equilibria',
           'critical_prestrain', 'normalized_potential', 'rest_shortening', 'branches',
           'polymer_voltage', 'stiffness_at_straight', 'rest_coords', 'rest_state',
           'RestStateError', 'initial_state']

_LAMBDA_MIN = 0.05      # equilibria are searched where the DET stretch stays above this
_N_GRID = 400           # sign-change grid on each side of q = 0
_CACHE_SIZE = 256
_NEWTON_ITERS = 30


class RestStateError(SceneError):
    """The scene has no usable rest state (initial_state 'rest'); the message says why."""


@dataclasses.dataclass(frozen=True)
class Equilibrium:
    """One equilibrium of U_pot at a given pre-strain and voltage."""

    kind: str            # 'straight', 'buckled+' or 'buckled-' (a further pair: 'buckled+2', ...)
    q: float             # reference deflection, m
    coords: tuple        # Ritz coordinates (q,) for one term
    stable: bool         # d^2 U_pot/dq^2 > 0 (smallest Hessian eigenvalue > 0 for several terms)
    stiffness: float     # d^2 U_pot/dq^2 (smallest Hessian eigenvalue), N/m
    y: float             # end shortening, m
    delta_y: float       # y0 - y with y0 = rest_shortening(scene), m
    energy: float        # U_pot, J
    voltage: float       # applied voltage v, V
    eps_b: float         # pre-strain


@dataclasses.dataclass(frozen=True)
class BranchPoint:
    """One point of an equilibrium branch (one row of the branches table)."""

    eps_b: float
    voltage: float
    branch: str
    q: float
    y: float
    delta_y: float
    stable: bool
    stiffness: float


def polymer_voltage(scene: Scene, v: float) -> float:
    """Steady-state polymer voltage v_p (eq 81): v R_p/(R_p + R_s) for 'rc', v for 'ideal'."""
    if scene.source == 'ideal':
        return float(v)
    p = scene.physics
    return float(v) * p.Rp / (p.Rp + p.Rs)


class _Statics:
    """The statics of one scene's structure (cached per beam, pre-strain, fidelity, physics)."""

    def __init__(self, scene: Scene):
        self.scene = scene
        ideal = scene.replace(**{'scene.source': 'ideal', 'scene.creep': False,
                                 'scene.monitor_power': False})
        self.model = build_model(ideal)
        self.nq = self.model.n_states // 2
        names = self.model.output_names
        self._iq, self._iy, self._iC, self._iH = (names.index(k) for k in ('q', 'y', 'C', 'H'))
        self._out = np.empty(len(names))
        self._x = np.zeros(self.model.n_states)
        self._dx = np.empty(self.model.n_states)
        self._u1 = np.zeros(1)
        basis = self.model.bases[0]
        self.ref = basis.reference_row()
        xs = np.linspace(0.0, basis.length, 201)
        smax = np.max(np.abs(basis.values(xs)), axis=0)
        self.length = scene.beam_length
        self.h = 1e-5 * self.length / smax          # finite-difference step per coordinate
        self._rest = None
        self._eq = {}
        self._q_lim = None

    # -- model evaluations --------------------------------------------------------------------
    def _eval(self, coords, vp):
        self._x[:self.nq] = coords
        self._x[self.nq:] = 0.0
        self._out[:] = self.model.output_vector(self._x, vp)
        return self._out

    def energy(self, coords, vp) -> float:
        out = self._eval(coords, vp)
        return float(out[self._iH] - out[self._iC] * vp * vp)

    def acceleration(self, q: float, vp: float) -> float:
        """One coordinate: q_ddot at q_dot = 0 (the sign of the generalized force -dU/dq).
        Model.f's compiled rhs, called directly: the root scans call this ~800 times per
        distinct cell, and Model.f's argument checks were 90 % of an array's build time."""
        if not math.isfinite(q):
            check(kernel.NON_FINITE)
        self._x[0] = q
        self._x[1] = 0.0
        self._u1[0] = vp
        check(self.model.kernel.rhs(self._x, self._u1, self._dx)[0])
        return float(self._dx[1])

    def y_of(self, coords, vp=0.0) -> float:
        return float(self._eval(coords, vp)[self._iy])

    def q_ref(self, coords) -> float:
        return float(np.dot(self.ref, coords))

    def gradient(self, coords, vp) -> np.ndarray:
        g = np.empty(self.nq)
        for j in range(self.nq):
            e = np.zeros(self.nq)
            e[j] = self.h[j]
            g[j] = (self.energy(coords + e, vp) - self.energy(coords - e, vp)) / (2 * self.h[j])
        return g

    def hessian(self, coords, vp) -> np.ndarray:
        n = self.nq
        Hm = np.empty((n, n))
        u0 = self.energy(coords, vp)
        for i in range(n):
            ei = np.zeros(n)
            ei[i] = self.h[i]
            Hm[i, i] = (self.energy(coords + ei, vp) - 2 * u0
                        + self.energy(coords - ei, vp)) / self.h[i] ** 2
            for j in range(i + 1, n):
                ej = np.zeros(n)
                ej[j] = self.h[j]
                Hm[i, j] = Hm[j, i] = (self.energy(coords + ei + ej, vp)
                                       - self.energy(coords + ei - ej, vp)
                                       - self.energy(coords - ei + ej, vp)
                                       + self.energy(coords - ei - ej, vp)) / (
                    4 * self.h[i] * self.h[j])
        return Hm

    def stiffness(self, coords, vp) -> float:
        coords = np.atleast_1d(np.asarray(coords, dtype=float))
        if self.nq == 1:
            return float(self.hessian(coords, vp)[0, 0])
        return float(np.linalg.eigvalsh(self.hessian(coords, vp))[0])

    # -- search range ---------------------------------------------------------------------------
    def q_limit(self) -> float:
        """Deflection (along the first shape) where the DET stretch falls to _LAMBDA_MIN."""
        if self._q_lim is None:
            l0 = self.scene.physics.l0
            y_max = self.length - _LAMBDA_MIN * l0
            e = np.zeros(self.nq)

            def y_at(q):
                e[0] = q
                try:
                    return self.y_of(e)
                except ModelDomainError:
                    return math.inf
            hi = self.length
            while y_at(hi) < y_max:
                hi *= 2.0
            lo = 0.0
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if y_at(mid) < y_max else (lo, mid)
            self._q_lim = lo
        return self._q_lim

    # -- equilibria -----------------------------------------------------------------------------
    def buckled_roots_1d(self, vp, sign):
        """Roots of the force on one side of q = 0 (one coordinate)."""
        q_lim = self.q_limit()
        grid = sign * q_lim * np.linspace(1e-6, 1.0, _N_GRID) ** 1.0
        vals = np.array([self.acceleration(q, vp) * sign for q in grid])
        roots = []
        for k in range(len(grid) - 1):
            if vals[k] == 0.0:
                roots.append(grid[k])
            elif vals[k] * vals[k + 1] < 0.0:
                roots.append(brentq(self.acceleration, grid[k], grid[k + 1], args=(vp,),
                                    xtol=1e-15, rtol=1e-13, maxiter=200))
        return [np.array([r]) for r in roots]

    def safe_energy(self, coords, vp) -> float:
        try:
            return self.energy(coords, vp)
        except ModelDomainError:
            return math.inf

    def minimize(self, x, vp, N=None, iters=60):
        """
        Local minimum of U_pot from x by Newton's method with the Hessian made positive
        definite (eigenvalues floored at their magnitude) and a backtracking line search; with
        N, only x + N z is searched (a constrained minimum).
        """
        x = np.array(x, dtype=float)
        N = np.eye(self.nq) if N is None else N
        hz = np.min(self.h)
        u = self.safe_energy(x, vp)
        for _ in range(iters):
            g = N.T @ self.gradient(x, vp)
            w, V = np.linalg.eigh(N.T @ self.hessian(x, vp) @ N)
            floor = 1e-8 * max(np.max(np.abs(w)), 1e-300)
            step = -V @ ((V.T @ g) / np.maximum(np.abs(w), floor))
            t = 1.0
            while t > 1e-6:
                x_new = x + N @ (t * step)
                u_new = self.safe_energy(x_new, vp)
                if u_new <= u:
                    break
                t *= 0.5
            else:
                break
            x, u = x_new, u_new
            if np.max(np.abs(t * step)) < 1e-6 * hz:
                break
        return x

    def buckled_roots_nd(self, vp):
        """
        Several coordinates: the stable buckled state, minimized from the one-term solution of
        the same scene (q1*, 0, ..., 0), else from the softest mode at q = 0 with the largest
        reference deflection. Only minima are returned for several coordinates.
        """
        one = _statics(self.scene.replace(**{'scene.n_ritz': 1}))
        guesses = [np.r_[c[0], np.zeros(self.nq - 1)] for kind, c, k, *_ in
                   one.equilibria(vp, None) if kind == 'buckled+']
        if not guesses:
            w, V = np.linalg.eigh(self.hessian(np.zeros(self.nq), vp))
            neg = [V[:, i] for i in range(self.nq) if w[i] < 0.0]
            if not neg:
                return []
            mode = max(neg, key=lambda m: abs(self.q_ref(m)))
            mode = mode * np.sign(self.q_ref(mode) or 1.0)
            guesses = [0.05 * self.q_limit() * mode / np.max(np.abs(mode))]
        roots = []
        for guess in guesses:
            x = self.minimize(guess, vp)
            if self.q_ref(x) < 0:
                x = -x                                   # mirror state: same energy
            if self.q_ref(x) > 1e-9 * self.length and self.stiffness(x, vp) > 0.0:
                roots.append(x)
        return roots

    def equilibria(self, vp, v):
        key = float(vp)
        if key in self._eq:
            return self._eq[key]
        zero = np.zeros(self.nq)
        found = [('straight', zero)]
        if self.nq == 1:
            plus = self.buckled_roots_1d(vp, 1.0)
            minus = self.buckled_roots_1d(vp, -1.0)
        else:
            plus = self.buckled_roots_nd(vp)
            minus = [self.minimize(-r, vp) for r in plus]
        for k, r in enumerate(sorted(plus, key=self.q_ref)):
            found.append(('buckled+' + (str(k + 1) if k else ''), r))
        for k, r in enumerate(sorted(minus, key=lambda c: -self.q_ref(c))):
            found.append(('buckled-' + (str(k + 1) if k else ''), r))
        rows = []
        for kind, c in found:
            k = self.stiffness(c, vp)
            rows.append((kind, c, k, self.y_of(c, vp), self.energy(c, vp)))
        self._eq[key] = rows
        return rows

    def rest_shortening(self) -> float:
        if self._rest is None:
            rows = self.equilibria(0.0, 0.0)
            stable = [r for r in rows if r[2] > 0.0]
            if not stable or stable[0][0] == 'straight':
                self._rest = 0.0                         # the straight beam is stable
            else:
                self._rest = min(r[3] for r in stable)   # both mirror states: same y
        return self._rest


_cache: 'collections.OrderedDict[tuple, _Statics]' = collections.OrderedDict()


def _key(scene: Scene) -> tuple:
    return (scene.beam, float(scene.eps_b), scene.fidelity, scene.n_ritz, scene.physics)


def _statics(scene: Scene) -> _Statics:
    key = _key(scene)
    st = _cache.get(key)
    if st is None:
        st = _Statics(scene)
        _cache[key] = st
        if len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    else:
        _cache.move_to_end(key)
    return st


# -- public API -----------------------------------------------------------------------------------
def potential_coords(scene: Scene, coords, v: float) -> np.ndarray:
    """U_pot (J) at Ritz coordinate vector(s) ``coords`` (last axis n_q) and voltage v (V)."""
    st = _statics(scene)
    vp = polymer_voltage(scene, v)
    c = np.asarray(coords, dtype=float)
    if c.shape[-1:] != (st.nq,):
        c = c[..., None] if st.nq == 1 else c
    if c.shape[-1] != st.nq:
        raise ValueError(f'coords must have a last axis of length {st.nq}')
    flat = c.reshape(-1, st.nq)
    return np.array([st.energy(row, vp) for row in flat]).reshape(c.shape[:-1])


def potential(scene: Scene, q, v: float) -> np.ndarray:
    """
    The voltage-controlled potential U_pot(q, v_p) of eq 79 (J) at reference deflection(s) q (m).

    For one Ritz coordinate this is U_s + U_DE,m - 1/2 C v_p^2 at q. For several coordinates it
    is the reduced potential: U_pot minimized over the other coordinates at the given reference
    deflection (it equals U_pot at every equilibrium and has the same stability along the path).
    """
    st = _statics(scene)
    vp = polymer_voltage(scene, v)
    qa = np.asarray(q, dtype=float)
    if st.nq == 1:
        return np.array([st.energy(np.array([x]), vp) for x in qa.reshape(-1)]).reshape(qa.shape)
    return np.array([_reduced_energy(st, x, vp) for x in qa.reshape(-1)]).reshape(qa.shape)


def _reduced_energy(st: _Statics, q: float, vp: float) -> float:
    """min U over the coordinates with ref . coords = q (minimized in the constraint's null
    space, started from the one-term shape, the first coordinate)."""
    r = st.ref
    _, _, Vt = np.linalg.svd(r[None, :])
    N = Vt[1:].T                                     # null space of the constraint
    x0 = np.zeros(st.nq)
    x0[0] = q / r[0]
    return st.energy(st.minimize(x0, vp, N), vp)


def equilibria(scene: Scene, v: float = 0.0) -> list:
    """
    All equilibria at the scene's pre-strain and voltage v (V): the straight configuration
    q = 0 and the mirror-symmetric buckled pair(s) +-q*, each an :class:`Equilibrium`.
    """
    st = _statics(scene)
    vp = polymer_voltage(scene, v)
    y0 = st.rest_shortening()
    return [Equilibrium(kind, st.q_ref(c), tuple(float(x) for x in c), bool(k > 0.0), k, y,
                        y0 - y, u, float(v), float(scene.eps_b))
            for kind, c, k, y, u in st.equilibria(vp, v)]


def stiffness_at_straight(scene: Scene, v: float = 0.0) -> float:
    """d^2 U_pot/dq^2 at q = 0 (smallest Hessian eigenvalue for several coordinates), N/m."""
    st = _statics(scene)
    return st.stiffness(np.zeros(st.nq), polymer_voltage(scene, v))


def critical_prestrain(scene: Scene, v: float = 0.0, xtol: float = 1e-9) -> float:
    """
    eps_b,min(v): the pre-strain where the straight beam loses stability (d^2 U_pot/dq^2 at
    q = 0 crosses zero), by root bracketing in eps_b. NaN if no crossing in (-0.9, 2].
    """
    def k0(e):
        sc = scene.replace(**{'scene.eps_b': float(e)})
        st = _Statics(sc)                                   # not cached: brentq probes many
        p = sc.physics          # normalized by the beams' bending scale 2 EI / l^3
        return st.stiffness(np.zeros(st.nq), polymer_voltage(sc, v)) / (
            2.0 * p.E_b * p.I / st.length ** 3)

    grid = [0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.10, 0.125, 0.15, 0.2, 0.25, 0.3,
            0.4, 0.5, 0.6, 0.8, 1.0, 1.25, 1.5, 2.0]
    prev_e, prev_k = None, None
    if k0(0.0) <= 0.0:                 # already unstable without pre-strain: look below
        grid = [0.0, -0.05, -0.1, -0.2, -0.3, -0.5, -0.7, -0.9]
    for e in grid:
        k = k0(e)
        if prev_k is not None and (k > 0.0) != (prev_k > 0.0):
            return float(brentq(k0, prev_e, e, xtol=xtol))
        prev_e, prev_k = e, k
    return math.nan


def normalized_potential(scene: Scene, q, v: float = 0.0) -> np.ndarray:
    """Eq 82: (U_pot - U_min)/(U_max - U_min) over the given q range (m)."""
    u = potential(scene, q, v)
    lo, hi = np.min(u), np.max(u)
    return (u - lo) / (hi - lo) if hi > lo else np.zeros_like(u)


def rest_shortening(scene: Scene) -> float:
    """
    y0 (m): the end shortening of the stable buckled equilibrium at 0 V (0.0 if the straight
    beam is stable). Cached per scene structure and physics; fast after the first call.
    """
    return _statics(scene).rest_shortening()


def branches(scene: Scene, eps_grid: Sequence[float], v: float = 0.0, progress=None) -> list:
    """
    Equilibrium branches versus pre-strain (the Fig. 5 analogue) at voltage v (V).

    Returns a list of :class:`BranchPoint` rows (one per equilibrium and pre-strain); delta_y is
    relative to the rest shortening at 0 V at the same pre-strain. ``progress(k)`` is called
    after each pre-strain if given.
    """
    rows = []
    for k, e in enumerate(eps_grid):
        sc = scene.replace(**{'scene.eps_b': float(e)})
        for eq in equilibria(sc, v):
            rows.append(BranchPoint(float(e), float(v), eq.kind, eq.q, eq.y, eq.delta_y,
                                    eq.stable, eq.stiffness))
        if progress is not None:
            progress(k + 1)
    return rows


# -- the rest state as an initial state ---------------------------------------------------------
_rest_cache: 'collections.OrderedDict[tuple, np.ndarray]' = collections.OrderedDict()


def _static_residual(model, coords):
    """The accelerations at (coords, q_dot = 0, eps_E = 0, q_p = 0), 0 V: zero at rest."""
    nq = len(coords)
    x = np.zeros(model.n_states)
    x[:nq] = coords
    return model.f(0.0, x, np.zeros(model.n_inputs))[nq:2 * nq]


def _polish(model, coords, length):
    """
    Newton on the model's own static residual (Model.f at zero velocity, 0 V) from ``coords``
    (a statics solution), to round-off: the Jacobian by central differences, the iterate with
    the smallest residual kept. Equilibria of Model.f are exactly the stationary states of the
    dynamic model (q_dot = 0 and eps_E = 0, q_p = 0 are the other states' equilibria at 0 V).
    """
    x = np.array(coords, dtype=float)
    nq = len(x)
    r = _static_residual(model, x)
    best, best_norm = x.copy(), float(np.max(np.abs(r)))
    h = 1e-7 * length
    for _ in range(_NEWTON_ITERS):
        J = np.empty((nq, nq))
        for j in range(nq):
            e = np.zeros(nq)
            e[j] = h
            J[:, j] = (_static_residual(model, x + e) - _static_residual(model, x - e)) / (2 * h)
        step = np.linalg.solve(J, -r)
        x = x + step
        r = _static_residual(model, x)
        norm = float(np.max(np.abs(r)))
        if not math.isfinite(norm):
            break
        if norm < best_norm:
            best, best_norm = x.copy(), norm
        if np.max(np.abs(step)) <= 4.0 * np.finfo(float).eps * length:
            break
    return best


def rest_coords(scene: Scene, branch: str = 'buckled+') -> np.ndarray:
    """
    Ritz coordinates of a single-cell scene's stable equilibrium at 0 V on ``branch``
    ('buckled+': reference deflection q > 0, 'buckled-': q < 0; the straight beam q = 0 when it
    is the stable state), solved to round-off in the scene's own dynamic model (its fidelity and
    n_ritz). Cached per beam, pre-strain, fidelity, physics and model switches.

    :raises RestStateError: no stable state on that branch, or one outside the model's domain.
    """
    key = (_key(scene), scene.creep, scene.source, scene.monitor_power, branch)
    cached = _rest_cache.get(key)
    if cached is not None:
        _rest_cache.move_to_end(key)
        return cached.copy()
    st = _statics(scene)
    where = (f'{scene.beam} beam, eps_b = {scene.eps_b:g}, fidelity {scene.fidelity!r}, '
             f'n_ritz {scene.n_ritz}')
    try:
        rows = st.equilibria(0.0, 0.0)
    except ModelDomainError as exc:
        raise RestStateError(f'no rest state at 0 V ({where}): {exc}') from None
    stable = [r for r in rows if r[2] > 0.0]
    if any(kind == 'straight' for kind, *_ in stable):
        guess = np.zeros(st.nq)                  # below the critical pre-strain: straight
    else:
        match = [c for kind, c, *_ in stable if kind == branch]
        if not match:
            raise RestStateError(f'no stable {branch} equilibrium at 0 V ({where}); use '
                                 "scene.initial_state: released")
        guess = np.asarray(match[0], dtype=float)
    model = build_model(scene)
    try:
        coords = guess if not np.any(guess) else _polish(model, guess, scene.beam_length)
        x = np.zeros(model.n_states)
        x[:len(coords)] = coords
        model.output_vector(x, np.zeros(model.n_inputs))   # inside the domain?
        residual = np.max(np.abs(_static_residual(model, coords)))
    except ModelDomainError as exc:
        raise RestStateError(f'the {branch} rest state at 0 V ({where}) is outside the '
                             f'model\'s domain: {exc}') from None
    if not math.isfinite(residual):
        raise RestStateError(f'the {branch} rest state at 0 V ({where}) is not finite')
    _rest_cache[key] = coords.copy()
    if len(_rest_cache) > _CACHE_SIZE:
        _rest_cache.popitem(last=False)
    return coords


def rest_state(model) -> np.ndarray:
    """
    The state vector of ``model`` with every cell at its own rest state (:func:`rest_coords`
    of the cell alone, on ``scene.rest_branch``), q_dot = 0, eps_E = 0, q_p = 0 and the energy
    book at 0: stationary at 0 V. Cells with identical physics share one solve.
    """
    scene = model.scene
    template = scene.cell_scene(0)
    x = np.zeros(model.n_states)
    solved = {}
    offset = 0
    for physics, basis in zip(scene.cell_physics(), model.bases):
        if physics not in solved:
            solved[physics] = rest_coords(dataclasses.replace(template, physics=physics),
                                          scene.rest_branch)
        x[offset:offset + basis.n_ritz] = solved[physics]
        offset += basis.n_ritz
    return x


def initial_state(model) -> np.ndarray:
    """
    The scene's initial state (``scene.initial_state``): 'rest' = every cell at its stable
    buckled equilibrium at 0 V, stationary (:func:`rest_state`); 'released' =
    :meth:`~det_sim_ros.physics.model.Model.released_state`.
    """
    if model.scene.initial_state == 'rest':
        return rest_state(model)
    return model.released_state()
