"""
The compiled kernel against the numpy reference, to round-off.

The reference is det_sim_ros/physics/reference.py; the checks run on random states of every
scene kind. Also: batch stepping per coupled group; named-record input.
"""

import dataclasses
import math

from det_sim_ros.core import kernel
from det_sim_ros.physics import reference, reference_linearized
from det_sim_ros.physics.model import build_model
from det_sim_ros.physics.statics import initial_state
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.integrators import get_method, make_stepper, METHODS, StepControl
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
import pytest

# the paper's one-term model: the fidelity is not the subject of these tests, and its
# numbers are the ones pinned here
PAPER = {'scene.fidelity': 'paper'}

SCENES = {
    'single paper rc creep': ('default', PAPER),
    'single paper ideal': ('default', {**PAPER, 'scene.source': 'ideal'}),
    'single paper no creep': ('default', {**PAPER, 'scene.creep': False}),
    'single paper no monitor': ('default', {**PAPER, 'scene.monitor_power': False,
                                            'scene.beam': 'simply_supported'}),
    'single consistent n3': ('default', {'scene.fidelity': 'consistent', 'scene.n_ritz': 3}),
    'single consistent n1': ('default', {'scene.fidelity': 'consistent', 'scene.n_ritz': 1}),
    'single exact n3 ss': ('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 3,
                                       'scene.beam': 'simply_supported'}),
    'single exact n1 ideal': ('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 1,
                                          'scene.source': 'ideal'}),
    'plate': ('plate', PAPER),
    'plate consistent n2 ideal': ('plate', {'scene.fidelity': 'consistent', 'scene.n_ritz': 2,
                                            'scene.source': 'ideal'}),
    'array 3 spread': ('array', {**PAPER, 'structure.copies': 3}),
    'array 3 exact n2 no creep': ('array', {'structure.copies': 3, 'scene.fidelity': 'exact',
                                            'scene.n_ritz': 2, 'scene.creep': False}),
}


def _random_state(model, rng):
    """
    Return a random state and input: a buckled beam in motion.

    q near the rest deflection with every mode excited, a velocity, creep strain and a charge
    near C0 v.
    """
    a = model.arrays
    x = initial_state(model)
    for c in range(a.n_cells):
        s = a.cell_slice(c)
        r = s.stop - s.start
        amp = 3e-3 / abs(model.bases[c].reference_row()[0])
        x[s] = amp * (rng.uniform(0.5, 1.5) * np.eye(r)[0] + 0.05 * rng.standard_normal(r))
        x[a.n_q + s.start:a.n_q + s.stop] = amp * 20.0 * rng.standard_normal(r)
    i = 2 * a.n_q
    if a.creep:
        x[i:i + a.n_cells] = 1e-3 * rng.standard_normal(a.n_cells)
        i += a.n_cells
    if a.rc_source:
        x[i:i + a.n_cells] = a.C0 * rng.uniform(500.0, 2500.0, a.n_cells)
        i += a.n_cells
    if a.power_monitor:
        x[i:i + 2] = rng.uniform(0.0, 1e-3, 2)
    u = rng.uniform(0.0, 3000.0, a.n_cells)
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
    scale = np.maximum(np.abs(expected), 1e-300)
    worst = np.max(np.abs(actual - expected) / np.maximum(scale, np.max(np.abs(expected)) * 1e-6))
    assert worst <= rel, f'relative deviation {worst:.2e}'


@pytest.fixture(scope='module', params=sorted(SCENES))
def model(request):
    name, overrides = SCENES[request.param]
    return build_model(load_scene(name, overrides))


def test_rhs_and_outputs_match_the_reference(model):
    rng = np.random.default_rng(7)
    for _ in range(5):
        x, u = _random_state(model, rng)
        dx = np.empty(model.n_states)
        status, p_in, p_diss = model.kernel.rhs(x, u, dx)
        assert status == kernel.OK
        expected, ref_in, ref_diss = reference.rhs(model.arrays, x, u)
        _close(dx, expected)
        assert p_in == pytest.approx(ref_in, rel=1e-10, abs=1e-18)
        assert p_diss == pytest.approx(ref_diss, rel=1e-10, abs=1e-18)
        if model.arrays.rc_source:   # the exponential methods' coordinates
            model.kernel.rhs(x, u, dx, True)
            _close(dx, reference.rhs(model.arrays, x, u, quasi_static=True)[0])
        _close(model.output_vector(x, u), reference.outputs(model.arrays, x, u))
        _close(model.stiff_rates(x), reference.stiff_rates(model.arrays, x))


