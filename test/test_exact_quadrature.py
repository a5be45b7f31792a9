"""
The exact kinematics' quadrature at the largest slopes the 'step' runs reach.

The rule (RitzBasis.quadrature(nonpolynomial=True)) is held to a finer one where it matters,
Delta-y over a whole step run, and the compiled pass to the numpy reference at the steepest
state of a run (|w'| = 0.99 on the simply supported beam).
"""

from det_sim_ros.analysis.scenarios import delta_y, STEP_END, step_scene, step_voltage
from det_sim_ros.core import kernel
from det_sim_ros.physics import reference
from det_sim_ros.physics.shapes import BucklingModeBasis, RitzBasis
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
import pytest

FINER = 24   # nodes added for the finer rule: Delta-y then moves by < 1e-9 of the stroke


def _step_run(beam, eps_b, n_ritz=5, shapes='polynomial'):
    """Return (model, run) of the 'step' run at fidelity exact (tolerance 1e-6)."""
    overrides = {'scene.fidelity': 'exact', 'scene.n_ritz': n_ritz, 'scene.shapes': shapes,
                 'integrator.tolerance': 1e-6}
    scene = step_scene(beam, eps_b, **overrides)
    sim = Simulator(scene)
    return sim.model, simulate(sim, step_voltage(scene.physics.v_max), STEP_END)


def _delta_y(model, run):
    u = np.zeros(model.n_inputs)
    y = np.array([model.outputs(x, u)['y'] for x in run.x])
    return delta_y(run.t, y, model.scene.beam_length)[0]


def _largest_slopes(model, run):
    """Return max |w'| over the beam (2001 points) of each state of the run."""
    basis = model.bases[0]
    slopes = basis.values(np.linspace(0.0, basis.length, 2001), 1)
    return np.max(np.abs(run.x[:, :basis.n_ritz] @ slopes.T), axis=1)


def test_the_rule_resolves_the_steepest_fixed_case(monkeypatch):
    """
    Check the rule's share of the error in Delta-y on the fixed eps_b 0.20 step run.

    Its slopes reach |w'| = 0.87; against a rule with FINER more nodes Delta-y moves by 1.4e-7 of
    the stroke (a seventh of the tolerance 1e-6); two nodes fewer would move it by 2.6e-6.
    """
    model, run = _step_run('fixed', 0.20)
    assert 0.85 < np.max(_largest_slopes(model, run)) < 0.9
    ours = _delta_y(model, run)
    rule = RitzBasis.quadrature

    def finer(basis, nonpolynomial=False):
        x, w = rule(basis, nonpolynomial)
        if not nonpolynomial:
            return x, w
        xi, wi = np.polynomial.legendre.leggauss(len(x) + FINER)
        return 0.5 * basis.length * (xi + 1.0), 0.5 * basis.length * wi

    monkeypatch.setattr(RitzBasis, 'quadrature', finer)
    fine_model, fine_run = _step_run('fixed', 0.20)
    assert fine_model.arrays.W.size == model.arrays.W.size + FINER
    fine = _delta_y(fine_model, fine_run)
    assert np.max(np.abs(ours - fine)) <= 5e-7 * np.max(np.abs(fine))


def test_the_mode_rule_resolves_the_steepest_fixed_case(monkeypatch):
    """
    Check the buckling modes' rule (16 + 8 n_r nodes) on the fixed eps_b 0.20 step run at n_r 3.

    Against a rule with FINER more nodes Delta-y moves by < 1e-9 of the stroke (measured); the
    bound 5e-7 (half the tolerance 1e-6) holds whatever the last digits a CPU gives.
    """
    model, run = _step_run('fixed', 0.20, 3, 'buckling_modes')
    assert 0.8 < np.max(_largest_slopes(model, run)) < 0.9
    ours = _delta_y(model, run)
    rule = BucklingModeBasis.quadrature

    def finer(basis, nonpolynomial=False):
        x, _ = rule(basis, nonpolynomial)
        xi, wi = np.polynomial.legendre.leggauss(len(x) + FINER)
        return 0.5 * basis.length * (xi + 1.0), 0.5 * basis.length * wi

    monkeypatch.setattr(BucklingModeBasis, 'quadrature', finer)
    fine_model, fine_run = _step_run('fixed', 0.20, 3, 'buckling_modes')
    assert fine_model.arrays.W.size == model.arrays.W.size + FINER
    fine = _delta_y(fine_model, fine_run)
    assert np.max(np.abs(ours - fine)) <= 5e-7 * np.max(np.abs(fine))


