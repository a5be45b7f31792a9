"""
Ritz statics of one beam alone, for measuring the model's fidelity against the exact solutions.

The exact solutions are those of :mod:`det_sim_ros.analysis.elastica`. The beam is the one the
simulator builds: its Ritz basis comes from :func:`det_sim_ros.physics.model.build_model` for the
scene (``model.bases``), and its energies are the model's (model.py): per beam

    U(q) = 1/2 EI int w''^2 (1 + w'^2) dx,      y(q) = int (1/2 w'^2 + kappa/8 w'^4) dx,

w = sum_j q_j S_j, kappa = 1 for the 'consistent' fidelity and 0 for 'paper' (eq 65); for
'exact', U = 1/2 EI int w''^2 / (1 - w'^2) dx and y = int (1 - sqrt(1 - w'^2)) dx. The model's
U_s and y are those of the beam pair (twice U; the same y for both beams, which share their ends);
:meth:`BeamRitz.check_against_model` verifies that these formulas reproduce the model's outputs
'H' (minus the DET energy) and 'y', so this module and the simulator have one source of truth.

* :meth:`BeamRitz.critical_load`: the Ritz buckling load, the smallest eigenvalue of
  K v = P G v with K = EI int S'' S''^T and G = int S' S'^T (Rayleigh-Ritz: it decreases
  monotonically to the Euler load from above as terms are added).
* :meth:`BeamRitz.path`: the post-buckling path under prescribed end shortening Y: minimize U
  subject to y(q) = Y; the chord force P is the Lagrange multiplier (dU = P dy). Solved by
  Newton's method on the KKT system with exact derivatives, continued in Y from the first mode.

Results are dimensionless like the elastica's: P l^2/EI, y/l, deflections w/l, with ``q_ref``
the deflection at the reference point (what the simulator publishes as q) and ``q_max`` the
largest |w| along the beam.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.linalg

from ..physics.model import build_model
from ..physics.shapes import RitzBasis
from ..scenes.scene import load_scene, Scene

__all__ = ['BeamRitz', 'RitzPath', 'beam_ritz', 'fidelity_scene']


def fidelity_scene(beam: str, fidelity: str = 'consistent', n_ritz: int = 1,
                   eps_b: float = 0.2) -> Scene:
    """
    Return the default scene with the given beam and fidelity, ideal source, no creep.

    Its H and y outputs at rest are U_s + U_DE and the end shortening.
    """
    return load_scene('default', {'scene.beam': beam, 'scene.eps_b': eps_b,
                                  'scene.fidelity': fidelity, 'scene.n_ritz': n_ritz,
                                  'scene.source': 'ideal', 'scene.creep': False,
                                  'scene.monitor_power': False,
                                  'scene.initial_state': 'released'})


@dataclasses.dataclass(frozen=True)
class RitzPath:
    """
    Post-buckling path of one beam.

    At each point: ``y`` y/l, ``load`` P l^2/EI, ``q_ref`` and ``q_max`` the reference and max
    deflection / l, and ``coords`` the Ritz coordinates (m).
    """

    y: np.ndarray
    load: np.ndarray
    q_ref: np.ndarray
    q_max: np.ndarray
    coords: np.ndarray


class BeamRitz:
    """One beam of a scene's model with its Ritz basis, bending stiffness EI and kinematics."""

    def __init__(self, basis: RitzBasis, EI: float, kappa: float):
        self.basis = basis
        self.EI = float(EI)
        self.kappa = float(kappa)
        self.length = basis.length
        if self.kappa == 2.0:   # exact kinematics: the model's rule for smooth integrands
            self.x, self.w = basis.quadrature(nonpolynomial=True)
        else:
            # a Gauss rule exact for w''^2 w'^2 and w'^4 is the model's own; use a finer one so
            # the statics do not depend on the model's choice (they agree to round-off, tests)
            n = basis.degree * 2 + 2
            xi, w = np.polynomial.legendre.leggauss(n)
            self.x = 0.5 * self.length * (xi + 1.0)
            self.w = 0.5 * self.length * w
        self.B1 = basis.values(self.x, 1)
        self.B2 = basis.values(self.x, 2)
        self.K = self.EI * self.B2.T @ (self.w[:, None] * self.B2)
        self.G = self.B1.T @ (self.w[:, None] * self.B1)
        self.ref = basis.reference_row()
        self._grid = np.linspace(0.0, self.length, 801)
        self._S = basis.values(self._grid)

    @property
    def n_ritz(self) -> int:
        """Return the number of Ritz terms of the beam."""
        return self.basis.n_ritz

    # -- energies (per beam) -------------------------------------------------------------------
    def _bending_factor(self, wp):
        """
        Return a(w') in U = 1/2 EI int w''^2 a dx and its first two derivatives.

        a(w') is 1 + w'^2 (eq 51) or 1/(1 - w'^2) (exact).
        """
        if self.kappa == 2.0:
            c2 = 1.0 - wp * wp
            return 1.0 / c2, 2.0 * wp / c2 ** 2, (2.0 + 6.0 * wp * wp) / c2 ** 3
        return 1.0 + wp * wp, 2.0 * wp, 2.0 + 0.0 * wp

    def _shortening_density(self, wp):
        """
        Return f(w') in y = int f dx and its first two derivatives.

        f(w') is w'^2/2 + kappa w'^4/8, or 1 - sqrt(1 - w'^2) (exact).
        """
        if self.kappa == 2.0:
            c = np.sqrt(1.0 - wp * wp)
            return 1.0 - c, wp / c, 1.0 / c ** 3
        k = self.kappa
        return (0.5 * wp ** 2 + 0.125 * k * wp ** 4, wp + 0.5 * k * wp ** 3,
                1.0 + 1.5 * k * wp * wp)

    def energy(self, q) -> float:
        """Return the energy U = 1/2 EI int w''^2 a(w') dx, J (see _bending_factor)."""
        wp, wpp = self.B1 @ q, self.B2 @ q
        return 0.5 * self.EI * float(self.w @ (wpp * wpp * self._bending_factor(wp)[0]))

    def shortening(self, q) -> float:
        """Return the end shortening y = int f(w') dx, m (see _shortening_density)."""
        return float(self.w @ self._shortening_density(self.B1 @ q)[0])

    def _derivatives(self, q):
        wp, wpp = self.B1 @ q, self.B2 @ q
        w, B1, B2, EI = self.w, self.B1, self.B2, self.EI
        a, da, dda = self._bending_factor(wp)
        gU = EI * (B2.T @ (w * wpp * a) + B1.T @ (0.5 * w * wpp * wpp * da))
        HU = EI * (B2.T @ ((w * a)[:, None] * B2)
                   + B2.T @ ((w * wpp * da)[:, None] * B1)
                   + B1.T @ ((w * wpp * da)[:, None] * B2)
                   + B1.T @ ((0.5 * w * wpp * wpp * dda)[:, None] * B1))
        _, df, ddf = self._shortening_density(wp)
        gy = B1.T @ (w * df)
        Hy = B1.T @ ((w * ddf)[:, None] * B1)
        return gU, HU, gy, Hy

    def deflection(self, q) -> tuple:
        """Return (reference-point deflection, max |w|), m."""
        q_ref = float(self.ref @ q)
        w = self._S @ q
        k = int(np.argmax(np.abs(w)))
        if 0 < k < len(w) - 1:  # parabola through the three grid points around the maximum
            a, b, c = np.abs(w[k - 1:k + 2])
            den = a - 2.0 * b + c
            q_max = b - 0.125 * (a - c) ** 2 / den if den < 0.0 else b
        else:
            q_max = abs(w[k])
        return q_ref, float(q_max)

    # -- buckling ------------------------------------------------------------------------------
    def critical_load(self) -> tuple:
        """Return (P_cr l^2/EI, mode) from K v = P G v (smallest eigenvalue)."""
        vals, vecs = scipy.linalg.eigh(self.K, self.G)
        mode = vecs[:, 0]
        if self.ref @ mode < 0.0:
            mode = -mode
        return float(vals[0]) * self.length ** 2 / self.EI, mode

    def path(self, y_over_l, tol: float = 1e-13) -> RitzPath:
        """Minimize U subject to y(q) = Y at each Y = y_over_l * l (increasing); P = dU/dy."""
        ys = np.atleast_1d(np.asarray(y_over_l, dtype=float))
        p_cr, mode = self.critical_load()
        l_beam = self.length
        q = mode * math.sqrt(2.0 * ys[0] * l_beam / float(mode @ self.G @ mode))
        P = p_cr * self.EI / l_beam ** 2
        y_prev = None
        rows, coords = [], []
        for yl in ys:
            Y = yl * l_beam
            if y_prev is not None:
                q = q * math.sqrt(Y / y_prev)
            for _ in range(50):
                gU, HU, gy, Hy = self._derivatives(q)
                r = np.r_[gU - P * gy, self.shortening(q) - Y]
                A = np.block([[HU - P * Hy, -gy[:, None]], [gy[None, :], np.zeros((1, 1))]])
                step = np.linalg.solve(A, -r)
                q = q + step[:-1]
                P = P + step[-1]
                if np.max(np.abs(step[:-1])) < tol * l_beam and abs(step[-1]) < tol * abs(P):
                    break
            else:
                raise RuntimeError(f'Ritz path: Newton did not converge at y/l = {yl}')
            gU, HU, gy, Hy = self._derivatives(q)
            Z = scipy.linalg.null_space(gy[None, :])
            if self.n_ritz > 1 and np.linalg.eigvalsh(Z.T @ (HU - P * Hy) @ Z)[0] <= 0.0:
                raise RuntimeError(f'Ritz path: not a constrained minimum at y/l = {yl}')
            y_prev = Y
            q_ref, q_max = self.deflection(q)
            rows.append((yl, P * l_beam * l_beam / self.EI, q_ref / l_beam, q_max / l_beam))
            coords.append(q.copy())
        rows = np.array(rows)
        return RitzPath(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], np.array(coords))

    # -- one source of truth -------------------------------------------------------------------
    def check_against_model(self, model, q) -> tuple:
        """
        Return (U_pair from the model, 2 U here, y from the model, y here) at coordinates q.

        At Ritz coordinates q, rest, 0 V; U_pair is the model's H minus its DET energy
        V Y/6 (lambda^2 + lambda^-2 - 2).
        """
        x = np.zeros(model.n_states)
        x[:len(q)] = q
        out = model.outputs(x, np.zeros(model.n_inputs))
        p = model.scene.physics
        lam = out['lambda']
        u_det = p.volume * p.Y / 6.0 * (lam * lam + 1.0 / (lam * lam) - 2.0)
        return out['H'] - u_det, 2.0 * self.energy(q), out['y'], self.shortening(q)


