"""
The model levels a fit runs at: a cheap coarse level that searches, the scene's own that polishes.

A search from several starts takes a few hundred runs of the log, and a run at the scene's own
level costs tens of times one at the coarse level, whose optimum lies within a few percent of
the scene level's on the step-and-sine logs (its model error: the parameters absorb the beam's
missing terms). So :func:`~.fitting.fit` searches at the coarse level and only corrects its
optimum at the scene's level, in a few runs. The costs and errors measured: docs/calibration.md
(Two levels; At the default level: two levels against one).

The coarse level keeps the scene's fidelity, structure, physics and stepper; it drops to
:data:`COARSE_N_RITZ` terms and runs at the explicit tolerance :data:`COARSE_TOLERANCE` or the
scene's own explicit one if looser. A scene at the auto tolerance (``integrator.tolerance`` 0,
resolved per level by :data:`~det_sim_ros.sim.integrators.AUTO_TOLERANCE`) gets a coarse level at
:data:`COARSE_TOLERANCE`, so the coarse pass runs at the same tolerance whatever the scene's
level. A scene that is already at least that cheap (one Ritz term, an explicit tolerance of
:data:`COARSE_TOLERANCE` or looser) is fitted at its own level alone.
"""

from __future__ import annotations

import dataclasses

from ..sim.integrators import integration_tolerance

__all__ = ['Level', 'fit_levels', 'COARSE_N_RITZ', 'COARSE_TOLERANCE']

# Ritz terms per beam of the coarse level: the cheapest; its optimum is off by its model error
# (docs/calibration.md, Two levels)
COARSE_N_RITZ = 1
# integrator tolerance of the coarse level (relative to the stroke): about one step per control
# period, and finite-difference sensitivities that still agree with a tight tolerance's
# (docs/calibration.md, Two levels)
COARSE_TOLERANCE = 1e-3


@dataclasses.dataclass(frozen=True)
class Level:
    """One level a fit runs at: ``role`` 'coarse' (the search) or 'scene' (the scene's own)."""

    role: str
    scene: object

    def describe(self) -> str:
        """
        Return e.g. 'exact buckling modes n_r=3, tolerance auto (0.01)'.

        An explicit tolerance is shown as a number; the stepper's substeps when fixed.
        """
        scene = self.scene
        shown = (f'{scene.tolerance:g}' if scene.tolerance > 0.0
                 else f'auto ({integration_tolerance(scene):g})')
        text = f'{scene.fidelity_label}, tolerance {shown}'
        if scene.substeps:
            text += f', {scene.substeps} substeps per period'
        return text


def fit_levels(scene) -> list:
    """
    Return the levels a fit of ``scene`` runs at, in order: [coarse, scene] or [scene].

    The coarse level is the scene with at most :data:`COARSE_N_RITZ` Ritz terms and an explicit
    tolerance of at least :data:`COARSE_TOLERANCE` (the auto tolerance, 0, counts as tighter);
    when that is the scene's own level there is none.
    """
    shapes, own_n_ritz = scene.ritz_level
    n_ritz = min(own_n_ritz, COARSE_N_RITZ)
    looser = max(float(scene.tolerance), COARSE_TOLERANCE)
    if n_ritz == own_n_ritz and looser == scene.tolerance:
        return [Level('scene', scene)]
    coarse = scene.replace(**{'scene.n_ritz': n_ritz, 'scene.shapes': shapes,
                              'integrator.tolerance': looser})
    return [Level('coarse', coarse), Level('scene', scene)]