@pytest.mark.parametrize('name', sorted(METHODS))
def test_one_step_of_every_method_matches_the_reference(model, name):
    """
    Check that one step of every method matches the reference.

    One step of each method: the compiled core (period() with one fixed step, so arrays step
    group by group) against the reference step on the whole model.
    """
    method = get_method(name)
    rng = np.random.default_rng(11)
    x, u = _random_state(model, rng)
    h = 2e-5
    stepper = make_stepper(model, method, StepControl(1), h)   # one step of h per period
    ours = x.copy()
    out = np.empty(len(model.output_names))
    assert stepper.period(ours, u, u, out) == kernel.OK
    if method.kind.name == 'linearized':   # the dense linear part taken at x, as the kernel
        A = reference_linearized.mechanical_jacobian(model.arrays, x, u)
        expected = reference_linearized.step_linearized(model.arrays, method, x, u, h, A)[0]
    else:
        expected = reference.step(model.arrays, method, x, u, h)
    power = slice(model.n_states - 2 * model.arrays.power_monitor, model.n_states)
    # (the energy book of an array is summed group by group: compare it to its own scale)
    _close(np.delete(ours, np.r_[power]), np.delete(expected, np.r_[power]), rel=1e-9)
    if model.arrays.power_monitor:
        assert np.allclose(ours[power], expected[power], rtol=1e-9, atol=1e-15)


def test_reference_phi_functions_reach_round_off():
    """
    Check that the reference's phi functions reach round-off.

    The reference's phi_k (matrix exponential) against the series (small |z|) and the closed
    form (e^z - sum_{m<k} z^m/m!) / z^k (large |z|, where it does not cancel).
    """
    for z in (-1e-8, -1e-3, -0.3, -0.49, -0.51, -2.0, -40.0, 0.2):
        for k in range(5):
            if abs(z) < 1.0:
                expected = sum(z ** m / math.factorial(m + k) for m in range(30))
            else:
                expected = ((math.exp(z) - sum(z ** m / math.factorial(m) for m in range(k)))
                            / z ** k)
            assert reference.phi(k, z) == pytest.approx(expected, rel=1e-12), (k, z)


@pytest.mark.parametrize('name', ['exp_euler', 'etd2', 'etdrk4', 'lawson4'])
@pytest.mark.parametrize('h', [1e-7, 2e-5, 2e-4, 1e-3])
def test_exponential_steps_match_the_reference_at_every_stiffness(name, h):
    """
    Check that exponential steps match the reference at every stiffness.

    h L from -0.004 to -35 on the charge: the kernel's phi_k branches (series with the downward
    recurrence below |z| = 0.5, the upward recurrence above) in a real step.
    """
    model = build_model(load_scene('default', PAPER))
    x, u = _random_state(model, np.random.default_rng(5))
    stepper = make_stepper(model, get_method(name), StepControl(1), h)
    ours = x.copy()
    assert stepper.advance(ours, u, h, 1) == kernel.OK
    _close(ours, reference.step(model.arrays, get_method(name), x, u, h), rel=1e-9)


def test_stepping_is_deterministic():
    """Check that two simulators, and one reset, repeat a run exactly: same inputs, same bits."""
    scene = load_scene('default', PAPER)
    volts = lambda t: 3000.0 * (0.1 <= t < 0.3)  # noqa: E731
    a = simulate(scene, volts, 0.4)
    sim = Simulator(scene)
    b = simulate(sim, volts, 0.4)
    sim.reset()
    c = simulate(sim, volts, 0.4)
    for r in (b, c):
        assert np.array_equal(a.x, r.x)
        assert all(np.array_equal(a[n], r[n]) for n in a.outputs)


def test_array_copies_keep_their_own_step_counts():
    """
    Check that the copies of an array keep their own step counts.

    One snapping copy does not force its step count on the others: each coupled group adapts
    alone, so every copy of an array steps exactly like that copy alone.
    """
    copies = 4
    scene = load_scene('array', {**PAPER, 'structure.copies': copies, 'structure.spread': 0.0})
    settle, snap = 1500, 20          # periods: settle at 0 V, then det0 alone switches to 3 kV
    volts = np.zeros((settle + snap, copies))
    volts[settle:, 0] = 3000.0
    sim = Simulator(scene)
    simulate(sim, volts[:settle], settle * sim.dt)
    run = simulate(sim, volts[settle:], snap * sim.dt)
    counts = sim.stepper.group_substeps()
    assert len(set(counts[1:])) == 1        # the resting copies go on at their own count
    assert counts[0] > 2 * max(counts[1:])  # the snapping one takes many more
    for det, column in (('det0', 0), ('det1', 1)):
        alone = Simulator(scene.cell_scene(column))
        simulate(alone, volts[:settle, column], settle * sim.dt)
        own = simulate(alone, volts[settle:, column], snap * sim.dt)
        assert np.array_equal(run[f'q[{det}]'], own['q'])
        assert np.array_equal(run[f'y[{det}]'], own['y'])


