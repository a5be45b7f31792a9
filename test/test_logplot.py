"""
``det_sim plot``: logs of single, plate and array scenes read back and plotted.

The logs read back to the simulated values, commands as held steps, the PNG and the
summary, unfinished files and bad input.
"""

import math

from det_sim_ros.cli.det_sim import main
from det_sim_ros.io import logplot
from det_sim_ros.io.log import Recorder
from det_sim_ros.io.replay import OutputContract, simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

# the paper's one-term model: the fidelity is not the subject of these tests, and it keeps
# them light
PAPER = {'scene.fidelity': 'paper'}


def make_log(path, scene, commands, n_steps, joint=False):
    sim = Simulator(scene)
    with Recorder(str(path), scene, metadata={'method': sim.method.name}) as rec:
        simulate_to_log(rec, sim, commands, n_steps, joint_commands=joint)
    return path


def expected(scene, commands, n_steps):
    """Publish values per sample, offline (the node's contract)."""
    sim = Simulator(scene)
    contract = OutputContract(sim.model)
    rows = [np.array(list(sim.outputs().values()))]
    for k in range(n_steps):
        if k in commands:
            sim.set_input(commands[k])
        rows.append(sim.step().copy())
    return contract, rows


@pytest.mark.parametrize('name, overrides, joint', [
    ('default', {}, False), ('plate', {}, True), ('array', {'structure.copies': 3}, False)])
def test_read_log_gives_the_published_values(tmp_path, name, overrides, joint):
    scene = load_scene(name, overrides)
    n_det = scene.n_dets
    commands = {0: [1000.0] * n_det, 50: [3000.0] * n_det, 120: [-5.0] + [500.0] * (n_det - 1)}
    log = make_log(tmp_path / 'run.mcap', scene, commands, 200, joint)
    data = logplot.read_log(str(log))
    assert data.det_names == list(scene.det_names) and data.complete
    # commands as held steps: clamped as the node does, from the command's time on
    np.testing.assert_allclose(data.voltage_t, [0.0, 0.0, 0.05, 0.12])
    np.testing.assert_allclose(data.voltage[-1], [0.0] + [500.0] * (n_det - 1))
    assert data.commands == 3 and data.refused == 0
    contract, rows = expected(scene, commands, 200)
    titles = {c.title: c for c in data.channels}
    want = {'deflection q': ('deflection', 'position', 1e3),
            'deflection rate dq/dt': ('deflection', 'velocity', 1.0),
            'displacement Δy': ('displacement', 'position', 1e3),
            'charge q_p': ('charge', 'position', 1e6),
            'current i_DE': ('current', 'position', 1e3)}
    for title, (topic, field, scale) in want.items():
        ch = titles[title]
        assert ch.names == list(scene.det_names)
        np.testing.assert_allclose(ch.t, np.arange(201) * scene.dt, atol=1e-12)
        np.testing.assert_array_equal(ch.values, np.array(
            [contract.values(r, topic, field) for r in rows]) * scale)
    if name == 'plate':
        structure = [contract.structure(r) for r in rows]
        np.testing.assert_array_equal(titles['plate height Δy'].values[:, 0],
                                      np.array(structure)[:, 0] * 1e3)
        assert 'plate tilt φ − φ0' in titles
    text = logplot.summary(data)
    assert '3 commands (0 refused)' in text and 'displacement Δy (mm)' in text


def test_refused_commands_hold_the_voltage(tmp_path):
    scene = load_scene('plate', PAPER)
    commands = {0: [1000.0, 1000.0], 10: [math.nan, 5.0], 20: [2000.0, 2000.0, 1.0]}
    sim = Simulator(scene)
    log = tmp_path / 'bad.mcap'
    with Recorder(str(log), scene) as rec:
        from std_msgs.msg import Float64MultiArray
        from sensor_msgs.msg import JointState
        for k, volts in commands.items():
            rec.record('voltage_command', Float64MultiArray(data=volts), k * 1_000_000)
        rec.record('voltage_command_joint', JointState(name=['right'], position=[2500.0]),
                   30_000_000)
        rec.record('voltage_command_joint', JointState(name=['middle'], position=[1.0]),
                   40_000_000)
        simulate_to_log(rec, sim, {}, 50)
    data = logplot.read_log(str(log))
    assert data.commands == 5 and data.refused == 3
    np.testing.assert_allclose(data.voltage_t, [0.0, 0.0, 0.03])
    np.testing.assert_allclose(data.voltage, [[0, 0], [1000, 1000], [1000, 2500]])


