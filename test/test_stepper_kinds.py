"""
The kinds of stepper: one table in Python (integrators.KINDS) and one in C (stepping/kind.c).

A method is a table of coefficients plus a kind ('stages', 'linearized', 'bdf'); the kind alone
says how the compiled core steps it. These tests hold the two tables of kinds together, check
that the compiled stepper takes each kind's options and refuses the others in one line, and that
a new coefficient table steps with no change anywhere else.
"""

import re

from det_sim_ros.core import kernel
from det_sim_ros.physics import reference
from det_sim_ros.physics.model import build_model
from det_sim_ros.physics.statics import initial_state
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.integrators import (get_method, KINDS, make_stepper, Method, METHODS,
                                         MULTISTEP, step_control, StepControl)
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

SINGLE = load_scene('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 3})


@pytest.fixture(scope='module')
def model():
    return build_model(SINGLE)


def _stepper(model, kind, options):
    """Return a compiled stepper of etdrk4's table with ``kind`` and ``options``."""
    c, terms = get_method('etdrk4').arrays()
    weights = np.ones(model.n_states)
    return kernel.Stepper(model.kernel, c, terms.reshape(-1, 5), np.zeros(0), weights,
                          dt=1e-3, z_tol=0.0, fine=1.0, substeps=1, tolerance=0.0,
                          min_substeps=1, max_substeps=1, exponent=1.0, kind=kind,
                          options=options)


def test_the_python_and_the_compiled_kinds_are_the_same_table(model):
    """
    Check that every kind is the compiled core's and each method's stepper has its kind.

    The compiled core names its kinds (kernel.STEPPER_KINDS); a kind in one table and not in the
    other, or a method whose compiled stepper steps as another kind, fails here.
    """
    assert tuple(KINDS) == kernel.STEPPER_KINDS
    for method in [*METHODS.values(), *MULTISTEP.values()]:
        assert method.kind is KINDS[method.kind.name]
        control = step_control(method, model)
        assert make_stepper(model, method, control, SINGLE.dt).kind == method.kind.name
    assert {m.kind.name for m in [*METHODS.values(), *MULTISTEP.values()]} == set(KINDS)


@pytest.mark.parametrize('kind, options, message', [
    ('stages', {'tolerance': 1e-3}, "the kind 'stages' takes no option 'tolerance'"),
    ('linearized', {'weights': [1.0]}, "the kind 'linearized' takes no option 'weights'"),
    ('bdf', {'refresh': 1e-2}, "the kind 'bdf' takes no option 'refresh'"),
    ('bdf', {'tolerance': 1e-3}, 'needs the options tolerance > 0 and weights'),
    ('bdf', {'tolerance': float('nan')}, 'option tolerance must be finite and >= 0'),
    ('linearized', {'refresh': -1.0}, 'option refresh must be finite and >= 0'),
    ('rk_implicit', None, r"unknown kind 'rk_implicit' \(known: stages, linearized, bdf\)"),
])
def test_a_kind_takes_its_own_options_and_refuses_others_in_one_line(model, kind, options,
                                                                     message):
    """
    Check that the compiled stepper refuses an option its kind does not read.

    Every kind's options are one record; a misspelt or foreign option, a bad value or an
    unknown kind is a ValueError naming it, never silently ignored.
    """
    with pytest.raises(ValueError, match=message):
        _stepper(model, kind, options)


def test_bdf_refuses_an_array_in_one_line():
    """
    Check that a kind refuses a model it cannot step, in the compiled core too.

    The BDF stepper steps one coupled group: an array (three groups) is refused with the reason.
    """
    array = build_model(load_scene('array', {'structure.copies': 3}))
    weights = np.ones(array.n_states)
    with pytest.raises(ValueError, match='one coupled group without an amplifier'):
        _stepper(array, 'bdf', {'tolerance': 1e-3, 'weights': weights})


def test_a_new_table_steps_as_a_row_and_nothing_else(model):
    """
    Check that a coefficient table not among METHODS steps through the same core.

    Heun's second-order method written as a Method row (kind 'stages' by default) against the
    numpy reference's step of the same row: one step from the scene's initial state under
    3 kV. Both evaluate the same stages in floating point in a different order, so they agree
    to round-off: each state within 1e-10 of itself or of 1e-6 of the largest (test_kernel's
    bound and its reasons, for the same right-hand sides; the symmetric modes sit at round-off
    of the others), far below what a wrong coefficient moves (order h^2 times the state's
    second derivative).
    """
    heun = Method('heun', 2, (0.0, 1.0),
                  ((1, 0, -1, 0.0, 1.0), (2, 0, -1, 0.0, 0.5), (2, 1, -1, 0.0, 0.5)),
                  False, "Heun's method")
    assert heun.kind is KINDS['stages']
    h = 1e-5
    x = initial_state(model)
    u = np.array([3000.0])
    stepper = make_stepper(model, heun, StepControl(1), h)
    ours = x.copy()
    out = np.empty(len(model.output_names))
    assert stepper.period(ours, u, u, out) == kernel.OK
    expected = reference.step(model.arrays, heun, x, u, h)
    floor = 1e-6 * np.max(np.abs(expected))
    assert np.all(np.abs(ours - expected) <= 1e-10 * np.maximum(np.abs(expected), floor))
    assert np.max(np.abs(ours - x) / np.maximum(np.abs(x), floor)) > 1e-6   # it moved


@pytest.mark.parametrize('overrides, phrase', [
    ({'scene.fidelity': 'paper', 'integrator.method': 'etdrk4', 'integrator.substeps': 12},
     r'^etdrk4 x12$'),
    ({'integrator.method': 'etdrk4_linearized'}, r'^etdrk4_linearized adaptive \(now x\d+\)$'),
    ({'scene.beam': 'simply_supported', 'integrator.method': 'bdf'},
     r'^bdf adaptive \(steps and order\)$'),
])
def test_each_kind_describes_its_stepping_as_the_user_reads_it(overrides, phrase):
    """
    Check the phrase of each kind that logs, the start line and /diagnostics show.

    A fixed count names it; an adaptive table names its current count; BDF, which has no count,
    says that it adapts its steps and order (a count there would be a number it never uses).
    """
    sim = Simulator(load_scene('default', overrides))
    assert re.match(phrase, sim.describe_stepper())
