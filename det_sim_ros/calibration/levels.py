"""
The model levels a fit runs at: a cheap coarse level that searches, the scene's own that polishes.

A run of a 10 s log at the default level (exact kinematics, five Ritz terms, integrator
tolerance 1e-6) takes about 1 s, and a search from several starts takes 150-400 runs. The same
scene with one Ritz term and a tolerance of 1e-3 runs 35-45x faster, and on the step-and-sine
log its optimum lies within a few percent of the default level's (its model error: the parameters
absorb the beam's missing terms). So :func:`~.fitting.fit` searches at that coarse level and
only corrects its optimum at the scene's level, in a few runs (docs/calibration.md, Two levels).

The coarse level keeps the scene's fidelity, structure, physics and stepper; it drops to
:data:`COARSE_N_RITZ` terms and loosens the tolerance to :data:`COARSE_TOLERANCE` (an explicit
tolerance, so whatever the scene's tolerance is, a number or one picked per level, the coarse
pass runs at the same one). A scene that is already at least that cheap is fitted at its own
level alone.
"""

from __future__ import annotations

import dataclasses

__all__ = ['Level', 'fit_levels', 'COARSE_N_RITZ', 'COARSE_TOLERANCE']

# Ritz terms per beam of the coarse level: the cheapest; on step-and-sine logs of the default
# scene its optimum is off the truth by its model error: m 0.9 %, eps_r 1.0-1.5 %, eta_b 0.4-2.5 %
COARSE_N_RITZ = 1
# integrator tolerance of the coarse level (relative to the stroke): one step per 1 ms period
# there; its finite-difference sensitivities agree with those at 1e-6 within 0.5 %
COARSE_TOLERANCE = 1e-3


@dataclasses.dataclass(frozen=True)
class Level:
    """One level a fit runs at: ``role`` 'coarse' (the search) or 'scene' (the scene's own)."""

    role: str
    scene: object

    def describe(self) -> str:
        """Return e.g. 'exact, n_ritz 5, tolerance 1e-06' (the stepper's substeps when fixed)."""
        scene = self.scene
        tolerance = scene.tolerance
        shown = f'{tolerance:g}' if isinstance(tolerance, (int, float)) else str(tolerance)
        text = f'{scene.fidelity_label}, tolerance {shown}'
        if scene.substeps:
            text += f', {scene.substeps} substeps per period'
        return text


def fit_levels(scene) -> list:
    """
    Return the levels a fit of ``scene`` runs at, in order: [coarse, scene] or [scene].

    The coarse level is the scene with at most :data:`COARSE_N_RITZ` Ritz terms and a tolerance
    of at least :data:`COARSE_TOLERANCE`; when that is the scene's own level there is none.
    """
    tolerance = scene.tolerance
    numeric = isinstance(tolerance, (int, float))
    shapes, own_n_ritz = scene.ritz_level
    n_ritz = min(own_n_ritz, COARSE_N_RITZ)
    looser = max(float(tolerance), COARSE_TOLERANCE) if numeric else COARSE_TOLERANCE
    if n_ritz == own_n_ritz and numeric and looser == tolerance:
        return [Level('scene', scene)]
    coarse = scene.replace(**{'scene.n_ritz': n_ritz, 'scene.shapes': shapes,
                              'integrator.tolerance': looser})
    return [Level('coarse', coarse), Level('scene', scene)]