@pytest.mark.parametrize('source', ['rc', 'ideal'])
@pytest.mark.parametrize('periods', [200, 45])   # whole chunks of 32 periods, and a part one
def test_batch_results_do_not_depend_on_threads(source, periods):
    """
    Check that batch results do not depend on the number of threads.

    States, outputs and the energy book (input-jump bookkeeping included) are bit-identical
    whether the copies step on one thread (per period) or on two (chunks of periods).
    """
    scene = load_scene('array', {**PAPER, 'structure.copies': 6, 'scene.source': source})
    rng = np.random.default_rng(3)
    volts = np.repeat(rng.uniform(0, 3000, (5, 6)), 40, axis=0)[:periods]
    runs = []
    for threads in (1, 2):
        sim = Simulator(scene, threads=threads)
        runs.append(simulate(sim, volts, periods * sim.dt))
    assert np.array_equal(runs[0].x, runs[1].x)
    assert all(np.array_equal(runs[0][n], runs[1][n]) for n in runs[0].outputs)
    assert runs[0].x[-1, -1] > 0.0           # the monitor booked dissipation
    stepped = Simulator(scene)               # and the node's path, period by period
    for k in range(periods):
        stepped.set_input(volts[k].tolist())
        stepped.step()
    assert np.array_equal(stepped.x, runs[1].x[-1])


def test_kernel_reads_named_fields_and_checks_them():
    model = build_model(load_scene('default', PAPER))
    # a field of the wrong type or size is refused with its name, not read out of bounds
    bad = dataclasses.replace(model.arrays, ref=np.zeros(3))
    with pytest.raises(ValueError, match='ref'):
        kernel.Model(bad)
    bad = dataclasses.replace(model.arrays, cell_q=model.arrays.cell_q.astype(float))
    with pytest.raises(TypeError, match='cell_q'):
        kernel.Model(bad)
    with pytest.raises(ValueError, match='x: expected'):
        model.kernel.outputs(np.zeros(3), np.zeros(1), np.zeros(len(model.output_names)))
    with pytest.raises(AttributeError, match='n_q'):
        kernel.Model(object())


@pytest.mark.parametrize('overrides', [PAPER, {**PAPER, 'scene.source': 'ideal'},
                                       {**PAPER, 'integrator.substeps': 4}])
def test_a_failing_period_leaves_the_last_good_state(overrides):
    """
    Check that a failing period leaves the last good state.

    Simulator.step() steps x in place; a period that leaves the domain (here the beam ends
    meet, lambda <= 0, within the period) must leave x exactly at the period's start.
    """
    from det_sim_ros.physics.model import ModelDomainError
    sim = Simulator(load_scene('default', overrides))
    a = sim.model.arrays
    x0 = initial_state(sim.model)
    # near the end of the domain and moving fast towards it: y -> l within 1 ms
    x0[0] = 0.97 * np.sqrt(a.length[0] / a.c2[0])
    x0[1] = 5000.0 * x0[0]   # (slower: the adaptive stepper finds the beam turns back)
    sim.reset(x0)
    before = sim.x.copy()
    with pytest.raises(ModelDomainError, match='lambda'):
        sim.step()
    assert np.array_equal(sim.x, before)
    assert sim.fault and sim.k == 0
    assert all(np.isfinite(v) for v in sim.outputs().values())   # what a node publishes next


def test_an_arena_one_array_past_its_bound_is_a_clear_error():
    """Every kernel object's arena holds ARENA_SLOTS arrays; one more is refused, not written."""
    from det_sim_ros.core.kernel import ARENA_SLOTS, keep_owned_probe
    assert ARENA_SLOTS >= 40   # the Model with the amplifier keeps 38
    assert keep_owned_probe(ARENA_SLOTS) == ARENA_SLOTS
    with pytest.raises(RuntimeError, match=f'keeps more than {ARENA_SLOTS} arrays'):
        keep_owned_probe(ARENA_SLOTS + 1)
    assert keep_owned_probe(3) == 3   # nothing was left half-kept
