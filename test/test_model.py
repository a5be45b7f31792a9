"""Model core: Ritz integrals, equations of motion, energy balance, reductions, bad parameters."""

import math

from det_sim_ros.physics.model import build_model, ModelDomainError
from det_sim_ros.physics.shapes import make_basis, ritz_coefficients
from det_sim_ros.physics.statics import initial_state
from det_sim_ros.scenes.scene import EPS0, load_scene, SceneError
import numpy as np
import pytest
from scipy.integrate import solve_ivp

# the paper's start (q = q0, released): these tests exercise the buckling transient
# the paper's model, released from q0: these tests check its equations and limits
PAPER_RELEASED = {'scene.initial_state': 'released', 'scene.fidelity': 'paper'}

BEAMS = ('simply_supported', 'fixed')


def paper_coefficients(beam, p, length):
    """Eqs 72 (simply supported) and 73 (fixed), typed in: the oracle, not the implementation."""
    l, I, A, rho, E, eta = length, p.I, p.area, p.rho_b, p.E_b, p.eta_b
    if beam == 'simply_supported':
        return {'a': 59049 / 1600 / l ** 2, 'b': 243 / 40 / l, 'd': 729 / 2 * I * eta / l ** 3,
                'M': 243 / 280 * rho * (A * l + 14 * I / l), 'c1': 729 / 2 * E * I / l ** 3,
                'c2': 243 / 80 / l, 'c3': 708588 / 70 * E * I / l ** 5}
    return {'a': 262144 / 11025 / l ** 2, 'b': 512 / 105 / l, 'd': 2048 / 5 * I * eta / l ** 3,
            'M': 256 / 315 * rho * (A * l + 12 * I / l), 'c1': 2048 / 5 * E * I / l ** 3,
            'c2': 256 / 105 / l, 'c3': 2097152 / 1155 * E * I / l ** 5}


def paper_rhs(scene, x, v):
    """Eq 71 as printed, with erratum 1 corrected (a m q qdot^2, not 2 a m q qdot^2)."""
    p = scene.physics
    l, l0 = scene.beam_length, p.l0
    k = paper_coefficients(scene.beam, p, l)
    a, b, d, M, c1, c2, c3 = (k[n] for n in ('a', 'b', 'd', 'M', 'c1', 'c2', 'c3'))
    V, C0 = p.volume, p.C0
    q, qd, eps, qp = x[:4]
    s = l - c2 * q * q
    dlz = 2 * l0 * c2 * q / s ** 2
    bracket = (p.Y / 3 * (q * s ** 4 / l0 ** 2 - l0 ** 2 * q)
               - l0 ** 2 * q * qp ** 2 / (p.A0 ** 2 * EPS0 * p.eps_r * p.n ** 2))
    force = (-(a * p.m * q * qd ** 2 + d * qd + c1 * q + c3 * q ** 3)
             + b * V / s ** 3 * bracket - V * (p.E_M * eps + p.eta_v * dlz * qd) * dlz)
    return np.array([
        qd,
        force / (M + a * p.m * q * q),
        dlz * qd - p.E_M / p.eta_M * eps,
        v / p.Rs - (1 / p.Rs + 1 / p.Rp) * l0 ** 2 * qp / (C0 * (c2 * q * q - l) ** 2),
    ])


@pytest.mark.parametrize('beam', BEAMS)
@pytest.mark.parametrize('eps_b', [0.0, 0.2, 0.37])
def test_ritz_integrals_match_eqs_72_73(beam, eps_b):
    scene = load_scene('default', {**PAPER_RELEASED, 'beam': beam, 'eps_b': eps_b})
    p = scene.physics
    basis = make_basis(beam, scene.beam_length)
    ours = ritz_coefficients(basis, p.rho_b, p.area, p.I, p.E_b, p.eta_b)
    for name, value in paper_coefficients(beam, p, scene.beam_length).items():
        assert ours[name] == pytest.approx(value, rel=1e-12), name
    # and the compiled model uses the same numbers
    model = build_model(scene)
    a = model.arrays
    assert a.Mb[0, 0] == pytest.approx(ours['M'], rel=1e-12)
    assert a.K[0, 0] == pytest.approx(ours['c1'], rel=1e-12)
    assert a.D[0, 0] == pytest.approx(ours['d'], rel=1e-12)
    assert a.c2[0] == pytest.approx(ours['c2'], rel=1e-12)
    assert 4 * a.e4[0] == pytest.approx(ours['c3'], rel=1e-12)


