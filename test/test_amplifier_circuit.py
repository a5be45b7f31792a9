"""
The amplifier in the supply circuit: current limit, slew rate and bandwidth as they act.

The current is checked between the control samples of a 1 kHz run (sampled at 50 kHz), the
ramp and the step response against their closed forms; every knob off changes nothing; the
power balance holds; a log re-simulates bit for bit.
"""

import math

from det_sim_ros.io.log import Recorder
from det_sim_ros.io.replay import resimulate, simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np

LIMIT = 2.0e-3   # A


def _run(overrides, profile, rate_hz, source='default'):
    sim = Simulator(load_scene(source, dict(overrides, rate_hz=rate_hz)))
    n = len(profile)
    return sim, simulate(sim, np.asarray(profile, dtype=float), n / rate_hz)


def _step(rate_hz, t_on, t_off, t_end, volts):
    t = np.arange(int(round(t_end * rate_hz))) / rate_hz
    return np.where((t >= t_on) & (t < t_off), volts, 0.0)


def test_the_current_never_exceeds_the_limit_between_samples():
    # a slow amplifier (200 Hz) so the limit is reached from the linear law inside steps too,
    # sampled at 50 kHz: 50 samples in each 1 ms period of a 1 kHz run
    rate = 5.0e4
    sim, run = _run({'amplifier.current_limit': LIMIT, 'amplifier.bandwidth': 200.0},
                    _step(rate, 1e-3, 0.03, 0.06, 3000.0), rate)
    current = run['i_DE']
    assert np.max(np.abs(current)) <= LIMIT * (1.0 + 1e-12)
    assert current.max() >= LIMIT * (1.0 - 2e-6) and current.min() <= -LIMIT * (1.0 - 2e-6)
    # between samples: the mean current through Rs (the charge's change plus the leak through
    # Rp) stays within the limit, so no internal step ran a current beyond it
    leak = 0.5 * (run['v_p'][1:] + run['v_p'][:-1]) / sim.scene.physics.Rp
    mean_current = np.diff(run['q_p']) * rate + leak
    assert np.max(np.abs(mean_current)) <= LIMIT * (1.0 + 1e-7)
    # at the limit the charge grows at I - v_p/Rp exactly
    at_limit = np.nonzero(current[1:] == LIMIT)[0][5:50] + 1
    rate_qp = np.diff(run['q_p'])[at_limit] * rate
    leak = run['v_p'][at_limit] / sim.scene.physics.Rp
    np.testing.assert_allclose(rate_qp, LIMIT - leak, rtol=1e-6)


def test_a_slew_limited_step_ramps_at_the_limit():
    rate, slew = 1.0e4, 1.0e6   # V/s: 2 kV in 2 ms
    sim, run = _run({'amplifier.slew_rate': slew}, _step(rate, 1e-3, 1.0, 6e-3, 2000.0), rate)
    v_a = run.x[:, sim.model.state_names.index('v_a[0]')]
    t = run.t
    ramp = (t > 1.0e-3) & (t < 2.9e-3)
    np.testing.assert_allclose(v_a[ramp], slew * (t[ramp] - 1e-3), rtol=1e-9)
    assert np.all(v_a[t >= 3.0e-3] == 2000.0)
    # the DET follows the ramp a lag Rs C behind: its voltage rises at the slew rate
    mid = (t >= 1.5e-3) & (t <= 2.5e-3)
    slope = np.polyfit(t[mid], run['v_p'][mid], 1)[0]
    assert abs(slope / slew - 1.0) < 0.01


