"""
Test ``det_sim_replay`` and ``det_sim plot`` on files that are not good sim_node logs.

A non-MCAP file, an empty file, a torn log, a directory without logs, a log without a scene
and random bytes: one line on stderr, a non-zero exit code, never a traceback.
"""

import random
import subprocess
import sys

from conftest import child_env
from det_sim_ros.cli import main as det_sim
from det_sim_ros.cli import main_replay
from det_sim_ros.io.log import Recorder
from det_sim_ros.io.log.format import MAGIC
from det_sim_ros.io.replay import simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import pytest

SUBCOMMANDS = ('info', 'resim', 'play', 'recover')


def _good_log(path):
    scene = load_scene('default')
    sim = Simulator(scene)
    with Recorder(str(path), scene, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, {0: [2000.0]}, 300)
    return path


def _log_without_scene(path):
    from mcap.writer import Writer
    with open(path, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema('std_msgs/msg/String', 'ros2msg', b'string data')
        channel = writer.register_channel('/chatter', 'cdr', schema)
        writer.add_message(channel, 1, b'\x00\x01\x00\x00\x03\x00\x00\x00hi\x00', 1)
        writer.finish()
    return path


@pytest.fixture(scope='module')
def bad_files(tmp_path_factory):
    """Name -> path of every kind of bad input."""
    folder = tmp_path_factory.mktemp('bad')
    good = _good_log(folder / 'good.mcap').read_bytes()
    rng = random.Random(5)
    files = {
        'not_mcap': b'time,voltage\n0,2000\n',
        'empty': b'',
        'torn': good[:len(good) * 2 // 3],
        'torn_in_header': good[:40],
        'random': bytes(rng.randrange(256) for _ in range(4096)),
        'magic_then_random': MAGIC + bytes(rng.randrange(256) for _ in range(4096)),
    }
    paths = {}
    for name, data in files.items():
        paths[name] = folder / f'{name}.mcap'
        paths[name].write_bytes(data)
    paths['no_scene'] = _log_without_scene(folder / 'no_scene.mcap')
    paths['empty_dir'] = folder / 'no_logs'
    paths['empty_dir'].mkdir()
    (paths['empty_dir'] / 'notes.txt').write_text('no logs here\n')
    return {name: str(path) for name, path in paths.items()}


def _argv(subcommand, path, tmp_path):
    if subcommand == 'recover':
        return ['recover', path, str(tmp_path / 'out.mcap')]
    if subcommand == 'play':
        return ['play', path, '--rate', '0']
    return [subcommand, path]


def _one_line_error(capsys, prog):
    err = capsys.readouterr().err
    assert 'Traceback' not in err
    assert err.count('\n') == 1 and err.startswith(f'{prog}: error: '), err
    return err


@pytest.mark.parametrize('kind, message', [
    ('not_mcap', 'not an MCAP file'), ('empty', 'an empty file'),
    ('empty_dir', 'no MCAP files'), ('no_scene', 'not a sim_node log'),
    ('random', 'not an MCAP file'), ('magic_then_random', 'torn before the scene'),
    ('torn_in_header', 'torn before the scene')])
@pytest.mark.parametrize('subcommand', SUBCOMMANDS)
def test_unusable_files_give_one_line_and_exit_1(bad_files, tmp_path, capsys, subcommand,
                                                 kind, message):
    argv = _argv(subcommand, bad_files[kind], tmp_path)
    for run, prog in ((main_replay, 'det_sim_replay'),
                      (lambda a: det_sim(['replay'] + a), 'det_sim')):
        assert run(argv) == 1
        assert message in _one_line_error(capsys, prog)
    assert not (tmp_path / 'out.mcap').exists()


@pytest.mark.parametrize('subcommand', ['info', 'resim', 'play'])
def test_a_torn_log_is_named_with_the_way_to_recover_it(bad_files, tmp_path, capsys,
                                                        subcommand):
    assert main_replay(_argv(subcommand, bad_files['torn'], tmp_path)) == 1
    err = _one_line_error(capsys, 'det_sim_replay')
    assert 'torn' in err and 'det_sim_replay recover' in err


def test_info_of_a_torn_log_shows_its_readable_part(bad_files, tmp_path, capsys):
    assert main_replay(['info', bad_files['torn']]) == 1
    out = capsys.readouterr().out
    assert '/deflection' in out and 'unfinished' in out


def test_recover_writes_the_readable_part_of_a_torn_log(bad_files, tmp_path, capsys):
    fixed = tmp_path / 'fixed.mcap'
    assert main_replay(['recover', bad_files['torn'], str(fixed)]) == 0
    assert 'source was unfinished' in capsys.readouterr().out
    assert main_replay(['info', str(fixed)]) == 0


@pytest.mark.parametrize('kind', ['not_mcap', 'empty', 'empty_dir', 'no_scene', 'random',
                                  'magic_then_random', 'torn_in_header'])
def test_plot_of_an_unusable_file_is_one_line(bad_files, tmp_path, capsys, kind):
    assert det_sim(['plot', bad_files[kind], '--out', str(tmp_path)]) != 0
    _one_line_error(capsys, 'det_sim')


def test_no_traceback_on_random_cuts_and_bytes(bad_files, tmp_path, capsys):
    """Every cut of a good log, and flipped bytes, give an exit code and at most one line."""
    good = open(bad_files['torn'].replace('torn', 'good'), 'rb').read()
    rng = random.Random(11)
    path = tmp_path / 'damaged.mcap'
    for trial in range(24):
        data = bytearray(good[:rng.randrange(len(good))])
        if trial % 2 and data:
            for _ in range(8):
                data[rng.randrange(len(data))] = rng.randrange(256)
        path.write_bytes(bytes(data))
        for subcommand in ('info', 'resim', 'recover'):
            code = main_replay(_argv(subcommand, str(path), tmp_path))
            err = capsys.readouterr().err
            assert 'Traceback' not in err and err.count('\n') <= 1
            assert (code == 0) == (err == ''), (subcommand, trial, err)


@pytest.mark.ros
@pytest.mark.parametrize('kind', ['random', 'torn'])
def test_the_console_command_prints_one_line(bad_files, kind):
    """The command as a process: nothing on stderr but the one line (no library noise)."""
    done = subprocess.run([sys.executable, '-m', 'det_sim_ros.cli.replay', 'info',
                           bad_files[kind]], capture_output=True, text=True, env=child_env(),
                          timeout=120)
    assert done.returncode == 1
    assert done.stderr.count('\n') == 1 and done.stderr.startswith('det_sim_replay: error: ')
