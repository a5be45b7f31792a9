"""
Several runs in one log directory: each run apart, the files of a split run together.

Three runs are recorded offline into one directory as the node names them (the recorder's
public seam): a short one, one in another namespace with another Rs, and one split into
several files. ``det_sim plot DIR`` and ``det_sim view DIR`` take the newest run whole and say
so in one line; ``det_sim plot DIR --each-run`` plots every run apart, each its own PNG.
"""

import os
import re
import time

from conftest import ChildProcess
from det_sim_ros.cli.det_sim import main
from det_sim_ros.io import logplot
from det_sim_ros.io.log import log_runs, LogReader, Recorder
from det_sim_ros.io.replay import simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

PAPER = {'scene.fidelity': 'paper'}
STEPS = {'short': 200, 'other_rs': 300, 'split': 500}   # periods of 1 ms per run
SPLIT_S = 0.15      # s of log time per file of the split run: 4 files


def _record(folder, steps, overrides=None, namespace='/', split_s=0.0):
    scene = load_scene('default', {**PAPER, **(overrides or {})})
    sim = Simulator(scene)
    with Recorder(str(folder), scene, namespace=namespace, split_s=split_s,
                  metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, {0: [2000.0]}, steps)
        files = list(recorder.paths)
    time.sleep(0.01)   # (the next run starts later by the wall clock, as a run does)
    return files


@pytest.fixture(scope='module')
def log_dir(tmp_path_factory):
    """Record three runs into one log directory; return it and {run label: its files}."""
    folder = tmp_path_factory.mktemp('runs') / 'det_sim_logs'
    runs = {'short': _record(folder, STEPS['short'])}
    runs['other_rs'] = _record(folder, STEPS['other_rs'], {'physics.Rs': 1.0e3}, '/arm2')
    runs['split'] = _record(folder, STEPS['split'], split_s=SPLIT_S)
    assert len(runs['split']) == 4 and len(set(sum(runs.values(), []))) == 6
    return folder, runs


def test_a_directory_is_told_apart_into_its_runs(log_dir):
    folder, runs = log_dir
    found = log_runs(str(folder))
    assert [list(run.files) for run in found] == list(runs.values())   # oldest first, in order
    assert [run.name for run in found] == [os.path.basename(files[0])[:-5]
                                           for files in runs.values()]
    assert found[0].start_ns < found[1].start_ns < found[2].start_ns


def test_a_run_whose_first_file_was_deleted_stays_one_run(log_dir, tmp_path):
    """The directory's limit deletes the oldest files first: the rest of a run is one run."""
    folder, runs = log_dir
    kept = runs['split'][1:]
    for path in kept:
        os.link(path, tmp_path / os.path.basename(path))
    [run] = log_runs(str(tmp_path))
    assert [os.path.basename(p) for p in run.files] == [os.path.basename(p) for p in kept]


def _times(paths, topic='/displacement'):
    return [m.log_time for m in LogReader(paths).messages() if m.topic.endswith(topic)]