def _mass_and_forces(model, x, acceleration):
    """
    Return (M, terms) of the one-cell model at x: the mass matrix Mb + J' MI J and the force terms.

    The terms are -K q, -D qd, -dU4/dq, -J' MI h and the DETs' force (what is left of
    F = M qdd), each a vector over the Ritz coordinates, from the reference's kinematics.
    """
    a = model.arrays
    assert a.n_cells == 1
    r = a.n_q
    q, qd = x[:r], x[r:2 * r]
    kin = reference.kinematics(a, x)
    mass = a.Mb[:r, :r] + a.mi_val[0] * np.outer(kin.J, kin.J)
    named = [-a.K[:r, :r] @ q, -a.D[:r, :r] @ qd, -kin.dU4, -a.mi_val[0] * kin.h[0] * kin.J]
    return mass, named + [mass @ acceleration - sum(named)]


def test_kernel_matches_the_reference_at_the_steepest_state():
    """
    Check the compiled exact pass and mass solve at |w'| = 0.99 against the numpy reference.

    Both compute the same formulas in different orders (the kernel's node loops, numpy's BLAS
    and LAPACK, each with its CPU's vector width), so neither is the exact value and the bound
    is on their difference, normwise over the accelerations (a component near zero is the
    difference of larger terms, so its relative error says nothing about either code):

        |qdd_kernel - qdd_ref| / |qdd| <= 2 eps kappa(M) (N A R)

    with the infinity norm. Each side solves M qdd = F with M and F carrying relative errors
    of at most N eps A R (a sum of N = nodes + Ritz terms products; A = 1 + 4 max w'^2/(1 - w'^2)
    amplifies a rounding of w' through 1/cos^k, k <= 4, which is the conditioning at |w'| -> 1;
    R = max sum|terms| / |F| is the cancellation among the force terms), and a perturbation
    of M or F moves qdd by kappa(M) times it; two sides make the 2. The LAPACK solve's own
    backward error (n eps, n = 5) is inside N. The bound is a worst case (1e-7 here; the two
    codes differ by ~1e-11 on an AVX2 build, and a formula error moves qdd by far more than
    1e-7), taken at the state itself, so it holds on any CPU and numpy/scipy from PyPI.
    The slots without a solve (q' = qd copied; the power-monitor slots) carry N eps A.
    """
    model, run = _step_run('simply_supported', 0.20)
    slopes = _largest_slopes(model, run)
    assert 0.98 < np.max(slopes) < 1.0
    a = model.arrays
    nq = a.n_q
    u = np.array([model.scene.physics.v_max])
    eps = np.finfo(float).eps
    nodes = a.W.size + nq
    for x in run.x[np.argsort(slopes)[-3:]]:
        dx = np.empty(model.n_states)
        status, p_in, p_diss = model.kernel.rhs(x, u, dx)
        assert status == kernel.OK
        expected, ref_in, ref_diss = reference.rhs(model.arrays, x, u)
        acceleration = expected[nq:2 * nq]
        mass, terms = _mass_and_forces(model, x, acceleration)
        wp = a.B1[:, :nq] @ x[:nq]
        amplification = 1.0 + 4.0 * np.max(wp ** 2 / (1.0 - wp ** 2))
        cancellation = np.max(sum(np.abs(t) for t in terms)) / np.max(np.abs(sum(terms)))
        local = nodes * eps * amplification
        bound = 2.0 * np.linalg.cond(mass, np.inf) * local * cancellation
        assert bound < 1e-5                      # the bound itself is meaningful
        norm = np.max(np.abs(acceleration))
        assert np.max(np.abs(dx[nq:2 * nq] - acceleration)) <= bound * norm
        assert np.array_equal(dx[:nq], expected[:nq])
        rest = expected[2 * nq:]
        assert np.max(np.abs(dx[2 * nq:] - rest)) <= 2.0 * local * np.max(np.abs(rest))
        assert (p_in, p_diss) == pytest.approx((ref_in, ref_diss), rel=2.0 * local, abs=1e-18)
