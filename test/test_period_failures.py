"""
How a control period fails: x at its start, a status that names the cause, the user's message.

Faults are planted with the kernel's public test seam ``Stepper.plant_nan`` (a NaN in a
right-hand side or in a BDF Jacobian) or reached with inputs far outside the scene's range
through ``Stepper.period``; the message is the one :class:`ModelDomainError` gives the user.
"""

from det_sim_ros.core import kernel
from det_sim_ros.physics.model import ModelDomainError
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
import pytest

SIMPLY_SUPPORTED = {'scene.beam': 'simply_supported'}   # the default scene's BDF level


def settled_at(volts, periods, **overrides):
    """Return a simply supported default scene after ``periods`` periods at ``volts``."""
    sim = Simulator(load_scene('default', {**SIMPLY_SUPPORTED, **overrides}))
    sim.set_input([volts])
    for _ in range(periods):
        sim.step()
    return sim


@pytest.mark.parametrize('method', ['bdf', 'etdrk4_linearized', 'etdrk4', 'dp5'])
def test_a_lasting_nan_in_the_rate_fails_the_period_with_x_at_its_start(method):
    """Every stepper: the user reads 'non-finite', the state is the period's start, bit for bit."""
    sim = settled_at(3000.0, 2, **{'integrator.method': method})
    assert sim.method.name == method
    start = sim.x.copy()
    sim.stepper.plant_nan('rhs', 3, lasting=True)
    with pytest.raises(ModelDomainError, match=r'^non-finite state, rate or output') as error:
        sim.step()
    assert error.value.status == kernel.NON_FINITE
    assert np.array_equal(sim.x, start)
    assert sim.fault and np.all(np.isfinite(list(sim.outputs().values())))


def test_a_nan_in_one_jacobian_is_stepped_around_never_accepted():
    """
    A Jacobian with a NaN is dropped and the step retried (a new one, a smaller step).

    Planted in the Jacobian each of 30 periods of a 3 kV step takes first (through the
    snap-through): every run ends finite, unfaulted, and within 10 x the scene tolerance
    (relative to the stroke) of the run without the fault; the retried steps are other steps
    within the same local tolerance, so the two runs differ by the integration error only. A
    norm that skips NaN accepted the NaN step instead (the state NaN, the period faulted or
    returned OK with x = NaN).
    """
    clean = settled_at(3000.0, 30)
    for period in range(0, 30, 3):
        sim = settled_at(3000.0, period)
        sim.stepper.plant_nan('jacobian', 1)
        for _ in range(30 - period):
            sim.step()
        assert not sim.fault and np.all(np.isfinite(sim.x))
        y, y_clean = sim.outputs()['y'], clean.outputs()['y']
        assert abs(y - y_clean) <= 10.0 * sim.tolerance * abs(y_clean)


def test_a_lasting_nan_in_the_jacobian_fails_the_period_with_x_at_its_start():
    """No step size avoids it: the user reads 'non-finite' (not a step underflow), x kept."""
    for period in (0, 4, 12):
        sim = settled_at(3000.0, period)
        sim.stepper.reset_control()   # the history restarts: its first step takes a Jacobian
        start = sim.x.copy()
        sim.stepper.plant_nan('jacobian', 1, lasting=True)
        with pytest.raises(ModelDomainError, match=r'^non-finite state, rate or output'):
            sim.step()
        assert np.array_equal(sim.x, start)


def test_a_nan_in_one_rate_is_stepped_around_by_bdf():
    """A single NaN right-hand side fails one Newton iteration: a smaller step, no fault."""
    for after in (1, 5, 20, 40):
        sim = settled_at(3000.0, 3)
        sim.stepper.plant_nan('rhs', after)
        for _ in range(5):
            sim.step()
        assert not sim.fault and np.all(np.isfinite(sim.x))


def test_a_nan_state_fails_at_once_for_every_stepper():
    for method in ('bdf', 'etdrk4_linearized', 'dp5'):
        sim = settled_at(0.0, 1, **{'integrator.method': method})
        x = sim.x.copy()
        x[1] = np.nan
        keep = x.copy()
        out = np.empty(len(sim.output_names))
        assert sim.stepper.period(x, sim.u, sim.u, out) == kernel.NON_FINITE
        assert np.array_equal(x, keep, equal_nan=True)


@pytest.mark.parametrize('volts, status, text', [
    (1e20, kernel.STEP_UNDERFLOW, r'^the BDF step size underflowed'),
    (1e8, kernel.NO_PROGRESS, r'^the BDF stepper made no progress'),
    (1e160, kernel.NON_FINITE, r'^non-finite'),
])
def test_bdf_failures_are_told_apart(volts, status, text):
    """
    Inputs far beyond any DET's range (v_max 3 kV; the simulator clamps, the kernel does not).

    1e20 V: a force no step resolves (the step underflows); 1e8 V: one the stepper follows in
    steps too small to end the period (100000 of them); 1e160 V: a force that overflows (it
    goes with the voltage squared).
    """
    sim = settled_at(0.0, 1)
    x = sim.x.copy()
    start = x.copy()
    out = np.empty(len(sim.output_names))
    got = sim.stepper.period(x, sim.u, np.array([volts]), out)
    assert got == status
    assert np.array_equal(x, start)
    with pytest.raises(ModelDomainError, match=text):
        raise ModelDomainError(got)


@pytest.mark.parametrize('source, overrides, after', [
    ('default', {'scene.source': 'ideal'}, 2000),
    ('array', {'structure.copies': 3, 'scene.source': 'ideal'}, 1000),
])
def test_a_failed_run_leaves_x_where_the_last_good_period_ended(source, overrides, after):
    """
    Check that Stepper.run, failing part-way, leaves x at the state of its last good period.

    The input ramps every period, so every period books an input jump into the power monitor
    before it steps (an ideal source books it at the jump); a lasting NaN planted ``after``
    evaluations on fails a period part-way through the run. x must then be X[done], bit for
    bit, as the periods one at a time leave it: not the failed period's booked start. A single
    group runs period by period, an array in chunks of groups.
    """
    sim = Simulator(load_scene(source, overrides))
    assert sim.model.arrays.power_monitor
    n = 40
    U = np.ascontiguousarray(np.linspace(100.0, 3000.0, n)[:, None]
                             * np.ones((1, sim.model.n_inputs)))
    X = np.empty((n + 1, sim.model.n_states))
    Y = np.empty((n + 1, len(sim.output_names)))
    x = sim.x.copy()
    start = x.copy()
    sim.stepper.plant_nan('rhs', after, lasting=True)
    status, done = sim.stepper.run(x, sim.u, sim.u, U, X, Y)
    assert status == kernel.NON_FINITE and 0 < done < n
    assert np.array_equal(X[0], start)
    assert np.array_equal(x, X[done])
    # simulate() on the same plant: the simulator keeps that state, at the last good period
    again = Simulator(load_scene(source, overrides))
    again.stepper.plant_nan('rhs', after, lasting=True)
    with pytest.raises(ModelDomainError):
        simulate(again, U, n * again.dt)
    assert again.k == done and np.array_equal(again.x, X[done])
