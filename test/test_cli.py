"""The det_sim console script: each subcommand on a small case (no ROS)."""

import csv
import io
import os
import subprocess
import sys
import types

from conftest import child_env
from det_sim_ros.cli import det_sim as cli
from det_sim_ros.cli.common import Progress
from det_sim_ros.physics import statics
from det_sim_ros.scenes.scene import load_scene, scene_to_dict
import numpy as np
import pytest
import yaml

# the statics and step verbs run the paper's one-term model (the paper's scenarios): the
# scenes these tests compare them with set it too
PAPER = {'scene.fidelity': 'paper'}


def read_csv(path):
    with open(path, newline='', encoding='utf-8') as stream:
        rows = list(csv.DictReader(stream))
    return rows


def has_matplotlib():
    try:
        import matplotlib  # noqa: F401
        return True
    except ImportError:
        return False


@pytest.fixture(scope='module')
def statics_out(tmp_path_factory):
    out = tmp_path_factory.mktemp('statics')
    code = cli.main(['statics', '--beams', 'fixed,simply_supported', '--eps-range', '0:0.3:13',
                     '--eps-b', '0.15,0.25', '--n-q', '41', '--out', str(out)])
    assert code == 0
    return out


def test_statics_files_and_columns(statics_out):
    names = ['statics_branches.csv', 'statics_potential.csv', 'statics_critical.csv']
    for name in names:
        assert (statics_out / name).is_file()
    branches = read_csv(statics_out / 'statics_branches.csv')
    assert list(branches[0]) == ['beam', 'voltage_V', 'eps_b', 'branch', 'q_m', 'y_m',
                                 'delta_y_m', 'stable', 'stiffness']
    pot = read_csv(statics_out / 'statics_potential.csv')
    assert list(pot[0]) == ['beam', 'voltage_V', 'eps_b', 'q_m', 'U_pot_J', 'U_pot_norm']
    un = np.array([float(r['U_pot_norm']) for r in pot])
    assert un.min() == 0.0 and un.max() == 1.0
    assert len(pot) == 2 * 2 * 2 * 41           # beams x pre-strains x voltages x points
    if has_matplotlib():
        for beam in ('fixed', 'simply_supported'):
            png = statics_out / f'statics_{beam}.png'
            assert png.is_file() and 0 < png.stat().st_size < 200_000


def test_statics_branches_are_symmetric_and_switch_where_statics_says(statics_out):
    branches = read_csv(statics_out / 'statics_branches.csv')
    crit = {(r['beam'], float(r['voltage_V'])): float(r['eps_b_min'])
            for r in read_csv(statics_out / 'statics_critical.csv')}
    assert set(crit) == {(b, v) for b in ('fixed', 'simply_supported') for v in (0.0, 3000.0)}
    for (beam, v), e_min in crit.items():
        scene = load_scene('default', {**PAPER, 'scene.beam': beam})
        assert e_min == pytest.approx(statics.critical_prestrain(scene, v), rel=1e-8)
        rows = [r for r in branches if r['beam'] == beam and float(r['voltage_V']) == v]
        for r in rows:
            if r['branch'] == 'straight':
                assert float(r['q_m']) == 0.0
                assert (r['stable'] == '1') == (float(r['eps_b']) < e_min)
        plus = {r['eps_b']: r for r in rows if r['branch'] == 'buckled+'}
        minus = {r['eps_b']: r for r in rows if r['branch'] == 'buckled-'}
        assert set(plus) == set(minus) == {r['eps_b'] for r in rows
                                           if r['branch'] == 'straight'
                                           and float(r['eps_b']) > e_min}
        for e, r in plus.items():
            assert float(minus[e]['q_m']) == pytest.approx(-float(r['q_m']), rel=1e-9)
            assert float(r['q_m']) > 0 and r['stable'] == '1'
            assert float(minus[e]['y_m']) == pytest.approx(float(r['y_m']), rel=1e-9)
            dy = float(r['delta_y_m'])
            assert dy == pytest.approx(0.0, abs=1e-12) if v == 0.0 else dy > 0
    assert crit['fixed', 0.0] > crit['simply_supported', 0.0]


@pytest.fixture(scope='module')
def step_out(tmp_path_factory):
    out = tmp_path_factory.mktemp('step')
    code = cli.main(['step', '--beams', 'fixed,simply_supported', '--eps-b', '0.20,0.25',
                     '--t-end', '3.0', '--out', str(out)])
    assert code == 0
    return out


