"""
The amplifier's command side: DAC levels, delay in whole periods and offset.

The same through Simulator.step, simulate() and a log's re-simulation.
"""

from det_sim_ros.io.log import LogReader, Recorder
from det_sim_ros.io.replay import resimulate, simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.amplifier import CommandStage
from det_sim_ros.sim.simulator import simulate, Simulator
import numpy as np
import yaml

V_MAX = 3000.0


def _profile(n=60):
    """Return a ramp, a step and a hold (commands per period, V)."""
    k = np.arange(n)
    return np.where(k < 20, k * 97.3, np.where(k < 40, 2345.6, 612.5))


def test_dac_levels_are_exact_multiples_of_the_lsb_within_half_an_lsb():
    scene = load_scene('default', {'amplifier.dac_bits': 6})
    stage = CommandStage.for_scene(scene)
    lsb = V_MAX / 63.0
    commands = np.linspace(0.0, V_MAX, 1001)
    applied = stage.run(commands)[:, 0]
    codes = np.rint(applied / lsb)
    assert np.array_equal(applied, codes * lsb)                  # exactly on a level
    assert np.all(np.abs(applied - commands) <= lsb / 2 * (1 + 1e-12))
    assert set(codes) == set(range(64))                          # every level is reached
    assert applied[0] == 0.0 and applied[-1] == 63 * lsb


def test_delay_is_exact_in_periods_and_offset_adds_to_every_period():
    stage = CommandStage.for_scene(load_scene(
        'plate', {'amplifier.delay': 0.003, 'dets.right.delay': 0.0,
                  'amplifier.offset': -2.5}))
    commands = np.column_stack([_profile(), _profile()[::-1]])
    one_by_one = np.array([stage.apply(row) for row in commands])
    stage.reset()
    assert np.array_equal(stage.run(commands), one_by_one)
    assert np.array_equal(one_by_one[3:, 0], commands[:-3, 0] - 2.5)   # 3 periods late
    assert np.array_equal(one_by_one[:3, 0], [-2.5] * 3)               # 0 V before
    assert np.array_equal(one_by_one[:, 1], commands[:, 1] - 2.5)      # right: no delay


def test_the_circuit_receives_what_the_stage_makes_of_the_commands():
    on = load_scene('default', {'amplifier.dac_bits': 8, 'amplifier.delay': 0.002,
                                'amplifier.offset': 4.0})
    commands = _profile()
    run = simulate(Simulator(on), commands, 0.06)
    lsb = V_MAX / 255.0
    expected = np.concatenate([[0.0, 0.0], np.rint(commands[:-2] / lsb) * lsb]) + 4.0
    ideal = simulate(Simulator('default'), expected, 0.06)
    assert np.array_equal(run.x, ideal.x)
    sim = Simulator(on)
    stepped = [sim.outputs()['q']]
    for volts in commands:
        sim.set_input([float(volts)])
        stepped.append(sim.step()[0])
        assert sim.u[0] == volts              # the command stays what the controller sent
    assert np.array_equal(stepped, run['q'])
    assert sim.applied_input[0] == expected[-1]


def test_resim_of_a_log_with_the_amplifier_on_is_bit_exact(tmp_path):
    scene = load_scene('default', {'amplifier.dac_bits': 10, 'amplifier.delay': 0.004,
                                   'amplifier.offset': 3.0})
    sim = Simulator(scene)
    log = str(tmp_path / 'amp.mcap')
    recorder = Recorder(log, scene, metadata={'method': sim.method.name,
                                              'substeps': sim.substeps_setting})
    simulate_to_log(recorder, sim, lambda k: [1234.5 + 3.1 * k] if k % 7 == 2 else None, 120)
    recorder.close()
    stored = yaml.safe_load(LogReader(log).scene_yaml)['sim_node']['ros__parameters']
    assert stored['amplifier']['delay'] == 0.004
    result = resimulate(log)
    assert result.steps == 120 and result.ok(tolerance=0.0), result.table()


def test_a_held_command_gives_what_the_line_makes_of_it_after_runs_and_resets():
    scene = load_scene('default', {'amplifier.dac_bits': 8, 'amplifier.delay': 0.002,
                                   'amplifier.offset': 4.0})
    held, other = np.full((6, 1), 1234.5), np.full((2, 1), 50.0)
    commands = np.concatenate([held, other, held, held[:1]])
    reference = CommandStage.for_scene(scene).run(commands)
    stage = CommandStage.for_scene(scene)
    stepped = [stage.apply(row) for row in held]
    stepped += list(stage.run(other))             # the line moves on by whole periods
    stepped += [stage.apply(row) for row in np.concatenate([held, held[:1]])]
    assert np.array_equal(np.array(stepped), reference)
    stage.reset()                                 # 0 V in the line again
    assert np.array_equal(np.array([stage.apply(row) for row in held]), reference[:6])
