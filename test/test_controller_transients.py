"""
A controller moves its command a little every period, and every move starts a charge transient.

Under the linearized method (set here: 'auto' steps 7 polynomials at 3e-3 with BDF, whose
own steps follow the transient, test/test_bdf.py) the transient's steps are dyadic fractions
of the period's step
(core/_csrc/stepping/period.c, dyadic_transient), so their sizes, and the matrix exponentials
their weights need, repeat from period to period instead of being new in every period. Checked
against what a user meets: the run stays within its tolerance of an independent solver
(scipy's Radau), and the stepper builds few new exponential chains.
"""

from det_sim_ros.analysis.scenarios import reference_solution, step_scene
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
import pytest

PERIODS = 200
# Every +-25 V move starts a transient from 3e-3 down (z_tol 9 C0); at 1e-4 the transient's
# steps decide the error (8 times coarser graded steps: 6-9 times the tolerance).
TOLERANCE = 3e-3
TIGHT = 1e-4
LEVELS = {   # the two ways back to the step grid: one step (3 modes), halvings (7 polynomials)
    'modes_3': {'scene.shapes': 'buckling_modes', 'scene.n_ritz': 3},
    'polynomial_7': {'scene.shapes': 'polynomial', 'scene.n_ritz': 7},
}
# chains built per period at most; the graded steps before (a size h0 gr^i and a remainder
# (dt - T) / n, both new in every period) built 1.75 per period on this run at either level
CHAINS_PER_PERIOD = {'modes_3': 1.0, 'polynomial_7': 0.25}


def dithered_run(level, tolerance=TOLERANCE, method='etdrk4_linearized'):
    """Return (scene, commands, run, simulator): 1.5 kV +-25 V per period, from rest."""
    scene = step_scene('fixed', 0.20, **{'scene.fidelity': 'exact', 'scene.initial_state': 'rest',
                                         'integrator.tolerance': tolerance,
                                         'integrator.method': method, **LEVELS[level]})
    volts = 1500.0 + np.random.default_rng(1).uniform(-25.0, 25.0, PERIODS)
    sim = Simulator(scene)
    return scene, volts, simulate(sim, volts, PERIODS * scene.dt), sim


@pytest.mark.parametrize('level', sorted(LEVELS))
def test_a_dithered_command_stays_within_its_tolerance_of_radau(level):
    """
    The deflection within TIGHT of its travel, against Radau at rtol 1e-9.

    The scene tolerance bounds the error over the travel by the step control's calibration
    (det_sim_ros.sim.integrators); measured here 0.21 (3 modes) and 0.36 (7 polynomials) of it.
    A different CPU or numpy changes the stepper's decisions at round-off only.
    """
    scene, volts, run, sim = dithered_run(level, TIGHT)
    t, X = reference_solution(scene, PERIODS * scene.dt, rtol=1e-9,
                              voltage=lambda s: volts[min(int(round(s / scene.dt)), PERIODS - 1)])
    n_r = sim.model.bases[0].n_ritz
    q_ref = X[:, :n_r] @ sim.model.bases[0].reference_row()
    assert np.allclose(run.t, t)
    error = np.max(np.abs(run['q'] - q_ref)) / np.ptp(q_ref)
    assert error <= TIGHT, f'{level}: {error:.2e} of the travel'


@pytest.mark.parametrize('level', sorted(LEVELS))
def test_the_transients_reuse_their_step_sizes(level):
    """Few new exponential chains: their sizes repeat (measured 0.7 and 0.065 per period)."""
    _, _, _, sim = dithered_run(level)
    jacobians, _, chains = sim.stepper.linear_counts()
    assert jacobians >= 1
    assert chains <= CHAINS_PER_PERIOD[level] * PERIODS, f'{level}: {chains} chains'