def test_step_files_and_columns(step_out):
    rows = read_csv(step_out / 'step.csv')
    assert list(rows[0]) == ['beam', 'eps_b', 't_s', 'v_V', 'q_m', 'y_m', 'delta_y_m', 'eps_y']
    assert len(rows) == 4 * 3001
    run = [r for r in rows if r['beam'] == 'fixed' and float(r['eps_b']) == 0.2]
    t = np.array([float(r['t_s']) for r in run])
    v = np.array([float(r['v_V']) for r in run])
    dy = np.array([float(r['delta_y_m']) for r in run])
    assert np.all(v[t < 1.5 - 1e-9] == 0.0) and np.all(v[(t > 1.5 + 1e-9) & (t < 3.0)] == 3000.0)
    i0 = int(np.searchsorted(t, 1.5 - 1e-9))
    assert dy[i0] == 0.0                                     # y0 = y at the end of the 0 V phase
    # the rest state before the step is the statics' stable buckled state
    y0 = float(run[i0]['y_m'])
    scene = load_scene('default', {**PAPER, 'scene.beam': 'fixed', 'scene.eps_b': 0.2})
    assert y0 == pytest.approx(statics.rest_shortening(scene), rel=2e-3)
    if has_matplotlib():
        png = step_out / 'step.png'
        assert png.is_file() and 0 < png.stat().st_size < 200_000


def test_step_paper_comparison(step_out):
    comp = {(r['beam'], float(r['eps_b'])): r
            for r in read_csv(step_out / 'paper_comparison.csv')}
    assert list(next(iter(comp.values()))) == [
        'beam', 'eps_b', 'switched', 'switched_paper', 'eps_y_percent', 'eps_y_paper_percent',
        'q_before_m', 'q_end_of_vmax_m', 'q_final_m']
    for beam in ('fixed', 'simply_supported'):
        assert comp[beam, 0.2]['switched'] == comp[beam, 0.2]['switched_paper'] == 'yes'
        assert comp[beam, 0.25]['switched'] == comp[beam, 0.25]['switched_paper'] == 'no'
        for eps in (0.2, 0.25):
            assert 5.0 < float(comp[beam, eps]['eps_y_percent']) < 10.0
    # the fixed beam gives the larger actuation strain (paper: ~8 % vs ~6.5 %)
    assert (float(comp['fixed', 0.2]['eps_y_percent'])
            > float(comp['simply_supported', 0.2]['eps_y_percent']))
    md = (step_out / 'paper_comparison.md').read_text()
    assert md.startswith('| beam | eps_b |') and md.count('\n') == 2 + 4


def test_without_matplotlib_csv_is_still_written(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, 'matplotlib', None)      # import matplotlib -> ImportError
    code = cli.main(['statics', '--eps-range', '0.1:0.2:3', '--eps-b', '0.2', '--n-q', '11',
                     '--out', str(tmp_path)])
    assert code == 0
    assert (tmp_path / 'statics_branches.csv').is_file()
    assert not list(tmp_path.glob('*.png'))
    err = capsys.readouterr().err
    assert 'matplotlib is not installed' in err and 'det_sim_ros[plots]' in err


def test_scene_file_and_set_overrides(tmp_path, capsys):
    scene = load_scene('default', {**PAPER, 'scene.beam': 'simply_supported'})
    path = tmp_path / 'my_scene.yaml'
    path.write_text(yaml.safe_dump(scene_to_dict(scene, wrap=True)))
    out = tmp_path / 'out'
    code = cli.main(['statics', '--scene', str(path), '--set', 'physics.t_b=3e-4',
                     '--set', 'physics.Rs=1e3', '--eps-range', '0.1:0.2:3', '--eps-b', '0.2',
                     '--n-q', '11', '--no-plots', '--out', str(out)])
    assert code == 0
    crit = read_csv(out / 'statics_critical.csv')
    assert {r['beam'] for r in crit} == {'simply_supported'}      # the scene's beam
    expected = statics.critical_prestrain(scene.replace(**{'physics.t_b': 3e-4,
                                                           'physics.Rs': 1e3}), 0.0)
    assert float(crit[0]['eps_b_min']) == pytest.approx(expected, rel=1e-8)
    assert float(crit[0]['eps_b_min']) > 0.04       # thicker beams buckle later than 3.5 %
    assert 'wrote' in capsys.readouterr().out


