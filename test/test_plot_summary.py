"""
Test the screen summary of ``det_sim plot``: a screenful for a 100-DET log, every channel on ask.

A log of config/array.yaml (100 DETs) prints one row per quantity; ``--all`` prints every
channel, and the summary file always holds every channel. A log of a few DETs prints every
channel.
"""

from det_sim_ros.cli.det_sim import main
from det_sim_ros.io import logplot
from det_sim_ros.io.log import Recorder
from det_sim_ros.io.replay import simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

# the paper's one-term model: the fidelity is not the subject of these tests, and it keeps
# them light
PAPER = {'scene.fidelity': 'paper'}

SCREEN_LINES = 24


def _log(path, scene, n_steps=20):
    sim = Simulator(scene)
    volts = list(np.linspace(0.0, 3000.0, scene.n_dets))
    with Recorder(str(path), scene, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, {0: volts}, n_steps)
    return str(path)


@pytest.fixture(scope='module')
def array_log(tmp_path_factory):
    return _log(tmp_path_factory.mktemp('array') / 'array_run.mcap',
                load_scene('array', PAPER))


@pytest.fixture(autouse=True)
def no_png(monkeypatch):
    """Skip the PNG: the summary is under test (100 lines per panel take long to draw)."""
    monkeypatch.setattr(logplot, 'plot_log', lambda data, path, **kwargs: path)


def _summary_lines(text):
    return [line for line in text.splitlines() if not line.startswith('wrote ')]


def test_a_100_det_log_prints_a_screenful(array_log, tmp_path, capsys):
    assert main(['plot', array_log, '--out', str(tmp_path)]) == 0
    lines = _summary_lines(capsys.readouterr().out)
    assert len(lines) <= SCREEN_LINES
    text = '\n'.join(lines)
    assert 'DETs: det0, det1 … det99 (100); sim time' in text and '--all' in text
    assert max(len(line) for line in lines) < 130
    rows = {line.split('  ')[0].strip(): line.split() for line in lines[3:-1]}
    assert set(rows) == {'voltage (V)', 'deflection q (mm)', 'deflection rate dq/dt (m/s)',
                         'displacement Δy (mm)', 'charge q_p (µC)', 'current i_DE (mA)'}
    voltage = rows['voltage (V)']
    # channels, samples, min (where), max (where), final min, median, max
    assert voltage[2:] == ['100', '2', '0', 'det0', '3000', 'det99', '0', '1500', '3000']
    written = (tmp_path / 'array_run_summary.txt').read_text().splitlines()
    assert len(written) > 600


def test_all_prints_every_channel(array_log, tmp_path, capsys):
    assert main(['plot', array_log, '--out', str(tmp_path), '--all']) == 0
    lines = _summary_lines(capsys.readouterr().out)
    assert len(lines) == 3 + 6 * 100
    assert lines == (tmp_path / 'array_run_summary.txt').read_text().splitlines()


def test_a_few_dets_print_every_channel(tmp_path, capsys):
    log = _log(tmp_path / 'plate.mcap', load_scene('plate', PAPER))
    assert main(['plot', log, '--out', str(tmp_path)]) == 0
    lines = _summary_lines(capsys.readouterr().out)
    assert lines == (tmp_path / 'plate_summary.txt').read_text().splitlines()
    assert sum(line.startswith('voltage (V)') for line in lines) == 2
