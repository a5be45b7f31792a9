"""
Linearization, checked against independent computations.

The equilibrium, A/B against independent finite differences of the compiled model, the poles
against a finite-difference Jacobian's eigenvalues, the linear step response against the
nonlinear simulation (first order), python-control, and `det_sim linearize`.
"""

import json
import math
import subprocess
import sys

from conftest import child_env
from det_sim_ros.cli.det_sim import main
from det_sim_ros.physics.linearize import LinearizationError, linearize
from det_sim_ros.physics.model import build_model
from det_sim_ros.physics.statics import rest_shortening
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest
from scipy.linalg import expm


def richardson_jacobian(func, x, scales):
    """
    Return the Jacobian of func at x by Richardson-extrapolated central differences.

    Central differences of func at x, Richardson-extrapolated (error O(h^4)); column j uses
    h_j = 1e-3 scales_j. Independent of the complex-step code (another implementation of the
    physics too: the compiled kernel through Model.f).
    """
    x = np.asarray(x, dtype=float)
    cols = []
    for j in range(x.size):
        def central(h):
            e = np.zeros_like(x)
            e[j] = h
            return (func(x + e) - func(x - e)) / (2.0 * h)
        h = 1e-3 * scales[j]
        cols.append((4.0 * central(h / 2.0) - central(h)) / 3.0)
    return np.column_stack(cols)


def state_scales(lin):
    """
    Return a typical size per state.

    Coordinates ~ the deflection, rates ~ omega x deflection, creep strain ~ 1e-3,
    charge ~ C0 v_max.
    """
    model = lin.model
    a = model.arrays
    q_scale = max(np.max(np.abs(lin.x0[:a.n_q])), 1e-3)
    scales = np.full(model.n_states, 1e-3)
    scales[:a.n_q] = q_scale
    scales[a.n_q:2 * a.n_q] = 500.0 * q_scale
    if a.rc_source:
        scales[-a.n_cells:] = a.C0 * model.scene.physics.v_max
    return scales


def fd_jacobians(lin, model=None):
    """Return A and B by differences of ``model``'s rhs (default: the linearization's model)."""
    model = model or lin.model
    A = richardson_jacobian(lambda x: model.f(0.0, x, lin.u0), lin.x0, state_scales(lin))
    B = richardson_jacobian(lambda u: model.f(0.0, lin.x0, u), lin.u0,
                            np.full(len(lin.u0), 100.0))
    return A, B