@pytest.mark.parametrize('argv, fragment', [
    ([], 'choose a subcommand'),
    (['statics', '--set', 'physics.Rs'], 'key=value'),
    (['statics', '--eps-range', '0:0.3'], 'START:STOP:N'),
    (['statics', '--eps-range', '0.3:0:5'], 'STOP > START'),
    (['step', '--beams', 'hinged'], 'unknown beam'),
    (['step', '--t-end', '-1'], 'must be > 0'),
    (['step', '--eps-b', '0.2,abc'], 'comma-separated'),
    (['statics', '--set', 'physics.Rs=-5'], "'physics.Rs'"),
    (['statics', '--set', 'physics.colour=3'], 'unknown scene key'),
    (['step', '--scene', 'no_such_scene'], 'not found'),
    (['frobnicate'], 'invalid choice'),
])
def test_bad_arguments_exit_2_with_one_line(argv, fragment, tmp_path, capsys):
    code = cli.main(argv + ['--out', str(tmp_path)] if argv and argv[0] != 'frobnicate'
                    else argv)
    assert code == 2
    err = capsys.readouterr().err
    assert fragment in err
    assert 'Traceback' not in err
    assert err.strip().splitlines()[-1].startswith('det_sim')


def test_help_exits_0_and_lists_every_verb(capsys):
    assert cli.main(['--help']) == 0
    text = capsys.readouterr().out
    for verb in ('statics', 'step', 'bench', 'plot', 'linearize', 'fleet', 'replay'):
        assert f'    {verb} ' in text


def test_bench_missing_module(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, 'sympy', types.ModuleType('sympy'))
    monkeypatch.setitem(sys.modules, 'det_sim_ros.analysis.benchmark', None)
    assert cli.main(['bench']) == 1
    err = capsys.readouterr().err
    assert 'not available' in err and len(err.strip().splitlines()) == 1


def test_bench_without_sympy_says_which_extra_in_one_line(monkeypatch, capsys):
    """
    Check that a missing sympy is reported, with its extra, before anything runs.

    The check comes first because the benchmark needs sympy minutes into its run.
    """
    ran = []
    fake = types.ModuleType('det_sim_ros.analysis.benchmark')
    fake.run = lambda *a, **k: ran.append(a) or iter(())
    monkeypatch.setitem(sys.modules, 'det_sim_ros.analysis.benchmark', fake)
    monkeypatch.setitem(sys.modules, 'sympy', None)            # import sympy -> ImportError
    assert cli.main(['bench', '--quick']) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err
    assert 'sympy' in err and 'det_sim_ros[bench]' in err
    assert not ran


def _fake_benchmark(monkeypatch, tmp_path):
    seen = {}
    fake = types.ModuleType('det_sim_ros.analysis.benchmark')
    row = {'beam': 'fixed', 'eps_b': 0.2, 'solver': 'auto', 'setting': 'tol 1e-06',
           'cpu_per_sim_s': 0.01, 'err_dy': 1e-6, 'err_qp': 1e-6, 'realtime_factor': 100.0,
           'steps_per_period': 1.0}

    def run(beams, eps_values, quick, repeats, reference_dir=None, log=print):
        seen.update(beams=beams, eps=eps_values, quick=quick, repeats=repeats)
        yield [row]

    fake.run = run
    fake.write_tables = lambda rows, out, command: seen.setdefault('written', (rows, out, command))
    monkeypatch.setitem(sys.modules, 'sympy', types.ModuleType('sympy'))
    monkeypatch.setitem(sys.modules, 'det_sim_ros.analysis.benchmark', fake)
    import det_sim_ros.analysis
    monkeypatch.setattr(det_sim_ros.analysis, 'benchmark', fake, raising=False)
    return seen


