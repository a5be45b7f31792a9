"""
The ``ros`` mark is checked: ``pytest -m "not ros"`` cannot silently start rclpy or a process.

Each check runs pytest in a child process on a small test file beside a copy of this folder's
conftest.py, so what is checked is the conftest the suite runs under.
"""

import os
import shutil
import subprocess
import sys

from conftest import child_env
import pytest

pytestmark = pytest.mark.ros

HERE = os.path.dirname(os.path.abspath(__file__))


def _pytest(tmp_path, source):
    shutil.copy(os.path.join(HERE, 'conftest.py'), tmp_path / 'conftest.py')
    (tmp_path / 'test_sample.py').write_text(source)
    return subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                           str(tmp_path / 'test_sample.py')], cwd=tmp_path, env=child_env(),
                          capture_output=True, text=True, timeout=120)


def test_a_ros_fixture_without_the_mark_is_refused_at_collection(tmp_path):
    run = _pytest(tmp_path, 'def test_unmarked(ros_context):\n    pass\n')
    assert run.returncode == pytest.ExitCode.USAGE_ERROR, run.stdout + run.stderr
    assert 'test_sample.py::test_unmarked' in run.stderr and 'without the ros mark' in run.stderr


def test_rclpy_or_a_process_without_the_mark_fails_and_with_it_runs(tmp_path):
    run = _pytest(tmp_path, '\n'.join([
        'import subprocess, sys',
        'import pytest',
        'from rclpy.context import Context',
        'def test_process():',
        '    subprocess.run([sys.executable, "-c", "pass"], check=True)',
        'def test_rclpy():',
        '    Context().init()',
        '@pytest.mark.ros',
        'def test_marked_process():',
        '    subprocess.run([sys.executable, "-c", "pass"], check=True)',
        'def test_plain():',
        '    pass', '']))
    assert '2 failed, 2 passed' in run.stdout, run.stdout + run.stderr
    assert 'test_process starts a process' in run.stdout
    assert 'test_rclpy initialises rclpy' in run.stdout


def test_a_test_that_draws_passes_on_a_fresh_machine(tmp_path):
    """
    Check that an unmarked test that draws text passes with empty per-user caches.

    matplotlib lists the fonts with a process on its first drawing after a fresh install; the
    guard must not take that for the test's own process.
    """
    pytest.importorskip('matplotlib')
    caches = {name: str(tmp_path / name) for name in ('MPLCONFIGDIR', 'XDG_CACHE_HOME')}
    for folder in caches.values():
        os.mkdir(folder)
    shutil.copy(os.path.join(HERE, 'conftest.py'), tmp_path / 'conftest.py')
    (tmp_path / 'test_sample.py').write_text('\n'.join([
        'def test_draw(tmp_path):',
        '    import matplotlib',       # on first use, as a verb the test calls imports it
        '    matplotlib.use("Agg")',
        '    import matplotlib.pyplot as plt',
        '    fig, ax = plt.subplots()',
        '    ax.set_title("a title")',
        '    fig.savefig(tmp_path / "a.png")', '']))
    run = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                          str(tmp_path / 'test_sample.py')], cwd=tmp_path,
                         env=child_env(**caches), capture_output=True, text=True, timeout=120)
    assert '1 passed' in run.stdout, run.stdout + run.stderr
    assert os.listdir(caches['MPLCONFIGDIR']), 'matplotlib kept no font cache in MPLCONFIGDIR'
