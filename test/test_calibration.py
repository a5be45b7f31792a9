"""
Test the fit of scene parameters to measured logs (det_sim_ros.calibration, no ROS).

Synthetic logs from known parameters (a step and a sine, Gaussian noise on Δy at 1 % of the
stroke): from every parameter 2x off, the well-identified ones come back within 2 % and inside
their 95 % intervals, and one the log cannot identify is flagged. The full check over ten noise
seeds and 10 s logs is bench/fit_accuracy.py.
"""

import math

import det_sim_ros
from det_sim_ros.calibration import problem as problem_module
from det_sim_ros.calibration.synthetic import step_and_sine, synthetic_measurement
from det_sim_ros.scenes.scene import load_scene
import pytest

WELL_IDENTIFIED = ('m', 'eta_b', 'eps_r')   # from Δy: the mode's mass and damping, the force
NOT_IDENTIFIED = 'Rp'                   # leakage: a time constant of ~100 s against a 2 s log


@pytest.fixture(scope='module')
def truth():
    # the paper's level: the fit's statistics do not depend on the level, and a fit at the
    # default level takes about 20x as long (docs/calibration.md, Speed)
    return load_scene('default', {'scene.fidelity': 'paper'})


def _start(scene, names):
    """Every parameter 2x off, alternately above and below."""
    return {name: getattr(scene.physics, name) * (2.0 if i % 2 == 0 else 0.5)
            for i, name in enumerate(names)}


@pytest.fixture(scope='module')
def fitted(truth):
    log = synthetic_measurement(truth, step_and_sine(2.0, truth.dt), noise=0.01, seed=3)
    names = [*WELL_IDENTIFIED, NOT_IDENTIFIED]
    return det_sim_ros.fit([log], names, scene=truth, start=_start(truth, names),
                           parallel='threads')


def test_well_identified_parameters_come_back_within_2_percent_and_their_intervals(
        truth, fitted):
    assert fitted.converged, fitted.message
    for estimate in fitted.estimates:
        if estimate.name not in WELL_IDENTIFIED:
            continue
        true = getattr(truth.physics, estimate.name)
        assert estimate.identified, (estimate.name, estimate.flags)
        assert abs(estimate.value / true - 1.0) <= 0.02, (estimate.name, estimate.value, true)
        assert estimate.lower95 <= true <= estimate.upper95, (estimate.name, estimate, true)
        assert 0.0 < estimate.relative_se < 0.01


def test_a_parameter_the_log_cannot_identify_is_flagged_without_an_interval(fitted):
    (leak,) = [e for e in fitted.estimates if e.name == NOT_IDENTIFIED]
    assert not leak.identified and 'rank-deficient' in leak.flags[0]
    assert math.isinf(leak.se) and leak.upper95 == math.inf
    assert fitted.flagged == [NOT_IDENTIFIED]
    assert f'WARNING {NOT_IDENTIFIED}' in fitted.report()
    assert leak.value == leak.start   # kept: it does not move the residual


def test_the_report_holds_the_result_numbers(fitted):
    text = fitted.report()
    for estimate in fitted.estimates:
        assert f'{estimate.value:.5g}' in text
    (key,) = fitted.rms_after
    assert fitted.rms_after[key] < 0.2 * fitted.rms_before[key]
    # at the optimum the residual is the noise: 1 % of the stroke
    assert fitted.residual_variance == pytest.approx(1.0, rel=0.1)
    assert 'correlation matrix' in text and len(fitted.starts) == 3


def test_a_start_on_the_other_branch_does_not_win(truth):
    """
    Check that a start that snaps the beam to its other state is not the answer.

    A modulus 0.3x the true one snaps the beam through in the step; the search from there
    goes the wrong way; another start finds the true one.
    """
    log = synthetic_measurement(truth, step_and_sine(1.0, truth.dt), noise=0.01, seed=4)
    result = det_sim_ros.fit([log], ['Y'], scene=truth, start={'Y': truth.physics.Y * 0.3},
                             bounds={'Y': (0.1 * truth.physics.Y, None)}, parallel='serial')
    assert abs(result.values['Y'] / truth.physics.Y - 1.0) <= 0.02
    given, *others = result.starts
    assert given.cost > 10 * min(s.cost for s in others)


def test_the_sensitivities_are_the_same_on_threads_and_serially(truth):
    from det_sim_ros.calibration.parameters import fit_parameters, to_z
    log = synthetic_measurement(truth, step_and_sine(0.3, truth.dt), noise=0.01, seed=5)
    parameters = fit_parameters(['Y', 'eta_b'], truth)
    problem = problem_module.Problem(truth, [log], parameters)
    z = to_z(parameters, [p.start for p in parameters])
    f0 = problem.residual(z)
    columns = []
    for kind in ('serial', 'threads'):
        evaluator = problem_module.Evaluator(problem, kind, 2)
        columns.append(problem.jacobian(z, f0, evaluator))
        evaluator.close()
    assert columns[0].tobytes() == columns[1].tobytes()
    assert abs(columns[0]).sum() > 0