@pytest.mark.parametrize('beam', BEAMS)
def test_rhs_matches_corrected_paper_equations(beam):
    scene = load_scene('default', {**PAPER_RELEASED, 'beam': beam, 'monitor_power': False})
    model = build_model(scene)
    rng = np.random.default_rng(1)
    for _ in range(20):
        x = np.array([rng.uniform(-0.02, 0.02), rng.uniform(-2, 2), rng.uniform(-0.05, 0.05),
                      rng.uniform(0, 1.5) * scene.physics.C0 * 3000])
        v = rng.uniform(0, 3000)
        np.testing.assert_allclose(model.f(0, x, [v]), paper_rhs(scene, x, v), rtol=1e-10,
                                   atol=1e-12)


def test_reference_point_deflection_is_q():
    for beam in BEAMS:
        basis = make_basis(beam, 0.06)
        assert basis.reference_row()[0] == pytest.approx(1.0, rel=1e-14)


def _tight(model, x0, v, t_end, rtol=1e-12):
    atol = rtol * np.maximum(np.abs(x0), 1e-6)
    sol = solve_ivp(lambda t, x: model.f(t, x, [v]), (0, t_end), x0, method='DOP853',
                    rtol=rtol, atol=atol, dense_output=False, t_eval=np.linspace(0, t_end, 201))
    assert sol.success
    return sol


def test_lossless_constant_charge_conserves_energy():
    """Check erratum 1: with the corrected inertia term H is conserved; the printed one drifts."""
    scene = load_scene('default', {**PAPER_RELEASED,
                                   'eta_b': 0.0, 'eta_v': 0.0, 'E_M': 0.0, 'creep': False,
                                   'Rs': 1e30, 'Rp': 1e30, 'monitor_power': False})
    model = build_model(scene)
    C0 = scene.physics.C0
    x0 = np.array([0.012, 0.0, C0 * 1.2 ** 2 * 2000.0])   # charged, released off equilibrium
    sol = _tight(model, x0, 0.0, 1.0)
    H = np.array([model.outputs(x, [0.0])['H'] for x in sol.y.T])
    assert np.ptp(H) / H[0] <= 1e-9
    assert np.ptp(sol.y[0]) > 1e-3   # it really moved (an oscillation of about 2 mm)

    k = paper_coefficients(scene.beam, scene.physics, scene.beam_length)
    am = k['a'] * scene.physics.m

    def printed(t, x):   # eq 75 as printed: 2 a m q qdot^2
        dx = model.f(t, x, [0.0])
        dx[1] -= am * x[0] * x[1] ** 2 / (k['M'] + am * x[0] ** 2)
        return dx
    bad = solve_ivp(printed, (0, 1.0), x0, method='DOP853', rtol=1e-10, atol=1e-14,
                    t_eval=sol.t)
    H_bad = np.array([model.outputs(x, [0.0])['H'] for x in bad.y.T])
    assert np.ptp(H_bad) / H_bad[0] > 1e-4


@pytest.mark.parametrize('source', ['rc', 'ideal'])
def test_power_balance_closes_with_losses(source):
    scene = load_scene('default', {**PAPER_RELEASED,
                                   'source': source, 'Rs': 2e4 if source == 'rc' else 2e3})
    model = build_model(scene)
    x0 = initial_state(model)
    x0[0] = 0.013
    H0 = model.outputs(x0, [0.0])['H']
    # charge phase then free motion: both supplied and dissipated energy are non-trivial
    model.apply_input_jump(x0, [0.0], [2500.0])   # ideal source: instantaneous recharge
    sol = _tight(model, x0, 2500.0, 0.05, rtol=1e-11)
    x1 = sol.y[:, -1].copy()
    model.apply_input_jump(x1, [2500.0], [0.0])
    sol2 = _tight(model, x1, 0.0, 0.05, rtol=1e-11)
    for s, v in ((sol, 2500.0), (sol2, 0.0)):
        for x in s.y.T[::20]:
            H = model.outputs(x, [v])['H']
            w_in, w_diss = x[-2], x[-1]
            assert abs(H - H0 - (w_in - w_diss)) <= 1e-8 * max(w_in, H0)
    assert sol2.y[-2, -1] > 1e-4 and sol2.y[-1, -1] > 1e-4


def test_ideal_source_is_the_small_rs_limit():
    ideal = build_model(load_scene('default', {**PAPER_RELEASED,
                                               'source': 'ideal', 'monitor_power': False}))
    full = build_model(load_scene('default', {**PAPER_RELEASED, 'Rs': 1e-3,
                                              'monitor_power': False}))
    rng = np.random.default_rng(2)
    for _ in range(10):
        q, qd, eps, v = rng.uniform(-0.02, 0.02), rng.uniform(-1, 1), 0.01, 3000.0
        x_ideal = np.array([q, qd, eps])
        charge = ideal.outputs(x_ideal, [v])['q_p']
        # the full model at the same (quasi-static) charge has the same mechanics
        a_full = full.f(0, np.array([q, qd, eps, charge]), [v])
        np.testing.assert_allclose(a_full[:3], ideal.f(0, x_ideal, [v]), rtol=1e-10)


