"""Test MIMO scenes: the two-DET plate, arrays of independent copies, scene validation."""

from det_sim_ros.physics.model import build_model
from det_sim_ros.physics.statics import initial_state
from det_sim_ros.scenes.scene import load_scene, SceneError
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
import pytest
from scipy.integrate import solve_ivp

# the paper's start (q = q0, released): these tests exercise the buckling transient
# the paper's one-term model: the fidelity is not the subject of these tests, and its
# numbers are the ones pinned here
PAPER = {'scene.fidelity': 'paper'}
RELEASED = {'scene.initial_state': 'released', **PAPER}


def _step(t):
    return 3000.0 * (t >= 0.05)


def test_plate_with_equal_inputs_reproduces_the_single_cell_to_round_off():
    siso = simulate(load_scene('default', RELEASED), _step, 0.4)
    plate = simulate(load_scene('plate', RELEASED), lambda t: [_step(t)] * 2, 0.4)
    for side in ('left', 'right'):
        for name in ('q', 'y', 'q_p', 'i_DE'):
            scale = np.max(np.abs(siso[name]))
            if name == 'i_DE':   # (v - v_p)/Rs cancels: round-off is relative to v/Rs
                scale = 3000.0 / 2.0e3
            assert np.max(np.abs(plate[f'{name}[{side}]'] - siso[name])) <= 1e-12 * scale
    assert np.max(np.abs(plate['plate_y'] - siso['y'])) <= 1e-12 * np.max(siso['y'])
    assert np.max(np.abs(plate['plate_phi'])) <= 1e-12
    # energy: two cells, the plate's 2 m moving with both
    assert np.max(np.abs(plate['H'] - 2 * siso['H'])) <= 1e-12 * np.max(np.abs(siso['H']))


@pytest.mark.parametrize('active', ['left', 'right'])
def test_plate_rotates_with_one_input_and_the_sign_follows_the_side(active):
    scene = load_scene('plate', RELEASED)
    volts = (lambda t: [_step(t), 0.0]) if active == 'left' else (lambda t: [0.0, _step(t)])
    r = simulate(scene, volts, 0.4)
    w = scene.structure['plate_width']
    # phi = (y_left - y_right) / w: positive when the right side's Delta-y = y0 - y is larger
    assert np.allclose(r['plate_phi'], (r['y[left]'] - r['y[right]']) / w, rtol=0, atol=1e-15)
    phi_end = r['plate_phi'][-1]
    assert abs(phi_end) > 0.02                       # rad: a real rotation, not round-off
    assert np.sign(phi_end) == (-1.0 if active == 'left' else 1.0)
    # ... and a translation: the plate's centre moves too
    assert abs(r['plate_y'][-1] - r['plate_y'][0]) > 1e-3


def test_plate_power_balance_closes():
    scene = load_scene('plate', {**RELEASED, 'Rs': 2e4})
    model = build_model(scene)
    x = initial_state(model)
    H0 = model.outputs(x, [0.0, 0.0])['H']
    u = np.array([2500.0, 800.0])
    scale = np.where(np.char.startswith(np.array(model.state_names), 'q_p'), 1e-5, 1e-3)
    sol = solve_ivp(lambda t, z: model.f(t, z, u), (0, 0.08), x, method='DOP853', rtol=1e-11,
                    atol=1e-11 * scale, dense_output=False)
    assert sol.success
    for z in sol.y.T[::10]:
        H = model.outputs(z, u)['H']
        w_in, w_diss = z[-2], z[-1]
        assert abs(H - H0 - (w_in - w_diss)) <= 1e-8 * max(w_in, abs(H0))
    assert sol.y[-2, -1] > 1e-4 and sol.y[-1, -1] > 1e-5
    # and through the project's stepper with its default tolerance
    sim = Simulator(scene)
    simulate(sim, lambda t: [2500.0 * (t > 0.01), 800.0 * (t > 0.03)], 0.2)
    assert abs(sim.power_residual()) < 1e-5


def test_array_copies_are_independent_and_each_has_its_own_physics():
    scene = load_scene('array', {**RELEASED, 'structure.copies': 3, 'structure.spread': 0.1,
                                 'dets.det1.Rs': 5.0e3})
    physics = scene.cell_physics()
    assert physics[1].Rs == 5.0e3
    assert len({p.Y for p in physics}) == 3          # spread applied per copy
    assert scene.cell_physics() == physics           # ... and seeded: deterministic
    volts = [lambda t: _step(t), lambda t: 1500.0 * (t >= 0.1), lambda t: 0.0]
    r = simulate(scene, lambda t: [v(t) for v in volts], 0.3)
    for i, name in enumerate(scene.det_names):
        single = simulate(scene.cell_scene(i), volts[i], 0.3)
        for out in ('q', 'y', 'q_p'):
            scale = max(np.max(np.abs(single[out])), 1e-30)
            # same physics, same steps: equal up to the step-size choice of the batch
            assert np.max(np.abs(r[f'{out}[{name}]'] - single[out])) <= 1e-6 * scale, out


def test_array_scene_scales_linearly_in_the_mass_matrix():
    """Check that 1000 copies solve the mass matrix per copy (block diagonal), not 1000 x 1000."""
    scene = load_scene('array', {**RELEASED, 'structure.copies': 1000, 'structure.spread': 0.0})
    model = build_model(scene)
    assert model.arrays.group_q.shape == (1001,)     # one group per copy
    assert model.kernel.mass_block == 1
    r = simulate(Simulator(model), lambda t: np.full(1000, _step(t)), 0.06)
    first = r['q[det0]']
    assert np.array_equal(r['q[det999]'], first)


@pytest.mark.parametrize('overrides, words', [
    ({'structure.type': 'plate', 'structure.dets': ['a', 'b', 'c']}, 'has 2 DET'),
    ({'structure.dets': ['x', 'x']}, 'unique'),
    ({'dets.nobody.Rs': 1.0}, 'no DET of that name'),
    ({'dets.det0.Rz': 1.0}, "unknown scene key dets.det0.'Rz'"),
    ({'dets.det0.Rs': -1.0}, 'out of range'),
    ({'structure.spread_keys': ['n']}, 'not a float physics key'),
    ({'structure.type': 'ring'}, 'must be one of'),
    ({'structure.colour': 1}, 'unknown scene key structure'),
])
def test_bad_structure_is_refused_with_a_clear_message(overrides, words):
    with pytest.raises(SceneError, match=words):
        load_scene('default', overrides)


def test_yaml_text_numbers_in_det_overrides_are_caught():
    data = {'sim_node': {'ros__parameters': {
        **_default_dict(), 'dets': {'det0': {'Rs': '4.0e9'}}}}}
    with pytest.raises(SceneError, match='4.0e\\+9'):
        load_scene(data)


def _default_dict():
    from det_sim_ros.scenes.scene import scene_to_dict
    return scene_to_dict(load_scene('default', RELEASED))


def test_multi_det_scene_round_trips_through_its_dict():
    scene = load_scene('plate', {**RELEASED, 'dets.left.Rs': 1.0e3})
    again = load_scene(_default_dict() | {'structure': dict(scene.structure),
                                          'dets': {'left': {'Rs': 1.0e3}}})
    assert again.cell_physics() == scene.cell_physics()
    assert scene.replace() == scene
