"""Steppers: order on analytic problems, determinism, zero-order hold, stability stress suite."""

import dataclasses

from det_sim_ros.physics.model import build_model, ModelDomainError
from det_sim_ros.physics.statics import initial_state
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim import integrators
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
import pytest

# the paper's start (q = q0, released): these tests exercise the buckling transient
# the paper's one-term model: the fidelity is not the subject of these tests, and its
# numbers are the ones pinned here
PAPER = {'scene.fidelity': 'paper'}
RELEASED = {'scene.initial_state': 'released', **PAPER}

ORDERS = {'euler': 1, 'midpoint': 2, 'rk3': 3, 'rk4': 4, 'dp5': 5, 'lawson4': 4,
          'lawson5': 5, 'exp_euler': 1, 'etd2': 2, 'etdrk4': 4, 'etdrk4_linearized': 4}


def test_every_method_is_declared_with_its_order():
    assert set(integrators.METHODS) == set(ORDERS)
    for name, method in integrators.METHODS.items():
        assert method.order == ORDERS[name]
        c, terms = method.arrays()
        assert np.all(np.diff(terms[:, 0]) >= 0)      # grouped by stage row for the core
        # consistency: the weights of b sum to 1 at L = 0 (phi_k(0) = 1/k!)
        b = terms[terms[:, 0] == method.n_stages]
        from math import factorial
        total = sum(w / factorial(int(k)) if k >= 0 else w for _, _, k, _, w in b)
        assert total == pytest.approx(1.0, abs=1e-14), name


def test_dormand_prince_table_is_scipys():
    """Check that the written-out DP5 table equals scipy's RK45 coefficients to the last bit."""
    from scipy.integrate import RK45
    dp5 = integrators.get_method('dp5')
    c, terms = dp5.arrays()
    assert np.array_equal(c, RK45.C)
    a = np.zeros((6, 6))
    b = np.zeros(6)
    for i, j, _, _, w in terms:
        if int(i) == 6:
            b[int(j)] = w
        else:
            a[int(i), int(j)] = w
    assert np.array_equal(a[:, :5], RK45.A) and np.array_equal(b, RK45.B)
    assert np.array_equal(np.array(dp5.embedded), RK45.E)


def _linear_charge_error(method, n_steps):
    """Return the error of a small oscillation of the ideal-source model against a finer run."""
    scene = load_scene('default', {**RELEASED,
                                   'source': 'ideal', 'creep': False, 'monitor_power': False,
                                   'eps_b': 0.2, 'rate_hz': 100.0})
    model = build_model(scene)
    x0 = initial_state(model)
    x0[0] = 0.0125

    def run(name, n):
        x = x0.copy()
        status = integrators.advance(x, np.array([1000.0]), model,
                                     integrators.get_method(name), 0.02 / n, n)
        assert status == 0
        return x
    ref = run('lawson5', 4000)
    return np.max(np.abs(run(method, n_steps) - ref) / np.array([0.01, 1.0]))


@pytest.mark.parametrize('name', sorted(ORDERS))
def test_convergence_order_on_the_non_stiff_model(name):
    """
    Check that every method shows its order on a non-stiff scene.

    On a non-stiff scene the exponential methods reduce to RK.
    """
    e1, e2 = _linear_charge_error(name, 60), _linear_charge_error(name, 120)
    observed = np.log2(e1 / e2)
    assert ORDERS[name] - 0.3 <= observed <= ORDERS[name] + 0.8   # pre-asymptotic: above


