"""
The dense linear part of 'etdrk4_linearized' against its numpy references.

The kernel's matrix phi functions (matrix_phi.c) against det_sim_ros.physics.matrix_phi (the same
algorithm) and the augmented matrix exponential; its Jacobian against complex steps; one step
and its error estimate against det_sim_ros.physics.reference_linearized.step_linearized;
determinism (runs, resets, threads); the step count following the error, not the stiff beam
modes; the amplified circuit under the linearized method.
"""

import os

from det_sim_ros.core import kernel
from det_sim_ros.io.log import Recorder
from det_sim_ros.io.replay import resimulate, simulate_to_log
from det_sim_ros.physics import matrix_phi, reference_linearized
from det_sim_ros.physics.model import build_model
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.integrators import get_method, make_stepper, StepControl
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
import pytest

from test_kernel import _random_state

METHOD = get_method('etdrk4_linearized')
EXACT = {'scene.fidelity': 'exact', 'scene.beam': 'simply_supported'}


def _model(n_ritz=3, **overrides):
    return build_model(load_scene('default', {**EXACT, 'scene.n_ritz': n_ritz, **overrides}))


def _jacobian(model, x, u):
    stepper = make_stepper(model, METHOD, StepControl(1), 1e-3)
    A = np.empty((2 * model.arrays.n_q,) * 2)
    assert stepper.linear_part(x, u, A) == kernel.OK
    return A


def _kernel_phis(Z, scale, k_max):
    full = np.zeros((k_max + 1,) + Z.shape)
    half = np.zeros_like(full)
    kernel.matrix_phis(np.ascontiguousarray(Z), scale, full, half)
    return full, half


def _matrices():
    """Random matrices of several norms and a stiff beam Jacobian (exact, 5 Ritz terms)."""
    rng = np.random.default_rng(3)
    model = _model(5)
    x, u = _random_state(model, rng)
    out = [(rng.standard_normal((n, n)), scale) for n in (1, 4, 7)
           for scale in (1e-3, 0.3, 40.0)]
    A = _jacobian(model, x, u)
    return out + [(A, h) for h in (1e-6, 1e-4, 1e-3)]


@pytest.mark.parametrize('case', range(12))
def test_matrix_phis_match_the_numpy_reference_and_the_augmented_exponential(case):
    """Check the kernel's phi_k(scale Z), phi_k(scale Z / 2), k <= 3, to round-off."""
    Z, scale = _matrices()[case]
    full, half = _kernel_phis(Z, scale, 3)
    ref_full, ref_half = matrix_phi.matrix_phis(Z, scale, 3)
    exact = matrix_phi.augmented_phis(scale * Z, 3)
    exact_half = matrix_phi.augmented_phis(0.5 * scale * Z, 3)
    for k in range(4):
        size = np.abs(exact[k]).max()
        # the numpy port: the same operations, BLAS's summation order
        assert np.abs(full[k] - ref_full[k]).max() <= 1e-12 * size, k
        assert np.abs(half[k] - ref_half[k]).max() <= 1e-12 * np.abs(exact_half[k]).max(), k
        # scaling and squaring against scipy's expm of the augmented matrix (the beam
        # Jacobians have norms ~1e6 and condition numbers ~1e4: 1e-9 of the largest entry)
        assert np.abs(full[k] - exact[k]).max() <= 1e-9 * size, k
        assert np.abs(half[k] - exact_half[k]).max() <= 1e-9 * np.abs(exact_half[k]).max(), k


@pytest.mark.parametrize('overrides', [{}, {'scene.source': 'ideal'}, {'scene.creep': False}])
def test_jacobian_matches_complex_steps(overrides):
    """Check the forward-difference Jacobian against the reference's complex steps (1e-6)."""
    model = _model(3, **overrides)
    x, u = _random_state(model, np.random.default_rng(11))
    A = _jacobian(model, x, u)
    exact = reference_linearized.mechanical_jacobian(model.arrays, x, u)
    for j in range(A.shape[1]):
        assert np.abs(A[:, j] - exact[:, j]).max() <= 1e-6 * np.abs(exact[:, j]).max() + 1e-6


@pytest.mark.parametrize('h', [1e-6, 1e-4, 1e-3])
@pytest.mark.parametrize('overrides', [{}, {'scene.source': 'ideal', 'scene.creep': False}])
def test_linearized_step_matches_the_reference(h, overrides):
    """Check one step and its error estimate against the reference, to round-off."""
    model = _model(3, **overrides)
    x, u = _random_state(model, np.random.default_rng(7))
    A = _jacobian(model, x, u)
    stepper = make_stepper(model, METHOD, StepControl(1), h)
    ours = x.copy()
    stepper.estimate = 0.0
    assert stepper.advance(ours, u, h, 1) == kernel.OK
    expected, error = reference_linearized.step_linearized(model.arrays, METHOD, x, u, h, A)
    scale = np.maximum(np.abs(expected), np.abs(x)) + 1e-300
    assert np.all(np.abs(ours - expected) <= 1e-9 * scale + 1e-18)
    a, nq = model.arrays, model.arrays.n_q
    weights = np.concatenate([np.full(nq, 1.0 / a.length[0]),
                              np.full(nq, model.scene.dt / a.length[0])])
    assert stepper.estimate == pytest.approx(np.max(np.abs(error) * weights), rel=1e-6)


def _volts(t):
    return 3000.0 * (0.05 <= t < 0.15)


