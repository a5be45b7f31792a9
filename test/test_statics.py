"""Statics (paper Section 4, Fig. 5) at the shared parameter set; no ROS needed."""

from det_sim_ros.physics import statics
from det_sim_ros.physics.model import build_model
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate
import numpy as np
import pytest

BEAMS = ('simply_supported', 'fixed')
V_MAX = 3000.0


def scene_for(beam, eps_b=0.20, **more):
    # the paper's model released from q0, its start (the dynamic checks below settle from it)
    return load_scene('default', {'scene.beam': beam, 'scene.eps_b': eps_b,
                                  'scene.initial_state': 'released', 'scene.fidelity': 'paper',
                                  **more})


@pytest.fixture(scope='module')
def eps_min():
    """eps_b,min at 0 V and v_max for both beams (printed for the report)."""
    values = {(b, v): statics.critical_prestrain(scene_for(b), v) for b in BEAMS
              for v in (0.0, V_MAX)}
    for (b, v), e in values.items():
        print(f'eps_b,min({b}, {v:g} V) = {e:.5f}')
    return values


def by_kind(eqs):
    return {e.kind: e for e in eqs}


@pytest.mark.parametrize('beam', BEAMS)
def test_straight_stable_below_critical_prestrain(beam, eps_min):
    for eps in (0.0, 0.5 * eps_min[beam, 0.0], eps_min[beam, 0.0] - 2e-3):
        eqs = statics.equilibria(scene_for(beam, eps), 0.0)
        kinds = by_kind(eqs)
        assert kinds['straight'].stable
        assert all(not e.stable for e in eqs if e.kind != 'straight')
        assert statics.rest_shortening(scene_for(beam, eps)) == 0.0


@pytest.mark.parametrize('beam', BEAMS)
@pytest.mark.parametrize('eps', [None, 0.15, 0.20, 0.25])
def test_two_mirror_symmetric_stable_buckled_states_above(beam, eps, eps_min):
    eps = eps_min[beam, 0.0] + 2e-3 if eps is None else eps
    scene = scene_for(beam, eps)
    eqs = statics.equilibria(scene, 0.0)
    kinds = by_kind(eqs)
    assert set(kinds) == {'straight', 'buckled+', 'buckled-'}
    assert not kinds['straight'].stable and kinds['straight'].stiffness < 0
    plus, minus = kinds['buckled+'], kinds['buckled-']
    assert plus.stable and minus.stable
    assert plus.q > 0 > minus.q
    assert minus.q == pytest.approx(-plus.q, rel=1e-9)
    assert minus.y == pytest.approx(plus.y, rel=1e-9)
    assert plus.energy < kinds['straight'].energy
    # y0 is the shortening of the stable buckled state; its own delta_y is zero
    assert statics.rest_shortening(scene) == pytest.approx(plus.y, rel=1e-12)
    assert plus.delta_y == pytest.approx(0.0, abs=1e-15)
    assert kinds['straight'].delta_y == pytest.approx(plus.y)


def test_critical_prestrain_values(eps_min):
    # parameters.yaml: eps_b,min(0 V) ~ 3.5 % (simply supported) / 4.8 % (fixed)
    assert eps_min['simply_supported', 0.0] == pytest.approx(0.035, abs=1.5e-3)
    assert eps_min['fixed', 0.0] == pytest.approx(0.048, abs=1.5e-3)
    assert eps_min['fixed', 0.0] > eps_min['simply_supported', 0.0]
    assert eps_min['fixed', V_MAX] > eps_min['simply_supported', V_MAX]
    for beam in BEAMS:   # the Maxwell stress relaxes the DET tension: buckling needs more strain
        assert eps_min[beam, V_MAX] > eps_min[beam, 0.0]


@pytest.mark.parametrize('beam', BEAMS)
@pytest.mark.parametrize('v', [0.0, V_MAX])
def test_straight_stiffness_changes_sign_at_critical_prestrain(beam, v, eps_min):
    e = eps_min[beam, v]
    assert statics.stiffness_at_straight(scene_for(beam, e - 1e-4), v) > 0
    assert statics.stiffness_at_straight(scene_for(beam, e + 1e-4), v) < 0


