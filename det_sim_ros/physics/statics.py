"""
Statics of the DET-buckled-beam actuator (paper Section 4, Fig. 5).

Equilibria, their stability, the critical pre-strain and the equilibrium branches versus
pre-strain.

Everything is derived from the dynamic model (:func:`det_sim_ros.physics.model.build_model`), so
there is one source of truth for the physics (the landscape of U_pot and the search for its
equilibria: :mod:`det_sim_ros.physics.landscape`). For a scene with an ideal voltage source, no
creep and no power monitor the state is x = [q, q_dot] and, at q_dot = 0, the model's energy
output is

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

from .brent import brentq
from .landscape import cache_key, CACHE_SIZE, Landscape, landscape
from .model import build_model, ModelDomainError
from ..scenes.scene import Scene, SceneError


__all__ = ['Equilibrium', 'BranchPoint', 'potential', 'potential_coords', 'equilibria',
           'critical_prestrain', 'normalized_potential', 'rest_shortening', 'branches',
           'polymer_voltage', 'stiffness_at_straight', 'rest_coords', 'rest_state',
           'RestStateError', 'initial_state']

_NEWTON_ITERS = 30      # most Newton steps polishing a rest state


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
    """
    Return the steady-state polymer voltage v_p (eq 81).

    v R_p/(R_p + R_s) for 'rc', v for 'ideal'.
    """
    if scene.source == 'ideal':
        return float(v)
    p = scene.physics
    return float(v) * p.Rp / (p.Rp + p.Rs)


# -- public API -----------------------------------------------------------------------------------
def potential_coords(scene: Scene, coords, v: float) -> np.ndarray:
    """
    Return U_pot (J) at Ritz coordinate vector(s) ``coords`` and voltage v (V).

    The last axis of ``coords`` is n_q.
    """
    st = landscape(scene)
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
    Return the voltage-controlled potential U_pot(q, v_p) of eq 79 (J) at deflection(s) q (m).

    q is the reference deflection. For one Ritz coordinate this is U_s + U_DE,m - 1/2 C v_p^2
    at q. For several coordinates it is the reduced potential: U_pot minimized over the other
    coordinates at the given reference deflection (it equals U_pot at every equilibrium and has
    the same stability along the path).
    """
    st = landscape(scene)
    vp = polymer_voltage(scene, v)
    qa = np.asarray(q, dtype=float)
    if st.nq == 1:
        return np.array([st.energy(np.array([x]), vp) for x in qa.reshape(-1)]).reshape(qa.shape)
    return np.array([_reduced_energy(st, x, vp) for x in qa.reshape(-1)]).reshape(qa.shape)


def _reduced_energy(st: Landscape, q: float, vp: float) -> float:
    """
    Return min U over the coordinates with ref . coords = q.

    Minimized in the constraint's null space, started from the one-term shape, the first
    coordinate.
    """
    r = st.ref
    _, _, Vt = np.linalg.svd(r[None, :])
    N = Vt[1:].T                                     # null space of the constraint
    x0 = np.zeros(st.nq)
    x0[0] = q / r[0]
    return st.energy(st.minimize(x0, vp, N), vp)


def equilibria(scene: Scene, v: float = 0.0) -> list:
    """
    Return all equilibria at the scene's pre-strain and voltage v (V).

    The straight configuration q = 0 and the mirror-symmetric buckled pair(s) +-q*, each an
    :class:`Equilibrium`.
    """
    st = landscape(scene)
    vp = polymer_voltage(scene, v)
    y0 = st.rest_shortening()
    return [Equilibrium(kind, st.q_ref(c), tuple(float(x) for x in c), bool(k > 0.0), k, y,
                        y0 - y, u, float(v), float(scene.eps_b))
            for kind, c, k, y, u in st.equilibria(vp, v)]


def stiffness_at_straight(scene: Scene, v: float = 0.0) -> float:
    """
    Return d^2 U_pot/dq^2 at q = 0, N/m.

    The smallest Hessian eigenvalue for several coordinates.
    """
    st = landscape(scene)
    return st.stiffness(np.zeros(st.nq), polymer_voltage(scene, v))