def test_linearized_runs_repeat_bit_for_bit_with_any_thread_count():
    """Check same inputs, same bits: two runs, a reset, and an array on 1 and 2 threads."""
    scene = load_scene('default', {**EXACT, 'scene.n_ritz': 4,
                                   'integrator.method': 'etdrk4_linearized'})
    a = simulate(scene, _volts, 0.2)
    sim = Simulator(scene)
    b = simulate(sim, _volts, 0.2)
    sim.reset()
    c = simulate(sim, _volts, 0.2)
    for r in (b, c):
        assert np.array_equal(a.x, r.x)
    array = load_scene('array', {'structure.copies': 3, 'scene.fidelity': 'exact',
                                 'scene.n_ritz': 2, 'integrator.method': 'etdrk4_linearized'})
    runs = [simulate(Simulator(array, threads=t), _volts, 0.2) for t in (1, 2)]
    assert np.array_equal(runs[0].x, runs[1].x)


def test_a_logged_linearized_run_resimulates_exactly(tmp_path):
    """Check that re-running a logged run of the linearized method gives the logged bits."""
    path = os.path.join(tmp_path, 'run.mcap')
    scene = load_scene('default', {**EXACT, 'scene.n_ritz': 3})
    sim = Simulator(scene)
    assert sim.method.name == 'etdrk4_linearized'
    with Recorder(path, scene, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, {0: [0.0], 20: [3000.0], 120: [1000.0]}, 200)
    result = resimulate(path)
    assert result.steps == 200
    assert result.max_deviation and max(result.max_deviation.values()) == 0.0


def test_step_count_follows_the_error_not_the_stiff_modes():
    """
    Check the linearized steps meet the tolerance in fewer steps than the explicit stages.

    Exact kinematics with 5 Ritz terms, a snap-through and back: the explicit stages of
    'etdrk4' need at least 78 steps per 1 ms period for the stiffest beam mode; the linearized
    method's count follows its error estimate (0.59 x the steps here, most of them in the
    ringing after the snaps) and its deflection stays within the tolerance of a tightly solved
    run.
    """
    overrides = {**EXACT, 'scene.n_ritz': 5, 'integrator.tolerance': 1e-6}
    runs = {}
    for name, method, tolerance in (('linearized', 'etdrk4_linearized', 1e-6),
                                    ('explicit', 'etdrk4', 1e-6), ('tight', 'etdrk4', 1e-9)):
        sim = Simulator(load_scene('default', {**overrides, 'integrator.method': method,
                                               'integrator.tolerance': tolerance}))
        runs[name] = (sim, simulate(sim, _volts, 0.25))
    y_tight = runs['tight'][1]['y']
    stroke = np.ptp(y_tight)
    assert np.max(np.abs(runs['linearized'][1]['y'] - y_tight)) <= 1e-6 * stroke
    assert runs['linearized'][0].steps_taken < 0.7 * runs['explicit'][0].steps_taken


def test_the_amplified_circuit_under_the_linearized_method_meets_the_tolerance():
    # the lab amplifier preset (every law: bandwidth, slew rate, current limit) on the default
    # scene, against the plain etdrk4 at a 1000x tighter tolerance
    def run(method, tolerance):
        sim = Simulator(load_scene('amplifier_lab', {'integrator.method': method,
                                                     'integrator.tolerance': tolerance}))
        y = []
        for k in range(1200):
            sim.set_input([3000.0 if 200 <= k < 800 else 0.0])
            sim.step()
            y.append(sim.outputs()['y'])
        assert not sim.fault
        return sim, np.array(y)

    sim, y = run('etdrk4_linearized', 1e-6)
    _, y_ref = run('etdrk4', 1e-9)
    assert np.ptp(y_ref) > 1e-3                       # it snapped through and back
    assert np.abs(y - y_ref).max() < 1e-6 * np.ptp(y_ref)


def test_auto_picks_the_linearized_method_for_amplified_scenes_too():
    def picked(scene, overrides=None):
        return Simulator(load_scene(scene, overrides or {})).method.name

    assert picked('default') == 'etdrk4_linearized'
    assert picked('amplifier_lab') == 'etdrk4_linearized'        # bandwidth 40 kHz
    assert picked('amplifier_dcdc') == 'etdrk4_linearized'       # bandwidth 20 Hz
    assert picked('amplifier_lab', {'scene.fidelity': 'paper'}) == 'etdrk4'


def test_a_new_command_every_period_through_the_lab_amplifier_takes_few_more_steps():
    """
    Check the lab amplifier's steps per period stay within 3x the same scene's without it.

    A controller's command, new every period (1.5 kV + 1 kV sin(2 pi 5 Hz t)), under the
    linearized method: the bandwidth's output transient after each command is integrated
    exactly with the charge (core/_csrc/stepping/coupling.c), so the steps need not stay below its
    4 us time constant (measured: 1.7x the steps without the amplifier; 28x with the coupling
    left to the explicit stages).
    """
    def steps_per_period(scene):   # at the tolerance the 1.7x was measured at
        sim = Simulator(load_scene(scene, {'integrator.tolerance': 1e-6}))
        for k in range(150):
            sim.set_input([1500.0 + 1000.0 * np.sin(2.0 * np.pi * 5.0 * k * 1e-3)])
            sim.step()
        assert not sim.fault
        return sim.steps_taken / 150

    assert steps_per_period('amplifier_lab') <= 3.0 * steps_per_period('default')
