"""
The model level a scene runs when it leaves the choice to the package.

That is scene.shapes 'auto' and scene.n_ritz 0. Per beam, the Ritz family with the fewest terms
that makes every snap of the 'switching' scenario (shared scenarios: released, a 2 Hz 3 kV square
wave) at its time and stays within 1 % of the converged beam's travel there and on the 'step'
cases; measured by bench/work_precision_map.py against bench/data/continuum_reference.npz
(docs/fidelity.md has the map). A log stores the resolved level, so a replay runs the same model
when this table changes.
"""

from __future__ import annotations

__all__ = ['AUTO_SHAPES', 'AUTO_RITZ', 'resolve_level']

# beam -> family: the clamped-clamped beam's symmetric buckling modes converge geometrically
# (its elastica is a whole period of an elliptic function); the clamped-pinned beam's do not,
# and its polynomials need fewer terms.
#
# The assumption this rests on: the clamped-clamped beam's buckling modes span only symmetric
# shapes (about mid-span), which is exact only while nothing loads a beam asymmetrically. Each
# beam is loaded only through its end shortening (the DET's force, the interface mass, the
# structure's inertia: physics/model.py), which is even in every antisymmetric shape, and
# starts symmetric (the rest state, the released shape): the antisymmetric coordinates of a
# complete basis then stay zero. A load off the axis or off mid-span (a point mass, a
# sensor's force, an imperfection) would break it: test/test_symmetric_modes.py runs every
# shipped scene on a complete basis and fails if a fixed beam's shape gains an antisymmetric
# part.
#
# n_ritz has one meaning in every family: the shape functions (coordinates) of a beam, each a
# state pair (q, q_dot). What they span differs: the fixed beam's buckling modes are
# symmetric modes only (3 of them span what the polynomials' 3 symmetric terms of n_r 5 do,
# and better), the polynomials and the clamped-pinned modes every shape.
AUTO_SHAPES = {'fixed': 'buckling_modes', 'simply_supported': 'polynomial'}
# (beam, family) -> shape functions per beam
AUTO_RITZ = {('fixed', 'buckling_modes'): 3, ('fixed', 'polynomial'): 9,
             ('simply_supported', 'polynomial'): 7, ('simply_supported', 'buckling_modes'): 9}


def resolve_level(beam: str, fidelity: str, shapes: str, n_ritz: int) -> tuple:
    """
    Return the (Ritz family, terms) a scene runs, 'auto' and 0 resolved by the tables above.

    The 'paper' fidelity is the paper's one-term polynomial shape whatever is asked; 'auto'
    is polynomial at the 'consistent' fidelity (whose truncated kinematics do not converge to
    the elastica: a better basis buys nothing there).
    """
    if fidelity == 'paper':
        return 'polynomial', 1
    if shapes == 'auto':
        shapes = AUTO_SHAPES[beam] if fidelity == 'exact' else 'polynomial'
    if n_ritz == 0:
        n_ritz = AUTO_RITZ[(beam, shapes)]
    return shapes, n_ritz
