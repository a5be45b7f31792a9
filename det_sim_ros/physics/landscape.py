"""
The potential landscape of one scene's structure.

U_pot and its derivatives from the model's energy output, the search range, the equilibria at a
polymer voltage and the rest shortening. :mod:`det_sim_ros.physics.statics` builds its public
functions on it; :func:`landscape` caches one per beam, pre-strain, fidelity and physics.
Units: m, V, J, N/m.
"""

from __future__ import annotations

import collections
import math

import numpy as np

from .brent import brentq
from .model import build_model, check, ModelDomainError
from ..core import kernel
from ..scenes.scene import Scene

__all__ = ['Landscape', 'landscape', 'cache_key', 'CACHE_SIZE']

_LAMBDA_MIN = 0.05      # equilibria are searched where the DET stretch stays above this
_N_GRID = 400           # sign-change grid on each side of q = 0
CACHE_SIZE = 256        # landscapes (and rest states) kept, least recently used dropped


class Landscape:
    """
    U_pot of one scene's structure and its equilibria.

    The model is built with an ideal source, no creep, no power monitor and no amplifier: at
    q_dot = 0 its energy output is H of the statics.
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        ideal = scene.replace(**{'scene.source': 'ideal', 'scene.creep': False,
                                 'scene.monitor_power': False, 'amplifier': None})
        self.model = build_model(ideal)
        self.nq = self.model.n_states // 2
        names = self.model.output_names
        self._iy, self._iC, self._iH = (names.index(k) for k in ('y', 'C', 'H'))
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
        """
        Return U_pot = H - C v_p^2 at ``coords`` and polymer voltage ``vp``, J.

        ``coords`` are Ritz coordinates.
        """
        out = self._eval(coords, vp)
        return float(out[self._iH] - out[self._iC] * vp * vp)

    def acceleration(self, q: float, vp: float) -> float:
        """
        Return q_ddot at q_dot = 0 for one coordinate.

        Its sign is that of the generalized force -dU/dq. Model.f's compiled rhs, called
        directly: the root scans call this ~800 times per distinct cell, and Model.f's argument
        checks were 90 % of an array's build time.
        """
        if not math.isfinite(q):
            check(kernel.NON_FINITE)
        self._x[0] = q
        self._x[1] = 0.0
        self._u1[0] = vp
        check(self.model.kernel.rhs(self._x, self._u1, self._dx)[0])
        return float(self._dx[1])

    def y_of(self, coords, vp=0.0) -> float:
        """Return the end shortening at ``coords``, m."""
        return float(self._eval(coords, vp)[self._iy])

    def q_ref(self, coords) -> float:
        """Return the reference deflection of ``coords``, m."""
        return float(np.dot(self.ref, coords))

    def gradient(self, coords, vp) -> np.ndarray:
        """Return dU_pot/dcoords by central differences."""
        g = np.empty(self.nq)
        for j in range(self.nq):
            e = np.zeros(self.nq)
            e[j] = self.h[j]
            g[j] = (self.energy(coords + e, vp) - self.energy(coords - e, vp)) / (2 * self.h[j])
        return g

    def hessian(self, coords, vp) -> np.ndarray:
        """Return d^2 U_pot/dcoords^2 by central differences."""
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
        """Return d^2 U_pot/dq^2 (one coordinate) or the smallest Hessian eigenvalue, N/m."""
        coords = np.atleast_1d(np.asarray(coords, dtype=float))
        if self.nq == 1:
            return float(self.hessian(coords, vp)[0, 0])
        return float(np.linalg.eigvalsh(self.hessian(coords, vp))[0])

    # -- search range ---------------------------------------------------------------------------
    def q_limit(self) -> float:
        """
        Return the deflection where the DET stretch falls to _LAMBDA_MIN.

        The deflection is along the first shape.
        """
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
        """Return the roots of the force on one side of q = 0 (one coordinate)."""
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
        """Return U_pot, or inf outside the model's domain."""
        try:
            return self.energy(coords, vp)
        except ModelDomainError:
            return math.inf

    def minimize(self, x, vp, N=None, iters=60):
        """
        Return a local minimum of U_pot from x by Newton's method.

        The Hessian is made positive definite (eigenvalues floored at their magnitude) and the
        step has a backtracking line search; with N, only x + N z is searched (a constrained
        minimum).
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
        Return the stable buckled states of several coordinates.

        Each is minimized from the one-term solution of the same scene (q1*, 0, ..., 0), else
        from the softest mode at q = 0 with the largest reference deflection. Only minima are
        returned for several coordinates.
        """
        one = landscape(self.scene.replace(**{'scene.n_ritz': 1}))
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
        """
        Return the straight and buckled equilibria at polymer voltage ``vp``.

        Rows (kind, coords, stiffness, y, U_pot), cached per ``vp``.
        """
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
        """
        Return y0: the shortening of the stable buckled state at 0 V.

        0.0 if straight is stable.
        """
        if self._rest is None:
            rows = self.equilibria(0.0, 0.0)
            stable = [r for r in rows if r[2] > 0.0]
            if not stable or stable[0][0] == 'straight':
                self._rest = 0.0                         # the straight beam is stable
            else:
                self._rest = min(r[3] for r in stable)   # both mirror states: same y
        return self._rest


_landscapes: 'collections.OrderedDict[tuple, Landscape]' = collections.OrderedDict()


def cache_key(scene: Scene) -> tuple:
    """Return what a landscape depends on: beam, pre-strain, fidelity, Ritz level, physics."""
    return (scene.beam, float(scene.eps_b), scene.fidelity, scene.ritz_level, scene.physics)


def landscape(scene: Scene) -> Landscape:
    """Return the cached :class:`Landscape` of ``scene``'s structure."""
    key = cache_key(scene)
    st = _landscapes.get(key)
    if st is None:
        st = Landscape(scene)
        _landscapes[key] = st
        if len(_landscapes) > CACHE_SIZE:
            _landscapes.popitem(last=False)
    else:
        _landscapes.move_to_end(key)
    return st