@pytest.mark.parametrize('name', ['exp_euler', 'etd2', 'etdrk4', 'lawson4', 'lawson5'])
def test_exponential_methods_solve_pure_charge_relaxation_exactly(name):
    """
    Check that exponential methods solve pure charge relaxation exactly.

    Frozen beam (huge mass): q_p follows the exact RC charging curve for any step size.
    """
    scene = load_scene('default', {**RELEASED, 'm': 1e6, 'rho_b': 1e9, 'creep': False,
                                   'monitor_power': False})
    model = build_model(scene)
    x = initial_state(model)
    h = 1e-3   # ~30 electrical time constants per step
    status = integrators.advance(x, np.array([3000.0]), model,
                                 integrators.get_method(name), h, 1)
    assert status == 0
    p = scene.physics
    cap = model.outputs(initial_state(model), [0.0])['C']
    tau = cap * p.Rs * p.Rp / (p.Rs + p.Rp)
    exact = cap * 3000.0 * p.Rp / (p.Rs + p.Rp) * (1 - np.exp(-h / tau))
    assert x[2] == pytest.approx(exact, rel=1e-6)


def test_explicit_rk4_diverges_where_the_exponential_core_is_stable():
    """
    Check that explicit RK4 diverges where the exponential core is stable.

    The reason for the exponential core: the charge pole Rs C ~ 30 us.
    """
    scene = load_scene('default', RELEASED)
    with pytest.raises(ModelDomainError):
        simulate(scene, lambda t: 3000.0, 0.05, method='rk4', substeps=1)
    r = simulate(scene, lambda t: 3000.0, 0.05, method='lawson5', substeps=1)
    assert np.all(np.isfinite(r['q_p']))


def test_determinism_bit_identical():
    a = simulate(load_scene('default', RELEASED), lambda t: 3000.0 * (t >= 0.1), 0.3)
    b = simulate(load_scene('default', RELEASED), lambda t: 3000.0 * (t >= 0.1), 0.3)
    assert np.array_equal(a.x, b.x)


def test_zero_order_hold_and_time_grid():
    sim = Simulator(load_scene('default', {**RELEASED, 'rate_hz': 400.0}))
    sim.set_input([1500.0])
    for _ in range(1000):
        sim.step()
    assert sim.t == 1000 * (1 / 400.0)        # k * dt, not an accumulated sum
    assert sim.u.tolist() == [1500.0]
    before = sim.x.copy()
    check = sim.set_input([float('nan')])
    assert not check.accepted and sim.u.tolist() == [1500.0]
    assert np.array_equal(sim.x, before)
    check = sim.set_input([-5.0])
    assert check.accepted and check.clamped and sim.u.tolist() == [0.0]
    assert not sim.set_input([1.0, 2.0]).accepted


def test_auto_step_meets_its_tolerance_on_the_step_scenario():
    """
    Check that the adaptive stepper meets its tolerance on the step scenario.

    The default (adaptive) stepper's error on a 0.5 s piece of the step scenario against a
    fixed run 4x finer than the tolerance's fixed count, in fewer steps than that count.
    """
    scene = load_scene('default', {**RELEASED, 'integrator.tolerance': 1e-6})
    sim = Simulator(scene)
    assert sim.adaptive
    fixed = integrators.choose_substeps(sim.method, sim.dt, 1e-6,
                                        sim.method.kind.beam_rate(sim.model))
    volts = lambda t: 3000.0 * (t >= 0.2)  # noqa: E731
    coarse = simulate(sim, volts, 0.5)
    fine = simulate(scene, volts, 0.5, method=sim.method.name, substeps=4 * fixed)
    stroke = np.ptp(fine['y'])
    assert np.max(np.abs(coarse['y'] - fine['y'])) / stroke <= 1e-6
    # over the whole 'step' scenario (4.5 s, mostly settled) it takes under half those steps
    from det_sim_ros.analysis.scenarios import STEP_END, step_voltage
    sim = Simulator(scene)
    simulate(sim, step_voltage(3000.0), STEP_END)
    assert sim.steps_taken < 0.5 * fixed * sim.k


def _steps_per_period(sim, volts, n):
    counts = []
    for k in range(n):
        sim.set_input([volts(k * sim.dt)])
        before = sim.steps_taken
        sim.step()
        counts.append(sim.steps_taken - before)
    return np.array(counts)


