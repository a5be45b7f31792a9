"""
The kernel's BDF stepper (core/_csrc/stepping/bdf.c) against its reference and contracts.

Held to its numpy reference (det_sim_ros/physics/reference_bdf.py), to an independent solver,
and to the simulator's contracts (bit-identical runs, a restart after reset, a clear refusal
where it cannot step).
"""

from det_sim_ros.analysis.scenarios import step_scene
from det_sim_ros.physics.reference_bdf import BdfStepper
from det_sim_ros.scenes.scene import load_scene, SceneError
from det_sim_ros.sim.integrators import bdf_weights
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest
from scipy.integrate import solve_ivp

LEVEL = {'scene.fidelity': 'exact', 'scene.shapes': 'polynomial', 'scene.n_ritz': 7}
# settled at 0 V, a 3 kV step, down to 1.5 kV: a new step size each period, input jumps
PROFILE = [0.0] * 20 + [3000.0] * 25 + [1500.0] * 15


def simulator(**overrides):
    return Simulator(step_scene('simply_supported', 0.20, **{**LEVEL, **overrides}))


def test_auto_picks_bdf_from_six_terms_on_one_group_only():
    assert simulator().method.name == 'bdf'
    assert simulator(**{'scene.n_ritz': 5}).method.name == 'etdrk4_linearized'
    assert Simulator().method.name == 'etdrk4_linearized'   # the shipped default: 3 modes
    assert Simulator(load_scene('array', {'scene.n_ritz': 7})).method.name != 'bdf'


def test_kernel_follows_the_numpy_reference():
    """
    Same steps, Jacobians, LU factorizations and rejections; states within 1e-9 of scale.

    The two differ by round-off only (numpy's BLAS sums against the kernel's loops, LAPACK's
    LU against the kernel's), which the settled and stepped beam (no snap in PROFILE) carries
    through 60 periods at ~1e-13 of the scale; a decision taken differently would show in the
    counts and move the states by about the local tolerance (~1e-6) instead.
    """
    sim = simulator()
    model = sim.model
    # the power monitor's integrals (last) are bookkeeping, outside the iteration
    n_core = sum(not name.startswith('W_') for name in model.state_names)
    ref = BdfStepper(lambda x, u: model.f(0.0, x, u), bdf_weights(model),
                     sim.control.tolerance, sim.dt, n_core)
    x_ref = sim.x.copy()
    weights = bdf_weights(model)   # 1 / scale (0: a state out of the norm)
    worst = 0.0
    for volts in PROFILE:
        sim.set_input([volts])
        sim.step()
        x_ref = ref.period(x_ref, np.array([volts]))
        worst = max(worst, float(np.max(np.abs(sim.x - x_ref) * weights)))
    jacobians, factorizations, rejected = sim.stepper.bdf_counts()
    assert (sim.steps_taken, jacobians, factorizations, rejected) == (
        ref.steps, ref.jacobians, ref.factorizations, ref.rejected)
    assert worst < 1e-9
    # the bookkeeping integrals (out of the norm), to round-off of their own size
    assert np.allclose(sim.x[n_core:], x_ref[n_core:], rtol=1e-9, atol=0.0)
    # the largest local error of the accepted steps (round-off of a ~1e-7 figure)
    assert sim.stepper.estimate == pytest.approx(ref.estimate, rel=1e-6)


def test_an_order_is_chosen_only_after_order_plus_one_steps_of_one_size():
    """
    Every order decision reads differences of one step size.

    scipy resets the count of equal steps at every step-size change, a fit of the step to the
    period included. On the numpy reference, which the kernel follows decision for decision
    (test_kernel_follows_the_numpy_reference): the simply supported level through PROFILE and
    a dither, every decision's last order + 1 accepted steps of one size (to FIT_ROUND_OFF).
    A fit that kept counting mixed two sizes in some of them.
    """
    sim = simulator()
    model = sim.model
    n_core = sum(not name.startswith('W_') for name in model.state_names)
    ref = BdfStepper(lambda x, u: model.f(0.0, x, u), bdf_weights(model),
                     sim.control.tolerance, sim.dt, n_core)
    x = sim.x.copy()
    dither = 1500.0 + np.random.default_rng(2).uniform(-25.0, 25.0, 40)
    for volts in list(PROFILE) + list(dither):
        x = ref.period(x, np.array([volts]))
    assert ref.order_decisions > 20
    assert ref.mixed_decisions == 0


def test_the_error_follows_the_tolerance_against_an_independent_solver():
    """
    The error against scipy's Radau falls with the tolerance, below it.

    Radau at rtol 1e-10 on the same right-hand side (absolute tolerances 1e-10 of each state's
    scale): a 3 kV step from rest and back to 0 V (0.3 s), the largest |y - y_radau| over the
    run's travel.

    Bounds: at the scene tolerance 1e-3, 1e-3 of the travel (the local tolerance 3e-7 per
    step accumulates over ~600 steps to ~1e-4); at 1e-5, ten times smaller at least (the NDF
    orders 1-5 bring the error down with the tolerance). Radau's own error at 1e-10 is orders
    below both, on any CPU.
    """
    volts = [3000.0] * 150 + [0.0] * 150
    errors = []
    for tolerance in (1e-3, 1e-5):
        sim = simulator(**{'integrator.tolerance': tolerance})
        model, x = sim.model, sim.x.copy()
        weights = bdf_weights(model)
        atol = 1e-10 / np.where(weights > 0.0, weights, 1e-3)
        y_bdf, y_ref = [], []
        for k, v in enumerate(volts):
            sim.set_input([v])
            sim.step()
            y_bdf.append(sim.outputs()['y'])
            u = np.array([v])
            x = solve_ivp(lambda _t, z: model.f(0.0, z, u), (0.0, sim.dt), x, method='Radau',
                          rtol=1e-10, atol=atol).y[:, -1]
            y_ref.append(model.outputs(x, u)['y'])
        y_bdf, y_ref = np.array(y_bdf), np.array(y_ref)
        errors.append(float(np.max(np.abs(y_bdf - y_ref)) / np.ptp(y_ref)))
    assert errors[0] < 1e-3
    assert errors[1] < errors[0] / 10.0