def test_cli_plot_writes_png_and_summary(tmp_path, capsys):
    scene = load_scene('plate', PAPER)
    log = make_log(tmp_path / 'plate_run.mcap', scene, {0: [3000.0, 0.0]}, 100)
    out = tmp_path / 'plots'
    assert main(['plot', str(log), '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    assert 'DETs: left, right' in printed and 'plate tilt' in printed
    assert (out / 'plate_run.png').stat().st_size > 5000
    assert (out / 'plate_run_summary.txt').read_text().startswith('log: ')


def test_unfinished_log_plots_its_readable_part(tmp_path):
    scene = load_scene('default', PAPER)
    log = make_log(tmp_path / 'run.mcap', scene, {0: [3000.0]}, 3000)
    raw = log.read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(raw[:len(raw) // 2])
    data = logplot.read_log(str(cut))
    assert not data.complete
    q = next(c for c in data.channels if c.title == 'deflection q')
    assert 100 < len(q.t) < 3001
    np.testing.assert_allclose(np.diff(q.t), scene.dt)      # no torn or mixed-up sample


def test_odd_payloads_take_the_slow_path(tmp_path):
    """
    Check that a message unlike its length group is decoded one by one and left out.

    A message whose fixed bytes differ from its length group (another name) is decoded one
    by one and, not having the node's channel set, left out.
    """
    from sensor_msgs.msg import JointState
    scene = load_scene('default', PAPER)
    log = tmp_path / 'odd.mcap'
    with Recorder(str(log), scene) as rec:
        sim = Simulator(scene)
        simulate_to_log(rec, sim, {}, 20)
        odd = JointState(name=['det9'], position=[1.0], velocity=[2.0])
        odd.header.stamp.sec = 5
        rec.record('deflection', odd, 5_000_000_000)
    data = logplot.read_log(str(log))
    q = next(c for c in data.channels if c.title == 'deflection q')
    assert len(q.t) == 21 and q.t[-1] < 1.0


@pytest.mark.parametrize('content, message', [
    (None, 'No such file'), (b'not an mcap file', 'not an MCAP file')])
def test_cli_plot_bad_input_one_line(tmp_path, capsys, content, message):
    path = tmp_path / 'x.mcap'
    if content is not None:
        path.write_bytes(content)
    assert main(['plot', str(path)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_a_killed_run_is_read_up_to_its_last_flush_and_marked_unfinished(tmp_path):
    """
    Check that a file as a SIGKILL leaves it is read to its last flush, unfinished.

    A file as a SIGKILL leaves it (records up to the last flush and the provisional end) is
    read by the same path as LogReader: its samples, and complete False.
    """
    import shutil
    scene = load_scene('default', PAPER)
    live = tmp_path / 'live.mcap'
    rec = Recorder(str(live), scene, flush_sim_s=0.02)
    simulate_to_log(rec, Simulator(scene), {0: [3000.0]}, 110)
    killed = tmp_path / 'killed.mcap'
    shutil.copyfile(live, killed)      # the file on disk before close
    rec.close()
    data = logplot.read_log(str(killed))
    assert not data.complete and 'UNFINISHED' in logplot.summary(data)
    q = next(c for c in data.channels if c.title == 'deflection q')
    assert 80 <= len(q.t) < 111    # the samples after the last flush are lost
    np.testing.assert_allclose(np.diff(q.t), scene.dt)
    assert logplot.read_log(str(live)).complete