def test_the_bandwidth_step_response_is_first_order_behind_rs_c():
    # a heavy interface mass freezes the beam, so C is constant: v_a is first order with
    # tau_a = 1/(2 pi f), and v_p follows it through Rs C (tau_c = C Rs || Rp): the two-pole
    # response v_inf (1 - (tau_a e^-t/tau_a - tau_c e^-t/tau_c) / (tau_a - tau_c))
    rate, f, volts = 1.0e5, 1.0e3, 2000.0
    sim, run = _run({'amplifier.bandwidth': f, 'physics.m': 100.0},
                    _step(rate, 0.0, 1.0, 3e-3, volts), rate)
    tau_a = 1.0 / (2.0 * math.pi * f)
    t = run.t[1:] - run.t[0]
    v_a = run.x[1:, sim.model.state_names.index('v_a[0]')]
    np.testing.assert_allclose(v_a, volts * -np.expm1(-t / tau_a), rtol=1e-9, atol=1e-9)
    p = sim.scene.physics
    cap = run['C'][0]
    tau_c = cap * p.Rs * p.Rp / (p.Rs + p.Rp)
    v_inf = volts * p.Rp / (p.Rs + p.Rp)
    two_pole = v_inf * (1.0 - (tau_a * np.exp(-t / tau_a) - tau_c * np.exp(-t / tau_c))
                        / (tau_a - tau_c))
    assert np.max(np.abs(run['v_p'][1:] - two_pole)) < 1e-4 * volts
    assert np.max(np.abs(run['C'] / cap - 1.0)) < 1e-5   # the beam was frozen indeed


def test_every_knob_off_is_bit_identical_to_no_amplifier():
    profile = _step(1e3, 0.05, 0.15, 0.2, 2500.0)
    off = {f'amplifier.{key}': 0 for key in ('slew_rate', 'current_limit', 'bandwidth',
                                             'dac_bits', 'delay', 'offset')}
    sim, zeros = _run(off, profile, 1e3)
    assert sim.model.arrays.amplifier == 0 and sim.command_stage is None
    _, plain = _run({}, profile, 1e3)
    assert np.array_equal(zeros.x, plain.x)


def test_the_power_balance_holds_with_every_knob_on():
    # at tolerance 1e-6: the power-balance residual grows with the tolerance (simulator.py)
    knobs = {'amplifier.current_limit': LIMIT, 'amplifier.bandwidth': 2.0e3,
             'amplifier.slew_rate': 1.0e6, 'amplifier.dac_bits': 12,
             'integrator.tolerance': 1e-6}
    profile = _step(1e3, 0.01, 0.12, 0.2, 3000.0) + _step(1e3, 0.15, 0.17, 0.2, 1500.0)
    sim, _ = _run(knobs, profile, 1e3)
    assert abs(sim.power_residual()) < 1e-4
    sim, _ = _run(knobs, np.column_stack([profile, 0.8 * profile]), 1e3, 'plate')
    assert abs(sim.power_residual()) < 1e-4


def test_resim_of_a_log_with_the_circuit_knobs_on_is_bit_exact(tmp_path):
    scene = load_scene('plate', {'amplifier.current_limit': LIMIT, 'dets.left.bandwidth': 2e3,
                                 'dets.right.slew_rate': 1.0e6, 'amplifier.delay': 0.002})
    sim = Simulator(scene)
    log = str(tmp_path / 'amp.mcap')
    recorder = Recorder(log, scene, metadata={'method': sim.method.name,
                                              'substeps': sim.substeps_setting})
    simulate_to_log(recorder, sim, lambda k: [2500.0, 1800.0 + k] if k % 20 == 3 else None, 120)
    recorder.close()
    result = resimulate(log)
    assert result.steps == 120 and result.ok(tolerance=0.0), result.table()


def test_a_limit_no_current_can_reach_in_a_period_steps_as_without_it():
    # a 2 mA limit (4 V across Rs) while the released beam rings at the 1 V offset: no period
    # can reach it, so they step as without the limit (whole calls, the same bits) and none is
    # watched step by step; the 3 kV step at 0.2 s reaches it (4.4 mA without the limit,
    # through the 40 kHz bandwidth)
    knobs = {'scene.initial_state': 'released', 'amplifier.bandwidth': 4.0e4,
             'amplifier.offset': 1.0}
    profile = _step(1e3, 0.2, 0.3, 0.3, 3000.0)
    sim = Simulator(load_scene('default', {**knobs, 'amplifier.current_limit': LIMIT}))
    held = simulate(sim, profile[:200], 0.2)
    assert sim.stepper.limit_watched_periods == 0
    _, free = _run(knobs, profile, 1e3)
    assert np.array_equal(held.x, free.x[:201])
    stepped = simulate(sim, profile[200:], 0.1)
    assert sim.stepper.limit_watched_periods > 0
    assert np.max(np.abs(stepped['i_DE'])) <= LIMIT * (1.0 + 1e-12)
    assert np.max(np.abs(free['i_DE'])) > LIMIT