PAPER = {'scene.fidelity': 'paper'}
CASES = [('default', {}, 0.0),         # the shipped default: exact kinematics, 5 Ritz terms
         ('default', PAPER, 0.0), ('default', PAPER, 1500.0),
         ('default', {**PAPER, 'scene.beam': 'simply_supported', 'scene.eps_b': 0.15}, 3000.0),
         ('default', {'scene.fidelity': 'consistent', 'scene.n_ritz': 3}, 1500.0),
         ('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 3}, 1500.0),
         ('array', {**PAPER, 'structure.copies': 3, 'structure.spread': 0.05}, 1000.0),
         ('default', {**PAPER, 'scene.source': 'ideal', 'scene.creep': False}, 2000.0),
         ('plate', PAPER, [1500.0, 500.0])]


@pytest.mark.parametrize('name, overrides, volts', CASES)
def test_equilibrium_and_jacobians_match_finite_differences(name, overrides, volts):
    scene = load_scene(name, overrides)
    lin = linearize(scene, volts)
    # the scene's own level: differences of the model built here from the scene, not of the
    # linearization's model
    model = build_model(scene.replace(**{'scene.monitor_power': False}))
    a = model.arrays
    assert a.n_q == scene.ritz_level[1] * scene.n_dets
    # an equilibrium of the compiled model: dx/dt = 0 (relative to the rates' scale)
    rate = model.f(0.0, lin.x0, lin.u0)
    assert np.max(np.abs(rate) / (state_scales(lin) * 1e3)) < 1e-9
    if a.rc_source:   # the charge at its RC equilibrium C(q) V Rp / (Rs + Rp)
        out = model.outputs(lin.x0, lin.u0)
        caps = [out['C']] if model.n_inputs == 1 else [out[f'C[{d}]'] for d in model.input_names]
        np.testing.assert_allclose(lin.x0[-a.n_cells:],
                                   np.array(caps) * lin.u0 * a.Rp / (a.Rs + a.Rp), rtol=1e-12)
    A_fd, B_fd = fd_jacobians(lin, model)
    for exact, fd in ((lin.A, A_fd), (lin.B, B_fd)):
        scale = np.max(np.abs(fd), axis=0, keepdims=True)     # per column
        scale[scale == 0.0] = 1.0
        assert np.max(np.abs(exact - fd) / scale) < 1e-7

    # C: Delta-y and q of the outputs, by differences of the published quantities
    def published(x):
        out = model.output_vector(x, lin.u0)
        y = out[model.channel('y')]
        return np.concatenate([-y, out[model.channel('q')]])
    C_fd = richardson_jacobian(published, lin.x0, state_scales(lin))
    np.testing.assert_allclose(lin.C, C_fd, rtol=1e-7, atol=1e-9 * np.max(np.abs(C_fd)))
    assert lin.D.shape == (2 * model.n_inputs, model.n_inputs) and not lin.D.any()


def test_poles_of_the_paper_model_at_0V_match_fd_eigenvalues():
    """
    Check that the poles at 0 V match the eigenvalues of a finite-difference Jacobian.

    The poles equal the eigenvalues of a finite-difference Jacobian of the nonlinear model to
    1e-6 relative.
    """
    lin = linearize(load_scene('default', PAPER), 0.0)
    A_fd, _ = fd_jacobians(lin)
    poles = lin.poles()
    fd = list(np.linalg.eigvals(A_fd))
    assert len(fd) == len(poles) == 4          # q, qdot, creep, charge
    for p in poles:
        nearest = min(fd, key=lambda e: abs(e - p))
        assert abs(nearest - p) <= 1e-6 * abs(p), (p, nearest)
        fd.remove(nearest)
    assert np.all(poles.real < 0)              # the buckled rest state is stable
    # the charge pole is -1/(C (Rs || Rp)), the beam pair a light resonance near 85 Hz
    slow_beam = poles[np.abs(poles.imag) > 0]
    assert 70.0 < abs(slow_beam[0]) / (2 * math.pi) < 100.0
    assert lin.damping(slow_beam)[0] < 0.05


def zoh_response(lin, du, dt, n):
    """Return the linear model's outputs at t = dt .. n dt for a step du at t = 0 (exact ZOH)."""
    N = lin.A.shape[0]
    M = np.zeros((N + len(du), N + len(du)))
    M[:N, :N], M[:N, N:] = lin.A * dt, lin.B * dt
    E = expm(M)
    Ad, Bd = E[:N, :N], E[:N, N:] @ du
    x, rows = np.zeros(N), []
    for _ in range(n):
        x = Ad @ x + Bd
        rows.append(lin.C @ x)
    return np.array(rows)


def nonlinear_response(scene, lin, du, n):
    sim = Simulator(scene)
    sim.reset(lin.x0)
    sim.set_input(list(lin.u0 + du))
    y0 = rest_shortening(scene)
    iq, iy = sim.output_names.index('q'), sim.output_names.index('y')
    rows = []
    for _ in range(n):
        out = sim.step()
        rows.append([y0 - out[iy], out[iq]])
    return np.array(rows) - lin.z0


def test_linear_step_response_matches_the_nonlinear_one_to_first_order():
    """
    Check that the linear step response matches the nonlinear one to first order.

    A small voltage step from the 1500 V equilibrium: the nonlinear response minus the linear
    one is second order in the step (relative error ~ proportional to it).
    """
    scene = load_scene('default', {**PAPER, 'scene.monitor_power': False,
                                   'integrator.tolerance': 1e-9})
    lin = linearize(scene, 1500.0)
    n = 200   # 0.2 s: the beam's ringing (85 Hz) and most of its decay
    errors = []
    for dv in (4.0, 8.0):
        linear = zoh_response(lin, np.array([dv]), scene.dt, n)
        nonlinear = nonlinear_response(scene, lin, dv, n)
        size = np.max(np.abs(linear), axis=0)
        assert np.all(size > 1e-6)                     # a real response (m)
        errors.append(np.max(np.abs(nonlinear - linear), axis=0) / size)
    assert np.all(errors[0] < 0.01)
    ratio = errors[1] / errors[0]                      # doubling the step doubles it
    assert np.all((1.7 < ratio) & (ratio < 2.3)), ratio


def test_python_control_statespace():
    control = pytest.importorskip('control')
    lin = linearize(load_scene('default', PAPER), 1500.0)
    sys = lin.to_statespace()
    assert isinstance(sys, control.StateSpace)
    np.testing.assert_allclose(np.sort_complex(control.poles(sys)), np.sort_complex(lin.poles()),
                               rtol=1e-9)
    np.testing.assert_allclose(np.ravel(control.dcgain(sys)), lin.dc_gain().ravel(), rtol=1e-9)
    assert list(sys.output_labels) == ['dy[det0]', 'q[det0]']


def test_equilibria_and_their_errors():
    scene = load_scene('default', PAPER)
    plus, minus = linearize(scene, 1500.0, 'buckled+'), linearize(scene, 1500.0, 'buckled-')
    assert plus.z0[1] > 0 > minus.z0[1] and plus.z0[0] == pytest.approx(minus.z0[0])
    straight = linearize(scene, 0.0, 'straight')
    assert straight.z0[1] == 0.0 and np.max(straight.poles().real) > 0    # unstable
    assert linearize(scene, 0.0).z0[0] == pytest.approx(0.0, abs=1e-12)  # Delta-y = 0 at rest
    with pytest.raises(LinearizationError, match='branch ends near'):
        linearize(load_scene('default', {**PAPER, 'scene.eps_b': 0.10}), 3000.0)
    with pytest.raises(LinearizationError, match="no 'buckled\\+' equilibrium"):
        linearize(load_scene('default', {**PAPER, 'scene.eps_b': 0.03}), 0.0)
    with pytest.raises(LinearizationError, match='outside'):
        linearize(scene, -1.0)
    with pytest.raises(LinearizationError, match='unknown branch'):
        linearize(scene, 0.0, 'sideways')


def test_cli_linearize(tmp_path, capsys):
    out = tmp_path / 'lin'
    assert main(['linearize', '--voltage', '1500', '--json', '--out', str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    lin = linearize(load_scene('default'), 1500.0)
    assert [complex(p['real'], p['imag']) for p in report['poles']] == pytest.approx(
        list(lin.poles()))
    assert report['dc_gain_m_per_V']['dy[det0]']['det0'] == pytest.approx(lin.dc_gain()[0, 0])
    assert report['dc_gain_m_per_V']['dy[det0]']['det0'] > 0      # more voltage, more stroke
    assert (out / 'bode.png').stat().st_size > 1000 and (out / 'linearization.json').exists()
    assert main(['linearize', '--scene', 'plate', '--voltage', '1500,1000', '--out',
                 str(out), '--no-plots']) == 0
    text = capsys.readouterr().out
    assert 'f_n (Hz)' in text and 'dy[right]' in text


@pytest.mark.ros
@pytest.mark.parametrize('voltages', [
    [], ['--voltage', '1500'], ['--scene', 'plate', '--voltage', '0,1500']])
def test_cli_linearize_writes_its_bode_plot_without_a_warning(tmp_path, voltages):
    """
    Check the verb's stderr, as a user sees it: nothing, also at 0 V (no gain, no line).

    matplotlib warned 'No artists with labels found to put in legend' for a plot of DETs all at
    0 V (the default).
    """
    pytest.importorskip('matplotlib')
    proc = subprocess.run([sys.executable, '-m', 'det_sim_ros.cli', 'linearize', *voltages,
                           '--out', str(tmp_path)], capture_output=True, text=True,
                          env=child_env(), timeout=120)
    assert proc.returncode == 0 and proc.stderr == '', proc.stderr
    assert (tmp_path / 'bode.png').stat().st_size > 1000


@pytest.mark.parametrize('argv, message', [
    (['--voltage', '4000'], 'outside [0, 3000] V'),
    (['--branch', 'sideways'], 'unknown branch'),
    (['--voltage', '1,2'], 'expected 1 voltage'),
    (['--set', 'scene.eps_b=0.10', '--voltage', '3000'], 'branch ends near'),
    (['--voltage', 'abc'], 'comma-separated'),
])
def test_cli_linearize_bad_input_one_line(tmp_path, capsys, argv, message):
    assert main(['linearize', '--out', str(tmp_path)] + argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert message in err[-1] and 'Traceback' not in '\n'.join(err)