def test_adaptive_step_count_follows_the_dynamics():
    """
    Check that the adaptive step count follows the dynamics.

    Many steps while the beam snaps after the 3 kV step, few once it has settled.
    """
    sim = Simulator(load_scene('default', RELEASED))
    counts = _steps_per_period(sim, lambda t: 3000.0 * (t >= 0.5), 1500)
    settled = counts[1300:].mean()
    snapping = counts[500:520].mean()
    assert snapping > 2.0 * settled
    assert counts.min() >= sim.control.min_substeps >= 1


def test_adaptive_step_repeats_a_period_over_its_tolerance():
    """Check that a period started with too few steps is repeated with more."""
    scene = load_scene('default', {**RELEASED, 'integrator.tolerance': 1e-7})
    sim = Simulator(scene)
    sim.set_input([3000.0])
    for _ in range(30):
        sim.step()
    sim.stepper.substeps = sim.control.min_substeps   # force a bad start
    n_min = sim.substeps
    before = sim.steps_taken
    sim.step()
    assert sim.steps_taken - before > 2 * n_min       # the rejected try plus the repeat
    assert sim.substeps > n_min


@pytest.mark.parametrize('source', ['rc', 'ideal'])
def test_stepping_equals_one_call_bit_for_bit(source):
    """
    Check that stepping period by period equals one compiled call, bit for bit.

    Simulator.set_input/step per period (the node's path, with set_input's fast path for one
    float) and simulate() in one compiled call give the same states, energy book included.
    """
    scene = load_scene('default', {**RELEASED,
                                   'integrator.tolerance': 1e-7, 'scene.source': source})
    stepped = Simulator(scene)
    volts = lambda t: 3000.0 * (t >= 0.01) - 1500.0 * (t >= 0.05)  # noqa: E731
    _steps_per_period(stepped, volts, 100)
    at_once = simulate(scene, volts, 0.1)
    assert np.array_equal(stepped.x, at_once.x[-1])
    assert stepped.x[-1] > 0.0    # the monitor booked dissipation


@pytest.mark.parametrize('name', ['etdrk4', 'rk4', 'dp5'])
def test_embedded_error_estimate_has_the_order_of_its_pair(name):
    """
    Check that the embedded error estimate scales with the order of its pair.

    The estimate h sum e_j N_j is the local error of the embedded solution: it scales as
    h^(p+1) with p the embedded order (RK4(3) FSAL pair: h^4; Dormand-Prince 5(4): h^5).
    """
    sim = Simulator(load_scene('default', {**RELEASED, 'scene.source': 'ideal'}), method=name)
    method = sim.method
    x0 = initial_state(sim.model)
    x0[0], x0[1] = 4e-3, 0.3          # a buckled beam in motion
    estimates = []
    for h in (2e-5, 1e-5):
        sim.stepper.estimate = 0.0
        x = x0.copy()
        assert sim.stepper.advance(x, np.array([1500.0]), h, 1) == 0
        estimates.append(sim.stepper.estimate)
    ratio = estimates[0] / estimates[1]
    expected = 2.0 ** (method.embedded_order + 1)
    assert 0.7 * expected < ratio < 1.4 * expected


# ---------------- stability stress suite (behaviour, never wall time) ----------------

def _run_checked(scene, volts, t_end, **kw):
    r = simulate(scene, volts, t_end, **kw)
    for name, values in r.outputs.items():
        assert np.all(np.isfinite(values)), name
    return r


@pytest.mark.parametrize('Rs', [1.0, 1e2, 2e3, 1e5, 1e6])
@pytest.mark.parametrize('rate_hz', [100.0, 1000.0, 1e5])
def test_stress_series_resistance_and_control_period(Rs, rate_hz):
    """Check Rs from 1 Ohm to 1 MOhm, dt from 10 ms to 10 us: finite, bounded power residual."""
    scene = load_scene('default', {**RELEASED,
                                   'Rs': Rs, 'rate_hz': rate_hz, 'integrator.tolerance': 1e-4})
    sim = Simulator(scene)
    n = int(round(0.06 / sim.dt))
    r = _run_checked(sim, lambda t: 3000.0 * (t >= 0.01), n * sim.dt)
    # The monitor integrates R_s i^2 explicitly: a charging spike far shorter than the step
    # (Rs C = 30 ns at 1 Ohm) is not resolved, so the residual is only bounded there.
    assert abs(sim.power_residual()) < (1e-3 if Rs >= 1e3 else 0.6)
    assert np.max(np.abs(r['q'])) < 0.03