def beam_ritz(beam: str, fidelity: str = 'consistent', n_ritz: int = 1,
              scene: Scene | None = None) -> tuple:
    """Return (BeamRitz, model) for one beam of the scene's model (default scene if None)."""
    scene = scene or fidelity_scene(beam, fidelity, n_ritz)
    model = build_model(scene)
    p = scene.physics
    kappa = {'paper': 0.0, 'consistent': 1.0, 'exact': 2.0}[scene.fidelity]
    return BeamRitz(model.bases[0], p.E_b * p.I, kappa), model


def stable_substeps(model, dt: float, substeps: int, limit: float = 2.0) -> int:
    """
    Return the internal steps per control period that keep an explicit stepper stable.

    For a many-term model: h times the fastest beam rate (the largest undamped frequency of (K, Mb)
    or the largest Kelvin-Voigt decay rate of (D, Mb), which grows like omega^2 eta_b/E_b and
    dominates from about 6 Ritz terms) at most ``limit``. Returns max(substeps, that count).

    An independent check of Model.fastest_beam_rate, which the simulator's automatic substeps
    use (without it the 'step' scenario diverges for n_ritz >= 6 simply supported, 7 fixed).
    """
    p = model.scene.physics
    basis = model.bases[0]
    x, w = basis.quadrature()
    S0, S1, S2 = (basis.values(x, k) for k in range(3))
    Mb = p.rho_b * (p.I * S1.T @ (w[:, None] * S1) + p.area * S0.T @ (w[:, None] * S0))
    bend = S2.T @ (w[:, None] * S2)          # same factor 2 (two beams) on all: ratios only
    K, D = p.E_b * p.I * bend, p.eta_b * p.I * bend
    omega = math.sqrt(max(scipy.linalg.eigh(K, Mb, eigvals_only=True)))
    decay = max(scipy.linalg.eigh(D, Mb, eigvals_only=True))
    return max(int(substeps), int(math.ceil(dt * max(omega, decay) / limit)))
