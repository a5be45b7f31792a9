"""
Pin the adaptive step counts of a fixed voltage profile on six scenes.

The adaptive step counts, pinned: the internal steps taken per stretch of a fixed voltage
profile on five scenes at tolerance 1e-6 (the paper's level set explicitly where the
fidelity is not the subject) and on the shipped default at its own tolerance ('auto':
AUTO_TOLERANCE). They follow from the step-size control's constants
(det_sim_ros.sim.integrators: LOCAL_TOLERANCE, MAX_SUBSTEPS_FACTOR, ERROR_CONSTANT,
TRANSIENT_FINE, TRANSIENT_CHARGE, MAX_STEP, STABLE_STEP, LINEAR_REFRESH, LINEAR_REFRESH_INPUT,
LINEARIZED_MAX_FACTOR, AUTO_TOLERANCE;
CTL_SAFETY, the growth rules, the count ladder and the dyadic charge transient (CLIMB_MIN_ND)
of linearized methods in
core/_csrc/stepping/period.c; 'default' and 'exact_n3' step with 'etdrk4_linearized', the others
with 'etdrk4' or 'dp5'), so a change to any of them shows here by name rather than only as a
changed fingerprint in bench/behaviour_hashes.py.

When a deliberate change moves these numbers: check that the accuracy tests still pass
(test_integrators.py: the tolerance is met on the 'step' scenario), rerun the calibration the
constant's comment names, then replace the numbers below with the new ones (the failure
message prints them) and say in the commit message why the step counts moved.
"""

from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import pytest

TOLERANCE = 1e-6
# (volts, periods): settled at 0 V, a 3 kV step (snap-through), down to 1.5 kV
PROFILE = ((0.0, 50), (3000.0, 130), (1500.0, 120))
PAPER = {'scene.fidelity': 'paper'}
SCENES = {
    'default': ('default', {}),           # the shipped default: exact, 3 buckling modes
    'default_auto': ('default', {'integrator.tolerance': 0.0}),   # ... at its own tolerance
    'paper': ('default', PAPER),
    'plate_paper': ('plate', PAPER),
    'exact_n3': ('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 3,
                             'scene.shapes': 'polynomial'}),
    'ideal_dp5_paper': ('default', {**PAPER, 'scene.source': 'ideal',
                                    'integrator.method': 'dp5'}),
}
# internal steps taken in each stretch of PROFILE
STEPS = {
    'default': [85, 4116, 4980],
    'default_auto': [51, 382, 429],
    'paper': [85, 2655, 2561],
    'plate_paper': [85, 2787, 2952],
    'exact_n3': [85, 2189, 1499],
    'ideal_dp5_paper': [66, 693, 720],
}
# periods the default (at auto) runs again with more steps over PROFILE
REPEATED_DEFAULT_AUTO = 23.0
# The BDF stepper (core/_csrc/stepping/bdf.c) on the simply supported default at its own
# tolerance (auto: 3e-3, AUTO_TOLERANCE), with its RC source and with an ideal one: per
# stretch of PROFILE, (steps, Jacobians, LU factorizations, rejected steps). They follow from
# its constants (NEWTON_MAXITER, NEWTON_TOL, LU_KEEP, MIN_FACTOR, MAX_FACTOR, FIT_ROUND_OFF,
# the first step's rule; BDF_LOCAL_TOLERANCE, BDF_SLOW_WEIGHT in det_sim_ros.sim.integrators),
# which the kernel and its numpy reference share: a change to one of them in both shows here.
BDF_SCENES = {
    'simply_supported': {'scene.beam': 'simply_supported'},
    'simply_supported_ideal': {'scene.beam': 'simply_supported', 'scene.source': 'ideal',
                               'integrator.method': 'bdf'},
}
BDF_COUNTS = {
    'simply_supported': [(53, 1, 4, 0), (698, 5, 36, 12), (716, 22, 59, 11)],
    'simply_supported_ideal': [(53, 1, 4, 0), (702, 4, 30, 9), (742, 23, 58, 15)],
}


def step_counts(name):
    source, overrides = SCENES[name]
    sim = Simulator(load_scene(source, {'integrator.tolerance': TOLERANCE, **overrides}))
    assert sim.adaptive
    counts = []
    for volts, periods in PROFILE:
        # the plate's second DET at a third of the first: the two cells differ
        sim.set_input([volts, volts / 3.0][:sim.model.n_inputs])
        before = sim.steps_taken
        for _ in range(periods):
            sim.step()
        counts.append(sim.steps_taken - before)
    assert not sim.fault
    return counts


@pytest.mark.parametrize('name', sorted(SCENES))
def test_adaptive_step_counts_are_pinned(name):
    assert step_counts(name) == STEPS[name]


def test_repeated_periods_are_counted_and_pinned():
    """The default at auto repeats a few periods through the snap; a fixed count none."""
    counts = {}
    for substeps in (0, 4):
        sim = Simulator(load_scene('default', {'integrator.substeps': substeps}))
        for volts, periods in PROFILE:
            sim.set_input([volts])
            for _ in range(periods):
                sim.step()
        counts[substeps] = sim.stepper.periods_repeated
    assert counts == {0: REPEATED_DEFAULT_AUTO, 4: 0.0}


@pytest.mark.parametrize('name', sorted(BDF_SCENES))
def test_bdf_steps_jacobians_factorizations_and_rejections_are_pinned(name):
    sim = Simulator(load_scene('default', {**BDF_SCENES[name], 'integrator.tolerance': 0.0}))
    assert sim.method.name == 'bdf'
    counts = []
    for volts, periods in PROFILE:
        sim.set_input([volts])
        before = (sim.steps_taken, *sim.stepper.bdf_counts())
        for _ in range(periods):
            sim.step()
        after = (sim.steps_taken, *sim.stepper.bdf_counts())
        counts.append(tuple(a - b for a, b in zip(after, before)))
    assert not sim.fault
    assert counts == BDF_COUNTS[name]