@pytest.mark.parametrize('eps_b', [0.0, 0.05, 0.1, 0.2, 0.3, 0.4])
@pytest.mark.parametrize('beam', ['simply_supported', 'fixed'])
def test_stress_prestrain_sweep_square_wave_near_resonance(beam, eps_b):
    """Check a 0..v_max square wave at the beam's ~90 Hz resonance, across pre-strains."""
    scene = load_scene('default', {**RELEASED,
                                   'beam': beam, 'eps_b': eps_b, 'integrator.tolerance': 1e-5})
    sim = Simulator(scene)
    volts = lambda t: 3000.0 * (int(t * 180.0) % 2)  # noqa: E731 - 90 Hz square wave
    _run_checked(sim, volts, 0.3)
    assert abs(sim.power_residual()) < 1e-3   # dominated by the 30 us charging spikes


@pytest.mark.parametrize('v', [0.0, 750.0, 1500.0, 2250.0, 3000.0])
def test_stress_voltage_steps(v):
    scene = load_scene('default', {**RELEASED, 'integrator.tolerance': 1e-5})
    sim = Simulator(scene)
    _run_checked(sim, lambda t: v * (t >= 0.02), 0.2)
    assert abs(sim.power_residual()) < 1e-3   # dominated by the 30 us charging spikes


@pytest.mark.parametrize('scene_name', ['default', 'plate'])
def test_supplied_energy_is_exact_under_a_new_voltage_every_period(scene_name):
    """
    Check that the supplied energy is exact under a new voltage every period.

    A controller's new voltage every period (a 1 V per period ramp, a 2 kV drop every 2 s) at
    the default tolerance: the supplied energy W_in matches a tight run to 1e-8 and the power
    balance stays near its ~1e-5 norm. (The stages integrate W_in - v q_p, whose rate is
    smooth; integrating v i instead would put every jump's charging current through the
    quadrature, ~1.4e-3 into the balance after 3 s, and the node would flag a run whose outputs
    are right.)
    """
    def run(tolerance):
        sim = Simulator(load_scene(scene_name, {**PAPER, 'integrator.tolerance': tolerance}))
        for k in range(2500):
            sim.set_input([500.0 + k % 2000] * sim.model.n_inputs)
            sim.step()
        return sim
    coarse, fine = run(1e-6), run(1e-10)
    assert abs(coarse.x[-2] - fine.x[-2]) / fine.x[-2] < 1e-8
    assert abs(coarse.power_residual()) < 1e-4


def test_small_input_jumps_start_their_graded_steps_longer():
    """
    Check that small input jumps start their graded steps longer.

    A controller's 1 V change per period: the charge transient's first step is sized by the
    jump (fine * (v_max / du)^(1/5); the 'step' scenes' v_max jumps keep fine): half the steps
    of sizing every jump like a v_max jump, and the error stays well under the tolerance
    (against the same drive at 1e-10).
    """
    def run(tolerance, same_first_step=False):
        sim = Simulator(load_scene('default', {**PAPER, 'integrator.tolerance': tolerance}))
        if same_first_step:
            settings = dataclasses.replace(sim.transient, jump_ref=0.0)
            sim.stepper = integrators.make_stepper(sim.model, sim.method, sim.control, sim.dt,
                                                   settings)
        assert sim.transient.jump_ref == sim.scene.physics.v_max
        q, steps = [], sim.steps_taken
        for k in range(400):
            sim.set_input([1500.0 + k])
            q.append(sim.step()[0])
        return np.array(q), sim.steps_taken - steps
    q, steps = run(1e-6)
    q_same, steps_same = run(1e-6, same_first_step=True)
    q_ref, _ = run(1e-10)
    assert steps < 0.6 * steps_same
    for got in (q, q_same):
        assert np.max(np.abs(got - q_ref)) / np.max(np.abs(q_ref)) < 2e-7   # tolerance 1e-6