@pytest.mark.parametrize('beam', BEAMS)
def test_potential_is_even_and_its_slope_is_the_model_force(beam):
    scene = scene_for(beam, 0.2)
    q = np.linspace(-0.02, 0.02, 41)
    for v in (0.0, V_MAX):
        u = statics.potential(scene, q, v)
        np.testing.assert_allclose(u, u[::-1], rtol=1e-12, atol=1e-15)
        eq = by_kind(statics.equilibria(scene, v))['buckled+']
        # slope of U_pot vanishes at the equilibrium and U_pot is minimal there
        h = 1e-6
        du = (statics.potential(scene, eq.q + h, v) - statics.potential(scene, eq.q - h, v)) / 2e-6
        assert abs(du) < 1e-6
        assert statics.potential(scene, eq.q, v) <= u.min() + 1e-12
    # the voltage lowers the potential by 1/2 C v_p^2 and moves the minimum inward (B -> C)
    b = by_kind(statics.equilibria(scene, 0.0))['buckled+']
    c = by_kind(statics.equilibria(scene, V_MAX))['buckled+']
    assert 0 < c.q < b.q and c.y < b.y and c.delta_y > 0


@pytest.mark.parametrize('beam', BEAMS)
def test_normalized_potential(beam):
    scene = scene_for(beam, 0.2)
    q_star = by_kind(statics.equilibria(scene, 0.0))['buckled+'].q
    q = np.linspace(-1.5 * q_star, 1.5 * q_star, 301)
    for v in (0.0, V_MAX):
        un = statics.normalized_potential(scene, q, v)
        assert un.min() == 0.0 and un.max() == 1.0
        i_mid = 150
        assert un[i_mid] > un[i_mid - 1] and un[i_mid] > un[i_mid + 1]   # A: maximum at q = 0
    un0 = statics.normalized_potential(scene, q, 0.0)
    assert abs(q[np.argmin(un0)]) == pytest.approx(q_star, rel=0.02)


@pytest.mark.parametrize('beam', BEAMS)
@pytest.mark.parametrize('v', [0.0, V_MAX])
def test_equilibrium_agrees_with_long_damped_simulation(beam, v):
    """
    Check that the dynamic model settles to the stable buckled equilibrium.

    The full dynamic model (RC source, creep) settles to the stable buckled equilibrium.
    """
    scene = scene_for(beam, 0.2)
    eq = by_kind(statics.equilibria(scene, v))['buckled+']
    r = simulate(scene, lambda t: v, 3.0)
    tail = r['q'][-500:]
    assert np.ptp(tail) < 1e-4 * eq.q                       # settled
    assert r['q'][-1] == pytest.approx(eq.q, rel=1e-3)
    assert r['y'][-1] == pytest.approx(eq.y, rel=2e-3)


def test_rest_shortening_cached_and_consistent():
    scene = scene_for('fixed', 0.21)
    y0 = statics.rest_shortening(scene)
    assert y0 > 0
    assert statics.rest_shortening(scene.replace(**{'scene.source': 'ideal'})) == y0
    assert statics.rest_shortening(scene) == y0
    # a longer beam (more pre-strain) buckles further
    assert statics.rest_shortening(scene_for('fixed', 0.25)) > y0


def test_branches_for_figure_5():
    eps_grid = np.linspace(0.0, 0.3, 13)
    scene = scene_for('simply_supported')
    e_min = statics.critical_prestrain(scene, 0.0)
    for v in (0.0, V_MAX):
        rows = statics.branches(scene, eps_grid, v)
        straight = [r for r in rows if r.branch == 'straight']
        assert len(straight) == len(eps_grid)
        e_min_v = statics.critical_prestrain(scene, v)
        for r in straight:
            assert r.stable == (r.eps_b < e_min_v)
        plus = {r.eps_b: r for r in rows if r.branch == 'buckled+'}
        minus = {r.eps_b: r for r in rows if r.branch == 'buckled-'}
        assert set(plus) == set(minus)
        for e, r in plus.items():
            assert minus[e].q == pytest.approx(-r.q, rel=1e-9)
            assert r.stable
            if v == 0.0:
                assert r.delta_y == pytest.approx(0.0, abs=1e-15)
            else:
                assert r.delta_y > 0
        assert {e for e in eps_grid if e > e_min_v} == set(plus)
        qs = [plus[e].q for e in sorted(plus)]
        assert np.all(np.diff(qs) > 0)                      # q grows with the pre-strain
    assert e_min < 0.05


