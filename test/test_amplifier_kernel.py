"""
The compiled amplifier against its numpy reference, to round-off.

Random states that put each DET's amplifier in every law (v_a following, slewing up or down,
held; the current linear or at either limit): the right-hand side (also in the exponential
methods' coordinates), the outputs, the stiff rates and one step of two exponential methods.
"""

from det_sim_ros.physics import reference
from det_sim_ros.physics.model import build_model
from det_sim_ros.physics.statics import initial_state
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.integrators import get_method, make_stepper, StepControl
import numpy as np
import pytest

SCENES = {
    'single, every knob': ('default', {'amplifier.bandwidth': 2.0e3, 'amplifier.slew_rate':
                                       1.0e6, 'amplifier.current_limit': 2.0e-3}),
    'single, limit only': ('default', {'amplifier.current_limit': 1.0e-3}),
    'plate, per DET': ('plate', {'dets.left.bandwidth': 5.0e2, 'dets.left.current_limit': 3e-3,
                                 'dets.right.slew_rate': 2.0e6, 'dets.right.current_limit':
                                 1.0e-3}),
}


@pytest.fixture(scope='module', params=sorted(SCENES))
def model(request):
    name, overrides = SCENES[request.param]
    return build_model(load_scene(name, overrides))


def _random_state(model, rng):
    """Return a state and input with each DET's laws drawn at random (a beam in motion)."""
    a = model.arrays
    x = initial_state(model)
    for c in range(a.n_cells):
        s = a.cell_slice(c)
        amp = 3e-3 / abs(model.bases[c].reference_row()[0])
        x[s] = amp * rng.uniform(0.5, 1.5) * np.eye(s.stop - s.start)[0]
        x[a.n_q + s.start:a.n_q + s.stop] = amp * 20.0 * rng.standard_normal(s.stop - s.start)
    nc, i_qp = a.n_cells, 2 * a.n_q + a.n_cells * a.creep
    if a.creep:
        x[2 * a.n_q:i_qp] = 1e-3 * rng.standard_normal(nc)
    u = rng.uniform(500.0, 2500.0, nc)
    lags = (a.amp_tau > 0.0) | (a.amp_slew > 0.0)
    band = np.where(a.amp_slew * a.amp_tau > 0.0, a.amp_slew * a.amp_tau, 50.0)
    v_a = np.where(lags, u - band * rng.uniform(-3.0, 3.0, nc), u)
    if a.amp_state:
        x[i_qp + nc:i_qp + 2 * nc] = v_a
    lam = (a.length - reference.kinematics(a, x).y) / a.l0
    limit = np.where(a.amp_imax > 0.0, a.amp_imax, 1e-3)
    v_p = v_a - a.Rs * limit * rng.uniform(-2.0, 2.0, nc)
    x[i_qp:i_qp + nc] = a.C0 * lam ** 2 * v_p
    return x, u


def _close(actual, expected, rel=1e-10):
    """
    Assert each component agrees to ``rel`` of itself or of 1e-6 of the vector's largest.

    The random states are moderate (|w'| well below 1, mass matrices of condition 1 to 3e2),
    where both codes carry a few hundred eps of each term: the largest deviation seen is 1.4e-12
    (70x inside 1e-10), the same with OpenBLAS's Haswell, SkylakeX and Nehalem kernels
    (OPENBLAS_CORETYPE), numpy's baseline SIMD, the kernel at -O0 and without AVX2. A steep
    state needs the conditioning-derived bound of test_exact_quadrature instead.
    """
    scale = np.maximum(np.abs(expected), np.max(np.abs(expected)) * 1e-6)
    worst = np.max(np.abs(actual - expected) / np.maximum(scale, 1e-300))
    assert worst <= rel, f'relative deviation {worst:.2e}'


def test_rhs_outputs_and_stiff_rates_match_the_reference_in_every_law(model):
    rng = np.random.default_rng(29)
    a = model.arrays
    seen = set()
    for _ in range(60):
        x, u = _random_state(model, rng)
        laws = reference.amplifier_laws(a, x, u)
        seen.update(('v', law) for law in laws[0])
        seen.update(('i', law) for law in laws[1])
        dx = np.empty(model.n_states)
        status, p_in, p_diss = model.kernel.rhs(x, u, dx)
        assert status == 0
        expected, ref_in, ref_diss = reference.rhs(a, x, u)
        _close(dx, expected)
        # (v_out = v_p + Rs i at the limit may nearly cancel: the scale is kV mA)
        assert p_in == pytest.approx(ref_in, rel=1e-10, abs=1e-9)
        assert p_diss == pytest.approx(ref_diss, rel=1e-10, abs=1e-9)
        _close(model.stiff_rates(x), reference.stiff_rates(a, x, laws))
        _close(model.output_vector(x, u), reference.outputs(a, x, u), rel=1e-9)   # P_in
        model.kernel.rhs(x, u, dx, True)   # laws read from the slots as given
        _close(dx, reference.rhs(a, x, u, True, reference.amplifier_laws(a, x, u))[0])
    expected_laws = {('i', 'linear'), ('i', '+limit'), ('i', '-limit')}
    if a.amp_state:
        expected_laws |= {('v', 'up'), ('v', 'down')}
    assert expected_laws <= seen


@pytest.mark.parametrize('name', ['exp_euler', 'etdrk4'])   # the reference's phi are slow
def test_one_step_of_an_exponential_method_matches_the_reference(model, name):
    rng = np.random.default_rng(3)
    method = get_method(name)
    stepper = make_stepper(model, method, StepControl(1), 1e-3)
    for h in (5e-5,):
        x, u = _random_state(model, rng)
        model.f(0.0, x, u)        # the laws at the step's start, as the period sets them
        ours = x.copy()
        assert stepper.advance(ours, u, h, 1) == 0
        _close(ours, reference.step(model.arrays, method, x, u, h), rel=1e-9)