def test_stress_long_run_million_steps():
    """
    Check a run of a million internal steps.

    10^6 internal steps (100 s at 1 kHz, 10 substeps, through the same compiled periods as
    Simulator.step) with a 0.1 Hz square wave: stays finite and the energy balance closes.
    """
    scene = load_scene('default', {**RELEASED, 'integrator.substeps': 10, 'rate_hz': 1000.0})
    sim = Simulator(scene)
    r = simulate(sim, lambda t: 3000.0 * (int(t / 5.0) % 2), 100.0)
    assert sim.k == 100_000
    for name, values in r.outputs.items():
        assert np.all(np.isfinite(values)), name
    # the charging transients after each of the 20 switches are resolved (fixed_period in
    # _csrc/stepping/period.c)
    assert abs(sim.power_residual()) < 1e-3


def test_leaving_the_domain_faults_cleanly_and_reset_recovers():
    # a huge initial deflection drives the beam ends together: lambda <= 0
    scene = load_scene('default', {**RELEASED, 'q0': 0.08})
    with pytest.raises(ModelDomainError, match='lambda'):
        Simulator(scene)
    scene = load_scene('default', {**RELEASED, 'q0': 0.02, 'eta_b': 0.0, 'm': 0.5})
    sim = Simulator(scene, method='euler', substeps=1)
    with pytest.raises(ModelDomainError) as info:
        for _ in range(5000):
            sim.step()
            assert np.all(np.isfinite(sim.x))
    assert sim.fault and np.all(np.isfinite(sim.x))
    with pytest.raises(ModelDomainError):
        sim.step()
    assert 'lambda' in str(info.value) or 'non-finite' in str(info.value)
    sim.reset()
    assert not sim.fault
    sim.step()


# -- the steppers' orders against scipy's DOP853 (not against one of the package's own methods,
# which would share a fault of the stepping core) ------------------------------------------------

def _small_oscillation():
    """Return the ideal-source scene without creep at 100 Hz: a non-stiff two-state system."""
    scene = load_scene('default', {**PAPER, 'scene.initial_state': 'released', 'source': 'ideal',
                                   'creep': False, 'monitor_power': False, 'eps_b': 0.2,
                                   'rate_hz': 100.0})
    model = build_model(scene)
    x0 = initial_state(model)
    x0[0] = 0.0125
    return model, x0


def _dop853_reference(model, x0, volts, t_end):
    from scipy.integrate import solve_ivp
    u = np.array([volts])
    sol = solve_ivp(lambda t, x: model.f(t, x, u), (0.0, t_end), x0, method='DOP853',
                    rtol=1e-13, atol=1e-16)
    assert sol.success
    return sol.y[:, -1]


@pytest.mark.parametrize('name, order', [('rk4', 4), ('dp5', 5), ('etdrk4', 4), ('etd2', 2)])
def test_each_stepper_converges_at_its_order_against_scipy_dop853(name, order):
    """Errors at the end of 20 ms against scipy's DOP853 at rtol 1e-13 shrink as h^order."""
    model, x0 = _small_oscillation()
    t_end, volts = 0.02, 1000.0
    reference = _dop853_reference(model, x0, volts, t_end)
    scale = np.array([0.01, 1.0])   # m, m/s

    def error(n):
        x = x0.copy()
        status = integrators.advance(x, np.array([volts]), model,
                                     integrators.get_method(name), t_end / n, n)
        assert status == 0
        return np.max(np.abs(x - reference) / scale)
    e1, e2 = error(40), error(80)
    assert order - 0.3 <= np.log2(e1 / e2) <= order + 0.8, (e1, e2)
