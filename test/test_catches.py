"""
Checks against something independent of the code they check.

A re-simulation that starts from a logged initial state other than the scene's, the steppers'
orders against scipy's DOP853 (not against one of the package's own methods, which would share
a fault of the stepping core), the rest state against scipy's root finder on the compiled
right-hand side, every ranged scene key just above its maximum, and numbers that YAML 1.1 reads
as text.
"""

from det_sim_ros.io import replay
from det_sim_ros.io.log import Recorder
from det_sim_ros.scenes.scene import load_scene, SceneError
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

# the paper's one-term model: the fidelity is not the subject of these tests, and its
# numbers are the ones pinned here
PAPER = {'scene.fidelity': 'paper'}

COMMANDS = {0: [0.0], 40: [2500.0], 90: [1200.0]}
N_STEPS = 150


def _record_from(tmp_path, x0, log_x0=True):
    """
    Run the default scene from ``x0`` and log it as the node logs it; return the path.

    With ``log_x0`` False the log lacks the 'x0' metadata (a re-simulation then starts from
    the scene's own initial state).
    """
    sim = Simulator(load_scene('default', PAPER))
    sim.x0 = np.array(x0, dtype=float)
    sim.reset()
    path = tmp_path / 'moved_start.mcap'
    metadata = {'method': sim.method.name, 'substeps': sim.substeps_setting}
    if log_x0:
        metadata['x0'] = repr(sim.x0.tolist())
    with Recorder(path, sim.scene, metadata=metadata) as recorder:
        replay.simulate_to_log(recorder, sim, COMMANDS, N_STEPS)
    return str(path)


def _moved_start():
    """Return the scene's initial state with the deflection, its rate and the charge moved."""
    sim = Simulator(load_scene('default', PAPER))
    scene_x0 = sim.x0
    x0 = scene_x0.copy()
    names = sim.model.state_names
    x0[names.index('q[0]')] *= 0.8          # deflection: 80 % of the rest value, m
    x0[names.index('q_dot[0]')] = 0.3       # m/s
    assert not np.array_equal(x0, scene_x0)
    return x0


def test_resimulation_starts_from_the_logged_initial_state(tmp_path):
    path = _record_from(tmp_path, _moved_start())
    result = replay.resimulate(path)
    assert result.ok(), result.table()
    assert result.steps == N_STEPS and result.commands == len(COMMANDS)
    assert all(v == 0.0 for v in result.max_deviation.values()), result.table()


def test_ignoring_the_logged_initial_state_would_be_seen(tmp_path):
    """
    Check that the check above can fail.

    The same run logged without its initial state re-simulates from the scene's own and
    deviates.
    """
    path = _record_from(tmp_path, _moved_start(), log_x0=False)
    result = replay.resimulate(path)
    assert max(result.max_deviation.values()) > 0.0
    assert not result.ok()


# -- the steppers' orders against scipy's DOP853 (not against one of the package's own methods) --

def _small_oscillation():
    """Return the ideal-source scene without creep at 100 Hz: a non-stiff two-state system."""
    from det_sim_ros.physics.model import build_model
    from det_sim_ros.physics.statics import initial_state
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
def test_stepper_order_against_scipy_dop853(name, order):
    """Errors at the end of 20 ms against scipy's DOP853 at rtol 1e-13 shrink as h^order."""
    from det_sim_ros.sim import integrators
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
    from det_sim_ros.physics.model import build_model
    from det_sim_ros.physics.statics import initial_state
    model = build_model(load_scene('default', overrides))
    rest = initial_state(model)
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


# -- scene values above their range and numbers YAML 1.1 reads as text ----------------------------

def _ranged_scene_keys():
    from det_sim_ros.scenes import keys
    sections = dict(keys.SECTIONS, structure=keys.STRUCTURE_SPEC, **{'': keys.TOP_SPEC})
    for section, spec in sections.items():
        for key, entry in spec.items():
            if entry[0] in ('int', 'float') and np.isfinite(entry[3]):
                yield (f'{section}.{key}' if section else key), entry


RANGED_SCENE_KEYS = dict(_ranged_scene_keys())


@pytest.mark.parametrize('key', sorted(RANGED_SCENE_KEYS))
def test_scene_value_just_above_its_maximum_is_refused(key):
    kind, upper = RANGED_SCENE_KEYS[key][0], RANGED_SCENE_KEYS[key][3]
    above = upper + 1 if kind == 'int' else upper * (1.0 + 1e-9) + 1e-12
    base = {'structure.type': 'array'} if key.startswith('structure.') else {}
    with pytest.raises(SceneError, match=f"{key}'.*out of range"):
        load_scene('default', {**PAPER, **base, key: above})


@pytest.mark.parametrize('text', ['4.0e9', '4e9'])
def test_yaml_11_exponent_text_in_a_mapping_is_refused_with_the_fix(text):
    """
    Check that YAML 1.1 exponent text in a mapping is refused with the fix.

    A mapping (as a parsed YAML 1.1 file gives it) holding '4.0e9' as text: refused, with the
    advice to write the exponent's sign; the same text as an override is a number.
    """
    from det_sim_ros.scenes.scene import scene_to_dict
    data = scene_to_dict(load_scene('default', PAPER))
    data['physics']['E_b'] = text
    with pytest.raises(SceneError, match=r"physics.E_b'.*YAML 1.1.*4.0e\+9"):
        load_scene(data)
    assert load_scene('default', {**PAPER, 'physics.E_b': text}).physics.E_b == 4.0e9