def critical_prestrain(scene: Scene, v: float = 0.0, xtol: float = 1e-9) -> float:
    """
    Return eps_b,min(v): the pre-strain where the straight beam loses stability.

    There d^2 U_pot/dq^2 at q = 0 crosses zero; found by root bracketing in eps_b. NaN if no
    crossing in (-0.9, 2].
    """
    def k0(e):
        sc = scene.replace(**{'scene.eps_b': float(e)})
        st = Landscape(sc)                                  # not cached: brentq probes many
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
    """Return eq 82: (U_pot - U_min)/(U_max - U_min) over the given q range (m)."""
    u = potential(scene, q, v)
    lo, hi = np.min(u), np.max(u)
    return (u - lo) / (hi - lo) if hi > lo else np.zeros_like(u)


def rest_shortening(scene: Scene) -> float:
    """
    Return y0 (m): the end shortening of the stable buckled equilibrium at 0 V.

    0.0 if the straight beam is stable. Cached per scene structure and physics; fast after the
    first call.
    """
    return float(landscape(scene).rest_shortening())


def rest_shortenings(scene: Scene) -> list[float]:
    """
    Return the rest shortening y0_i (m) of each cell in DET order.

    Cell i is alone at 0 V (``scene.cell_scene(i)``). Cells with identical physics share one
    statics solve, so an array of identical copies costs one solve; an array with spread costs
    one per copy (docs/development.md).
    """
    cells = scene.cell_physics()
    template = scene.cell_scene(0)
    solved = {}
    for physics in cells:
        if physics not in solved:
            solved[physics] = rest_shortening(dataclasses.replace(template, physics=physics))
    return [solved[physics] for physics in cells]


def branches(scene: Scene, eps_grid: Sequence[float], v: float = 0.0, progress=None) -> list:
    """
    Return the equilibrium branches versus pre-strain (the Fig. 5 analogue) at voltage v (V).

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
    """Return the accelerations at (coords, q_dot = 0, eps_E = 0, q_p = 0), 0 V: zero at rest."""
    nq = len(coords)
    x = np.zeros(model.n_states)
    x[:nq] = coords
    return model.f(0.0, x, np.zeros(model.n_inputs))[nq:2 * nq]


def _polish(model, coords, length):
    """
    Polish ``coords`` by Newton's method on the model's own static residual.

    The residual is Model.f at zero velocity, 0 V; ``coords`` is a statics solution, polished
    to round-off: the Jacobian by central differences, the iterate with the smallest residual
    kept. Equilibria of Model.f are exactly the stationary states of the dynamic model
    (q_dot = 0 and eps_E = 0, q_p = 0 are the other states' equilibria at 0 V).
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
    Return the Ritz coordinates of a single-cell scene's stable equilibrium at 0 V on ``branch``.

    'buckled+': reference deflection q > 0, 'buckled-': q < 0; the straight beam q = 0 when it
    is the stable state. Solved to round-off in the scene's own dynamic model (its fidelity and
    n_ritz). Cached per beam, pre-strain, fidelity, physics and model switches.

    :raises RestStateError: no stable state on that branch, or one outside the model's domain.
    """
    key = (cache_key(scene), scene.creep, scene.source, scene.monitor_power, branch)
    cached = _rest_cache.get(key)
    if cached is not None:
        _rest_cache.move_to_end(key)
        return cached.copy()
    st = landscape(scene)
    where = f'{scene.beam} beam, eps_b = {scene.eps_b:g}, {scene.fidelity_label}'
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
                                 'scene.initial_state: released')
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
                             f"model's domain: {exc}") from None
    if not math.isfinite(residual):
        raise RestStateError(f'the {branch} rest state at 0 V ({where}) is not finite')
    _rest_cache[key] = coords.copy()
    if len(_rest_cache) > CACHE_SIZE:
        _rest_cache.popitem(last=False)
    return coords


def rest_state(model) -> np.ndarray:
    """
    Return the state vector of ``model`` with every cell at its own rest state.

    Each cell's rest state is :func:`rest_coords` of the cell alone, on ``scene.rest_branch``;
    q_dot = 0, eps_E = 0, q_p = 0 and the energy book at 0: stationary at 0 V. Cells with
    identical physics share one solve.
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
    Return the scene's initial state (``scene.initial_state``).

    'rest' = every cell at its stable buckled equilibrium at 0 V, stationary
    (:func:`rest_state`); 'released' = :meth:`~det_sim_ros.physics.model.Model.released_state`.
    """
    if model.scene.initial_state == 'rest':
        return rest_state(model)
    return model.released_state()