def test_bench_arguments_reach_the_benchmark(monkeypatch, tmp_path, capsys):
    seen = _fake_benchmark(monkeypatch, tmp_path)
    out = str(tmp_path / 'wp')
    assert cli.main(['bench', '--quick', '--out', out, '--beams', 'simply_supported,fixed',
                     '--repeats', '2']) == 0
    assert seen['beams'] == ['simply_supported'] and seen['eps'] == [0.20]
    assert seen['quick'] and seen['repeats'] == 2 and seen['written'][1] == out
    assert 'wrote' in capsys.readouterr().out
    if has_matplotlib():
        assert (tmp_path / 'wp' / 'work_precision.png').is_file()
    seen.clear()
    assert cli.main(['bench', '--eps-b', '0.15,0.25', '--out', out, '--no-such-option']) == 2
    assert not seen and 'unrecognized arguments' in capsys.readouterr().err
    assert cli.main(['bench', '--beams', 'hinged', '--out', out]) == 2
    assert 'unknown beam' in capsys.readouterr().err


@pytest.mark.ros   # git runs in a process (the commit)
def test_bench_page_opens_with_its_date_commit_machine_and_command(monkeypatch, tmp_path):
    """
    Check that the page det_sim bench writes opens with its date, commit, machine and command.

    The real page writer on a one-row run (the benchmark itself takes an hour): the date is
    today's (UTC), the commit one this checkout's git knows ('unknown' outside a checkout),
    and the command, parsed again, asks for the same run.
    """
    from datetime import datetime, timezone
    import re
    import shlex
    from det_sim_ros.analysis import benchmark
    row = {'beam': 'fixed', 'eps_b': 0.2, 'solver': 'auto', 'setting': 'tol 1e-06',
           'cpu_per_sim_s': 0.01, 'err_dy': 1e-6, 'err_qp': 1e-6, 'realtime_factor': 100.0,
           'steps_per_period': 1.0}
    monkeypatch.setattr(benchmark, 'run', lambda *args, **kwargs: iter([[row]]))
    monkeypatch.setitem(sys.modules, 'sympy', types.ModuleType('sympy'))
    out = str(tmp_path / 'wp')
    argv = ['bench', '--quick', '--out', out, '--eps-b', '0.15,0.2', '--repeats', '2']
    days = {datetime.now(timezone.utc).strftime('%Y-%m-%d')}
    assert cli.main(argv) == 0
    days.add(datetime.now(timezone.utc).strftime('%Y-%m-%d'))
    with open(os.path.join(out, 'work_precision.md'), encoding='utf-8') as f:
        first, blank, header = f.read().splitlines()[:3]
    found = re.fullmatch(r'Measured (\S+), commit (\S+), (\d+)-core (\S+), by `([^`]+)` .*', first)
    assert found, first
    day, commit, cores, _, command = found.groups()
    assert day in days and int(cores) == os.cpu_count()
    assert blank == '' and header.startswith('| beam |')
    # the package's own tree: a source checkout names its commit, an installed copy (CI's
    # `pip install .`, whose site-packages may sit inside some other repository) says 'unknown'
    import det_sim_ros
    source = os.path.dirname(os.path.dirname(os.path.abspath(det_sim_ros.__file__)))
    top = subprocess.run(['git', '-C', source, 'rev-parse', '--show-toplevel'],
                         capture_output=True, text=True)
    in_checkout = (top.returncode == 0
                   and os.path.realpath(top.stdout.strip()) == os.path.realpath(source))
    if in_checkout:
        known = subprocess.run(['git', '-C', source, 'rev-parse', '--verify', '--quiet',
                                commit.removesuffix('-dirty') + '^{commit}'], capture_output=True)
        assert known.returncode == 0, commit
    else:
        assert commit == 'unknown'
    words = shlex.split(command)
    assert words[0] == 'det_sim'
    again, asked = (cli.build_parser().parse_args(a) for a in (words[1:], argv))
    assert vars(again) == vars(asked)


def test_bench_help_lists_its_options(capsys):
    assert cli.main(['bench', '--help']) == 0
    text = capsys.readouterr().out
    assert '--quick' in text and '--reference-dir' in text and 'det_sim_ros[bench]' in text


def test_progress_bar_only_after_delay():
    quiet = io.StringIO()
    bar = Progress(10, 'sweep', stream=quiet, delay=3600.0)
    for k in range(10):
        bar.advance()
    bar.close()
    assert quiet.getvalue() == ''
    loud = io.StringIO()
    bar = Progress(4, 'sweep', stream=loud, delay=0.0)
    for k in range(4):
        bar.advance()
    bar.close()
    text = loud.getvalue()
    assert 'sweep [' in text and '4/4' in text and text.endswith('\n')