def test_plot_of_the_directory_is_the_newest_run_whole(log_dir, tmp_path, capsys):
    folder, runs = log_dir
    out = tmp_path / 'plots'
    assert main(['plot', str(folder), '--out', str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    newest = os.path.basename(runs['split'][0])[:-5]
    [note] = [line for line in printed if line.startswith('det_sim plot: the newest of')]
    assert f'the newest of 3 runs, {newest} (4 file(s))' in note and '--each-run' in note
    # the whole split run, and only it: its sim time, its files, time only going forward
    assert f'sim time 0 .. {STEPS["split"] * 1e-3:.6g} s' in '\n'.join(printed)
    data = logplot.read_log(runs['split'])
    summary = (out / f'{newest}_summary.txt').read_text()
    assert summary.splitlines()[0] == 'log: ' + ', '.join(runs['split'])
    q = next(c for c in data.channels if c.title == 'deflection q')
    assert len(q.t) == STEPS['split'] + 1 and np.all(np.diff(q.t) > 0)
    assert sorted(os.listdir(out)) == [f'{newest}.png', f'{newest}_summary.txt']


def test_plot_each_run_writes_one_png_per_run_and_overwrites_none(log_dir, tmp_path, capsys):
    folder, runs = log_dir
    out = tmp_path / 'plots'
    first = runs['short'][0]
    assert main(['plot', first, '--out', str(out)]) == 0     # one run's own PNG first
    name = os.path.basename(first)[:-5]
    png = (out / f'{name}.png').read_bytes()
    assert main(['plot', str(folder), '--out', str(out), '--each-run']) == 0
    printed = capsys.readouterr().out
    assert 'the newest of' not in printed
    names = [os.path.basename(files[0])[:-5] for files in runs.values()]
    assert sorted(os.listdir(out)) == sorted([f'{n}.png' for n in names]
                                             + [f'{n}_summary.txt' for n in names])
    assert (out / f'{name}.png').read_bytes() == png         # the same run drawn the same
    for label, files in runs.items():
        summary = (out / f'{os.path.basename(files[0])[:-5]}_summary.txt').read_text()
        assert summary.splitlines()[0] == 'log: ' + ', '.join(files)
        assert f'sim time 0 .. {STEPS[label] * 1e-3:.6g} s' in summary
    assert np.all(np.diff(_times(runs['split'])) > 0)


@pytest.mark.ros
def test_view_of_the_directory_serves_the_newest_run_and_its_duration(log_dir, tmp_path):
    """Check det_sim view's start lines: the run it took, its files and its real duration."""
    pytest.importorskip('foxglove')
    import sys
    folder, runs = log_dir
    view = ChildProcess([sys.executable, '-m', 'det_sim_ros.cli', 'view', str(folder),
                         '--port', '0'], tmp_path)
    try:
        line = view.wait_for('on ws://')
    finally:
        view.stop()
    newest = os.path.basename(runs['split'][0])[:-5]
    notes = [text for text in view.lines if text.startswith('det_sim view: the newest of')]
    assert len(notes) == 1 and f'the newest of 3 runs, {newest} (4 file(s))' in notes[0]
    messages = len(list(LogReader(runs['split']).messages()))
    match = re.search(r'(\d+) file\(s\), (\d+) messages, ([\d.]+) s of sim time', line)
    assert match and match.groups() == ('4', str(messages), f'{STEPS["split"] * 1e-3:.3f}')


def test_replay_of_the_directory_is_the_newest_run(log_dir, capsys):
    """Check that info and resim of a log directory take its newest run whole, said in a line."""
    from det_sim_ros.cli import main_replay
    folder, runs = log_dir
    newest = os.path.basename(runs['split'][0])[:-5]
    assert main_replay(['info', str(folder)]) == 0
    printed = capsys.readouterr().out.splitlines()
    [note] = [line for line in printed if line.startswith('det_sim replay info: the newest of')]
    assert f'the newest of 3 runs, {newest} (4 file(s))' in note
    assert printed[1] == 'files: ' + ', '.join(runs['split'])
    assert f'log time: 0.000000 .. {STEPS["split"] * 1e-3:.6f} s' in printed
    # re-simulated: the newest run's own scene and inputs reproduce it bit for bit
    assert main_replay(['resim', str(folder)]) == 0
    assert 'bit-exact' in capsys.readouterr().out


def _foreign_mcap(path):
    """Write a valid MCAP file of another program (no det_sim_ros metadata record)."""
    from mcap.writer import Writer
    with open(path, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='another program')
        schema = writer.register_schema('std_msgs/msg/String', 'ros2msg', b'string data')
        channel = writer.register_channel('/chatter', 'cdr', schema)
        writer.add_message(channel, 1, b'\x00\x01\x00\x00\x03\x00\x00\x00hi\x00', 1)
        writer.finish()


@pytest.fixture
def folder_with_foreign_files(log_dir, tmp_path):
    """Link the three runs' files, then write three files of no run, newer than them."""
    folder, runs = log_dir
    mixed = tmp_path / 'mixed'
    mixed.mkdir()
    for files in runs.values():
        for path in files:
            os.link(path, mixed / os.path.basename(path))
    time.sleep(0.01)
    (mixed / 'zz_notes.mcap').write_text('time,voltage\n0,2000\n')
    (mixed / 'zz_empty.mcap').write_bytes(b'')
    _foreign_mcap(mixed / 'zz_other_program.mcap')
    return mixed, runs


def test_files_of_no_run_are_named_and_never_the_newest(folder_with_foreign_files, tmp_path,
                                                        capsys):
    """
    Check that an empty, a non-MCAP and another program's MCAP file are in no run.

    They are the newest files of the folder by modification time; the newest run is still the
    recorder's, and plot and replay name the left-out files in one line each.
    """
    from det_sim_ros.cli import main_replay
    mixed, runs = folder_with_foreign_files
    found = log_runs(str(mixed))
    assert [os.path.basename(run.files[0]) for run in found] == [
        os.path.basename(files[0]) for files in runs.values()]
    assert {os.path.basename(path): why for path, why in found.unreadable} == {
        'zz_empty.mcap': 'empty', 'zz_notes.mcap': 'not an MCAP file',
        'zz_other_program.mcap': "no det_sim_ros metadata: another program's file"}
    newest = os.path.basename(runs['split'][0])[:-5]
    assert main(['plot', str(mixed), '--out', str(tmp_path / 'plots')]) == 0
    assert main_replay(['info', str(mixed)]) == 0
    printed = capsys.readouterr().out.splitlines()
    for verb in ('plot', 'replay info'):
        [left_out] = [line for line in printed
                      if line.startswith(f'det_sim {verb}: left out 3 file(s)')]
        assert all(f'zz_{name}.mcap' in left_out for name in ('empty', 'notes', 'other_program'))
        [note] = [line for line in printed if line.startswith(f'det_sim {verb}: the newest')]
        assert f'the newest of 3 runs, {newest} (4 file(s))' in note
    assert sorted(os.listdir(tmp_path / 'plots')) == [f'{newest}.png', f'{newest}_summary.txt']