def test_runs_are_bit_identical_and_a_reset_starts_the_history_anew():
    runs = []
    sim = simulator()
    for _ in range(2):
        sim.reset()
        ys = []
        for volts in PROFILE:
            sim.set_input([volts])
            sim.step()
            ys.append(sim.x.copy())
        runs.append(np.array(ys))
    fresh = simulator()
    for volts in PROFILE:
        fresh.set_input([volts])
        fresh.step()
    assert np.array_equal(runs[0], runs[1])
    assert np.array_equal(runs[1][-1], fresh.x)


@pytest.mark.parametrize('scene', ['array', 'amplifier_lab'])
def test_a_scene_it_cannot_step_is_refused_in_one_line(scene):
    with pytest.raises(SceneError, match="integrator.method.*'bdf' steps one coupled group"):
        Simulator(load_scene(scene, {'integrator.method': 'bdf'}))


def test_a_dithered_command_stays_within_its_tolerance_of_radau():
    """
    A controller's +-25 V every period at 1.5 kV (200 periods, from rest), BDF at 1e-3.

    Against scipy's Radau at rtol 1e-9 on the same model, the deflection within the tolerance
    of the beam's deflection (max |q|, 13 mm: the scale the tolerance is stated on, a stroke;
    measured 3.3e-4 of it). Each jump restarts the charge's relaxation, which the history
    carries on through (no restart), and the step control must still see it. Against the
    dither's own travel (1.6 mm) BDF's error is 2.9e-3, the linearized stages' 1.5e-4 at the
    same tolerance (docs/numerics.md, "The BDF stepper").
    """
    from det_sim_ros.analysis.scenarios import reference_solution
    from det_sim_ros.sim.simulator import simulate
    periods, tolerance = 200, 1e-3
    scene = step_scene('fixed', 0.20, **{**LEVEL, 'scene.initial_state': 'rest',
                                         'integrator.tolerance': tolerance,
                                         'integrator.method': 'bdf'})
    volts = 1500.0 + np.random.default_rng(1).uniform(-25.0, 25.0, periods)
    sim = Simulator(scene)
    run = simulate(sim, volts, periods * scene.dt)
    t, X = reference_solution(scene, periods * scene.dt, rtol=1e-9,
                              voltage=lambda s: volts[min(int(round(s / scene.dt)), periods - 1)])
    q_ref = X[:, :7] @ sim.model.bases[0].reference_row()
    assert np.allclose(run.t, t)
    assert np.max(np.abs(run['q'] - q_ref)) / np.max(np.abs(q_ref)) <= tolerance


def test_fixed_steps_are_refused_and_a_bad_state_fails_the_period_cleanly():
    """advance() is for table methods; a non-finite state fails its period, x kept."""
    sim = simulator()
    u = np.array([1000.0])
    with pytest.raises(ValueError, match="kind 'bdf' steps whole periods"):
        sim.stepper.advance(sim.x.copy(), u, 1e-4, 1)
    x = sim.x.copy()
    x[0] = np.nan
    keep = x.copy()
    out = np.empty(len(sim.output_names))
    assert sim.stepper.period(x, u, u, out) != 0
    assert np.array_equal(x, keep, equal_nan=True)


def test_a_logged_bdf_run_resimulates_bit_for_bit(tmp_path):
    """The history restarts from the log's initial state as it did in the run: no deviation."""
    from det_sim_ros.io.log import Recorder
    from det_sim_ros.io.replay import resimulate, simulate_to_log
    scene = step_scene('simply_supported', 0.20, **LEVEL)
    sim = Simulator(scene)
    assert sim.method.name == 'bdf'
    commands = {0: [0.0], 20: [3000.0], 45: [1500.0]}
    path = str(tmp_path / 'bdf.mcap')
    with Recorder(path, scene, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, commands, len(PROFILE))
    resim = resimulate(path)
    assert resim.method == 'bdf'
    assert resim.ok(0.0), resim.table()


def test_a_beam_at_rest_takes_one_step_a_period_and_never_faults():
    """
    At an exact equilibrium every Newton correction is round-off.

    Their ratio is then noise around 1, which must not read as a diverging iteration: it did,
    the step size halved until it underflowed and the period faulted (after 2969 periods of
    the simply supported default at 0 V).
    """
    sim = Simulator(load_scene('default', {'scene.beam': 'simply_supported'}))
    assert sim.method.name == 'bdf'
    sim.set_input([0.0])
    for _ in range(3500):
        sim.step()
    assert not sim.fault
    assert sim.steps_taken <= 3500 + 10
    assert sim.stepper.bdf_counts()[2] == 0   # no step rejected