def test_module_entry_point_runs():
    assert os.path.isfile(cli.__file__)
    assert callable(cli.main)


@pytest.mark.parametrize('error, code, line', [
    (KeyboardInterrupt(), 130, 'det_sim: interrupted'),
    (RuntimeError('boom'), 1, 'det_sim: error: RuntimeError: boom'),
    (OSError('disk full'), 1, 'det_sim: error: disk full'),
])
def test_any_error_of_a_verb_is_one_line(monkeypatch, capsys, error, code, line):
    from det_sim_ros.cli.verbs import fleet

    def fail(args):
        raise error
    monkeypatch.setattr(fleet, 'main', fail)
    monkeypatch.delenv('DET_SIM_TRACEBACK', raising=False)
    assert cli.main(['fleet', 'any.yaml']) == code
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith(line)
    monkeypatch.setenv('DET_SIM_TRACEBACK', '1')        # the developer's way to the traceback
    if isinstance(error, RuntimeError):
        with pytest.raises(RuntimeError):
            cli.main(['fleet', 'any.yaml'])


def test_the_paper_verbs_run_the_paper_model_unless_a_fidelity_is_set():
    """Check `det_sim statics` and `step` take the paper's level unless --set names one."""
    import argparse
    from det_sim_ros.cli import common
    args = argparse.Namespace(scene='default', overrides=[('scene.eps_b', 0.15)])
    scene = common.paper_level(common.base_scene(args), args)
    assert (scene.fidelity, scene.n_ritz, scene.eps_b) == ('paper', 1, 0.15)
    args.overrides.append(('scene.fidelity', 'exact'))
    scene = common.paper_level(common.base_scene(args), args)
    assert (scene.fidelity, scene.n_ritz) == ('exact', 0)    # the shipped default's: auto


@pytest.mark.ros
def test_verbs_asked_for_no_plot_do_not_import_matplotlib(tmp_path):
    """
    Check that statics, step, linearize and fit with --no-plots never import matplotlib.

    matplotlib's first import on a fresh machine builds its font cache (a process, seconds): a
    verb that draws nothing must not pay for it, nor fail where matplotlib cannot start.
    """
    code = '\n'.join([
        'import contextlib, io, sys',
        'import numpy as np',
        'from det_sim_ros.calibration.synthetic import step_and_sine, synthetic_measurement',
        'from det_sim_ros.cli.det_sim import main',
        'from det_sim_ros.scenes.scene import load_scene',
        'truth = load_scene("default", {"physics.Y": 1.2e6})',
        'data = synthetic_measurement(truth, step_and_sine(0.2, truth.dt), noise=0.01, seed=7,',
        '                             channels=("dy",))',
        'volts = np.append(data.volts[:, 0], data.volts[-1, 0])',
        'rows = [f"{k * data.dt:.6f},{v!r},{d!r}" for k, (v, d)',
        '        in enumerate(zip(volts.tolist(), data.channels["dy"].values[:, 0].tolist()))]',
        f'csv = {str(tmp_path / "rig.csv")!r}',
        'open(csv, "w").write("t (s),v (V),dy (m)\\n" + "\\n".join(rows) + "\\n")',
        f'out = {str(tmp_path)!r}',
        'runs = {',
        '    "statics": ["statics", "--eps-range", "0.1:0.2:3", "--eps-b", "0.2", "--n-q", "11"],',
        '    "step": ["step", "--eps-b", "0.2", "--t-end", "0.05"],',
        '    "linearize": ["linearize", "--voltage", "1500"],',
        '    "fit": ["fit", csv, "--params", "Y", "--quiet", "--starts", "1",',
        '            "--parallel", "serial", "-o", out + "/fitted.yaml"],',
        '}',
        'for verb, argv in runs.items():',
        '    extra = [] if verb == "fit" else ["--out", out]',
        '    with contextlib.redirect_stdout(io.StringIO()):',
        '        assert main(argv + extra + ["--no-plots"]) == 0, verb',
        '    loaded = [m for m in sys.modules if m.split(".")[0] == "matplotlib"]',
        '    assert not loaded, f"{verb} --no-plots imported {loaded[:3]}"',
        'print("ok")'])
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          env=child_env(), timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == 'ok', proc.stdout + proc.stderr