def test_no_creep_is_the_zero_maxwell_modulus_limit():
    from det_sim_ros.sim.simulator import simulate
    no_creep = simulate(load_scene('default', {**PAPER_RELEASED,
                                               'creep': False}), lambda t: 3000.0 * (t > 0.05),
                        0.2)
    soft = simulate(load_scene('default', {**PAPER_RELEASED,
                                           'E_M': 1e-9}), lambda t: 3000.0 * (t > 0.05), 0.2)
    np.testing.assert_allclose(no_creep['y'], soft['y'], rtol=1e-9, atol=1e-13)
    assert 'eps_E[0]' not in build_model(load_scene('default', {**PAPER_RELEASED,
                                                                'creep': False})).state_names
    assert 'q_p[0]' not in build_model(load_scene('default', {**PAPER_RELEASED,
                                                              'source': 'ideal'})).state_names


def test_domain_error_names_the_stretch():
    model = build_model(load_scene('default', PAPER_RELEASED))
    x = initial_state(model)
    x[0] = 1.0   # y = c2 q^2 far beyond the beam length
    with pytest.raises(ModelDomainError, match='lambda'):
        model.f(0, x, [0.0])
    x[0] = math.nan
    with pytest.raises(ModelDomainError, match='non-finite'):
        model.f(0, x, [0.0])


@pytest.mark.parametrize('overrides, message', [
    ({'physics.l0': -0.05}, r"physics.l0'.*out of range \(0"),
    ({'physics.E_b': ['4.0e9']}, 'must be a number'),
    ({'physics.Rs': 0.0}, "physics.Rs'"),
    ({'physics.n': 2.5}, 'integer'),
    ({'scene.eps_b': -1.0}, "scene.eps_b'"),
    ({'scene.beam': 'cantilever'}, "must be one of 'simply_supported', 'fixed'"),
    ({'scene.creep': 1}, 'true or false'),
    ({'physics.Y': math.inf}, 'finite'),
    ({'physics.bogus': 1.0}, "unknown scene key physics.'bogus'"),
    ({'scene.n_ritz': 13}, r"scene.n_ritz'.*out of range"),
])
def test_bad_parameters_are_refused_with_the_key(overrides, message):
    with pytest.raises(SceneError, match=message):
        load_scene('default', overrides)


@pytest.mark.parametrize('beam', ['fixed', 'simply_supported'])
@pytest.mark.parametrize('fidelity', ['consistent', 'exact'])
def test_every_allowed_ritz_count_builds_and_steps(beam, fidelity):
    """
    Check the largest n_ritz the scene keys allow (12) builds and steps at every level.

    The kernel holds a cell's quadrature nodes in fixed arrays; the exact rule at 12 terms on
    the fixed beam needs 66 nodes, and a smaller array refused the model ("inconsistent
    layout") although the key allowed it.
    """
    from det_sim_ros.sim.simulator import Simulator
    sim = Simulator(load_scene('default', {'scene.n_ritz': 12, 'scene.beam': beam,
                                           'scene.fidelity': fidelity}))
    sim.set_input([3000.0])
    for _ in range(20):
        out = sim.step()
    assert np.all(np.isfinite(out)) and not sim.fault


def test_missing_key_and_malformed_yaml(tmp_path):
    from det_sim_ros.scenes.scene import scene_to_dict
    data = scene_to_dict(load_scene('default', PAPER_RELEASED))
    del data['physics']['Rp']
    with pytest.raises(SceneError, match=r"physics.'Rp'.*missing"):
        load_scene(data)
    bad = tmp_path / 'bad.yaml'
    bad.write_text('sim_node:\n  ros__parameters:\n    scene: [unclosed\n')
    with pytest.raises(SceneError, match='malformed YAML.*line'):
        load_scene(str(bad))
    with pytest.raises(SceneError, match='not found'):
        load_scene('no_such_scene')


def test_scene_round_trip_and_overrides():
    scene = load_scene('default', {**PAPER_RELEASED, 'eps_b': 0.25, 'Rs': '1.0e3'})
    assert scene.eps_b == 0.25 and scene.physics.Rs == 1000.0
    assert load_scene(scene) == scene
    assert scene.beam == 'fixed' and scene.rate_hz == 1000.0 and scene.source == 'rc'


def test_yaml_exponent_without_sign_in_a_file_is_refused(tmp_path):
    text = open(load_scene.__globals__['find_config']('default')).read()
    bad = tmp_path / 'exp.yaml'
    bad.write_text(text.replace('E_b: 4.0e+9', 'E_b: 4.0e9'))
    with pytest.raises(SceneError, match=r"physics.E_b'.*YAML 1.1.*4.0e\+9"):
        load_scene(str(bad))