@pytest.mark.parametrize('beam', BEAMS)
def test_consistent_three_term_model(beam):
    scene = scene_for(beam, 0.2, **{'scene.fidelity': 'consistent', 'scene.n_ritz': 3})
    kinds = by_kind(statics.equilibria(scene, 0.0))
    assert set(kinds) == {'straight', 'buckled+', 'buckled-'}
    plus, minus = kinds['buckled+'], kinds['buckled-']
    assert plus.stable and minus.stable and not kinds['straight'].stable
    assert len(plus.coords) == 3
    np.testing.assert_allclose(minus.coords, -np.array(plus.coords), rtol=1e-6, atol=1e-9)
    assert minus.y == pytest.approx(plus.y, rel=1e-6)
    # it is a minimum of the full three-coordinate potential
    c = np.array(plus.coords)
    u0 = statics.potential_coords(scene, c, 0.0)
    rng = np.random.default_rng(1)
    for _ in range(10):
        d = rng.normal(size=3) * 1e-4
        assert statics.potential_coords(scene, c + d, 0.0) > u0
    # more Ritz terms soften the beam: it buckles at a lower pre-strain than the one-term model
    one = scene.replace(**{'scene.n_ritz': 1})
    assert statics.critical_prestrain(scene, 0.0) < statics.critical_prestrain(one, 0.0)
    # the reduced potential has its minimum at the equilibrium deflection
    q = np.linspace(-1.4 * plus.q, 1.4 * plus.q, 29)
    u = statics.potential(scene, q, 0.0)
    assert abs(q[np.argmin(u)]) == pytest.approx(plus.q, rel=0.06)


def test_brentq_finds_the_roots_scipy_finds():
    """
    Check that statics.brentq finds the roots scipy's brentq finds, to the last bit.

    statics.brentq (written out to keep scipy.optimize out of a node's start) is Brent's
    method with scipy's steps and stopping rule: the same roots, to the last bit.
    """
    from scipy.optimize import brentq as scipy_brentq
    from det_sim_ros.physics.statics import brentq
    cases = [(lambda x: x ** 3 - 2 * x - 5, 2.0, 3.0), (np.cos, 0.0, 3.0),
             (lambda x: np.tanh(40 * (x - 0.3)) + 1e-3 * x, -1.0, 2.0),
             (lambda x: np.exp(x) - 1e6, 0.0, 30.0)]
    for f, a, b in cases:
        for xtol, rtol in ((2e-12, 8.9e-16), (1e-15, 1e-13)):
            ours = brentq(f, a, b, xtol=xtol, rtol=rtol)
            theirs = scipy_brentq(f, a, b, xtol=xtol, rtol=rtol)
            assert ours == theirs, (f, ours, theirs)
    with pytest.raises(ValueError, match='opposite signs'):
        brentq(np.cos, 0.0, 1.0)


# -- the rest state against scipy's root finder on the compiled right-hand side ------------------

@pytest.mark.parametrize('overrides', [
    {},
    {'scene.beam': 'simply_supported', 'scene.eps_b': 0.15},
    {'scene.fidelity': 'consistent', 'scene.n_ritz': 3},
    {'scene.fidelity': 'exact', 'scene.n_ritz': 3},
])
def test_rest_state_is_the_root_scipy_finds(overrides):
    """
    Check that the rest state is the root scipy finds.

    scipy.optimize.root (MINPACK's Levenberg-Marquardt) on the compiled accelerations at zero
    velocity and 0 V, started 5 % off, lands on the rest state the statics give (the buckled+
    side) to round-off.
    """
    from scipy.optimize import root
    model = build_model(load_scene('default', overrides))
    rest = statics.initial_state(model)
    n_q = model.arrays.n_q
    u = np.zeros(model.n_inputs)

    def accelerations(coords):
        x = np.zeros(model.n_states)
        x[:n_q] = coords
        return model.f(0.0, x, u)[n_q:2 * n_q]
    length = model.scene.beam_length
    found = root(lambda z: accelerations(z * length), 0.95 * rest[:n_q] / length, method='lm',
                 options={'xtol': 1e-13})
    assert found.success, found.message
    np.testing.assert_allclose(rest[:n_q], found.x * length, rtol=0, atol=1e-11 * length)
    assert not rest[n_q:].any()                      # at rest: no velocity, creep or charge
